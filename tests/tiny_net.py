"""CLI options of a network small enough to train for a few steps in seconds (shared by tests)."""

TINY_NET: list[str] = [
    *("--input-size", "64", "64", "--layout-size", "16"),
    *("--encoder-width", "8", "--hidden", "16", "--decoder-width", "8"),
    *("--threads", "1", "--quiet"),
]


def lift_row_head(path, bias: float = 2.0) -> None:
    """Make a barely trained checkpoint's row head find boards, so its (noisy) slots decode to content.

    An untrained row head starts at a low board probability everywhere (no slots, empty layouts);
    tests of the plumbing after the network want layouts with shelves and boxes in them.
    """
    from network.checkpoint import load_checkpoint, save_checkpoint

    payload, record = load_checkpoint(path)
    state = dict(payload["model"])
    last = max(
        (k for k in state if k.startswith("rows.net.") and k.endswith(".bias")), key=lambda k: int(k.split(".")[2])
    )
    state[last] = state[last].clone().fill_(bias)
    payload["model"] = state
    payload.pop("record_json", None)
    record = {k: v for k, v in record.items() if k not in ("format", "format_version")}
    save_checkpoint(path, payload, record)

"""CLI options of a network small enough to train for a few steps in seconds (shared by tests)."""

TINY_NET: list[str] = [
    *("--input-size", "64", "64", "--layout-size", "16"),
    *("--encoder-width", "8", "--hidden", "16", "--decoder-width", "8"),
    *("--threads", "1", "--quiet"),
]


def tiny_config(spec, variant: str = "mvracklay-disc-4", **options):
    """The `ModelConfig` of `TINY_NET` for ``spec`` (64x64 input), with model ``options`` (e.g. ``parallax``)."""
    from network.model.config import ModelConfig

    return ModelConfig(
        variant=variant,
        input_width=64,
        input_height=64,
        spec=spec,
        encoder_width=8,
        hidden=16,
        decoder_width=8,
        **options,
    )


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


def cached_and_naive_windows(model, spec, num_frames: int = 6):
    """A model's windowed predictions over a toy sequence, cached and re-encoded (``recompute=True``).

    Lifts the row head's bias first (as `lift_row_head` does for a checkpoint) so slots decode.
    Returns ``(predictor, frames, cached, naive)``.
    """
    import torch

    from network.inference.predictor import Predictor
    from network.training.toy import ToySequence

    torch.nn.init.constant_(model.rows.net[-1].bias, 2.0)
    seq = ToySequence(spec, num_frames=num_frames, image_size=(64, 64))
    frames = [seq.rgb(i) for i in range(num_frames)]
    pred = Predictor(model, fuse_tau=0)  # each frame's own outputs (network.inference.fusion aside)
    return pred, frames, list(pred.window(frames)), list(pred.window(frames, recompute=True))


def fixed_steps(step: float):
    """A stand-in for `network.model.motion.StepReader` (patched into the predictor): ``step`` metres for every
    frame after the first (0 for the first), confidence 1."""
    import torch

    class FixedSteps:
        def __init__(self, view) -> None:
            self.seen = 0

        def __call__(self, sig):
            self.seen += 1
            return torch.tensor([step if self.seen > 1 else 0.0]), torch.ones(1)

    return FixedSteps

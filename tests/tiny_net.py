"""CLI options of a network small enough to train for a few steps in seconds (shared by tests)."""

TINY_NET: list[str] = [
    *("--input-size", "64", "64", "--layout-size", "16"),
    *("--encoder-width", "8", "--hidden", "16", "--decoder-width", "8"),
    *("--threads", "1", "--quiet"),
]

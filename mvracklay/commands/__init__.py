"""CLI sub-commands. Each module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` (or ``SETTINGS``, the
settings dataclass its options are made from) and ``run(args) -> int``; `mvracklay.cli` discovers them, so adding
a command touches one file."""

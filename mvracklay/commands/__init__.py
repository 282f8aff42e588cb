"""CLI sub-commands. Each module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``; `mvracklay.cli` discovers them, so adding a command touches one file."""

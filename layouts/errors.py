"""Error types for bad input, raised with a one-line message naming the culprit.

Every component raises a subclass of `InputError` for bad user input (files, arguments,
configs); the CLI prints its message as one line and exits non-zero.
"""


class InputError(ValueError):
    """Bad user input: the message names the file/argument and the problem, on one line."""


class LayoutError(InputError):
    """Bad layout data, spec or file."""

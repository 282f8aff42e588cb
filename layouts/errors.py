"""Error types for bad input, raised with a one-line message naming the culprit.

Every component raises a subclass of `InputError` for bad user input (files, arguments,
configs); the CLI prints its message as one line and exits non-zero. `ContractError` is the
other kind: data the code built breaks the schema its own readers check (a defect, never bad input).
"""


class InputError(ValueError):
    """Bad user input: the message names the file/argument and the problem, on one line."""


class LayoutError(InputError):
    """Bad layout data, spec or file."""


class ContractError(AssertionError):
    """A defect: something built here breaks its declared schema; raised before it is published, naming the
    element (an `AssertionError`, so no handler of bad input turns it into a user's mistake)."""


def first_problem(errors: list[dict]) -> str:
    """The first entry of a schema validator's error list (pydantic's ``ValidationError.errors()``: dicts with
    ``loc``, ``msg``, ``type``, ``input``) as one line, ``racks[0].shelves[1].yaw: what is wrong (got ...)``."""
    err = errors[0]
    loc = ""
    for part in err.get("loc", ()):
        loc += f"[{part}]" if isinstance(part, int) else (f".{part}" if loc else str(part))
    msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
    got = err.get("input")
    quiet = err.get("type") in ("value_error", "missing") or isinstance(got, (dict, list))
    tail = "" if quiet else f" (got {got!r})"[:80]
    return f"{loc}: {msg}{tail}" if loc else f"{msg}{tail}"

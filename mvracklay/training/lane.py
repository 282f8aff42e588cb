"""One lane of a group of side-by-side stages, in a process of its own: ``python -m mvracklay.training.lane
SPEC.json`` runs the stages the runner wrote into SPEC in order (on the settings their values give,
`mvracklay.training.stages.stage_settings`), each's output (and progress) into its log,
and records each in the run's state file as it finishes. The process ends with the runner's (Linux)."""

from __future__ import annotations

import contextlib
import ctypes
import json
import signal
import sys
import time
from pathlib import Path

from layouts.errors import InputError
from mvracklay.training.plan import shell_line
from mvracklay.training.stages import run_settings, stage_settings
from mvracklay.training.state import State


def _die_with_parent() -> None:
    """Ask Linux to kill this process when the runner that started it dies (a ``kill -9`` of the runner)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def main(argv: list[str]) -> int:
    _die_with_parent()
    spec = json.loads(Path(argv[0]).read_text())
    state = State(Path(spec["out"]))
    for st in spec["steps"]:
        if state.finished(st["id"]) is not None:
            continue
        log = Path(st["log"])
        log.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.monotonic()
        with open(log, "w" if st["fresh"] else "a") as f:
            if not st["fresh"]:
                f.write(f"== {time.strftime('%Y-%m-%d %H:%M:%S')} {shell_line(st['name'], st['argv'])}\n")
                f.flush()
            try:
                with contextlib.redirect_stdout(f), contextlib.redirect_stderr(f):
                    rc = run_settings(st["name"], stage_settings(st["name"], st["options"], st["args"]))
            except InputError as e:
                print(f"stage {st['name']} ({st['id']}): {e}", file=sys.stderr)
                return 2
        if rc:
            print(f"stage {st['name']} ({st['id']}) ended with status {rc}; see {log}", file=sys.stderr)
            return rc
        state.mark(st["id"], st["name"], (time.monotonic() - t0) / 60, st["argv"], st["outputs"])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

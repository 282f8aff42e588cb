"""The state file of a recipe's run folder: which stages (and groups of side-by-side stages) finished, with
their wall minutes and arguments. Every update is read, changed and replaced whole (atomically, under a
lock, as the lanes of a group finish in processes of their own), so a ``kill -9`` leaves either the old
file or the new one; a re-run of the same command skips what it records."""

from __future__ import annotations

import fcntl
import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from layouts.fileio import atomic_write_json

STATE_NAME = "recipe-state.json"


class State:
    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.path = self.out / STATE_NAME

    def read(self) -> dict[str, Any]:
        if not self.path.is_file():
            return {"finished": {}, "groups": {}}
        try:
            data = json.loads(self.path.read_text())
        except ValueError as e:
            raise InputError(f"{self.path}: not JSON ({e}); remove it to run every stage again") from None
        data.setdefault("finished", {})
        data.setdefault("groups", {})
        return data

    @contextmanager
    def _locked(self) -> Iterator[dict[str, Any]]:
        self.out.mkdir(parents=True, exist_ok=True)
        with open(self.out / f".{STATE_NAME}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            data = self.read()
            yield data
            atomic_write_json(self.path, data, fsync=True)

    def begin(self, recipe: str, overrides: list[str]) -> None:
        """Note the recipe and overrides this folder runs (a later run with others is told so)."""
        with self._locked() as data:
            data["recipe"], data["overrides"] = recipe, overrides

    def finished(self, key: str) -> dict[str, Any] | None:
        return self.read()["finished"].get(key)

    def mark(self, key: str, stage: str, minutes: float, argv: list[str], outputs: list[str]) -> None:
        with self._locked() as data:
            data["finished"][key] = {
                "stage": stage,
                "minutes": round(minutes, 4),
                "argv": argv,
                "outputs": outputs,
                "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S"),
            }

    def mark_group(self, group: str, minutes: float) -> None:
        with self._locked() as data:
            data["groups"][group] = round(minutes, 4)

    def wall_minutes(self) -> dict[str, float]:
        """Recorded wall minutes by stage id and group name."""
        data = self.read()
        return {**{k: v["minutes"] for k, v in data["finished"].items()}, **data["groups"]}

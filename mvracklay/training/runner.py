"""``mvracklay train --recipe``: run a recipe's data and stages in order, resumably, with one progress display.

Each stage prints a line ``[3/9] fit-back-edges (id) ...`` with its own progress bar under it; its
printed output goes to its log (RUNS/logs/ID.log unless the recipe names one). Stages of one ``group``
run side by side, each ``lane`` in a process of its own. A state file in RUNS records every stage
finished (`mvracklay.training.state`), so the same command run again, after a ``kill -9`` too, goes on
at the stage it reached; a training stage always runs with ``--resume`` and continues from its last.pt.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from layouts.errors import InputError
from mvracklay.training import budget as budget_mod
from mvracklay.training.plan import Step, check_steps, describe_recipe, generate_argv, shell_line, stage_step
from mvracklay.training.recipe import Context, find_recipe, load_recipe
from mvracklay.training.stages import call_stage, run_settings
from mvracklay.training.state import State

#: a test hook: the runner kills itself (SIGKILL, as ``kill -9`` would) once stage K of this run is recorded
KILL_AFTER_ENV = "MVRACKLAY_RECIPE_KILL_AFTER"
INDENT = "      "


@dataclass
class Row:
    number: int
    name: str
    id: str
    status: str
    minutes: float | None = None
    outputs: list[str] = field(default_factory=list)


def default_run_folder(recipe_arg: str) -> Path:
    """A recipe's run folder when ``--out`` is not given: ``$XDG_CACHE_HOME/mvracklay/train/NAME`` (else
    ``~/.cache/...``), outside any work tree, so a later start on the same machine goes on where it stopped."""
    from layouts.fileio import user_cache_dir

    folder = user_cache_dir("train", find_recipe(recipe_arg).stem)
    if folder is None:
        raise InputError(f"--recipe {recipe_arg}: no home folder to keep the run in; give --out RUN")
    return folder


def run_recipe(recipe_arg: str, out: Path, overrides: list[str], dry_run: bool = False, quiet: bool = False) -> int:
    """Load, check and run (or with ``dry_run`` only print) a recipe into the run folder ``out``."""
    from network.precision import auto_precision  # torch: imported when a recipe runs

    recipe = load_recipe(recipe_arg, overrides)
    precision = auto_precision() if recipe.precision == "auto" else recipe.precision
    ctx = Context(recipe, out, precision)
    steps = check_steps(ctx, out, quiet)
    runner = Runner(ctx, out, steps, quiet, overrides)
    if dry_run:
        runner.print_plan()
        return 0
    runner.run()
    return 0


class Runner:
    def __init__(self, ctx: Context, out: Path, steps: list[Step], quiet: bool, overrides: list[str]) -> None:
        self.ctx, self.out, self.steps, self.quiet = ctx, out, steps, quiet
        self.recipe = ctx.recipe
        self.overrides = overrides
        self.state = State(out)
        self.first = 2 if self.recipe.data else 1  # the data come first, as stage 1
        self.count = len(steps) + self.first - 1
        self.rows: list[Row] = []
        self.tty: TextIO = sys.stdout
        kill = os.environ.get(KILL_AFTER_ENV, "")
        self.kill_after = int(kill) if kill.isdigit() else None

    def say(self, text: str) -> None:
        print(text, file=self.tty, flush=True)

    def units(self) -> list[list[tuple[int, Step]]]:
        """The stages numbered, consecutive stages of one group together."""
        out: list[list[tuple[int, Step]]] = []
        for n, step in enumerate(self.steps, self.first):
            g = step.stage.group
            if g and out and out[-1][0][1].stage.group == g:
                out[-1].append((n, step))
            else:
                out.append([(n, step)])
        return out

    # -- the plan --------------------------------------------------------------------------------------

    def header(self) -> None:
        p = self.ctx.values["precision"]
        self.say(f"recipe {self.recipe.name} ({self.recipe.path}): {describe_recipe(self.recipe)}")
        self.say(f"{self.count} stages into {self.out}, precision {p}")

    def print_plan(self) -> None:
        """Every stage with its arguments (``--dry-run``); a finished one is marked so."""
        self.header()
        done = self.state.read()["finished"] if self.state.path.is_file() else {}
        if self.recipe.data:
            self.say(f"[1/{self.count}] generate" + (" (finished)" if "generate" in done else ""))
            for spec in self.recipe.data.values():
                self.say(INDENT + shell_line("generate", generate_argv(spec, self.recipe.workers, self.quiet)))
        for unit in self.units():
            for n, step in unit:
                note = (
                    " (finished)"
                    if step.stage.id in done
                    else f" (skipped: {step.skip_reason})" * bool(step.skip_reason)
                )
                lane = f", lane {step.stage.lane}" if step.stage.lane is not None else ""
                side = f" [group {step.stage.group}{lane}: side by side]" if step.stage.group else ""
                self.say(f"[{n}/{self.count}] {step.stage.name} ({step.stage.id}){side}{note}")
                self.say(INDENT + shell_line(step.stage.name, step.argv) + f"  > {step.log}")
                if step.budget_minutes:
                    b = self.recipe.budget or {}
                    ratio = self.ctx.by_precision(b.get("fit_ratio", 0.0))
                    self.say(
                        f"{INDENT}<budget> = ({b.get('total')} - minutes spent - {b.get('margin', 0)}) / (1 + {ratio})"
                        f", spent = {' + '.join([*(f'prior {p}' for p in self.prior_paths()), *b.get('count', [])])}"
                    )

    def prior_paths(self) -> list[str]:
        return [str(self.ctx.resolve(p, "[budget] prior")) for p in (self.recipe.budget or {}).get("prior", [])]

    # -- running ---------------------------------------------------------------------------------------

    def run(self) -> None:
        self.header()
        before = self.state.read()
        if before.get("recipe") and before.get("recipe") != str(self.recipe.path.resolve()):
            self.say(f"note: {self.out} was run with {before['recipe']}; its finished stages are kept")
        self.state.begin(str(self.recipe.path.resolve()), self.overrides)
        t0 = time.monotonic()
        if self.recipe.data:
            self.run_data()
        for unit in self.units():
            if len(unit) == 1 and unit[0][1].stage.group is None:
                self.run_step(*unit[0])
            else:
                self.run_group(unit)
        self.summary((time.monotonic() - t0) / 60)

    def _finished_before(self, n: int, name: str, key: str, argv: list[str] | None = None) -> bool:
        """Whether stage ``key`` finished in an earlier run (it is then skipped). One that finished with other
        options than ``argv`` is kept too (a machine without bf16 must not redo a bf16 training), and said so."""
        done = self.state.finished(key)
        if done is None:
            return False
        changed = changed_option(done.get("argv"), argv)
        self.say(
            f"[{n}/{self.count}] {name} ({key}): finished before, skipped"
            + (f"; its options differ now ({changed}): remove '{key}' from {self.state.path} to run it again"
               if changed else "")
        )  # fmt: skip
        self.rows.append(Row(n, name, key, "finished before", done.get("minutes"), done.get("outputs", [])))
        return True

    def _after(self, n: int) -> None:
        if self.kill_after is not None and n >= self.kill_after:
            self.say(f"{KILL_AFTER_ENV}={self.kill_after}: killed after stage {n}")
            os.kill(os.getpid(), signal.SIGKILL)

    def run_data(self) -> None:
        if self._finished_before(1, "generate", "generate"):
            return
        specs = list(self.recipe.data.values())
        self.say(f"[1/{self.count}] generate: {len(specs)} datasets")
        log = self.out / "logs" / "generate.log"
        t0 = time.monotonic()
        for spec in specs:
            self.say(
                f"{INDENT}{spec.folder} ({spec.sequences} x {spec.frames} frames, {spec.size} px, seed {spec.seed})"
            )
            argv = generate_argv(spec, self.recipe.workers, self.quiet)
            self.call(1, "generate", "generate", argv, log, fresh=False)
        minutes = (time.monotonic() - t0) / 60
        folders = [s.folder for s in specs]
        self.state.mark("generate", "generate", minutes, [], folders)
        self.rows.append(Row(1, "generate", "generate", "done", minutes, folders))
        self.say(f"{INDENT}done in {minutes:.1f} min")
        self._after(1)

    def call(
        self, n: int, name: str, key: str, argv: list[str], log: Path, fresh: bool, step: Step | None = None
    ) -> None:
        """Run one stage in this process (on ``step``'s settings; ``generate`` on ``argv``), its printed output into
        ``log``; a failure names the stage."""
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "w" if fresh else "a") as f:
            if not fresh:
                f.write(f"== {time.strftime('%Y-%m-%d %H:%M:%S')} {shell_line(name, argv)}\n")
                f.flush()
            try:
                with contextlib.redirect_stdout(f):
                    rc = run_settings(name, step.settings()) if step is not None else call_stage(name, argv)
            except InputError as e:
                raise InputError(f"stage {n}/{self.count} {name} ({key}): {e}") from None
            except BaseException:
                print(f"stage {n}/{self.count} {name} ({key}) failed; its output is in {log}", file=sys.stderr)
                raise
        if rc:
            raise InputError(f"stage {n}/{self.count} {name} ({key}) ended with status {rc}; see {log}")

    def resolved(self, step: Step) -> Step:
        """``step`` with the box-depth head's pass minutes filled in from the budget spent so far."""
        if not step.budget_minutes:
            return step
        pass_minutes = budget_mod.pass_minutes(self.recipe.budget or {}, self.fit_ratio(), self.spent()["total"])
        return stage_step(self.ctx, step.stage, self.out, self.quiet, pass_minutes=pass_minutes)

    def fit_ratio(self) -> float:
        return float(self.ctx.by_precision((self.recipe.budget or {}).get("fit_ratio", 0.0)))

    def spent(self) -> dict[str, float]:
        runs = {}
        for s in self.steps:
            if s.stage.name == "train" and s.options.get("out"):
                runs[s.stage.id] = str(s.options["out"])
        resolve = lambda v: self.ctx.resolve(v, "[budget] prior")  # noqa: E731
        return budget_mod.spent(self.recipe.budget or {}, resolve, runs, self.state.wall_minutes())

    def run_step(self, n: int, step: Step) -> None:
        s = step.stage
        if self._finished_before(n, s.name, s.id, step.argv):
            return
        if step.skip_reason:
            self.say(f"[{n}/{self.count}] {s.name} ({s.id}): skipped ({step.skip_reason})")
            self.rows.append(Row(n, s.name, s.id, f"skipped: {step.skip_reason}"))
            return
        t0 = time.monotonic()
        if s.name == "budget":
            self.say(f"[{n}/{self.count}] budget ({s.id})")
            out = step.settings().out
            try:
                line = budget_mod.write_record(self.recipe.budget or {}, self.spent(), out)
            except InputError as e:
                raise InputError(f"stage {n}/{self.count} budget ({s.id}): {e}") from None
        else:
            try:
                step = self.resolved(step)
            except InputError as e:
                raise InputError(f"stage {n}/{self.count} {s.name} ({s.id}): {e}") from None
            self.say(f"[{n}/{self.count}] {s.name} ({s.id}) ...")
            self.call(n, s.name, s.id, step.argv, step.log, fresh=s.log is not None, step=step)
            line = last_line(step.log)
        minutes = (time.monotonic() - t0) / 60
        self.state.mark(s.id, s.name, minutes, step.argv, step.outputs)
        self.rows.append(Row(n, s.name, s.id, "done", minutes, step.outputs))
        self.say(f"{INDENT}done in {minutes:.1f} min" + (f": {line}" if line else ""))
        self._after(n)

    def run_group(self, unit: list[tuple[int, Step]]) -> None:
        """Stages side by side: each lane (a stage, or the stages sharing a ``lane``) in a process of its own."""
        group = unit[0][1].stage.group or ""
        todo = [(n, st) for n, st in unit if not self._finished_before(n, st.stage.name, st.stage.id, st.argv)]
        lanes: dict[Any, list[tuple[int, Step]]] = {}
        for n, st in todo:
            if st.skip_reason:
                self.say(f"[{n}/{self.count}] {st.stage.name} ({st.stage.id}): skipped ({st.skip_reason})")
                self.rows.append(Row(n, st.stage.name, st.stage.id, f"skipped: {st.skip_reason}"))
                continue
            lanes.setdefault(st.stage.id if st.stage.lane is None else st.stage.lane, []).append((n, st))
        if not lanes:  # all finished before; a kill between the last and the group's record leaves it unset
            if group not in self.state.read()["groups"]:
                done = [self.state.finished(st.stage.id) for _, st in unit]
                self.state.mark_group(group, max((d["minutes"] for d in done if d), default=0.0))
            return
        try:
            lanes = {k: [(n, self.resolved(st)) for n, st in v] for k, v in lanes.items()}
        except InputError as e:
            raise InputError(f"group {group}: {e}") from None
        for k, members in lanes.items():
            for n, st in members:
                self.say(
                    f"[{n}/{self.count}] {st.stage.name} ({st.stage.id}) ... side by side (group {group}, lane {k})"
                )
        t0 = time.monotonic()
        procs = [self.start_lane(group, i, members) for i, members in enumerate(lanes.values())]
        failures = []
        for proc, err, members in procs:
            proc.wait()
            if proc.returncode:
                msg = last_line(err) or f"status {proc.returncode}"
                failures.append(f"group {group}: {msg} (lane of {', '.join(st.stage.id for _, st in members)})")
        minutes = (time.monotonic() - t0) / 60
        for members in lanes.values():
            for n, st in members:
                done = self.state.finished(st.stage.id)
                if done is not None:
                    self.rows.append(Row(n, st.stage.name, st.stage.id, "done", done["minutes"], st.outputs))
                    line = last_line(st.log)
                    self.say(f"{INDENT}{st.stage.id} done in {done['minutes']:.1f} min" + (f": {line}" if line else ""))
        if failures:
            raise InputError("\n".join(failures))
        self.state.mark_group(group, minutes)
        self.say(f"{INDENT}group {group} done in {minutes:.1f} min")
        self._after(max(n for n, _ in unit))

    def start_lane(self, group: str, i: int, members: list[tuple[int, Step]]) -> tuple[Any, Path, Any]:
        spec = {
            "out": str(self.out),
            "steps": [
                {"id": st.stage.id, "name": st.stage.name, "argv": st.argv, "options": st.options, "args": st.args,
                 "log": str(st.log), "outputs": st.outputs, "fresh": st.stage.log is not None}
                for _, st in members
            ],
        }  # fmt: skip
        logs = self.out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        path = logs / f".lane-{group}-{i}.json"
        path.write_text(json.dumps(spec))
        err = logs / f".lane-{group}-{i}.err"
        with open(err, "w") as f:
            proc = subprocess.Popen(
                [sys.executable, "-m", "mvracklay.training.lane", str(path)], stdout=subprocess.DEVNULL, stderr=f
            )
        return proc, err, members

    def summary(self, minutes: float) -> None:
        self.say(f"summary ({minutes:.1f} min this run):")
        for r in sorted(self.rows, key=lambda r: r.number):
            took = f"{r.minutes:6.1f} min" if r.minutes is not None else "       -  "
            outputs = ", ".join(r.outputs)
            self.say(
                f"  [{r.number}/{self.count}] {r.name:<19} {r.id:<22} {took}  {r.status}"
                + (f"  {outputs}" if outputs else "")
            )


def last_line(path: Path) -> str:
    """The last non-empty line of a log (a stage's closing message), shortened."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").replace("\r", "\n").splitlines() if ln.strip()]
    except OSError:
        return ""
    line = lines[-1] if lines else ""
    return line if len(line) <= 160 else line[:157] + "..."


def changed_option(before: list[str] | None, now: list[str] | None) -> str:
    """The first option whose value differs between two argument lists, as ``--opt OLD -> NEW`` ('' when they
    are the same or either is unknown)."""
    if before is None or now is None or before == now:
        return ""
    for i, (a, b) in enumerate(zip(before, now)):
        if a != b:
            opt = "" if b.startswith("--") else next((t for t in reversed(now[:i]) if t.startswith("--")), "")
            return f"{opt + ' ' if opt else ''}{a} -> {b}"
    longer = before if len(before) > len(now) else now
    return f"{' '.join(longer[min(len(before), len(now)) :])} {'dropped' if longer is before else 'added'}"

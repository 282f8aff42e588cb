"""A recipe's stages resolved: each stage's options (a TOML table) checked against its own parser before anything
runs, so that a bad option is refused up front. A stage runs on the settings its values give
(`Step.settings`, `mvracklay.training.stages.stage_settings`); its argument list (`Step.argv`, the same
values as flags) is what a dry run and the logs show, and what a lane of side-by-side stages is handed."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from mvracklay.training.recipe import MINUTES_OPTION, Context, DataSpec, Recipe, Stage
from mvracklay.training.stages import RUNNER_STAGES, STAGE_MODULES, option_actions, stage_parser, stage_settings

#: what a stage's ``minutes = "budget"`` stands for before the budget is known (a dry run shows the rule)
BUDGET_PLACEHOLDER = "<budget>"
#: option names whose values a stage writes (the summary lists them)
OUTPUT_OPTIONS = ("out", "json-out", "json", "to")


@dataclass
class Step:
    """One stage ready to run: its name, id, the argument list and where its output goes."""

    stage: Stage
    argv: list[str]
    log: Path
    outputs: list[str]
    skip_reason: str | None = None
    #: the values the stage runs with, by option name, and its positional arguments (what ``argv`` spells out)
    options: dict[str, Any] = field(default_factory=dict)
    args: list[str] = field(default_factory=list)

    def settings(self, placeholder: Any = None) -> Any:
        """The stage's settings, built from its values (no command line in between); ``placeholder``: the
        minutes to check with while they wait for the budget."""
        if self.budget_minutes and placeholder is None:
            raise InputError(f"stage {self.stage.id}: its minutes wait for the budget")
        options = {k: (placeholder if v == BUDGET_PLACEHOLDER else v) for k, v in self.options.items()}
        return stage_settings(self.stage.name, options, self.args, where="")

    @property
    def budget_minutes(self) -> bool:
        """Whether ``argv`` still holds `BUDGET_PLACEHOLDER` (the box-depth head's pass minutes)."""
        return BUDGET_PLACEHOLDER in self.argv


def generate_argv(spec: DataSpec, workers: int, quiet: bool) -> list[str]:
    """``mvracklay generate``'s arguments for one data spec."""
    argv = [spec.folder, "--sequences", str(spec.sequences), "--frames", str(spec.frames), "--size", str(spec.size)]
    argv += ["--seed", str(spec.seed), "--workers", str(workers)]
    if spec.layout_size is not None:
        argv += ["--layout-size", str(spec.layout_size)]
    if spec.config:
        argv += ["--config", spec.config]
    if quiet:
        argv += _quiet_flag("generate")
    return argv


def _quiet_flag(name: str) -> list[str]:
    flags = stage_parser(name)._option_string_actions
    return ["--quiet"] if "--quiet" in flags else ["--no-progress"] if "--no-progress" in flags else []


def _flag_values(key: str, value: Any, action: argparse.Action, where: str) -> list[str]:
    """The flags one option gives: ``--key`` for a true switch, ``--key V...`` for values, nothing when unset."""
    flag = f"--{key}"
    if action.nargs == 0:
        if not isinstance(value, bool):
            raise InputError(f"{where}: option {key!r} is a switch: true or false, got {value!r}")
        return [flag] if value else []
    if action.nargs == "?" and value is True:
        return [flag]  # an option whose value may be left out (e.g. --fuse-frames)
    if isinstance(value, bool):
        raise InputError(f"{where}: option {key!r} takes a value, not {str(value).lower()}")
    if value is None or value == "" or value == []:
        return []  # an empty var: the stage's own default
    if isinstance(value, dict):
        raise InputError(f"{where}: option {key!r}: a value or a list, not a table")
    values = value if isinstance(value, list) else [value]
    return [flag, *(f"{v:g}" if isinstance(v, float) else str(v) for v in values)]


def stage_step(ctx: Context, stage: Stage, out: Path, quiet: bool, pass_minutes: float | None = None) -> Step:
    """Stage ``stage`` resolved for this run; ``pass_minutes`` fills ``minutes = "budget"`` (else a
    placeholder stands there)."""
    where = f"{ctx.recipe.path}: stage {stage.index} ({stage.id})"
    if stage.name not in STAGE_MODULES and stage.name not in RUNNER_STAGES:
        raise InputError(f"{where}: unknown stage {stage.name!r} (known: {', '.join(sorted(STAGE_MODULES))})")
    actions = option_actions(stage.name)
    options = dict(stage.options)
    if stage.minutes is not None:
        minutes = ctx.by_precision(stage.minutes)
        if minutes == "budget":
            minutes = BUDGET_PLACEHOLDER if pass_minutes is None else round(pass_minutes, 2)
        options[MINUTES_OPTION[stage.name]] = minutes
    argv: list[str] = []
    outputs: list[str] = []
    values: dict[str, Any] = {}
    for key, raw in options.items():
        key = key.replace("_", "-")  # pass_minutes or pass-minutes
        if key not in actions or key == "args":
            known = ", ".join(k for k in actions if k != "args")
            raise InputError(f"{where}: unknown option {key!r} (the {stage.name} stage takes: {known})")
        value = ctx.resolve(raw, f"stage {stage.index} ({stage.id}) option {key!r}")
        flags = _flag_values(key, value, actions[key], where)
        argv += flags
        if flags:  # a false switch or an empty value leaves the stage's own default
            values[key] = value
        if key in OUTPUT_OPTIONS and value and value is not True:  # eval-reconstruction's --json prints
            outputs.append(str(value))
    if stage.name == "train" and "--resume" not in argv and "--export" not in argv:
        argv.append("--resume")  # a recipe run again goes on from the run's last.pt
        values["resume"] = True
    if quiet and "--quiet" not in argv:
        flag = _quiet_flag(stage.name)
        argv += flag
        values.update({f[2:]: True for f in flag})
    args = [str(a) for a in ctx.resolve(stage.args, f"stage {stage.index} ({stage.id}) args")]
    if args:
        if "args" not in actions:
            raise InputError(f"{where}: key 'args': the {stage.name} stage takes no positional arguments")
        argv += ["--", *args]
    if not outputs and "checkpoint" in options:  # updated in place
        outputs.append(str(ctx.resolve(options["checkpoint"], where)))
    log = Path(ctx.resolve(stage.log, f"{where} log")) if stage.log else out / "logs" / f"{stage.id}.log"
    step = Step(stage, argv, log, outputs, options=values, args=args)
    if stage.skip:
        step.skip_reason = "skip = true"
    elif stage.unless_exists:
        path = Path(ctx.resolve(stage.unless_exists, f"{where} unless_exists"))
        if path.exists():
            step.skip_reason = f"{path} exists"
    return step


def check_steps(ctx: Context, out: Path, quiet: bool) -> list[Step]:
    """Every stage resolved and its arguments parsed by its own parser; all problems at once, one line each."""
    problems, steps = [], []
    for stage in ctx.recipe.stages:
        try:
            step = stage_step(ctx, stage, out, quiet)
            if stage.name not in RUNNER_STAGES:
                step.settings(placeholder=1)  # each value converted and checked by its option, as it will run
            else:
                stage_parser(stage.name).parse_args(step.argv)
            steps.append(step)
        except InputError as e:
            msg = str(e)
            where = f"{ctx.recipe.path}: stage {stage.index} ({stage.id})"
            problems.append(msg if msg.startswith(str(ctx.recipe.path)) else f"{where}: {msg}")
    for n, need in enumerate(ctx.recipe.requires):
        try:
            path = Path(ctx.resolve(need, f"requires[{n}]"))
        except InputError as e:
            problems.append(str(e))
            continue
        if not path.exists():
            problems.append(f"{ctx.recipe.path}: key 'requires': {path} is missing")
    from waresynth.config import is_config

    for spec in ctx.recipe.data.values():
        if spec.config and not is_config(spec.config):
            problems.append(
                f"{ctx.recipe.path}: data {spec.name!r}: key 'config': {spec.config} is no file nor a shipped config"
            )
    if problems:
        raise InputError("\n".join(problems))
    return steps


def shell_line(name: str, argv: list[str]) -> str:
    """A stage's arguments as one readable line (``mvracklay train stage NAME ...``)."""
    import shlex

    return " ".join([name, *(a if a == BUDGET_PLACEHOLDER else shlex.quote(a) for a in argv)])


def describe_recipe(recipe: Recipe) -> str:
    """The recipe's first description line, for the header."""
    return recipe.description.strip().splitlines()[0] if recipe.description.strip() else recipe.name

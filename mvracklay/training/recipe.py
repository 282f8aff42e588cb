"""Recipes of ``mvracklay train``: a TOML file naming the data to generate and the stages to run in order.

A recipe is read with `tomllib`, changed by ``--set PATH=VALUE`` overrides, and checked whole before
anything runs: every problem is one line naming the file, the stage and the key (unknown keys are
refused); its structure, types and ranges are the declared schema's (`mvracklay.training.recipe_schema`). Values may hold placeholders, ``{out}`` (the run folder), ``{repo}`` (the project folder),
``{recipe_dir}``, ``{precision}``, ``{data.NAME}`` (a data folder) and ``{NAME}`` (a ``[vars]`` entry).
docs/training.md describes the format.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from layouts.fileio import loads_toml
from mvracklay.training.recipe_schema import StageDoc, recipe_problems

STAGE_KEYS = tuple(StageDoc.model_fields)
#: the option a stage's ``minutes`` sets
MINUTES_OPTION = {"train": "minutes", "fit-box-depth": "pass-minutes"}
PLACEHOLDER = re.compile(r"\{([A-Za-z_][A-Za-z0-9_.\-]*)\}")
REPO = Path(__file__).resolve().parents[2]


@dataclass
class DataSpec:
    """One generated dataset: ``mvracklay generate FOLDER --sequences ... --seed ...``."""

    name: str
    folder: str
    sequences: int
    frames: int
    size: int
    seed: int
    config: str = ""
    layout_size: int | None = None


@dataclass
class Stage:
    """One stage of a recipe as written (values not yet resolved)."""

    index: int
    name: str
    id: str
    options: dict[str, Any] = field(default_factory=dict)
    minutes: Any = None
    group: str | None = None
    lane: int | None = None
    skip: bool = False
    unless_exists: str | None = None
    log: str | None = None
    args: list[Any] = field(default_factory=list)


@dataclass
class Recipe:
    path: Path
    description: str
    precision: str
    workers: int
    vars: dict[str, Any]
    requires: list[str]
    data: dict[str, DataSpec]
    budget: dict[str, Any] | None
    stages: list[Stage]

    @property
    def name(self) -> str:
        return self.path.stem


def shipped_recipes() -> list[str]:
    """The names of the recipes shipped in mvracklay/recipes/."""
    folder = resources.files("mvracklay") / "recipes"
    return sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml"))


def find_recipe(name_or_file: str) -> Path:
    """``NAME`` of a shipped recipe, or the path of a recipe file; one line if it is neither."""
    shipped = resources.files("mvracklay") / "recipes" / f"{name_or_file}.toml"
    if "/" not in name_or_file and not name_or_file.endswith(".toml") and shipped.is_file():
        return Path(str(shipped))
    path = Path(name_or_file)
    if path.is_file():
        return path
    raise InputError(f"--recipe {name_or_file}: neither a shipped recipe ({', '.join(shipped_recipes())}) nor a file")


def parse_value(text: str) -> Any:
    """An override's VALUE: a TOML value (number, bool, list, quoted string), else the text itself."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(raw: dict[str, Any], overrides: list[str], path: Path) -> None:
    """Apply ``--set PATH=VALUE`` overrides to the recipe as read; one line per bad one."""
    problems = []
    stages = {(s.get("id") or s.get("stage")): s for s in raw.get("stages", []) if isinstance(s, dict)}
    for item in overrides:
        key, eq, text = item.partition("=")
        parts = key.split(".")
        if not eq or not all(parts):
            problems.append(f"--set {item}: not PATH=VALUE")
            continue
        value = parse_value(text)
        if parts[0] in ("precision", "workers", "description") and len(parts) == 1:
            raw[parts[0]] = value
        elif parts[0] == "vars" and len(parts) == 2:
            if parts[1] not in raw.get("vars", {}):
                problems.append(f"--set {key}: {path} has no var {parts[1]!r}")
                continue
            raw["vars"][parts[1]] = value
        elif parts[0] == "data" and len(parts) == 3:
            if parts[1] not in raw.get("data", {}):
                problems.append(f"--set {key}: {path} has no data {parts[1]!r}")
                continue
            raw["data"][parts[1]][parts[2]] = value
        elif parts[0] == "budget" and len(parts) == 2:
            if not isinstance(raw.get("budget"), dict):
                problems.append(f"--set {key}: {path} has no [budget]")
                continue
            raw["budget"][parts[1]] = value
        elif parts[0] == "stage" and len(parts) == 3:
            stage = stages.get(parts[1])
            if stage is None:
                problems.append(f"--set {key}: {path} has no stage with id {parts[1]!r} (ids: {', '.join(stages)})")
                continue
            if parts[2] in STAGE_KEYS and parts[2] not in ("stage", "id", "options"):
                stage[parts[2]] = value
            else:
                stage.setdefault("options", {})[parts[2]] = value
        else:
            problems.append(
                f"--set {key}: not precision, workers, vars.NAME, data.NAME.KEY, budget.KEY or stage.ID.KEY"
            )
    if problems:
        raise InputError("\n".join(problems))


def load_recipe(name_or_file: str, overrides: list[str] | None = None) -> Recipe:
    """Read, override and check a recipe's structure (the stages' options are checked by `check_options`)."""
    path = find_recipe(name_or_file)
    try:
        text = path.read_text()
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not TOML: {e}") from None
    raw = loads_toml(text, str(path))
    apply_overrides(raw, list(overrides or []), path)
    problems = recipe_problems(raw, path)  # the declared schema: structure, types, ranges, all at once
    if problems:
        raise InputError("\n".join(problems))
    precision, workers = raw.get("precision", "auto"), raw.get("workers", 1)
    variables, requires = raw.get("vars", {}), raw.get("requires", [])
    data = {name: DataSpec(name, **spec) for name, spec in raw.get("data", {}).items()}
    stages = _stages(raw["stages"], path, problems)
    _merge_defaults(raw.get("defaults", {}), stages, path, problems)
    budget = raw.get("budget")
    if budget is not None:
        _check_budget(budget, stages, path, problems)
    if problems:
        raise InputError("\n".join(problems))
    description = str(raw.get("description", ""))
    return Recipe(path, description, precision, workers, variables, requires, data, budget, stages)


def _stages(raw: list[dict[str, Any]], path: Path, problems: list[str]) -> list[Stage]:
    """The stages of a recipe its schema accepted; what needs them all (ids unique, minutes) to ``problems``."""
    out: list[Stage] = []
    ids: dict[str, int] = {}
    for n, entry in enumerate(raw, 1):
        sid = entry.get("id", entry["stage"])
        where = f"{path}: stage {n} ({sid})"
        if not sid or "." in sid:
            problems.append(f"{where}: key 'id': a name without dots")
        elif sid in ids:
            problems.append(f"{where}: id {sid!r} is stage {ids[sid]}'s too; give the stage an 'id' of its own")
        ids[sid] = n
        stage = Stage(n, entry["stage"], str(sid), options=entry.get("options", {}), args=entry.get("args", []))
        for key in ("group", "lane", "skip", "unless_exists", "log"):
            if key in entry:
                setattr(stage, key, entry[key])
        if "minutes" in entry:
            stage.minutes = entry["minutes"]
            _check_minutes(stage, where, problems)
        out.append(stage)
    seen_groups: set[str] = set()
    for prev, stage in zip([None, *out], out):
        if stage.group and stage.group != (prev.group if prev else None):
            if stage.group in seen_groups:
                problems.append(f"{path}: stage {stage.index} ({stage.id}): group {stage.group!r} is not contiguous")
            seen_groups.add(stage.group)
        if stage.lane is not None and not stage.group:
            problems.append(f"{path}: stage {stage.index} ({stage.id}): key 'lane' needs a 'group'")
    return out


def _merge_defaults(defaults: Any, stages: list[Stage], path: Path, problems: list[str]) -> None:
    """``[defaults.STAGE]``: options every stage of that kind takes unless it sets them itself."""
    if not isinstance(defaults, dict) or not all(isinstance(v, dict) for v in defaults.values()):
        problems.append(f"{path}: key 'defaults': [defaults.STAGE] tables of options")
        return
    names = {s.name for s in stages}
    for name in defaults:
        if name not in names:
            problems.append(f"{path}: [defaults.{name}]: the recipe has no {name!r} stage")
    for stage in stages:
        given = {k.replace("_", "-") for k in stage.options}
        extra = {k: v for k, v in defaults.get(stage.name, {}).items() if k.replace("_", "-") not in given}
        stage.options = {**extra, **stage.options}


def _check_minutes(stage: Stage, where: str, problems: list[str]) -> None:
    """Which stages take ``minutes`` (their values are the schema's: a number >= 0, a table, "budget")."""
    option = MINUTES_OPTION.get(stage.name)
    if option is None:
        problems.append(f"{where}: key 'minutes': only the {' and '.join(MINUTES_OPTION)} stages take minutes")
        return
    if option in stage.options:
        problems.append(f"{where}: key 'minutes' and option {option!r} both given")
    if stage.minutes == "budget" and stage.name != "fit-box-depth":
        problems.append(f"{where}: key 'minutes': \"budget\" is for the fit-box-depth stage, got {stage.minutes!r}")


def _check_budget(budget: dict[str, Any], stages: list[Stage], path: Path, problems: list[str]) -> None:
    """``[budget]`` ``count`` names stages of the recipe (its values are the schema's)."""
    names = {s.id for s in stages} | {s.group for s in stages if s.group}
    for name in budget.get("count", []):
        if name not in names:
            problems.append(f"{path}: [budget]: key 'count': {name!r} is no stage id or group of the recipe")


class Context:
    """Resolves a recipe's placeholders for one run folder and precision."""

    def __init__(self, recipe: Recipe, out: Path, precision: str) -> None:
        self.recipe = recipe
        self.values: dict[str, Any] = {
            "out": str(out),
            "repo": str(REPO),
            "recipe_dir": str(recipe.path.resolve().parent),
            "precision": precision,
        }
        self.values.update({f"data.{n}": d.folder for n, d in recipe.data.items()})
        self._vars = dict(recipe.vars)
        for name in list(self._vars):
            self.values[name] = self.resolve(self._vars[name], f"vars.{name}", (name,))
        for n, d in recipe.data.items():
            self.values[f"data.{n}"] = d.folder = self.resolve(d.folder, f"data.{n}.folder")
            d.config = self.resolve(d.config, f"data.{n}.config")

    def resolve(self, value: Any, where: str, chain: tuple[str, ...] = ()) -> Any:
        """``value`` with its placeholders filled (a string that is one placeholder takes the value's type)."""
        if isinstance(value, list):
            return [self.resolve(v, where, chain) for v in value]
        if not isinstance(value, str):
            return value
        whole = PLACEHOLDER.fullmatch(value)
        if whole:
            return self._lookup(whole.group(1), where, chain)
        return PLACEHOLDER.sub(lambda m: str(self._lookup(m.group(1), where, chain)), value)

    def _lookup(self, name: str, where: str, chain: tuple[str, ...]) -> Any:
        if name in chain:
            raise InputError(f"{self.recipe.path}: {where}: placeholders refer to each other ({' -> '.join(chain)})")
        if name in self.values:
            return self.values[name]
        if name in self._vars:  # a var not resolved yet (vars may refer to later ones)
            self.values[name] = self.resolve(self._vars[name], f"vars.{name}", (*chain, name))
            return self.values[name]
        raise InputError(f"{self.recipe.path}: {where}: unknown placeholder {{{name}}}")

    def by_precision(self, value: Any) -> Any:
        """A ``{bf16 = .., fp32 = ..}`` table's entry for this run's precision; any other value as it is."""
        return value[self.values["precision"]] if isinstance(value, dict) else value

"""A recipe stage runs on settings built from the recipe's values (`mvracklay.training.stages.stage_settings`),
not on a command line: for every stage of every shipped recipe they equal what its parser makes of the
argument list a dry run shows, and bad values are refused in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from layouts.errors import InputError
from mvracklay.training.plan import check_steps
from mvracklay.training.recipe import Context, load_recipe, shipped_recipes
from mvracklay.training.small_stages import CurvesSettings
from mvracklay.training.stages import settings_of, stage_parser, stage_settings


@pytest.mark.parametrize("name", shipped_recipes())
def test_every_shipped_stage_gets_the_settings_its_arguments_give(name, tmp_path):
    recipe = load_recipe(name)
    steps = check_steps(Context(recipe, tmp_path / "run", "fp32"), tmp_path / "run", quiet=True)
    compared = 0
    for step in steps:
        if step.budget_minutes or step.stage.name == "budget":
            continue
        parsed = settings_of(step.stage.name, stage_parser(step.stage.name).parse_args(step.argv))
        assert step.settings() == parsed, step.stage.id
        compared += 1
    assert compared >= 1


def test_a_stage_built_from_values_alone(tmp_path):
    got = stage_settings("curves", {"from": 150, "x": "steps"}, [str(tmp_path / "c.png"), "a=runs/a", "b=runs/b"])
    assert got == CurvesSettings(out=str(tmp_path / "c.png"), runs=["a=runs/a", "b=runs/b"], x_from=150.0, x="steps")
    fit = stage_settings("calibrate", {"checkpoint": "m.pt", "data": "d", "json-out": "s.json", "quiet": True})
    assert fit.checkpoint == Path("m.pt") and fit.json_out == Path("s.json") and fit.quiet is True


@pytest.mark.parametrize(
    "name, options, args, says",
    [
        ("curves", {"x": "hours"}, ["o.png", "a=b"], "x must be one of"),
        ("curves", {"colour": "red"}, ["o.png", "a=b"], "unknown option 'colour'"),
        ("curves", {}, ["o.png"], "required: LABEL=RUN_DIR"),
        ("copy", {"from": "a.pt"}, [], "required: --to"),
        ("copy", {"from": "a.pt", "to": "b.pt"}, ["extra"], "unrecognized arguments: extra"),
    ],
)
def test_bad_values_are_refused_in_one_line(name, options, args, says):
    with pytest.raises(InputError, match=says) as e:
        stage_settings(name, options, args)
    assert len(str(e.value).splitlines()) == 1


@pytest.mark.parametrize(
    "name, option",
    [("calibrate", "threads"), ("calibrate", "every"), ("fit-back-edges", "sequences"), ("fit-uprights", "threads"),
     ("fit-box-depth", "threads"), ("fit-box-depth", "sequences")],
)  # fmt: skip
def test_a_count_below_one_is_refused_naming_its_option_before_any_work(name, option):
    from mvracklay.training.stages import run_settings

    settings = stage_settings(name, {**_required(name), option: 0}, _positional(name))
    with pytest.raises(InputError, match=f"^--{option} must be >= 1, got 0$"):
        run_settings(name, settings)  # the checkpoint "a" is never opened


def test_every_stage_runs_on_a_settings_dataclass_its_options_come_from():
    import dataclasses

    from mvracklay.training.stages import STAGE_MODULES, stage_config

    for name in STAGE_MODULES:
        cls = stage_config(name)
        assert cls is not None and dataclasses.is_dataclass(cls), name
        defaults = stage_settings(name, _required(name), _positional(name))
        assert isinstance(defaults, cls), name


def _required(name):
    from mvracklay.training.stages import stage_parser

    return {
        a.option_strings[0][2:]: ("a" if a.nargs is None else ["a"])
        for a in stage_parser(name)._actions
        if a.required and a.option_strings
    }


def _positional(name):
    return {"curves": ["o.png", "a=b"], "fit-distance": ["d"], "generate": ["out"], "eval-reconstruction": ["p"]}.get(
        name, []
    )


def test_the_generator_makes_positionals_groups_old_names_and_nested_settings(capsys):
    import argparse
    from dataclasses import dataclass

    from mvracklay.settings import (
        InferenceSettings,
        add_options,
        from_args,
        json_out_setting,
        nested,
        quiet_setting,
        setting,
    )

    @dataclass(frozen=True)
    class Example:
        out: str | None = setting("out", "where", metavar="OUT")
        size: list[int] = setting("--size", "W H", [2, 3], type=int, nargs=2, group="model")
        src: Path | None = setting("--from", "from", type=Path, dest="src")
        augment: bool = setting("--no-augment", "off", True, invert=True)
        inference: InferenceSettings = nested(InferenceSettings, only=("flip",))
        json_out: Path | None = json_out_setting("json")
        quiet: bool = quiet_setting(alias=True)

    p = argparse.ArgumentParser()
    add_options(p, Example)
    got = from_args(Example, p.parse_args(["o", "--size", "4", "5", "--from", "x", "--no-augment", "--flip-average",
                                           "--json", "j.json", "--no-progress"]))  # fmt: skip
    assert got == Example(out="o", size=[4, 5], src=Path("x"), augment=False,
                          inference=InferenceSettings(flip=True), json_out=Path("j.json"), quiet=True)  # fmt: skip
    assert "use --json-out" in capsys.readouterr().err
    assert from_args(Example, p.parse_args(["o"])) == Example(out="o")
    help_text = p.format_help()
    assert "model:" in help_text and "--no-progress" not in help_text and "--json " not in help_text


def test_a_recipe_value_of_the_wrong_kind_names_the_file_stage_and_key(tmp_path):
    recipe = tmp_path / "r.toml"
    recipe.write_text('[[stages]]\nstage = "copy"\nid = "c"\noptions = { from = "a.pt", to = "b.pt" }\n'
                      '[[stages]]\nstage = "curves"\nid = "k"\nargs = ["o.png", "a=b"]\noptions = { from = "soon" }\n')  # fmt: skip
    from mvracklay.training.runner import run_recipe

    with pytest.raises(InputError) as e:
        run_recipe(str(recipe), tmp_path / "run", [], dry_run=True)
    assert str(e.value) == f"{recipe}: stage 2 (k): option 'from': not a valid value: 'soon'"

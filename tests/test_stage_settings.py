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

"""Recipes of `mvracklay train --recipe`: the shipped ones check and dry-run, a bad one is refused up front
with one line per problem (file, stage, key), overrides, and the budget's arithmetic."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from layouts.errors import InputError
from mvracklay.cli import main
from mvracklay.training import budget
from mvracklay.training.recipe import load_recipe, parse_value, shipped_recipes
from mvracklay.training.stages import STAGE_MODULES, option_actions

REPO = Path(__file__).resolve().parents[1]

GOOD = """
description = "two stages"
precision = "fp32"
[vars]
run = "{out}/net"
epochs = ""
[data.train]
folder = "{out}/data"
sequences = 2
frames = 4
size = 64
seed = 1
[[stages]]
stage = "train"
minutes = 0.5
[stages.options]
data = ["{data.train}"]
out = "{run}"
[[stages]]
stage = "fit-box-depth"
minutes = "budget"
[stages.options]
checkpoint = "{run}/best.pt"
data = ["{data.train}"]
epochs = "{epochs}"
parallax = true
[budget]
total = 10
margin = 1
fit_ratio = {bf16 = 1, fp32 = 3}
count = ["train"]
"""


def dry_run(recipe: str, out: Path, capsys, *extra: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(["train", "--recipe", recipe, "--out", str(out), "--dry-run", *extra])
    got = capsys.readouterr()
    return rc, got.out, got.err


def test_the_shipped_recipes_check_and_dry_run(tmp_path, capsys) -> None:
    assert {"smoke", "default-128", "default-256", "budget-256"} <= set(shipped_recipes())
    for name in shipped_recipes():
        rc, out, err = dry_run(name, tmp_path / name, capsys)
        assert rc == 0, err
        assert out.startswith(f"recipe {name} ")
        # the reader's recipe trains no network, look-256 tunes a shipped one's trunk
        assert ("train --data" in out) != (name in ("distance-reader", "look-256")), name
        assert all("--resume" in line for line in out.splitlines() if line.strip().startswith("train --data"))
    rc, out, _ = dry_run(
        "budget-256", tmp_path / "b", capsys, "--set", "stage.stage2.epochs=1", "--set", "precision=fp32"
    )
    assert "--epochs 1" in out and "--precision fp32" in out and "--pass-minutes <budget>" in out
    assert "<budget> = (120 - minutes spent - 1.5) / (1 + 1.3)" in out  # fp32's fit ratio
    assert "racklay256-stage1.pt + stage2 + rack-heads + box-depth" in out
    assert not (tmp_path / "b").exists()  # a dry run writes nothing


def test_the_shipped_recipes_train_in_steps_and_in_bf16_where_native(tmp_path, capsys) -> None:
    """A busy machine slows a shipped recipe without weakening it: no network stage stops at a wall minute;
    the recipes that train a network run in the CPU's native precision (the smoke check stays fp32)."""
    for name in shipped_recipes():
        rc, out, err = dry_run(name, tmp_path / name, capsys)
        assert rc == 0, err
        lines = [ln.strip() for ln in out.splitlines()]
        trains = [ln for ln in lines if ln.startswith(("train --data", "fit-look"))]
        assert not any(" --minutes " in ln for ln in trains), name
        assert all(" --epochs " in ln for ln in trains if ln.startswith("train")), name
        if any(ln.startswith("train --data") for ln in lines) and name != "smoke":
            assert load_recipe(name).precision == "auto", name
            assert all(" --precision " in ln for ln in trains), name
    rc, out, _ = dry_run("default-128", tmp_path / "m", capsys, "--set", "precision=fp32")
    stage1 = next(ln for ln in out.splitlines() if "--variant racklay" in ln)
    assert "--epochs 31" in stage1 and "--stop-at 5170" in stage1 and "--precision fp32" in stage1


def test_auto_precision_is_bf16_only_where_the_cpu_computes_it(tmp_path) -> None:
    from network.precision import auto_precision

    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16\n")
    assert auto_precision(info) == "bf16"
    info.write_text("processor\t: 0\nflags\t\t: fpu avx2 amx_tile amx_bf16\n")
    assert auto_precision(info) == "bf16"
    info.write_text("processor\t: 0\nflags\t\t: fpu sse2 avx2 avx512f fma\n")
    assert auto_precision(info) == "fp32"
    assert auto_precision(tmp_path / "missing") == "fp32"  # unknown: the safe one


def test_a_recipe_without_out_keeps_its_run_in_the_cache_folder_and_goes_on_there(
    tmp_path, capsys, monkeypatch
) -> None:
    """No --out: the run folder is $XDG_CACHE_HOME/mvracklay/train/NAME; a second start skips what the first
    finished (its state file is there), a start with the folder gone does it all again."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    recipe = tmp_path / "two.toml"
    recipe.write_text(
        '[vars]\nsrc = "{recipe_dir}/w.pt"\n'
        '[[stages]]\nstage = "copy"\nid = "first"\n[stages.options]\nfrom = "{src}"\nto = "{out}/a.pt"\n'
        '[[stages]]\nstage = "copy"\nid = "second"\n[stages.options]\nfrom = "{out}/a.pt"\nto = "{out}/b.pt"\n'
    )
    (tmp_path / "w.pt").write_bytes(b"weights")
    run = tmp_path / "cache" / "mvracklay" / "train" / "two"
    assert main(["train", "--recipe", str(recipe), "--quiet"]) == 0
    assert (run / "b.pt").read_bytes() == b"weights" and (run / "recipe-state.json").is_file()
    (tmp_path / "w.pt").unlink()  # the first stage could not run again: a second start must skip it
    capsys.readouterr()
    assert main(["train", "--recipe", str(recipe), "--quiet"]) == 0
    assert str(run) in capsys.readouterr().out
    (tmp_path / "w.pt").write_bytes(b"new")
    import shutil

    shutil.rmtree(run)  # the state gone: everything again
    assert main(["train", "--recipe", str(recipe), "--quiet"]) == 0
    assert (run / "b.pt").read_bytes() == b"new"


def test_plain_training_still_needs_out(capsys) -> None:
    assert main(["train", "--data", "d"]) == 2
    assert "--out is required" in capsys.readouterr().err


def test_a_recipe_file_runs_by_path_and_empty_values_leave_the_stage_default(tmp_path, capsys) -> None:
    path = tmp_path / "mine.toml"
    path.write_text(GOOD)
    rc, out, err = dry_run(str(path), tmp_path / "r", capsys)
    assert rc == 0, err
    assert f"generate {tmp_path}/r/data --sequences 2 --frames 4 --size 64 --seed 1" in out
    box = next(line for line in out.splitlines() if line.strip().startswith("fit-box-depth"))
    assert "--epochs" not in box and "--parallax" in box  # an empty var: the stage's own default
    assert "(10 - minutes spent - 1) / (1 + 3)" in out
    rc, out, _ = dry_run(str(path), tmp_path / "r", capsys, "--set", "vars.epochs=3", "--set", "data.train.seed=9")
    assert rc == 0 and "--epochs 3" in out and "--seed 9" in out


def test_a_bad_recipe_is_refused_with_one_line_per_problem(tmp_path, capsys) -> None:
    path = tmp_path / "bad.toml"
    text = GOOD.replace('precision = "fp32"', 'precision = "fp32"\ncolour = 1')
    text = text.replace("parallax = true", "parallax = true\nwarp-speed = 9\nepochs-x = 1")
    text = text.replace('[[stages]]\nstage = "train"', '[[stages]]\nstage = "train"\nwhen = 1')
    text = text.replace("seed = 1", "seed = 1\nshape = 2")
    text += '\n[[stages]]\nstage = "teleport"\n'
    path.write_text(text)
    rc, out, err = dry_run(str(path), tmp_path / "r", capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and out == ""
    assert any("unknown key 'colour'" in ln for ln in lines)
    assert any("data 'train': unknown key 'shape'" in ln for ln in lines)
    assert any("stage 1 (train): unknown key 'when'" in ln for ln in lines)
    assert len(lines) == 3 and all(str(path) in ln for ln in lines)  # structure first, all of it at once
    path.write_text(
        GOOD.replace("parallax = true", "parallax = true\nwarp-speed = 9") + '[[stages]]\nstage = "teleport"\n'
    )
    rc, _, err = dry_run(str(path), tmp_path / "r", capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 2 and all(str(path) in ln for ln in lines)
    assert "stage 2 (fit-box-depth): unknown option 'warp-speed'" in lines[0]
    assert "stage 3 (teleport): unknown stage 'teleport'" in lines[1]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (("parallax = true", "parallax = 3"), "option 'parallax' is a switch"),
        (('out = "{run}"', 'out = "{nowhere}"'), "unknown placeholder {nowhere}"),
        (("minutes = 0.5", 'minutes = "lots"'), "key 'minutes'"),
        (('count = ["train"]', 'count = ["training"]'), "'training' is no stage id or group"),
        (('[[stages]]\nstage = "fit-box-depth"', '[[stages]]\nstage = "fit-box-depth"\nid = "train"'), "id 'train'"),
        (('epochs = "{epochs}"', 'epochs = "many"'), "option 'epochs': not a valid value: 'many'"),
    ],
)
def test_each_kind_of_problem_names_its_key(tmp_path, change, words) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.replace(*change))
    from mvracklay.training.runner import run_recipe

    with pytest.raises(InputError, match=r"bad\.toml") as e:
        run_recipe(str(path), tmp_path / "r", [], dry_run=True)
    assert words in str(e.value)


def test_overrides_and_training_options_with_a_recipe(tmp_path, capsys) -> None:
    for bad, words in (
        ("stage.nope.lr=1", "no stage with id 'nope'"),
        ("vars.nope=1", "no var 'nope'"),
        ("colour=red", "not precision, workers"),
        ("novalue", "not PATH=VALUE"),
    ):
        rc, _, err = dry_run("smoke", tmp_path / "r", capsys, "--set", bad)
        assert rc == 2 and words in err and len(err.strip().splitlines()) == 1, err
    rc, _, err = dry_run("smoke", tmp_path / "r", capsys, "--lr", "0.1")
    assert rc == 2 and "--lr: not with --recipe" in err
    rc, _, err = dry_run("no-such-recipe", tmp_path / "r", capsys)
    assert rc == 2 and "no-such-recipe" in err and "smoke" in err
    assert main(["train", "--out", str(tmp_path / "r"), "--set", "vars.x=1"]) == 2
    assert parse_value("0.3") == 0.3 and parse_value("[1, 2]") == [1, 2] and parse_value("a/b.pt") == "a/b.pt"
    assert parse_value("{bf16 = 1, fp32 = 2}") == {"bf16": 1, "fp32": 2}


def test_the_budget_shares_the_minutes_left_between_the_pass_and_the_fit(tmp_path) -> None:
    rule = {"total": 120, "margin": 1.5, "prior": ["{w}"], "count": ["stage2", "rack-heads"]}
    (tmp_path / "w.json").write_text(json.dumps({"train_wall_minutes": 80.0}))
    run = tmp_path / "run"
    run.mkdir()
    (run / "last.json").write_text(json.dumps({"train_wall_minutes": 7.0}))
    parts = budget.spent(rule, lambda v: str(tmp_path / "w.pt"), {"stage2": str(run)}, {"rack-heads": 10.0})
    assert parts == {"prior:w.pt": 80.0, "stage2": 7.0, "rack-heads": 10.0, "total": 97.0}
    assert budget.pass_minutes(rule, 0.95, parts["total"]) == pytest.approx((120 - 97 - 1.5) / 1.95)
    with pytest.raises(InputError, match="118.6 of 120 minutes spent, none left"):
        budget.pass_minutes(rule, 0.95, 118.6)
    line = budget.write_record(rule, parts, tmp_path / "budget.json")
    assert (
        line.startswith("97.0 of 120 minutes spent")
        and json.loads((tmp_path / "budget.json").read_text())["budget"] == 120
    )
    with pytest.raises(InputError, match="over the budget of 120"):
        budget.write_record(rule, {**parts, "total": 121.0}, None)


def test_every_stage_has_a_parser_whose_options_have_help() -> None:
    for name in STAGE_MODULES:
        actions = option_actions(name)
        assert actions and all((a.help or "").strip() for a in actions.values()), name
    with pytest.raises(InputError, match="unknown stage 'nope'"):
        option_actions("nope")
    recipe = load_recipe("smoke")
    assert [s.id for s in recipe.stages][:3] == ["train", "calibrate", "back-edges"]


def test_the_mixed_recipes_blend_the_fine_tuned_network_into_the_weights_it_started_from(tmp_path, capsys) -> None:
    """mixed-128 / mixed-256: stage 2 starts from the shipped file, `blend` mixes its best step back into that
    file (whose depth heads stay), and the offsets, tables and export read the blend."""
    for name, shipped in (("mixed-128", "mvracklay-disc-4.pt"), ("mixed-256", "mvracklay-disc-4-256.pt")):
        rc, out, err = dry_run(name, tmp_path / name, capsys)
        assert rc == 0, err
        lines = [ln.strip() for ln in out.splitlines()]
        train = next(ln for ln in lines if ln.startswith("train --data"))
        blend = next(ln for ln in lines if ln.startswith("blend "))
        assert f"--init-from {REPO / 'mvracklay' / 'models' / shipped}" in train
        assert f"--base {REPO / 'mvracklay' / 'models' / shipped}" in blend and "/best.pt --alpha 0.3" in blend
        calibrate = next(ln for ln in lines if ln.startswith("calibrate "))
        assert "/blended.pt" in calibrate and lines.index(calibrate) > lines.index(blend)
        # the box-depth head fitted again on the calibrated blend with the default look's two sets, into model.pt
        box = next(ln for ln in lines if ln.startswith("fit-box-depth "))
        assert "/calibrated.pt" in box and "def --sequences 4320" in box and f"--out {tmp_path / name}/model.pt" in box
        assert lines.index(box) > lines.index(calibrate)


def test_a_stage_finished_with_other_options_is_kept_and_said_so(tmp_path, capsys) -> None:
    """A re-run whose stage now has other options keeps what the first run made (a moved machine must not
    redo a training) and names the option that differs and how to run the stage again."""
    recipe = tmp_path / "one.toml"
    recipe.write_text(
        '[vars]\nsrc = "{recipe_dir}/w.pt"\n'
        '[[stages]]\nstage = "copy"\nid = "first"\n[stages.options]\nfrom = "{src}"\nto = "{out}/a.pt"\n'
    )
    (tmp_path / "w.pt").write_bytes(b"weights")
    (tmp_path / "v.pt").write_bytes(b"other")
    run = tmp_path / "run"
    assert main(["train", "--recipe", str(recipe), "--out", str(run), "--quiet"]) == 0
    capsys.readouterr()
    other = ["--set", f"vars.src={tmp_path / 'v.pt'}"]
    assert main(["train", "--recipe", str(recipe), "--out", str(run), "--quiet", *other]) == 0
    out = capsys.readouterr().out
    assert f"--from {tmp_path / 'w.pt'} -> {tmp_path / 'v.pt'}" in out and "remove 'first'" in out
    assert (run / "a.pt").read_bytes() == b"weights"
    assert main(["train", "--recipe", str(recipe), "--out", str(run), "--quiet"]) == 0
    assert "differ now" not in capsys.readouterr().out  # the same options: no word of it

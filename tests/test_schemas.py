"""Each file format we read against its declared schema: a few impossible files per format, each one line
naming the file and the field (`InputError`, exit status 2 on the command line), and a good file still read."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from layouts.errors import InputError

# --- --camera files (mvracklay.camera_schema) -------------------------------------------------------------------

INTR = {"fx": 110.85, "fy": 110.85, "cx": 64.0, "cy": 64.0, "width": 128, "height": 128}

CAMERA_FAULTS = {
    "NaN focal": ({**INTR, "fx": float("nan")}, "fx: Input should be a finite number"),
    "negative focal": ({**INTR, "fy": -3.0}, "fy: Input should be greater than 0"),
    "text": ({**INTR, "cx": "64"}, "cx: Input should be a valid number"),
    "size 0": ({**INTR, "width": 0}, "width: Input should be greater than or equal to 1"),
    "float size": ({**INTR, "height": 128.5}, "height: Input should be a valid integer"),
    "lens beyond 2": ({**INTR, "k1": 7.0}, "k1: Input should be less than or equal to 2"),
    "nested NaN": ({"intrinsics": {**INTR, "cy": float("inf")}}, "intrinsics.cy: Input should be a finite number"),
    "missing": ({"fx": 100.0, "cx": 64.0}, "missing fy, cy"),
    "unknown": ({**INTR, "skew": 0.0}, "unknown key 'skew'"),
}


@pytest.mark.parametrize("fault", list(CAMERA_FAULTS))
def test_a_camera_file_breaking_its_schema_is_one_line(fault, tmp_path: Path):
    from mvracklay.camera import load_camera, parse_camera_option

    record, needle = CAMERA_FAULTS[fault]
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(record))
    for read in (lambda: load_camera(cam, 128, 128), lambda: parse_camera_option(str(cam), 128, 128)):
        with pytest.raises(InputError) as e:
            read()
        said = str(e.value)
        assert "\n" not in said and said.startswith(f"--camera {cam}") and needle in said, said


def test_a_good_camera_file_is_read(tmp_path: Path):
    from mvracklay.camera import load_camera, load_lens

    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"intrinsics": {k: v * 2 for k, v in INTR.items()}, "k1": -0.1}))
    intr = load_camera(cam, 128, 128)
    assert (intr.fx, intr.cx, intr.width) == (pytest.approx(110.85), 64.0, 128)
    assert load_lens(cam).k1 == -0.1


# --- run --config files (mvracklay.config_schema, typed from RunConfig / InferenceSettings) ---------------------

CONFIG_FAULTS = {
    "NaN": ({"rack-depth": float("nan")}, "rack-depth: Input should be a finite number"),
    "negative": ({"rack-depth": -1.0}, "rack-depth: Input should be greater than or equal to 0"),
    "out of range": ({"board-thickness": 5}, "board-thickness: Input should be less than or equal to 1"),
    "angle": ({"roll": 90}, "roll: Input should be less than or equal to 45"),
    "size 0": ({"every": 0}, "every: Input should be greater than or equal to 1"),
    "wrong type": ({"camera": 5}, "camera: Input should be a valid string"),
    "unknown": ({"rack_depth": 1.0}, "unknown option 'rack_depth' (did you mean 'rack-depth'?)"),
}


@pytest.mark.parametrize("fault", list(CONFIG_FAULTS))
def test_a_run_config_breaking_its_schema_is_one_line(fault, tmp_path: Path, capsys):
    from mvracklay.cli import main

    content, needle = CONFIG_FAULTS[fault]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    assert main(["run", str(tmp_path), "--out", str(tmp_path / "out"), "--config", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"--config {path}: {needle}" in lines[0], lines
    assert not (tmp_path / "out").exists()


def test_the_config_schema_comes_from_the_settings_and_a_good_file_is_read(tmp_path: Path):
    import argparse

    from mvracklay import cli
    from mvracklay.config_schema import config_schema
    from mvracklay.options import read_config
    from mvracklay.settings import InferenceSettings, RunConfig

    parser = cli.build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    run = sub.choices["run"]
    actions = tuple(sorted((s[2:], a) for a in run._actions for s in a.option_strings if s.startswith("--")))
    schema = config_schema(actions, (RunConfig, InferenceSettings)).model_json_schema()["properties"]
    assert schema["rack-depth"]["anyOf"][0] == {"minimum": 0.0, "type": "number"}  # RunConfig's range, one place
    assert schema["every"]["anyOf"][0] == {"minimum": 1, "type": "integer"}
    path = tmp_path / "good.toml"
    path.write_text('quality = "offline"\nrack-depth = 1.1\nroll = "auto"\nfuse-frames = true\nno-rrd = true\n')
    got = read_config(path, run, settings=(RunConfig, InferenceSettings))
    assert (got["rack_depth"], got["roll"], got["no_rrd"], got["quality"]) == (1.1, "auto", True, "offline")


# --- training recipes (mvracklay.training.recipe_schema) --------------------------------------------------------

RECIPE_FAULTS = {
    "inf minutes": (("total = 30", "total = inf"), "not readable TOML (number inf is out of range"),  # the reader's
    "size 0": (("sequences = 4", "sequences = 0"), "data 'train': key 'sequences': Input should be greater than"),
    "negative seed": (("seed = 7", "seed = -7"), "data 'train': key 'seed': Input should be greater than or equal"),
    "wrong type": (("frames = 8", 'frames = "8"'), "data 'train': key 'frames': Input should be a valid integer"),
    "unknown": (("margin = 0.5", "margin = 0.5\nslack = 1"), "[budget]: unknown key 'slack' (known: total,"),
    "missing": (('folder = "{out}/data/train"\n', ""), "data 'train': missing key 'folder'"),
    "stage": (
        ('[[stages]]\nstage = "train"', '[[stages]]\nstage = "train"\nlane = "x"'),
        "stage 1 (train): key 'lane'",
    ),
}


@pytest.mark.parametrize("fault", list(RECIPE_FAULTS))
def test_a_recipe_breaking_its_schema_is_one_line(fault, tmp_path: Path):
    from mvracklay.training.recipe import find_recipe, load_recipe

    (old, new), needle = RECIPE_FAULTS[fault]
    text = find_recipe("smoke").read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(InputError) as e:
        load_recipe(str(path))
    said = str(e.value)
    assert "\n" not in said and said.startswith(f"{path}: ") and needle in said, said


def test_a_nan_set_on_the_command_line_meets_the_schema():
    from mvracklay.training.recipe import load_recipe

    for item, needle in (
        ("budget.total=nan", "[budget]: key 'total': Input should be a finite number"),
        ("stage.train.minutes=-1", "stage 1 (train): key 'minutes': Input should be greater than or equal to 0"),
    ):
        with pytest.raises(InputError) as e:
            load_recipe("smoke", [item])
        assert "\n" not in str(e.value) and "smoke.toml: " in str(e.value) and needle in str(e.value), str(e.value)


def test_the_shipped_recipes_keep_their_schema():
    from mvracklay.training.recipe import load_recipe, shipped_recipes

    for name in shipped_recipes():
        assert load_recipe(name).stages


# --- generator configs (waresynth.config_schema, from the defaults and waresynth.config's ranges) ---------------

GENERATOR_FAULTS = {
    "NaN": (("camera", "hfov_deg"), float("nan"), "camera.hfov_deg: Input should be a finite number"),
    "reversed": (("camera", "distance"), [3.0, 2.0], "camera.distance: [low, high] with low <= high"),
    "out of range": (("camera", "height"), [1.0, 500.0], "camera.height[1]: Input should be less than or equal to 50"),
    "not an integer": (("rack", "levels"), [2.5, 4], "rack.levels[0]: Input should be a multiple of 1"),
    "wrong type": (("rack", "levels"), True, "rack.levels: Input should be a valid tuple"),
    "unknown": (("camera", "fov"), 60, "camera.fov: Extra inputs are not permitted"),
    "missing": (("camera", None), "distance", "camera.distance: Field required"),
    "colour": (("floor", "colours"), [[300, 0, 0]], "floor.colours[0][0]: Input should be less than or equal to 255"),
}


@pytest.mark.parametrize("fault", list(GENERATOR_FAULTS))
def test_a_generator_config_breaking_its_schema_is_one_line(fault):
    from waresynth.config import load_config
    from waresynth.config_schema import check_config

    (section, key), value, needle = GENERATOR_FAULTS[fault]
    cfg = load_config()
    if key is None:
        del cfg[section][value]
    else:
        cfg[section][key] = value
    with pytest.raises(InputError) as e:
        check_config(cfg, "gen.json")
    assert "\n" not in str(e.value) and str(e.value).startswith(f"gen.json: {needle}"), str(e.value)


def test_the_generator_schema_holds_the_ranges_and_every_shipped_config_keeps_it(tmp_path: Path):
    from waresynth.config import _BOUNDS, load_config, shipped_configs
    from waresynth.config_schema import config_model

    schema = config_model().model_json_schema()
    camera = schema["$defs"]["GeneratorConfig_camera"]["properties"]
    lo, hi, _ = _BOUNDS["camera.distance"]
    assert camera["distance"]["prefixItems"][0] == {"maximum": hi, "minimum": lo, "type": "number"}
    for name in shipped_configs():
        load_config(name)
    good = tmp_path / "gen.json"
    good.write_text(json.dumps({"camera": {"hfov_deg": [50, 70], "distance": [2.0, 3.0]}}))
    assert load_config(good)["camera"]["hfov_deg"] == [50, 70]


# --- checkpoint records (network.checkpoint_schema) -------------------------------------------------------------

RECORD_FAULTS = {
    "NaN": (("nominal_distance",), float("nan"), "nominal_distance: Input should be a finite number"),
    "negative": (("train_wall_minutes",), -3.0, "train_wall_minutes: Input should be greater than or equal to 0"),
    "size 0": (("intrinsics", "width"), 0, "intrinsics.width: Input should be greater than or equal to 1"),
    "wrong type": (("step",), "many", "step: Input should be a valid integer"),
    "offset": (("box_logit_offset", "top"), 50.0, "box_logit_offset.top: Input should be less than or equal to 5"),
    "unknown view": (("box_logit_offset", "side"), 0.5, "box_logit_offset.side: Extra inputs are not permitted"),
    "missing": (("intrinsics", "fx"), None, "intrinsics.fx: Field required"),
    "reversed": (("hfov_range_deg",), [90.0, 40.0], "hfov_range_deg [90.0, 40.0] is reversed"),
}


def _with_record(src: Path, dst: Path, keys: tuple[str, ...], value) -> Path:
    import torch

    payload = torch.load(src, map_location="cpu", weights_only=True)
    record = json.loads(payload["record_json"])
    record.setdefault("intrinsics", dict(INTR))
    record.setdefault("box_logit_offset", {"top": 0.0, "front": 0.0})
    inner = record
    for k in keys[:-1]:
        inner = inner[k]
    if value is None:
        del inner[keys[-1]]
    else:
        inner[keys[-1]] = value
    payload["record_json"] = json.dumps(record)
    torch.save(payload, dst)
    return dst


@pytest.mark.parametrize("fault", list(RECORD_FAULTS))
def test_a_checkpoint_record_breaking_its_schema_is_one_line(fault, tiny_checkpoint: Path, tmp_path: Path):
    from network.checkpoint import load_checkpoint

    keys, value, needle = RECORD_FAULTS[fault]
    bad = _with_record(tiny_checkpoint, tmp_path / "bad.pt", keys, value)
    with pytest.raises(InputError) as e:
        load_checkpoint(bad)
    assert "\n" not in str(e.value) and str(e.value).startswith(f"{bad}: checkpoint record: {needle}"), str(e.value)


def test_commands_refuse_a_bad_record_in_one_line_and_take_a_good_one(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    from mvracklay.cli import main
    from network.checkpoint import load_checkpoint

    bad = _with_record(tiny_checkpoint, tmp_path / "bad.pt", ("rack_depth_offset",), float("inf"))
    seq = tiny_dataset / "seq_00000"
    assert main(["predict", str(seq), "--out", str(tmp_path / "lay"), "--checkpoint", str(bad), "--quiet"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "bad.pt: checkpoint record: rack_depth_offset: Input should be a finite" in lines[0]
    assert not (tmp_path / "lay").exists()
    good = _with_record(tiny_checkpoint, tmp_path / "good.pt", ("step",), 7)
    assert load_checkpoint(good)[1]["step"] == 7


# --- a route's faces (stitching.building.route): validated as the FacePlan dataclass itself ------------------------

FACE = {"aisle": 1, "side": "L", "front_z": 0.0, "x_min": 0.0, "x_max": 10.0, "levels_m": [0.1, 1.0]}
FACE_FAULTS = {
    "ends": ({**FACE, "x_min": 5.0, "x_max": 1.0}, "faces[0]: x_min 5.0 must lie below x_max 1.0"),
    "boards down": ({**FACE, "levels_m": [1.0, 0.5]}, "faces[0].levels_m: must rise from the lowest up"),
    "boards text": ({**FACE, "levels_m": "x"}, "faces[0].levels_m: Input should be a valid list (got 'x')"),
    "board below": ({**FACE, "levels_m": [-1.0]}, "faces[0].levels_m[0]: Input should be greater than or equal to 0"),
    "aisle text": ({**FACE, "aisle": "1"}, "faces[0].aisle: Input should be a valid integer (got '1')"),
    "side": ({**FACE, "side": "X"}, "faces[0].side: String should match pattern"),
    "no front": ({k: v for k, v in FACE.items() if k != "front_z"}, "faces[0].front_z: Field required"),
    "not a record": ([1], "faces[0]: Input should be a valid dictionary or instance of PlanFace"),
}


@pytest.mark.parametrize("fault", list(FACE_FAULTS))
def test_a_route_face_breaking_its_schema_is_one_line(fault):
    from stitching.building.route import parse_route

    face, needle = FACE_FAULTS[fault]
    doc = {"faces": [face], "passes": [{"sequence": "s", "aisle": 1, "side": "L",
                                        "start": {"x": 0, "z": 1, "heading_deg": 90}}]}  # fmt: skip
    with pytest.raises(InputError) as e:
        parse_route(doc, "route.json")
    assert str(e.value).startswith(f"route.json: {needle}") and "\n" not in str(e.value)


def test_a_route_face_is_read_into_its_dataclass_unknown_keys_ignored():
    from stitching.building.route import FacePlan, parse_route, plan_dict, plan_face

    doc = {"faces": [{**FACE, "note": "x"}, {**FACE, "side": "R", "levels_m": None}],
           "passes": [{"sequence": "s", "aisle": 1, "side": "L", "start": {"x": 0, "z": 1, "heading_deg": 90}}]}  # fmt: skip
    faces = parse_route(doc, "route.json").faces
    assert faces[1, "L"] == FacePlan(1, "L", 0.0, 0.0, 10.0, (0.1, 1.0))
    assert faces[1, "R"].levels_m == ()
    assert plan_face(plan_dict(faces[1, "L"])) == faces[1, "L"]

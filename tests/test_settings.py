"""Settings as data (`mvracklay.settings`): the options of the inference settings come from the dataclass's
fields, parse back into it, and the presets and the Python API name the same fields; an old option name
still works and says which to use."""

from __future__ import annotations

import argparse
import dataclasses
import json

import pytest

from layouts.errors import InputError
from mvracklay.options import FUSE_TAU
from mvracklay.pipeline import RunConfig
from mvracklay.presets import PRESETS, preset_defaults, preset_fields
from mvracklay.settings import InferenceSettings, OutputSettings, add_options, check_range, from_args


def _parser(**kwargs) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(exit_on_error=False)
    add_options(p, InferenceSettings, **kwargs)
    return p


def test_every_field_is_an_option_that_parses_back():
    p = _parser()
    assert from_args(InferenceSettings, p.parse_args([])) == InferenceSettings()
    argv = ["--flip-average", "--rack-depth", "1.1", "--no-depth-read", "--whole-sequence", "--fuse-frames",
            "--roll", "auto", "--pitch", "2", "--yaw", "-3"]  # fmt: skip
    got = from_args(InferenceSettings, p.parse_args(argv))
    assert got == InferenceSettings(True, 1.1, False, True, FUSE_TAU, "auto", "2", "-3")
    got.validate()
    names = {s for a in p._actions for s in a.option_strings if s.startswith("--")} - {"--help"}
    fields = {f.metadata["option"] for f in dataclasses.fields(InferenceSettings)}
    assert fields <= names and len(fields) == 8


def test_a_subset_with_a_prefix_and_fields_set_otherwise():
    p = _parser(prefix="with --checkpoint: ", only=("read_depth", "roll"))
    assert [a.option_strings[0] for a in p._actions[1:]] == ["--no-depth-read", "--roll"]
    assert all(a.help.startswith("with --checkpoint: ") for a in p._actions[1:])
    got = from_args(InferenceSettings, p.parse_args(["--no-depth-read"]), rack_depth=0.9)
    assert got == InferenceSettings(read_depth=False, rack_depth=0.9)


@pytest.mark.parametrize(
    "bad, says",
    [
        (InferenceSettings(fuse_tau=-1.0), "--fuse-frames"),
        (InferenceSettings(rack_depth=-0.5), "--rack-depth"),
        (InferenceSettings(roll=60.0), "--roll"),
    ],
)
def test_a_setting_out_of_its_range_is_refused_naming_its_option(bad, says):
    with pytest.raises(InputError, match=says):
        check_range(InferenceSettings, bad)
    with pytest.raises(InputError, match=says):
        bad.validate()


def test_presets_and_the_api_name_the_settings_fields():
    assert preset_fields("default") == {}
    off = RunConfig.build(**preset_fields("offline"))
    assert off.inference == InferenceSettings(flip=True, whole_sequence=True, fuse_tau=FUSE_TAU)
    fast = RunConfig.build(**preset_fields("fast"))
    assert not fast.inference.read_depth and not fast.rgb and fast.map_every == 10
    assert set(PRESETS) == {"fast", "default", "offline"}
    assert RunConfig.build(rack_depth=1.0, threads=1) == RunConfig(
        inference=InferenceSettings(rack_depth=1.0), threads=1
    )
    with pytest.raises(InputError, match="unknown option.*flip_average"):
        RunConfig.build(flip_average=True)
    with pytest.raises(InputError, match="quality must be one of"):
        preset_fields("best")


def test_presets_become_parser_defaults_through_the_fields_options():
    """A preset names fields; as parser defaults a switch that turns a field off takes the opposite value."""
    assert preset_defaults("fast") == {"no_depth_read": True, "no_rgb": True, "map_every": 10}
    assert preset_defaults("offline") == {"whole_sequence": True, "flip_average": True, "fuse_frames": FUSE_TAU}
    assert preset_defaults("default") == {}


def test_run_config_checks_each_declared_range_once():
    """``--board-thickness``' range is its field's: [0, 1] from the Python API as in a config file."""
    RunConfig(board_thickness=1.0).validate()
    for bad, says in ((-0.1, r"--board-thickness must be in \[0.0, 1.0\]"), (1.5, "--board-thickness must be in"),
                      ("x", "board_thickness: want a number")):  # fmt: skip
        with pytest.raises(InputError, match=says):
            RunConfig(board_thickness=bad).validate()
    with pytest.raises(InputError, match="--map-every must be >= 1, got 0"):
        RunConfig(map_every=0).validate()
    with pytest.raises(InputError, match="--mode must be one of stream, window, got 'batch'"):
        RunConfig(mode="batch").validate()


def test_the_old_json_path_still_writes_and_warns(capsys, tmp_path):
    p = argparse.ArgumentParser()
    add_options(p, OutputSettings, only=("json_out",), helps={"json_out": "write here"})
    assert p.parse_args([]).json_out is None
    assert p.parse_args(["--json-out", "a.json"]).json_out.name == "a.json"
    assert capsys.readouterr().err == ""
    assert p.parse_args(["--json", "b.json"]).json_out.name == "b.json"
    err = capsys.readouterr().err
    assert "--json is deprecated here: use --json-out" in err and len(err.splitlines()) == 1
    assert "--json " not in p.format_help() and "--json-out PATH" in p.format_help()


def test_evaluate_baseline_writes_its_json_under_either_name(tiny_dataset, tmp_path, capsys):
    from mvracklay.cli import main

    base = ["evaluate-baseline", "--data", str(tiny_dataset), "--split", "all", "--quiet"]
    assert main([*base, "--json-out", str(tmp_path / "new.json")]) == 0
    assert main([*base, "--json", str(tmp_path / "old.json")]) == 0
    assert "deprecated" in capsys.readouterr().err
    new, old = (json.loads((tmp_path / n).read_text()) for n in ("new.json", "old.json"))
    assert new == old and new["sequences"] > 0


def test_runs_options_are_its_config_fields():
    from mvracklay import cli
    from mvracklay.settings import dest

    parser = cli.build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    run = sub.choices["run"]
    options = {s for a in run._actions for s in a.option_strings}
    for cls in (RunConfig, InferenceSettings):
        named = [f for f in dataclasses.fields(cls) if dest(f) is not None]
        assert named and all(f.metadata["option"] in options for f in named), cls.__name__
    argv = [
        "IN",
        "--max-frames",
        "3",
        "--no-rgb",
        "--board-thickness",
        "0.05",
        "--rack-depth",
        "1.2",
        "--mode",
        "window",
    ]
    args = run.parse_args(argv)
    cfg = from_args(RunConfig, args, inference=from_args(InferenceSettings, args), threads=1)
    assert cfg == RunConfig(
        max_frames=3,
        rgb=False,
        board_thickness=0.05,
        mode="window",
        inference=InferenceSettings(rack_depth=1.2),
        threads=1,
    )

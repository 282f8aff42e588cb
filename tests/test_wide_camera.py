"""The shipped wide camera geometry (`waresynth/configs/wide_camera.json`) and configs joined by ``+``
(``wide_look+wide_camera``): the ranges it documents, the order parts apply in, a missing part named, and
sequences generated with both drawing their lens, distance, height, step and mount turn in those ranges."""

from __future__ import annotations

import json

import pytest

from layouts.errors import InputError
from waresynth.config import is_config, load_config


def test_wide_camera_holds_the_documented_ranges_and_keeps_the_default_look() -> None:
    cam = load_config("wide_camera")["camera"]
    assert cam["hfov_deg"] == [45.0, 80.0] and cam["distance"] == [1.8, 3.5] and cam["step"] == [0.06, 0.3]
    assert (cam["yaw_deg"], cam["pitch_deg"], cam["roll_deg"]) == ([-8.0, 8.0], [-6.0, 6.0], [-4.0, 4.0])
    default = load_config()
    assert cam["height"][0] <= default["camera"]["height"][0] and cam["height"][1] >= default["camera"]["height"][1]
    assert load_config("wide_camera")["lighting"] == default["lighting"]


def test_configs_joined_by_plus_apply_in_order_and_a_missing_part_is_named(tmp_path) -> None:
    both = load_config("wide_look+wide_camera")
    look, cam = load_config("wide_look"), load_config("wide_camera")
    assert both["camera"] == cam["camera"] and both["lighting"] == look["lighting"] and both["sensor"] == look["sensor"]
    mine = tmp_path / "near.json"
    mine.write_text(json.dumps({"camera": {"distance": [1.9, 2.0]}}))
    later = load_config(f"wide_camera+{mine}")
    assert later["camera"]["distance"] == [1.9, 2.0] and later["camera"]["hfov_deg"] == [45.0, 80.0]
    assert is_config("wide_look+wide_camera") and not is_config("wide_look+no_camera")
    with pytest.raises(InputError, match=r"^no_camera: config file not found \(nor a shipped config: .*wide_camera"):
        load_config("wide_look+no_camera")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"camera": {"yaw_deg": [3, 2]}}))
    with pytest.raises(InputError, match=r"^/.*bad.json: camera.yaw_deg must be \[low, high\] with low <= high"):
        load_config(f"wide_look+{bad}")


def test_generated_sequences_draw_their_camera_from_the_wide_ranges(tmp_path) -> None:
    from mvracklay.cli import main
    from waresynth.dataset import open_dataset

    out = tmp_path / "w"
    args = ["generate", str(out), "--sequences", "3", "--frames", "2", "--size", "32", "--seed", "5", "--no-progress"]
    assert main([*args, "--config", "wide_look+wide_camera"]) == 0
    ds = open_dataset(out)
    assert ds.config["camera"]["hfov_deg"] == [45.0, 80.0] and ds.config["lighting"]["level"] == [0.35, 1.3]
    cams = [json.loads((out / sq.name / "meta.json").read_text()) for sq in ds.sequences()]
    for m in cams:
        c = m["camera"]
        assert 45.0 <= c["hfov_deg"] <= 80.0 and 1.8 <= c["distance"] <= 3.5 and 0.6 <= c["height"] <= 2.6
        assert abs(c["yaw_deg"]) <= 8 and abs(c["pitch_deg"]) <= 6 and abs(c["roll_deg"]) <= 4
        assert 0.06 <= abs(m["step"]) <= 0.3
    assert len({round(m["camera"]["hfov_deg"], 3) for m in cams}) == 3  # one lens drawn per sequence

"""camera.hfov_deg as a [low, high] range: one field of view drawn per sequence, recorded, used."""

from __future__ import annotations

import json

import pytest

from layouts.camera import Intrinsics
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from waresynth.config import draw_hfov, load_config
from waresynth.generate import DatasetSettings, generate_dataset

SMALL = dict(num_sequences=4, frames=1, image_size=(64, 48), spec=LayoutSpec(size=32), seed=3, progress=False)


def metas(root):
    return [json.loads(p.read_text()) for p in sorted(root.glob("seq_*/meta.json"))]


def test_config_takes_a_number_or_a_range():
    assert load_config({"camera": {"hfov_deg": 50}})["camera"]["hfov_deg"] == 50
    assert load_config({"camera": {"hfov_deg": [45, 65]}})["camera"]["hfov_deg"] == [45, 65]
    for bad, match in [
        ([65, 45], "camera.hfov_deg must be \\[low, high\\] with low <= high"),
        ([5, 60], "camera.hfov_deg must lie in \\[10, 150\\]"),
        ([45, 50, 55], "camera.hfov_deg must be \\[low, high\\]"),
        ("wide", "camera.hfov_deg must be a number or \\[low, high\\]"),
    ]:
        with pytest.raises(InputError, match=match):
            load_config({"camera": {"hfov_deg": bad}})
    # other number keys stay numbers only
    with pytest.raises(InputError, match="camera.reverse_probability must be a number, got"):
        load_config({"camera": {"reverse_probability": [0.2, 0.4]}})


def test_draw_is_per_sequence_seed_and_in_range():
    cfg = load_config({"camera": {"hfov_deg": [45, 65]}})
    drawn = [draw_hfov(cfg, s) for s in range(50)]
    assert all(45 <= f <= 65 for f in drawn) and max(drawn) - min(drawn) > 10
    assert drawn == [draw_hfov(cfg, s) for s in range(50)]
    assert draw_hfov(load_config(), 7) == 60.0
    assert draw_hfov(load_config({"camera": {"hfov_deg": [52, 52]}}), 7) == 52.0


def test_generated_sequences_record_and_use_their_own_camera(tmp_path):
    ranged = generate_dataset(tmp_path / "r", DatasetSettings(**SMALL, config={"camera": {"hfov_deg": [45, 65]}}))
    fixed = generate_dataset(tmp_path / "f", DatasetSettings(**SMALL))
    fovs = []
    for mr, mf in zip(metas(ranged), metas(fixed)):
        fov = mr["camera"]["hfov_deg"]
        fovs.append(fov)
        assert 45 <= fov <= 65 and mf["camera"]["hfov_deg"] == 60.0
        # the intrinsics are that camera's: half the width over tan(half the angle)
        assert mr["intrinsics"]["fx"] == pytest.approx(Intrinsics.from_fov(64, 48, fov).fx)
        # the sequence's other draws are the fixed camera's (same height, distance, step)
        for k in ("height", "distance", "motion_blur"):
            assert mr["camera"][k] == mf["camera"][k]
        assert mr["step"] == mf["step"]
    assert len(set(fovs)) == len(fovs)
    # same seed, same bytes
    again = generate_dataset(tmp_path / "r2", DatasetSettings(**SMALL, config={"camera": {"hfov_deg": [45, 65]}}))
    assert [m["camera"]["hfov_deg"] for m in metas(again)] == fovs
    assert (again / "seq_00001" / "rgb" / "000000.png").read_bytes() == (
        ranged / "seq_00001" / "rgb" / "000000.png"
    ).read_bytes()


def test_inspect_reports_the_cameras_fields_of_view(tmp_path):
    from waresynth.dataset import open_dataset
    from waresynth.preview import format_summary, summarise

    ranged = generate_dataset(tmp_path / "r", DatasetSettings(**SMALL, config={"camera": {"hfov_deg": [45, 65]}}))
    fovs = sorted(m["camera"]["hfov_deg"] for m in metas(ranged))
    s = summarise(open_dataset(ranged), progress=False)
    assert s["hfov_deg"] == pytest.approx([fovs[0], fovs[-1]])
    assert f"camera       {fovs[0]:.1f} to {fovs[-1]:.1f} deg horizontal field of view" in format_summary(s)
    fixed = summarise(open_dataset(generate_dataset(tmp_path / "f", DatasetSettings(**SMALL))), progress=False)
    assert "camera       60.0 deg horizontal field of view" in format_summary(fixed)

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

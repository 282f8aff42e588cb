"""warehouse.glb passes the Khronos glTF validator (npm gltf-validator) with zero errors and zero warnings.

Runs scripts/validate_gltf.mjs with node; skipped when node or node_modules/gltf-validator is
missing (install with `npm ci` in the repository root).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from mvracklay.cli import main
from stitching.export_gltf import export_glb, glb_json, map_cuboids
from stitching.warehouse_map import WarehouseMap

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "validate_gltf.mjs"
NODE = shutil.which("node")

pytestmark = [
    pytest.mark.skipif(NODE is None, reason="node is not installed (the glTF validator runs on Node.js)"),
    pytest.mark.skipif(
        not (ROOT / "node_modules" / "gltf-validator").is_dir(),
        reason="npm package gltf-validator not installed: run 'npm ci' in the repository root",
    ),
]


def validate(path: Path) -> dict:
    """The validator's full JSON report for ``path``."""
    proc = subprocess.run([NODE, str(SCRIPT), str(path), "--json"], capture_output=True, text=True, timeout=120)
    assert proc.returncode in (0, 1), proc.stderr
    return json.loads(proc.stdout)


def _errors(report: dict) -> list[str]:
    return [
        f"{m['code']} at {m.get('pointer')}: {m['message']}" for m in report["issues"]["messages"] if m["severity"] == 0
    ]


def test_ground_truth_reconstruction_glb_is_valid(tiny_dataset: Path, tmp_path: Path):
    out = tmp_path / "gt"
    assert main(["reconstruct", str(tiny_dataset / "seq_00000"), "--out", str(out), "--no-rrd", "--quiet"]) == 0
    wmap = WarehouseMap.load(out / "warehouse.json")
    assert wmap.boxes()
    report = validate(out / "warehouse.glb")
    assert report["issues"]["numErrors"] == 0, _errors(report)
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]
    # per rack 2 uprights at each end it is not cut at, per shelf a board and 2 beams, and every box
    cuts = {None: 0, "start": 1, "end": 1, "both": 2}
    uprights = sum(4 - 2 * cuts[getattr(r, "partial", None)] for r in wmap.racks if r.shelves)
    assert report["info"]["drawCallCount"] == uprights + 3 * len(wmap.shelves()) + len(wmap.boxes())
    assert report["info"]["drawCallCount"] == len(map_cuboids(wmap))


def test_pipeline_glb_is_valid(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path):
    out = tmp_path / "run"
    argv = ["run", str(tiny_dataset / "seq_00000"), "--out", str(out), "--checkpoint", str(tiny_checkpoint)]
    assert main([*argv, "--no-rrd", "--quiet", "--max-frames", "4"]) == 0
    report = validate(out / "warehouse.glb")
    assert report["issues"]["numErrors"] == 0, _errors(report)
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]
    # the run coloured the boxes the frames saw, and the .glb says so
    wmap = WarehouseMap.load(out / "warehouse.json")
    extras = {n["name"]: n.get("extras", {}) for n in glb_json(out / "warehouse.glb").get("nodes", [])}
    for b in wmap.boxes():
        assert extras[b.id]["colour_source"] == ("frames" if b.colour is not None else "default")
    assert not wmap.boxes() or any(b.colour is not None for b in wmap.boxes())


def test_empty_map_glb_is_valid(tmp_path: Path):
    path = tmp_path / "empty.glb"
    export_glb(WarehouseMap(racks=[], steps=[], board_thickness=0.06), path)
    report = validate(path)
    assert report["issues"]["numErrors"] == 0, _errors(report)
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]


def test_validator_reports_errors_on_a_broken_file(tmp_path: Path):
    path = tmp_path / "broken.glb"
    path.write_bytes(b"glTF" + b"\x02\x00\x00\x00" + b"\xff" * 40)
    proc = subprocess.run([NODE, str(SCRIPT), str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode in (1, 2)
    assert proc.returncode == 2 or not proc.stdout.startswith("errors 0 ")


def test_validator_prints_warnings(tmp_path: Path):
    path = tmp_path / "warn.gltf"
    path.write_text(json.dumps({"asset": {"version": "2.0", "foo": 1}}))
    proc = subprocess.run([NODE, str(SCRIPT), str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0  # warnings are not errors
    assert proc.stdout.startswith("errors 0 warnings 1 ")
    assert "warning UNEXPECTED_PROPERTY at /asset/foo" in proc.stdout

"""Racking as it is built: continuous runs (bays share one upright frame), shelving units side by side (touching,
two uprights back to back) and racks apart, in the plan, the ground truth, the scenes and the layouts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layouts.classes import SHELF
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from waresynth import semantics as sem
from waresynth.building.generate import generate_building
from waresynth.building.plan import pass_row, plan_building
from waresynth.building.schema import BUILDING_DEFAULTS, load_building
from waresynth.building.truth import ground_truth
from waresynth.config import load_config
from waresynth.groundtruth import frame_layouts
from waresynth.row_plan import CameraPlan
from waresynth.scene_builder import build_scene

BUILDING = {"aisles": 2, "bays": [4, 6], "bay_width": [1.6, 2.2], "levels": [2, 3]}
SPEC = LayoutSpec(size=64)


def _plan(kinds: dict[str, float], seed: int = 5, **extra):
    bcfg = load_building({**BUILDING, "rack_build": kinds, **extra})
    return plan_building(bcfg, load_config(None), seed, (64, 48), SPEC.num_slots)


def _joints(face) -> list[float]:
    return [a[1] - b[0] for a, b in zip(face.bays, face.bays[1:])]


@pytest.mark.parametrize("kind", ["run", "units", "apart"])
def test_each_kind_has_its_uprights_and_joints(kind):
    plan = _plan({kind: 1.0}, run_bays=[12, 12])  # one run (one line of units) per face
    doc, rows = ground_truth(plan)
    for face, racking in zip(plan.faces, doc["racking"]):
        n = len(face.bays)
        assert face.build == racking["build"] == kind and n >= 4
        frames = racking["uprights"]
        uw = face.row.upright_width
        assert len(frames) == {"run": n + 1, "units": 2 * n, "apart": 2 * n}[kind]
        assert all(abs((hi - lo) - uw) < 1e-5 for lo, hi in frames)
        assert all(b[0] > a[1] - 1e-9 for a, b in zip(frames, frames[1:]))  # none overlaps the next
        if kind == "apart":
            assert all(j < -0.09 for j in _joints(face))  # a gap of bay_gap between racks
        else:
            assert all(j == 0.0 for j in _joints(face))  # touching, no gap
            assert len({round(w[1] - w[0], 9) for w in face.bays}) == 1  # one run: one beam length
        for b0, b1 in zip(face.bays, face.bays[1:]):
            at_joint = [f for f in frames if f[0] - 1e-6 <= b0[1] <= f[1] + 1e-6]
            if kind == "run":  # one frame centred on the joint
                assert len(at_joint) == 1 and abs((at_joint[0][0] + at_joint[0][1]) / 2 - b0[1]) < 1e-5
            elif kind == "units":  # two frames back to back, touching at the joint
                assert len(at_joint) == 2
                assert abs(at_joint[0][1] - b0[1]) < 1e-5 and abs(at_joint[1][0] - b0[1]) < 1e-5
            else:  # each rack's own frame flush with its end, the gap between them clear
                mid = (b0[1] + b1[0]) / 2
                assert len(at_joint) == 1 and abs(at_joint[0][1] - b0[1]) < 1e-5
                assert not [f for f in frames if f[0] <= mid <= f[1]]
    codes = [r["location"] for r in rows]
    assert len(codes) == len(set(codes)) == sum(len(f.bays) * len(f.row.levels) for f in plan.faces)


def test_truth_spans_uprights_and_boxes_agree():
    """Each bay records its span (its own uprights whole, a shared frame to its centre line) and its two frames;
    its boxes stand between the frames' inner faces."""
    plan = _plan({"apart": 1.0, "run": 1.0, "units": 1.0}, seed=1)
    doc, _ = ground_truth(plan)
    assert {r["build"] for r in doc["racking"]} == {"apart", "run", "units"}
    faces = {(r["aisle"], r["side"]): r for r in doc["racking"]}
    boxes = 0
    for rack in doc["racks"]:
        face = faces[(rack["aisle"], rack["side"])]
        others = [o for o in doc["racks"] if (o["aisle"], o["side"]) == (rack["aisle"], rack["side"])]
        (l0, l1), (r0, r1) = rack["uprights"]
        assert [l0, l1] in face["uprights"] and [r0, r1] in face["uprights"]
        low = face["build"] == "run" and any(o["x_max"] == rack["x_min"] for o in others)
        high = face["build"] == "run" and any(o["x_min"] == rack["x_max"] for o in others)
        assert abs(((l0 + l1) / 2 if low else l0) - rack["x_min"]) < 1e-5
        assert abs(((r0 + r1) / 2 if high else r1) - rack["x_max"]) < 1e-5
        for lv in rack["levels"]:
            for pos in lv["positions"]:
                for b in pos["boxes"]:
                    w, _, d = b["size"]
                    half = 0.5 * (abs(np.cos(b["yaw"])) * w + abs(np.sin(b["yaw"])) * d)
                    assert l1 < b["center"][0] - half and b["center"][0] + half < r0
                    boxes += 1
    assert boxes > 50


def test_scene_builds_a_shared_frame_once_and_units_two():
    """The rendered parts: a run's joint holds one frame (front and rear post), a units' joint two."""
    cfg = load_config(None)
    for kind, per_joint in (("run", 1), ("units", 2)):
        plan = _plan({kind: 1.0}, run_bays=[12, 12])
        face = plan.faces[1]  # an R face: row frame X is building X
        row = pass_row(plan, next(p for p in plan.passes if p.face == 1))
        cam = CameraPlan(2.0, 1.2, 0.3, (row.racks[0].x_max + row.racks[1].x_min) / 2)
        scene = build_scene(np.random.default_rng(0), cfg, _intr(), 2, planned=(row, cam))
        height = row.top + 0.08
        posts = sorted(
            round(p.center[0], 6) for p in scene.parts if p.semantic == sem.RACK and abs(p.size[1] - height) < 1e-9
        )
        xs = sorted(set(posts))
        assert all(posts.count(x) == 2 for x in xs)  # a front and a rear post per frame
        assert len(xs) == {"run": len(row.racks) + 1, "units": 2 * len(row.racks)}[kind]
        joint = row.racks[0].x_max
        near = [x for x in xs if abs(x - joint) <= face.row.upright_width]
        assert len(near) == per_joint
        # the layouts: the board runs on across the joint (no empty column there)
        lay = frame_layouts(scene, SPEC, joint)
        mid = SPEC.size // 2
        assert (lay.top[0][:, mid - 1 : mid + 1] == SHELF).any()


def _intr():
    from layouts.camera import Intrinsics

    return Intrinsics.from_fov(64, 48, 60.0)


def test_without_rack_build_nothing_changes():
    """A config without rack_build, or with racks apart only, plans the same racks and stacks."""
    cfg = load_config(None)
    base = plan_building(load_building(BUILDING), cfg, 5, (64, 48), 3)
    apart = plan_building(load_building({**BUILDING, "rack_build": {"apart": 1}}), cfg, 5, (64, 48), 3)
    assert "rack_build" not in BUILDING_DEFAULTS and "rack_build" not in load_building(BUILDING)
    for a, b in zip(base.faces, apart.faces):
        assert a.bays == b.bays and a.row.racks == b.row.racks and a.build == b.build == "apart"
    mixed = _plan({"apart": 1.0, "run": 1.0, "units": 1.0}, seed=1)
    assert any(a.bays != b.bays for a, b in zip(base.faces, mixed.faces))


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ({"rack_build": {"runs": 1}}, "unknown key 'rack_build.runs' \\(known: apart, run, units\\)"),
        ({"rack_build": {"apart": 0}}, "must not all be 0"),
        ({"rack_build": {"run": 2}}, "rack_build.run"),
        ({"run_bays": [5, 2]}, "run_bays: \\[low, high\\] with low <= high"),
    ],
)
def test_bad_rack_build_is_one_line(tmp_path, value, match):
    bad = tmp_path / "b.json"
    bad.write_text(json.dumps(value))
    err = pytest.raises(InputError, load_building, str(bad))
    assert err.match(match) and "b.json" in str(err.value) and "\n" not in str(err.value)


def test_generated_building_records_its_racking(tmp_path):
    """A rendered tiny mixed building: the ground truth lists each face's build, the route keeps the plan."""
    out = generate_building(
        tmp_path / "b",
        building={**BUILDING, "aisles": 1, "bays": [3, 3], "rack_build": {"run": 1, "units": 1}, "pass_length": 12.0,
                  "twice_share": 0.0},
        config={"camera": {"step": [2.0, 2.0]}}, image_size=(32, 24), spec=LayoutSpec(size=16), seed=2,
        progress=False,
    )  # fmt: skip
    doc = json.loads((out / "ground_truth" / "building.json").read_text())
    builds = {r["build"] for r in doc["racking"]}
    assert builds <= {"run", "units"} and builds
    for r in doc["racking"]:
        assert len(r["uprights"]) == {"run": 4, "units": 6}[r["build"]]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["building"]["rack_build"] == {"run": 1, "units": 1}


def test_changed_stock_stays_clear_of_shared_uprights():
    """A rescan's moved, shifted and added stacks stand between the uprights of runs and units too."""
    from waresynth.building.changes import apply_changes
    from waresynth.building.schema import change_rates

    plan = _plan({"run": 1.0, "units": 1.0}, seed=2)
    rates = {**change_rates(None), "added": 0.3, "moved": 0.2, "shifted": 0.3}
    changed, changes = apply_changes(plan, rates, 7, load_config(None))
    assert changes
    doc, _ = ground_truth(changed)
    assert {r["build"] for r in doc["racking"]} == {"run", "units"}
    for rack in doc["racks"]:
        (_, l1), (r0, _) = rack["uprights"]
        for lv in rack["levels"]:
            for pos in lv["positions"]:
                for b in pos["boxes"]:
                    w, _, d = b["size"]
                    half = 0.5 * (abs(np.cos(b["yaw"])) * w + abs(np.sin(b["yaw"])) * d)
                    assert l1 < b["center"][0] - half and b["center"][0] + half < r0

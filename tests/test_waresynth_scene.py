"""Scene model, config and renderer of WareSynth (no files written)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from layouts.camera import Intrinsics
from waresynth import semantics
from waresynth.config import _BOUNDS, default_config, load_config
from waresynth.render import Renderer
from waresynth.row_plan import level_visible
from waresynth.scene_builder import build_scene


def _scene(seed: int, size=(96, 64), frames: int = 6, config=None):
    intr = Intrinsics.from_fov(size[0], size[1], 60.0)
    return build_scene(np.random.default_rng(seed), load_config(config), intr, frames), intr


def test_default_config_is_complete_and_bounded():
    cfg = default_config()
    for key in _BOUNDS:
        node = cfg
        for part in key.split("."):
            node = node[next(iter(node))] if part == "*" else node[part]
    assert load_config({}) == cfg


@pytest.mark.parametrize("seed", range(6))
def test_scene_structure(seed):
    scene, intr = _scene(seed)
    cfg = default_config()
    row = scene.row
    assert 1 <= len(scene.visible_levels)
    for k in scene.visible_levels:
        clear = scene.racks[0].shelves[k].clear_height
        assert level_visible(intr, scene.camera.height, scene.camera.distance, row["levels"][k], clear)
    # The renderer relies on the floor being below and the wall behind everything else.
    wall = next(p for p in scene.parts if p.semantic == semantics.WALL)
    wall_front = wall.center[2] - wall.size[2] / 2
    for p in scene.parts:
        if p.semantic in (semantics.FLOOR, semantics.WALL):
            continue
        reach = 0.5 * (abs(math.sin(p.yaw)) * p.size[0] + abs(math.cos(p.yaw)) * p.size[2])
        assert p.center[2] + reach <= wall_front + 1e-9
        assert p.center[1] + p.size[1] / 2 <= 1e-9
    for a, b in zip(scene.racks, scene.racks[1:]):
        assert b.x_min - a.x_max >= 0.2 - 1e-9
    xs = scene.camera.positions[:, 0]
    assert scene.racks[0].x_min < xs.min() + 1.0 and scene.racks[-1].x_max > xs.max() - 1.0
    for rack in scene.racks:
        assert [s.board_top_y for s in rack.shelves] == [-lv for lv in row["levels"]]
        for shelf in rack.shelves:
            stacks: dict[str, list] = {}
            for box in shelf.boxes:
                stacks.setdefault(box.stack_id, []).append(box)
            for boxes in stacks.values():
                foot = {(b.center[0], b.center[2], b.size[0], b.size[2], b.yaw) for b in boxes}
                assert len(foot) == 1, "a stack shares its footprint"
                height = sum(b.size[1] for b in boxes)
                assert height <= shelf.clear_height - cfg["boxes"]["head_room"] + 1e-9
                bottom = max(b.center[1] + b.size[1] / 2 for b in boxes)
                assert math.isclose(bottom, shelf.board_top_y)
                assert [b.stack_level for b in boxes] == list(range(len(boxes)))


def test_scene_is_a_function_of_the_seed():
    a, _ = _scene(3)
    b, _ = _scene(3)
    c, _ = _scene(4)
    assert a.to_dict() == b.to_dict()
    assert a.to_dict() != c.to_dict()


def test_block_fill_matches_exact_ray_casting():
    scene, intr = _scene(2, size=(128, 96))
    fast, exact = Renderer(scene, intr), Renderer(scene, intr, exact=True)
    for pos in scene.camera.positions[::3]:
        f = fast.render(pos, np.random.default_rng(0))
        e = exact.render(pos, np.random.default_rng(0))
        assert (f.instance != e.instance).mean() < 0.002
        assert (f.semantic != e.semantic).mean() < 0.002
        same = f.instance == e.instance
        assert np.abs(f.depth_mm[same].astype(int) - e.depth_mm[same]).max() <= 1
        assert f.rgb.dtype == np.uint8 and f.rgb.shape == (96, 128, 3)


def test_shipped_no_sparse_config_never_draws_the_sparse_preset():
    """mvracklay/recipes/no_sparse.json (a generator config for budget-256's box scenes) drops the sparse preset."""
    path = Path(__file__).resolve().parents[1] / "mvracklay" / "recipes" / "no_sparse.json"
    drawn = {_scene(seed, config=path)[0].density for seed in range(40)}
    assert "sparse" not in drawn
    assert len(drawn) >= 2
    assert "sparse" in {_scene(seed)[0].density for seed in range(40)}


def test_render_outputs_are_consistent():
    scene, intr = _scene(5, size=(64, 64))
    r = Renderer(scene, intr)
    f1 = r.render(scene.camera.positions[0], np.random.default_rng(1))
    f2 = r.render(scene.camera.positions[0], np.random.default_rng(1))
    assert np.array_equal(f1.rgb, f2.rgb)
    assert np.array_equal(f1.depth_mm > 0, f1.semantic != semantics.VOID)
    table = {i["instance_id"]: i["semantic"] for i in scene.instances}
    for iid in np.unique(f1.instance[f1.instance > 0]):
        names = {semantics.SEMANTIC_NAMES[int(s)] for s in np.unique(f1.semantic[f1.instance == iid])}
        assert names == {table[int(iid)]}
    # Depth is metric Z: the floor straight below the image centre row is where the pinhole says.
    floor = f1.semantic == semantics.FLOOR
    if floor.any():
        v, u = np.argwhere(floor)[-1]
        ray_y = (v + 0.5 - intr.cy) / intr.fy
        assert f1.depth_mm[v, u] / 1000 == pytest.approx(scene.camera.height / ray_y, abs=0.01)

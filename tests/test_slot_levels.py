"""The ground truth's shelf slots are the visible levels inside the canonical view (`waresynth.groundtruth`):
a board a wide lens shows below the network's window is no slot, so slot 0 is the board the row head can find."""

from __future__ import annotations

import numpy as np

from layouts.camera import Intrinsics
from layouts.canonical import CanonicalView
from layouts.classes import SHELF
from layouts.spec import LayoutSpec
from waresynth.config import load_config
from waresynth.groundtruth import frame_layouts, frame_slots, in_canonical_view, slot_levels
from waresynth.scene_builder import build_scene

SPEC = LayoutSpec(size=32)
#: a high camera over a two-level rack whose lowest board lies on the floor, with a wide lens
FLOOR = {
    "camera": {"height": [2.3, 2.4], "distance": [3.0, 3.1], "hfov_deg": 80.0},
    "rack": {"levels": [2, 2], "first_level": [0.0, 0.02], "spacing": [0.9, 1.0]},
}


def _scene(config, seed: int, fov: float):
    intr = Intrinsics.from_fov(64, 64, fov)
    return build_scene(np.random.default_rng(seed), load_config(config), intr, 2)


def test_a_floor_board_below_the_canonical_view_is_no_slot_and_slot_0_is_the_next_board_up() -> None:
    for seed in range(4):
        scene = _scene(FLOOR, seed, 80.0)
        assert scene.visible_levels == [0, 1]  # the wide lens shows both boards
        assert not in_canonical_view(scene, SPEC, 0) and in_canonical_view(scene, SPEC, 1)
        assert slot_levels(scene, SPEC) == [1]
        slots = frame_slots(scene, SPEC)
        assert [s["level"] for s in slots] == [1]
        # the slot's anchor lies on the canonical rows the row head scores; level 0's would not
        view = CanonicalView(64, 64, SPEC.x_extent)
        cam_y = -scene.camera.height
        assert 0 <= view.row_of(slots[0]["board_top_y"] - cam_y) < view.height
        assert view.row_of(float(scene.racks[0].shelves[0].board_top_y) - cam_y) >= view.height
        # slot 0's layout is level 1's shelf, and slots 1-2 are empty
        lay = frame_layouts(scene, SPEC, float(scene.camera.positions[0][0]))
        assert (lay.top[0] == SHELF).any() and not lay.top[1:].any() and not lay.front[1:].any()


def test_the_default_camera_keeps_its_visible_levels_as_slots() -> None:
    for seed in range(8):
        scene = _scene(None, seed, 60.0)
        inside = [k for k in scene.visible_levels if in_canonical_view(scene, SPEC, k)]
        assert slot_levels(scene, SPEC) == inside[: SPEC.num_slots]
        if scene.camera.distance <= 2.6:  # the canonical view holds the whole 60-degree image
            assert slot_levels(scene, SPEC) == scene.visible_levels[: SPEC.num_slots]

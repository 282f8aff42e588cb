"""The ground truth's shelf slots are the visible levels inside the canonical view (`waresynth.groundtruth`):
a board a wide lens shows below the network's window is no slot, so slot 0 is the board the row head can find."""

from __future__ import annotations

import numpy as np
import pytest

from layouts.camera import Intrinsics
from layouts.canonical import CanonicalView
from layouts.classes import SHELF
from layouts.errors import InputError
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
    # the window's margin holds what the 60-degree camera sees at its farthest (2.9 m): the default's
    # slots, and every dataset generated with it, are as they were
    far = {"camera": {"distance": [2.88, 2.9]}}
    for seed in range(12):
        for config in (None, far):
            scene = _scene(config, seed, 60.0)
            assert all(in_canonical_view(scene, SPEC, k) for k in scene.visible_levels)
            assert slot_levels(scene, SPEC) == scene.visible_levels[: SPEC.num_slots]


def test_a_sampled_scene_is_drawn_again_until_it_has_a_slot() -> None:
    intr = Intrinsics.from_fov(64, 64, 80.0)
    low = {
        "camera": {"height": [2.5, 2.6], "distance": [3.0, 3.1], "hfov_deg": 80.0},
        "rack": {"levels": [2, 2], "first_level": [0.0, 0.02], "spacing": [0.7, 0.75]},
    }
    # the lens sees both low boards, both more than 1.5 m below the camera: no scene has a slot
    scene = build_scene(np.random.default_rng(0), load_config(low), intr, 2)
    assert scene.visible_levels and slot_levels(scene, SPEC) == []
    with pytest.raises(InputError, match="never make a shelf visible inside the canonical view"):
        build_scene(np.random.default_rng(0), load_config(low), intr, 2, x_extent=SPEC.x_extent)
    for seed in range(4):  # a floor board below the view and one inside: drawn as before, one slot
        scene = build_scene(np.random.default_rng(seed), load_config(FLOOR), intr, 2, x_extent=SPEC.x_extent)
        assert slot_levels(scene, SPEC) == [1]

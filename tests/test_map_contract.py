"""What we write, we read: every row map the stitcher publishes keeps the schema its readers check.

A property test drives the stitcher with noisy layouts of random racks (shelf depths, boxes turned or reaching
past their shelf, stray box pixels, flipped cells), random camera steps (the window's moves and the steps given
to it, right or wrong), random visible ranges and random slot assignments (a slot missing, the slots moved by
one), and asserts that the map at every step and at the end passes `check_map`, saves, loads back and
round-trips. A regression case stitches the layouts that once built a box wholly outside its shelf
(tests/data/box_off_shelf/, predicted by a briefly trained network). The schema's rules for a map edited by
hand are in tests/test_faults.py.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from layouts import LayoutSpec
from layouts.codecs import FrameLayouts, LayoutFolder
from layouts.errors import ContractError
from stitching.map_schema import DUPLICATE_SHARE, check_map, footprint_extent, overlap_share
from stitching.pipeline import StitchConfig, Stitcher, folder_frames, reconstruct
from stitching.warehouse_map import MapBox, WarehouseMap

SPEC = LayoutSpec(num_slots=3, size=16)  # the tiny network's layouts: coarse cells, where noise bites hardest
PROPS = settings(
    max_examples=60, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow]
)
DATA = Path(__file__).parent / "data" / "box_off_shelf"


def _rect(mask: np.ndarray, r0: float, r1: float, c0: float, c1: float, yaw: float) -> None:
    """Set the cells of ``mask`` (rows x cols) whose centres lie in the rectangle turned by ``yaw`` about its centre."""
    rr, cc = np.mgrid[: mask.shape[0], : mask.shape[1]] + 0.5
    rc, cc0 = (r0 + r1) / 2, (c0 + c1) / 2
    c, s = math.cos(yaw), math.sin(yaw)
    u = (cc - cc0) * c + (rr - rc) * s
    v = -(cc - cc0) * s + (rr - rc) * c
    mask |= (np.abs(u) <= (c1 - c0) / 2) & (np.abs(v) <= (r1 - r0) / 2)


def _world(rng: np.random.Generator, width: int, noise: float, strays: int) -> np.ndarray:
    """``(2, R, D, width)`` class ids along a row: per slot a shelf depth and racks with gaps (top view), a clear
    height (front view), boxes on the racks (some turned, some reaching past the shelf's depth), stray box cells
    anywhere (a lone pixel beyond the shelf), then ``noise`` of the cells flipped."""
    R, D = SPEC.num_slots, SPEC.size
    world = np.zeros((2, R, D, width), np.uint8)
    for r in range(R):
        if rng.random() < 0.15:
            continue  # no shelf in this slot anywhere
        d0 = int(rng.integers(0, D // 2))
        d1 = int(rng.integers(d0 + 2, D + 1))
        top_row = int(rng.integers(0, D // 2))
        c = int(rng.integers(0, 6))
        while c < width:
            run = int(rng.integers(3, 2 * D))
            world[0, r, d0:d1, c : c + run] = 1
            world[1, r, top_row:, c : c + run] = 1
            b = c
            while b < min(c + run, width):
                bw = int(rng.integers(1, 8))
                if rng.random() < 0.7:
                    mask = np.zeros((D, width), bool)
                    reach = int(rng.integers(-2, 3))  # a box may reach past the shelf's depth by a cell or two
                    r0, r1 = max(d0 - max(reach, 0), 0), min(d1 + max(reach, 0), D)
                    r0 = int(rng.integers(r0, max(r0 + 1, r1 - 1)))
                    yaw = float(rng.choice([0.0, 0.0, rng.uniform(-0.6, 0.6)]))
                    _rect(mask, r0, r1, b, b + bw, yaw)
                    world[0, r][mask] = 2
                    hb = int(rng.integers(1, D - top_row + 1))
                    world[1, r, D - hb :, b : b + bw] = 2
                b += bw + int(rng.integers(0, 3))
            c += run + int(rng.integers(1, D))
    for _ in range(strays):
        world[0, rng.integers(0, R), rng.integers(0, D), rng.integers(0, width)] = 2
    flip = rng.random(world.shape) < noise
    world[flip] = rng.integers(0, 3, int(flip.sum()), dtype=np.uint8)
    return world


def _slots(top: np.ndarray, front: np.ndarray, how: str) -> tuple[np.ndarray, np.ndarray]:
    """The frame's slot assignment: as is, one slot unseen, or every slot moved down by one (a camera raised)."""
    top, front = top.copy(), front.copy()
    if how.startswith("drop"):
        r = int(how[-1])
        top[r] = front[r] = 0
    elif how == "raise":
        top, front = np.roll(top, -1, axis=0), np.roll(front, -1, axis=0)
        top[-1] = front[-1] = 0
    return top, front


@st.composite
def walks(draw):
    """A camera's walk along a noisy row: frames, the steps given to the stitcher, and the settings."""
    D = SPEC.size
    dx = SPEC.x_extent / D
    seed = draw(st.integers(0, 2**32 - 1))
    n = draw(st.integers(2, 8))
    noise = draw(st.sampled_from([0.0, 0.01, 0.05, 0.2]))
    strays = draw(st.integers(0, 6))
    steps = draw(st.lists(st.integers(-5, 5), min_size=n, max_size=n))
    told = draw(st.sampled_from(["none", "true", "wrong"]))
    vis = draw(st.sampled_from(["all", "none", "range"]))
    slots = draw(st.lists(st.sampled_from(["as is"] * 4 + ["drop 0", "drop 2", "raise"]), min_size=n, max_size=n))
    rng = np.random.default_rng(seed)
    width = 2 * D + 5 * n + 2
    world = _world(rng, width, noise, strays)
    c = 5 * n // 2 + D // 2
    frames, motion = [], []
    for k in range(n):
        step = steps[k] if k else 0
        c = int(np.clip(c + step, 0, width - D))
        top, front = _slots(world[0, ..., c : c + D], world[1, ..., c : c + D], slots[k])
        visible = None
        if vis == "range":
            a = int(rng.integers(0, D // 2))
            visible = np.zeros(D, bool)
            visible[a : a + int(rng.integers(D // 2, D + 1))] = True
        elif vis == "all":
            visible = np.ones(D, bool)
        frames.append(FrameLayouts(np.ascontiguousarray(top), np.ascontiguousarray(front), visible))
        given_step = {"none": None, "true": step * dx, "wrong": float(rng.uniform(-0.6, 0.6))}[told]
        motion.append(None if k == 0 else given_step)
    return frames, motion, draw(st.booleans())


def _published(wmap: WarehouseMap, folder: Path, where: str) -> dict:
    """Assert that ``wmap`` keeps its schema, saves, loads back and saves again to the same document."""
    doc = json.loads(json.dumps(wmap.to_dict()))
    check_map(doc, where)
    path = folder / "warehouse.json"
    wmap.save(path)
    back = WarehouseMap.load(path)
    assert json.loads(json.dumps(back.to_dict())) == doc == json.loads(path.read_text()), where
    return doc


def _stands_on_its_shelf(wmap: WarehouseMap) -> None:
    """What the stitcher promises beyond the schema's tolerances: each box's centre over its shelf's depth, its
    footprint within that depth, no box longer than its rack, none covering half of another."""
    for rack in wmap.racks:
        for sh in rack.shelves:
            (x0, x1), (z0, z1) = sh.x_range, sh.z_range
            assert x0 >= rack.x_range[0] and x1 <= rack.x_range[1]
            for b in sh.boxes:
                bx0, bx1, bz0, bz1 = footprint_extent(b.center[0], b.center[2], b.size[0], b.size[2], b.yaw)
                assert z0 - 1e-9 <= bz0 and bz1 <= z1 + 1e-9, (b, sh.z_range)
                assert bx1 > x0 and bx0 < x1 and bx1 - bx0 <= x1 - x0 + 1e-9, (b, sh.x_range)
                assert sh.clear_height == 0 or b.size[1] <= sh.clear_height + 1e-9
            feet = [(b.center[0], b.center[2], b.size[0], b.size[2], b.yaw) for b in sh.boxes]
            for i, a in enumerate(feet):
                for j in range(i + 1, len(feet)):
                    assert overlap_share(a, feet[j]) <= DUPLICATE_SHARE, (sh.boxes[i].id, sh.boxes[j].id)


@PROPS
@given(walks())
def test_every_published_map_keeps_its_schema_and_round_trips(walk):
    frames, motion, noisy = walk
    config = StitchConfig.noisy() if noisy else StitchConfig()
    stitcher = Stitcher(SPEC, config)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (fl, step) in enumerate(zip(frames, motion)):
            stitcher.push(fl, i, motion=step)
            wmap = stitcher.map()
            _published(wmap, Path(tmp), f"step {i}")
            _stands_on_its_shelf(wmap)
        final = _published(stitcher.map((1.0, -1.5, 0.5), {"frames": len(frames)}), Path(tmp), "end")
    if all(m is None for m in motion):  # the whole-sequence entry point builds the same map
        again = reconstruct(frames, SPEC, config, origin_world=(1.0, -1.5, 0.5), meta={"frames": len(frames)})
        assert json.loads(json.dumps(again.map.to_dict())) == final


def test_the_layouts_that_built_a_box_off_its_shelf_give_a_map_that_loads(tmp_path):
    """A briefly trained network's layouts of 5 frames: a lone box pixel beyond the shelf's depth in frame 2
    became a box wholly outside its shelf, and `run` wrote a warehouse.json its own reader refused."""
    folder = LayoutFolder(DATA)
    indices = folder.indices()
    assert indices == [0, 1, 2, 3, 4] and folder.spec == SPEC
    lone = folder.read(2).top[0]
    assert lone[2, 11] == 2 and not lone[1:4, 10:13].sum() - 2  # the stray cell, beyond the shelf's rows
    for config in (StitchConfig(), StitchConfig.noisy()):
        stitcher = Stitcher(folder.spec, config)
        for i, fl in folder_frames(folder, indices):
            stitcher.push(fl, i)
            _published(stitcher.map(), tmp_path, f"frame {i}")
            _stands_on_its_shelf(stitcher.map())
        whole = reconstruct(folder_frames(folder), folder.spec, config, indexed=True).map
        assert whole.to_dict() == stitcher.map().to_dict()
        # every box the map keeps stands within its shelf's depth: none beyond z 0.3 (the stray cell's z 0.48)
        assert all(b.center[2] < 0.3 for b in whole.boxes())


def test_a_map_that_breaks_its_schema_is_never_written(tmp_path):
    """A map the code built with a box off its shelf raises `ContractError` naming the element; nothing is
    written and the earlier file stays as it was."""
    stitcher = Stitcher(SPEC)
    folder = LayoutFolder(DATA)
    for i, fl in folder_frames(folder):
        stitcher.push(fl, i)
    wmap = stitcher.map()
    path = tmp_path / "warehouse.json"
    wmap.save(path)
    before = path.read_bytes()
    shelf = wmap.racks[0].shelves[0]
    z1 = shelf.z_range[1]
    shelf.boxes.append(MapBox("stray", (0.3, -0.2, z1 + 0.3), (0.19, 0.37, 0.09), 0.0, 0.13, 1))
    with pytest.raises(ContractError, match=r"racks\[0\]\.shelves\[0\]\.boxes\[\d+\]: box stray .* wholly outside"):
        wmap.save(path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["warehouse.json"]
    shelf.boxes.pop()
    wmap.save(path)
    assert path.read_bytes() == before

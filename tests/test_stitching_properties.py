"""Property tests: any valid layout stream stitches without crashing into a finite, plausible map;
invalid values and non-finite numbers are refused with one-line errors."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from layouts import InputError, LayoutSpec
from layouts.codecs import FrameLayouts
from stitching.detect import DetectConfig
from stitching.free_space import fits, free_space
from stitching.lift import LiftConfig
from stitching.merge import MergeConfig
from stitching.pipeline import StitchConfig, Stitcher, frame_arrays
from stitching.shift import ShiftConfig
from stitching.warehouse_map import WarehouseMap

SPEC = LayoutSpec(num_slots=2, size=32)
TINY = LayoutSpec(num_slots=2, size=12)  # small enough for hypothesis to draw every pixel
PROPS = settings(
    max_examples=150, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow]
)


def _random_world(rng: np.random.Generator, width: int, noise: float) -> np.ndarray:
    """A (2, R, D, width) strip of class ids: rectangles of random classes over a random base, plus flips."""
    R, D = SPEC.num_slots, SPEC.size
    world = np.zeros((2, R, D, width), np.uint8)
    world[:] = rng.integers(0, 2)
    for _ in range(int(rng.integers(1, 16))):
        v, r = int(rng.integers(0, 2)), int(rng.integers(0, R))
        r0, c0 = int(rng.integers(0, D)), int(rng.integers(0, width))
        world[v, r, r0 : r0 + int(rng.integers(1, D)), c0 : c0 + int(rng.integers(1, 3 * D // 2))] = rng.integers(0, 3)
    flip = rng.random(world.shape) < noise
    world[flip] = rng.integers(0, 3, int(flip.sum()), dtype=np.uint8)
    return world


def _visible(rng: np.random.Generator, kind: str) -> np.ndarray | None:
    D = SPEC.size
    if kind == "none":
        return None
    if kind == "all":
        return np.ones(D, bool)
    if kind == "empty":
        return np.zeros(D, bool)
    if kind == "range":
        a = int(rng.integers(0, D))
        v = np.zeros(D, bool)
        v[a : a + int(rng.integers(1, D + 1))] = True
        return v
    return rng.random(D) < 0.7  # scattered columns


@st.composite
def layout_streams(draw):
    """A short stream of valid frames: windows moving over a random strip (so edges can match)."""
    seed = draw(st.integers(0, 2**32 - 1))
    n = draw(st.integers(1, 6))
    step = draw(st.integers(-6, 6))
    noise = draw(st.sampled_from([0.0, 0.0, 0.02, 0.2, 1.0]))
    vis = draw(st.sampled_from(["none", "all", "range", "scattered", "empty"]))
    rng = np.random.default_rng(seed)
    D = SPEC.size
    world = _random_world(rng, 3 * D + 6 * 6, noise)
    start = 3 * 6 + D if step >= 0 else 3 * 6 + 2 * D
    frames = []
    for k in range(n):
        c = start + k * step if step >= 0 else start + k * step - D
        c = int(np.clip(c, 0, world.shape[-1] - D))
        frames.append(
            FrameLayouts(world[0, ..., c : c + D].copy(), world[1, ..., c : c + D].copy(), _visible(rng, vis))
        )
    return frames


def _check_map(st_: Stitcher, n: int) -> None:
    spec, cfg = st_.spec, st_.config
    wmap = st_.map()
    dx = spec.x_extent / spec.size
    steps = wmap.steps
    assert len(steps) == n and [s.frame for s in steps] == list(range(n))
    offs = [s.offset for s in steps]
    assert all(math.isfinite(v) for s in steps for v in (s.offset, s.shift, s.confidence))
    assert all(abs(s.shift) <= cfg.shift.max_step + 2 * dx and s.direction in (-1, 0, 1) for s in steps)
    assert all(0.0 <= s.confidence <= 1.0 for s in steps)
    x_lo, x_hi = min(offs) - spec.x_extent, max(offs) + spec.x_extent
    diag = math.hypot(spec.x_extent, spec.z_extent)
    ids = []
    for rack in wmap.racks:
        assert x_lo <= rack.x_range[0] < rack.x_range[1] <= x_hi
        assert len(rack.shelves) <= spec.num_slots
        for sh in rack.shelves:
            assert 0 <= sh.slot < spec.num_slots
            assert math.isfinite(sh.board_height) and sh.board_height >= 0
            assert 0 <= sh.clear_height <= spec.h_extent + 1e-9
            assert -spec.z_extent / 2 - 1e-9 <= sh.z_range[0] <= sh.z_range[1] <= spec.z_extent / 2 + 1e-9
            assert 0 <= sh.confidence <= 1
            # Each frame adds at most one box per component (>= 1 px) or front run per slot.
            assert len(sh.boxes) <= n * (spec.size**2 + spec.size)
            for b in sh.boxes:
                ids.append(b.id)
                w, h, d = b.size
                assert all(math.isfinite(v) for v in (*b.center, *b.size, b.yaw, b.confidence))
                assert 0 < w <= diag + 1e-9 and 0 < d <= diag + 1e-9, b
                if b.yaw == 0.0:
                    assert w <= spec.x_extent + 1e-9 and d <= spec.z_extent + 1e-9, b
                assert 0 < h <= spec.h_extent + 1e-9
                assert x_lo <= b.center[0] <= x_hi
                assert b.center[1] <= 0  # Y down: boxes stand above slot 0's board
                assert 0 <= b.confidence <= 1 and b.observations >= 1
    assert len(ids) == len(set(ids))
    assert len(wmap.racks) <= (x_hi - x_lo) / cfg.merge.min_rack_length + 1
    # Downstream consumers accept it: JSON round trip (finite values only) and free-space queries.
    again = WarehouseMap.from_dict(wmap.to_dict())
    assert len(again.boxes()) == len(wmap.boxes())
    for fs in free_space(wmap):
        assert all(math.isfinite(v) for v in (fs.free_length, fs.free_area, fs.free_volume, fs.occupancy))
        assert -1e-9 <= fs.free_length <= fs.length + 1e-9
    fits(wmap, 0.3, 0.3, 0.2, margin=0.01)


@PROPS
@given(layout_streams(), st.booleans())
def test_valid_streams_stitch_into_plausible_maps(frames, noisy):
    stitcher = Stitcher(SPEC, StitchConfig.noisy() if noisy else None)
    for i, fl in enumerate(frames):
        rec, step = stitcher.push(fl, i)
        assert all(math.isfinite(b.cx) and b.height > 0 for b in rec.boxes)
    _check_map(stitcher, len(frames))


@PROPS
@given(
    hnp.arrays(np.uint8, (3, *TINY.shape), elements=st.integers(0, 2)),
    hnp.arrays(np.uint8, (3, *TINY.shape), elements=st.integers(0, 2)),
)
def test_pure_noise_frames_stitch(tops, fronts):
    stitcher = Stitcher(TINY)
    for i, fl in enumerate(frame_arrays(tops, fronts)):
        stitcher.push(fl, i)
    _check_map(stitcher, 3)


@PROPS
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from(["top", "front"]),
    st.integers(3, 255),
    st.integers(1, 50),
)
def test_values_above_two_are_refused(seed, view, value, count):
    rng = np.random.default_rng(seed)
    top = rng.integers(0, 3, SPEC.shape, dtype=np.uint8)
    front = rng.integers(0, 3, SPEC.shape, dtype=np.uint8)
    arr = top if view == "top" else front
    arr.flat[rng.integers(0, arr.size, count)] = value
    stitcher = Stitcher(SPEC)
    with pytest.raises(InputError, match=rf"frame 4 \({view}\): class ids must be 0, 1 or 2, found {value}"):
        stitcher.push(FrameLayouts(top, front), 4)
    assert stitcher.count == 0 and stitcher.map().racks == []  # nothing half-merged


@PROPS
@given(hnp.arrays(np.uint8, (2, 8, 8), elements=st.integers(0, 255)))
def test_any_uint8_stack_of_the_wrong_shape_is_refused(arr):
    with pytest.raises(InputError, match="does not match the layout spec"):
        Stitcher(SPEC).push((arr, arr.copy()), 0)


BAD = [math.nan, math.inf, -math.inf]


@pytest.mark.parametrize("bad", BAD)
def test_non_finite_numbers_are_refused(bad):
    fl = FrameLayouts(np.zeros(SPEC.shape, np.uint8), np.zeros(SPEC.shape, np.uint8))
    vis = np.ones(SPEC.size)
    vis[3] = bad
    with pytest.raises(InputError, match=r"frame 0: visible must be bool"):
        Stitcher(SPEC).push((fl.top, fl.front, vis), 0)
    with pytest.raises(InputError, match=r"visible must be a numpy bool array"):
        Stitcher(SPEC).push((fl.top, fl.front, [True] * SPEC.size), 0)
    with pytest.raises(InputError, match=r"\(top\): dtype must be uint8, got float64"):
        Stitcher(SPEC).push((np.full(SPEC.shape, bad), fl.front), 0)
    with pytest.raises(InputError, match="LayoutSpec.x_extent must be a positive finite number"):
        LayoutSpec(size=32, x_extent=bad)
    for make, name in [
        (lambda: DetectConfig(split_step=bad), "DetectConfig.split_step"),
        (lambda: LiftConfig(board_thickness=bad), "LiftConfig.board_thickness"),
        (lambda: LiftConfig(min_profile_fraction=bad), "LiftConfig.min_profile_fraction"),
        (lambda: ShiftConfig(max_step=bad), "ShiftConfig.max_step"),
        (lambda: ShiftConfig(tol_px=bad), "ShiftConfig.tol_px"),
        (lambda: MergeConfig(match_score=bad), "MergeConfig.match_score"),
        (lambda: MergeConfig(min_rack_length=bad), "MergeConfig.min_rack_length"),
    ]:
        with pytest.raises(InputError, match=name):
            make()
    stitcher = Stitcher(SPEC)
    with pytest.raises(InputError, match="frame index must be an integer"):
        stitcher.push(fl, bad)
    with pytest.raises(InputError, match="origin_world must be three finite numbers"):
        stitcher.map(origin_world=(0.0, bad, 0.0))
    with pytest.raises(InputError, match="must be a finite number"):
        fits(stitcher.map(), 0.3, bad, 0.3)
    d = stitcher.map().to_dict()
    d["board_thickness"] = bad
    d["racks"] = [{"id": "rack_00", "x_range": [0.0, bad], "shelves": []}]
    with pytest.raises(InputError, match="malformed warehouse map"):
        WarehouseMap.from_dict(d)

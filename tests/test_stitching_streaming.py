"""Streaming: the Stitcher's memory is the map, not the number of frames pushed."""

import gc
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import stitching
from layouts import InputError, LayoutError, LayoutSpec
from stitching.merge import MergeConfig
from stitching.path_record import StepStats
from stitching.pipeline import StitchConfig, Stitcher
from stitching.synthetic import long_aisle, random_scene, stream_frames
from stitching.xindex import XIndex

SPEC = LayoutSpec(size=64)


def _back_and_forth(n_frames: int, seed: int = 0, density: str = "sparse"):
    """A camera sweeping 3 m of a short row back and forth (0.1 m per frame): 31 distinct frames."""
    scene = random_scene(np.random.default_rng(seed), length=9.0, density=density)
    frames = list(stream_frames(scene, SPEC, 2.6 + 0.1 * np.arange(31)))
    cycle = list(range(31)) + list(range(29, 0, -1))
    return [frames[cycle[i % len(cycle)]] for i in range(n_frames)]


def _map_size(st: Stitcher) -> tuple:
    b = st.builder
    return sum(len(s) for s in b.boxes), len(b.ends), b.votes.shape


def _traced_growth(st: Stitcher, frames, start: int, settle: int, window: int) -> int:
    """Growth (bytes) of memory allocated by lines of ``stitching/`` over ``window`` frames, traced
    after ``settle`` frames of tracing. Only those allocations count, so background threads of other
    libraries (e.g. a Rerun recording) cannot disturb it.
    ``settle`` must cover a whole sweep and the kept steps: objects made before tracing started and
    replaced later would otherwise count as growth."""
    only = [tracemalloc.Filter(True, str(Path(stitching.__file__).parent / "*"), all_frames=False)]
    gc.collect()
    tracemalloc.start(1)
    try:
        for i in range(start, start + settle):
            st.push(frames[i], i)
        gc.collect()
        mid = tracemalloc.take_snapshot().filter_traces(only)
        for i in range(start + settle, start + settle + window):
            st.push(frames[i], i)
        gc.collect()
        end = tracemalloc.take_snapshot().filter_traces(only)
        return sum(d.size_diff for d in end.compare_to(mid, "filename"))
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_frames_beyond_the_map():
    frames = _back_and_forth(540)
    st = Stitcher(SPEC, StitchConfig(merge=MergeConfig(keep_steps=20)))
    for i in range(180):  # warm-up: three sweeps build the whole map
        st.push(frames[i], i)
    size_warm = _map_size(st)
    for i in range(180, 300):
        st.push(frames[i], i)
    # 360 more frames (six sweeps): the map keeps its size, and the traced heap stays flat over the last
    # 180 (one StepRecord per frame alone adds ~40 kB there: see the next test's contrast).
    assert _map_size(st) == size_warm
    grown = _traced_growth(st, frames, 300, 60, 180)
    assert grown < 12 * 1024, f"stitcher memory grew by {grown} bytes over 180 frames"
    assert len(st.builder.steps) == 20 and st.builder.steps[-1].frame == 539
    stats = st.step_stats
    assert stats.frames == 540 and stats.reversals >= 8
    assert stats.methods.get("edges", 0) >= 530
    wmap = st.map()
    assert wmap.meta["step_summary"]["frames"] == 540 and len(wmap.steps) == 20
    # The camera comes back to the same places: the offsets stay on the 3 m sweep.
    assert -0.05 <= stats.offset_min and stats.offset_max <= 3.05


def test_unbounded_step_history_is_what_grows():
    frames = _back_and_forth(300)
    st = Stitcher(SPEC)
    for i in range(60):
        st.push(frames[i], i)
    grown = _traced_growth(st, frames, 60, 60, 180)
    assert grown > 30 * 1024  # the per-frame records (the camera path) are the only growth
    assert len(st.builder.steps) == 300


def test_default_keeps_every_step_and_bounded_history_keeps_the_same_map():
    frames = _back_and_forth(150, seed=1, density="moderate")
    full, ring = Stitcher(SPEC), Stitcher(SPEC, StitchConfig(merge=MergeConfig(keep_steps=10)))
    for i, fl in enumerate(frames):
        full.push(fl, i)
        ring.push(fl, i)
    a, b = full.map(), ring.map()
    assert len(a.steps) == 150 and [s.frame for s in b.steps] == list(range(140, 150))
    assert [(s.offset, s.method) for s in a.steps[-10:]] == [(s.offset, s.method) for s in b.steps]
    assert a.to_dict()["racks"] == b.to_dict()["racks"]
    assert a.meta["step_summary"] == b.meta["step_summary"]
    none = Stitcher(SPEC, StitchConfig(merge=MergeConfig(keep_steps=0)))
    none.push(frames[0], 0)
    assert len(none.map().steps) == 0 and none.step_stats.frames == 1


def test_long_aisle_per_frame_work_stays_local():
    """Map queries touch only boxes near the camera: the candidates per frame do not grow with the row."""
    scene, xs = long_aisle(3, 400, SPEC, step=0.15)
    st = Stitcher(SPEC)
    cand = []
    b = st.builder
    for i, fl in enumerate(stream_frames(scene, SPEC, xs)):
        st.push(fl, i)
        if i in (60, 399):
            off = b.steps[-1].offset
            cand.append(sum(len(b._boxes_near(r, off - 3.0, off + 3.0)) for r in range(SPEC.num_slots)))
    total = sum(len(s) for s in b.boxes)
    assert total > 4 * cand[1]  # the row holds far more boxes than any frame looks at
    assert cand[1] <= 2 * cand[0] + 10
    wmap = st.map()
    assert len(wmap.steps) == 400 and all(s.method == "edges" for s in wmap.steps[1:])
    assert abs(wmap.steps[-1].offset - (xs[-1] - xs[0])) < 0.1


def test_xindex_queries_match_a_full_scan():
    rng = np.random.default_rng(0)
    idx = XIndex(0.5)
    xs = rng.uniform(-20, 20, 300)
    for i, x in enumerate(xs):
        idx.add(i, float(x))
    for i in range(0, 300, 3):  # moves
        xs[i] += rng.uniform(-2, 2)
        idx.move(i, float(xs[i]))
    for lo, hi in [(-3.0, 4.0), (10.0, 10.1), (-100.0, 100.0), (5.0, 1.0)]:
        got = [i for i in idx.query(lo, hi) if lo <= xs[i] <= hi]
        assert got == [i for i in range(300) if lo <= xs[i] <= hi]
    assert len(idx) == 300
    with pytest.raises(ValueError):
        XIndex(0.0)


def test_config_validation_and_step_stats():
    with pytest.raises(LayoutError, match="keep_steps"):
        MergeConfig(keep_steps=-1)
    with pytest.raises(LayoutError, match="keep_steps"):
        MergeConfig(keep_steps=2.5)
    with pytest.raises(InputError, match="StitchConfig.merge"):
        StitchConfig(merge={"keep_steps": 3})
    s = StepStats()
    assert s.to_dict()["frames"] == 0

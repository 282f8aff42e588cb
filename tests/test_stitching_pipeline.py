"""Detect -> lift -> shift -> merge on small synthetic rows (stitching.synthetic) and edge cases."""

import math

import numpy as np
import pytest

from layouts import BOX, SHELF, InputError, LayoutError, LayoutSpec
from layouts.codecs import FrameLayouts, LayoutFolder
from layouts.raster import fill_rect
from stitching.detect import DetectConfig, detect_frame
from stitching.lift import lift_frame
from stitching.map_eval import covered_range, evaluate_map
from stitching.pipeline import StitchConfig, Stitcher, frame_arrays, reconstruct, stitch_folder
from stitching.synthetic import degrade, make_sequence

SPEC = LayoutSpec(size=128)


def _frame_with(boxes, spec=SPEC, clear=1.0):
    """One slot-0 shelf across the view with boxes (x, z, w, d, h, yaw)."""
    top = np.zeros(spec.shape, np.uint8)
    front = np.zeros(spec.shape, np.uint8)
    fill_rect(top[0], spec, "top", (0, 0), (3.0, 1.0), SHELF)
    fill_rect(front[0], spec, "front", (0, clear / 2), (3.0, clear), SHELF)
    for x, z, w, d, h, yaw in boxes:
        fill_rect(top[0], spec, "top", (x, z), (w, d), BOX, yaw)
        ext = abs(math.cos(yaw)) * w + abs(math.sin(yaw)) * d
        fill_rect(front[0], spec, "front", (x, h / 2), (ext, h), BOX)
    return FrameLayouts(top, front, np.ones(spec.size, bool))


def _evaluate(seq, layouts=None, records=None, config=None):
    layouts = layouts if layouts is not None else seq.layouts
    records = records if records is not None else seq.frames
    res = reconstruct(layouts, seq.spec, config)
    spec = seq.spec
    vx = (float(spec.col_to_x(0)), float(spec.col_to_x(spec.size)))
    return evaluate_map(res.map, seq.scene, records, covered_range(records, [vx] * len(records))), res.map


def test_detect_and_lift_metric_extents():
    fl = _frame_with([(-0.8, -0.1, 0.5, 0.4, 0.3, 0.0), (0.3, 0.0, 0.4, 0.6, 0.5, 0.0)])
    det = detect_frame(fl.top, fl.front, SPEC, fl.visible)
    s0 = det.slots[0]
    assert s0.present and len(s0.boxes) == 2
    assert s0.clear_height == pytest.approx(1.0, abs=SPEC.h_extent / SPEC.size)
    px = SPEC.x_extent / SPEC.size
    a, b = s0.boxes
    assert (a.x0, a.x1) == pytest.approx((-1.05, -0.55), abs=px)
    assert (b.z1 - b.z0) == pytest.approx(0.6, abs=2 * SPEC.z_extent / SPEC.size)
    rec = lift_frame(det)
    assert [round(bx.height, 1) for bx in rec.boxes] == [0.3, 0.5]
    assert all(bx.source == "top+front" for bx in rec.boxes)
    assert not det.slots[1].present and det.slots[1].boxes == []


def test_touching_boxes_of_different_depth_are_split():
    # Two boxes side by side with no gap: one component in the top view, split at the depth step.
    fl = _frame_with([(-0.25, -0.1, 0.5, 0.4, 0.3, 0.0), (0.25, 0.0, 0.5, 0.7, 0.3, 0.0)])
    det = detect_frame(fl.top, fl.front, SPEC, fl.visible)
    xs = sorted((round(b.x0, 2), round(b.x1, 2)) for b in det.slots[0].boxes)
    assert len(xs) == 2
    assert xs[0][1] == pytest.approx(0.0, abs=0.03)


def test_yaw_is_estimated_for_a_turned_box():
    yaw = math.radians(10)
    fl = _frame_with([(0.0, 0.0, 0.6, 0.4, 0.3, yaw)])
    box = detect_frame(fl.top, fl.front, SPEC, fl.visible).slots[0].boxes[0]
    assert box.yaw == pytest.approx(yaw, abs=math.radians(3))
    assert (box.w, box.d) == pytest.approx((0.6, 0.4), abs=0.04)
    no_yaw = detect_frame(fl.top, fl.front, SPEC, fl.visible, DetectConfig(fit_yaw=False)).slots[0].boxes[0]
    assert no_yaw.yaw == 0.0


def test_sequence_reconstruction_recall_and_drift():
    seq = make_sequence(seed=1, frames=30, spec=SPEC, step=0.12)
    ev, wmap = _evaluate(seq)
    assert ev.recall >= 0.95 and ev.precision >= 0.9
    assert ev.count_accuracy >= 0.95
    assert ev.drift_end <= 0.02
    ids = [b.id for b in wmap.boxes()]
    assert len(ids) == len(set(ids))
    assert all(s.method in ("first", "edges") for s in wmap.steps)
    assert all(s.direction == 1 for s in wmap.steps[1:])


def test_reversing_camera():
    seq = make_sequence(seed=2, frames=30, spec=SPEC, step=0.1, reverse_at=15)
    ev, wmap = _evaluate(seq)
    dirs = [s.direction for s in wmap.steps[1:]]
    assert dirs[:14] == [1] * 14 and dirs[14:] == [-1] * 15
    assert ev.recall >= 0.95 and ev.drift_end <= 0.02
    # Revisited boxes are fused, not duplicated.
    assert ev.fp == 0


def test_degraded_layouts_keep_recall():
    seq = make_sequence(seed=3, frames=30, spec=SPEC, step=0.1, density="moderate")
    rng = np.random.default_rng(0)
    lays = [degrade(f, rng, morph, 0.03) for f, morph in zip(seq.layouts, [1, -1] * 15)]
    recs = list(seq.frames)
    del lays[12], recs[12]  # a dropped frame
    ev, _ = _evaluate(seq, lays, recs, StitchConfig.noisy())
    assert ev.recall >= 0.85


def test_empty_layouts_and_a_single_frame():
    empty = FrameLayouts(np.zeros(SPEC.shape, np.uint8), np.zeros(SPEC.shape, np.uint8))
    res = reconstruct([empty] * 3, SPEC)
    assert res.map.racks == [] and res.frames == 3
    assert [s.method for s in res.map.steps] == ["first", "prediction", "prediction"]
    seq = make_sequence(seed=4, frames=1, spec=SPEC)
    one = reconstruct(seq.layouts, SPEC).map
    assert one.boxes() and one.steps[0].method == "first"


def test_a_frame_with_no_matches_falls_back():
    seq = make_sequence(seed=5, frames=20, spec=SPEC, step=0.1)
    lays = list(seq.layouts)
    # Frame 10 shows one featureless shelf across the whole view (no box, no rack end): no edge can
    # match, so the shift falls back to correlation or the previous velocity.
    top = np.full(SPEC.shape, SHELF, np.uint8)
    lays[10] = FrameLayouts(top, np.zeros(SPEC.shape, np.uint8), lays[10].visible)
    ev, wmap = _evaluate(seq, lays)
    assert wmap.steps[10].method in ("correlation", "prediction")
    assert wmap.steps[10].matches == 0
    assert ev.recall >= 0.9 and ev.drift_end <= 0.03


def test_still_camera_keeps_the_map_size_constant():
    """Streaming: repeated frames fuse into the same boxes; nothing grows with the frame count."""
    seq = make_sequence(seed=6, frames=1, spec=SPEC)
    st = Stitcher(SPEC)
    sizes = []
    for i in range(40):
        st.push(seq.layouts[0], i)
        sizes.append((sum(len(b) for b in st.builder.boxes), st.builder.votes.shape))
    assert sizes[5] == sizes[-1]
    assert all(abs(s.offset) < 1e-9 for s in st.builder.steps)


def test_wrong_inputs_give_one_line_errors():
    bad = FrameLayouts(np.zeros((3, 64, 64), np.uint8), np.zeros((3, 64, 64), np.uint8))
    with pytest.raises(LayoutError, match=r"frame 0.*does not match the layout spec"):
        reconstruct([bad], SPEC)
    with pytest.raises(LayoutError, match="dtype must be uint8"):
        reconstruct([(np.zeros(SPEC.shape, np.int32), np.zeros(SPEC.shape, np.uint8))], SPEC)
    with pytest.raises(InputError, match="expected FrameLayouts"):
        reconstruct([np.zeros(SPEC.shape, np.uint8)], SPEC)
    with pytest.raises(InputError, match=r"top/front must both be \(N, R, D, D\)"):
        frame_arrays(np.zeros((2, 3, 8, 8), np.uint8), np.zeros((2, 3, 8, 4), np.uint8))
    with pytest.raises(InputError, match="spec must be a LayoutSpec"):
        Stitcher("not a spec")


def _featureless(fl):
    """The same frame with one box-free shelf across the view: nothing for the edge vote."""
    top = np.full(SPEC.shape, SHELF, np.uint8)
    return FrameLayouts(top, np.zeros(SPEC.shape, np.uint8), fl.visible)


def _stitch_offsets(layouts, motions, config=None):
    st = Stitcher(SPEC, config)
    steps = [st.push(fl, i, motion=m)[1] for i, (fl, m) in enumerate(zip(layouts, motions))]
    return st, steps


def test_a_motion_estimate_carries_the_path_where_the_layouts_cannot():
    # The camera turns back at frame 15 while frames 13-17 show nothing to register on. Without a
    # motion estimate the stitcher keeps the old velocity through the turn; with the true steps
    # (as `network.model.motion` reads them from the images) it follows the camera.
    seq = make_sequence(seed=7, frames=30, spec=SPEC, step=0.1, reverse_at=15)
    lays = [(_featureless(fl) if 13 <= i <= 17 else fl) for i, fl in enumerate(seq.layouts)]
    xs = np.array([r["camera_position"][0] for r in seq.frames])
    truth = xs - xs[0]
    steps_true = [None] + np.diff(xs).tolist()
    _, blind = _stitch_offsets(lays, [None] * len(lays))
    _, guided = _stitch_offsets(lays, steps_true)
    assert [s.method for s in guided[13:18]] == ["motion"] * 5
    assert all(s.method != "motion" for s in blind)
    err_blind = max(abs(s.offset - t) for s, t in zip(blind[13:18], truth[13:18]))
    err_guided = max(abs(s.offset - t) for s, t in zip(guided, truth))
    assert err_guided < 0.02 < err_blind
    # Where the layouts agree, they decide: a hint 4 cm off does not move the registered path.
    noisy = [None] + [d + 0.04 for d in steps_true[1:]]
    _, edges = _stitch_offsets(seq.layouts, noisy)
    assert all(s.method == "edges" for s in edges[1:])
    assert max(abs(s.offset - t) for s, t in zip(edges, truth)) < 0.02


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "0.1", True])
def test_a_bad_motion_estimate_is_refused(bad):
    seq = make_sequence(seed=7, frames=2, spec=SPEC)
    st = Stitcher(SPEC)
    st.push(seq.layouts[0], 0)
    with pytest.raises(LayoutError, match="motion"):
        st.push(seq.layouts[1], 1, motion=bad)


def test_a_layout_folder_is_stitched_by_one_function(tmp_path):
    """`stitch_folder`: the folder's frames in index order, as `reconstruct` stitches them in memory; the upright
    columns given by frame index reach the stitcher; a folder that is not one is refused in one line."""
    seq = make_sequence(seed=5, frames=12, spec=SPEC, density="moderate")
    folder = LayoutFolder.create(tmp_path / "layouts", SPEC)
    for i, fl in enumerate(seq.layouts):
        folder.write(i, fl)
    seen = []
    got = stitch_folder(folder, on_frame=lambda i, *_: seen.append(i), meta={"from": "folder"})
    want = reconstruct(seq.layouts, SPEC, meta={"from": "folder"})
    assert got.map.to_dict() == want.map.to_dict() and got.frames == 12 and seen == list(range(12))
    assert got.seconds > 0
    assert stitch_folder(folder, [0, 1, 2]).frames == 3
    end = seq.scene["racks"][0]["x_max"]  # an upright where the first rack ends, in every frame's view of it
    ups = {}
    for i, rec in enumerate(seq.frames):
        c = int((end - rec["camera_position"][0] + SPEC.x_extent / 2) * SPEC.size / SPEC.x_extent)
        ups[i] = np.zeros(SPEC.size, bool)
        ups[i][max(c - 1, 0) : max(min(c + 2, SPEC.size), 0)] = True
    assert stitch_folder(folder, uprights=ups).map.uprights and not want.map.uprights
    with pytest.raises(InputError, match="must be a LayoutFolder"):
        stitch_folder(tmp_path / "layouts")

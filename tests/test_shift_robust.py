"""The camera path under a stretch of bad layouts: the motion prior rejects steps that break it, flags
them untrusted with low confidence, and the map says so (stitching.shift.MotionPrior)."""

import numpy as np
import pytest

from layouts import LayoutError, LayoutSpec
from stitching.merge import MergeConfig
from stitching.pipeline import StitchConfig, Stitcher
from stitching.shift import MotionPrior, ShiftConfig
from stitching.synthetic import make_sequence, render_frame
from stitching.warehouse_map import WarehouseMap

SPEC = LayoutSpec(size=128)
BAD = range(20, 28)


def _stitch(seq, corrupt: bool, motion: list[float] | None = None, config: StitchConfig | None = None):
    """Stitch ``seq``; with ``corrupt`` the frames in BAD are rendered where the camera is not (a wrong
    jump of 0.15-0.3 m, alternately ahead and behind: layouts that agree with the map at a wrong offset)."""
    rng = np.random.default_rng(7)
    st = Stitcher(SPEC, config)
    xs = [r["camera_position"][0] for r in seq.frames]
    levels = list(range(len(seq.frames[0]["slots"])))
    for i, fl in enumerate(seq.layouts):
        if corrupt and i in BAD:
            wrong = xs[i] + (-1) ** i * rng.uniform(0.15, 0.3)
            fl = render_frame(seq.scene, SPEC, wrong, levels)
            fl.visible = seq.layouts[i].visible
        st.push(fl, i, motion=None if motion is None or i == 0 else motion[i])
    errs = [abs(s.offset - (x - xs[0])) for s, x in zip(st.map().steps, xs)]
    return st, errs


@pytest.fixture(scope="module")
def seq():
    return make_sequence(seed=11, frames=40, spec=SPEC, step=0.1)


def test_clean_sequence_all_trusted(seq):
    st, errs = _stitch(seq, corrupt=False)
    wmap = st.map()
    assert max(errs) < 0.02
    assert all(s.trusted for s in wmap.steps)
    assert wmap.meta["registration"]["trusted"] is True
    assert wmap.meta["registration"]["untrusted_frames"] == []


def test_corrupted_stretch_is_flagged_not_bent(seq):
    st, errs = _stitch(seq, corrupt=True)
    wmap = st.map()
    assert errs[-1] < 0.05 and max(errs[BAD[-1] + 2 :]) < 0.05  # the path does not stay bent
    # every step placed off the path is flagged (a strong wrong consensus is taken for a frame, untrusted)
    assert all(not s.trusted for s, e in zip(wmap.steps, errs) if e > 0.08)
    bad = [s for s in wmap.steps if s.frame in BAD]
    good = [s for s in wmap.steps if s.frame not in BAD and s.frame > 0]
    untrusted = [s.frame for s in bad if not s.trusted]
    assert len(untrusted) >= len(bad) // 2
    assert all(s.trusted for s in good[:18])  # before the stretch
    assert np.mean([s.confidence for s in bad]) < 0.5 * np.mean([s.confidence for s in good])
    reg = wmap.meta["registration"]
    assert reg["trusted"] is False and set(untrusted) <= set(reg["untrusted_frames"])
    assert reg["untrusted_x"] and max(reg["rack_untrusted_share"].values()) > 0
    # the flags survive a save / load
    back = WarehouseMap.from_dict(wmap.to_dict())
    assert [s.trusted for s in back.steps] == [s.trusted for s in wmap.steps]


def test_a_bounded_step_history_bounds_the_untrusted_list_too(seq):
    st, _ = _stitch(seq, corrupt=True, config=StitchConfig(merge=MergeConfig(keep_steps=2)))
    reg = st.map().meta["registration"]
    assert reg["untrusted_count"] > 2 and len(reg["untrusted_frames"]) == 2 and reg["trusted"] is False


def test_agreeing_motion_keeps_steps_trusted(seq):
    """Where the layouts say nothing, a given camera step that fits the prior is trusted."""
    xs = [r["camera_position"][0] for r in seq.frames]
    motion = [0.0] + list(np.diff(xs))
    st, errs = _stitch(seq, corrupt=True, motion=motion)
    assert errs[-1] < 0.05 and max(errs) < 0.05  # the image motion tells the wrong consensus apart
    for s in st.map().steps:
        if s.method == "motion":
            assert s.trusted and s.confidence > 0


def test_prior_rejects_a_jump_and_relocks():
    cfg = ShiftConfig()
    p = MotionPrior(cfg)
    for k in range(1, 6):
        p.update(k, 0.1 * k, True)
    assert p.ready
    assert p.predict(6, 0.5, 0.0) == pytest.approx(0.1)
    assert p.agrees(0.11) and not p.agrees(0.3)
    assert p.agreement(0.1) == pytest.approx(1.0) and p.agreement(0.3) < 0.1
    g = p.gate()
    for k in range(cfg.relock):
        p.update(6 + k, 0.0, False)
    assert p.gate() > g  # a long untrusted stretch widens the gate: a real change is taken up again


def test_config_checks():
    with pytest.raises(LayoutError, match="prior_gate"):
        ShiftConfig(prior_gate=-1.0)
    with pytest.raises(LayoutError, match="override_support"):
        ShiftConfig(override_support=1.5)


def _stitch_with(seq, corrupt: range, motion: list[float], conf: float = 1.0):
    """Stitch ``seq`` with the frames in ``corrupt`` rendered 0.15-0.3 m off and ``motion`` given as the images'
    steps, blended in where they agree (``motion_gain`` 0.5)."""
    rng = np.random.default_rng(7)
    st = Stitcher(SPEC, StitchConfig(shift=ShiftConfig(motion_gain=0.5)))
    xs = [r["camera_position"][0] for r in seq.frames]
    levels = list(range(len(seq.frames[0]["slots"])))
    for i, fl in enumerate(seq.layouts):
        if i in corrupt:
            fl = render_frame(seq.scene, SPEC, xs[i] + (-1) ** i * rng.uniform(0.15, 0.3), levels)
            fl.visible = seq.layouts[i].visible
        st.push(fl, i, *((motion[i], conf) if i else ()))
    return st.map(), [abs(s.offset - (x - xs[0])) for s, x in zip(st.map().steps, xs)]


def test_good_image_steps_carry_a_long_corrupted_stretch(seq):
    """A long stretch of wrong layouts with good image steps: the path stays on the camera's."""
    xs = [r["camera_position"][0] for r in seq.frames]
    wmap, errs = _stitch_with(seq, range(12, 30), [0.0] + list(np.diff(xs)))
    assert max(errs) < 0.05 and errs[-1] < 0.03
    assert any(s.method == "edges+motion" for s in wmap.steps)  # blended where both agree


def test_wrong_image_steps_lose_to_good_layouts(seq):
    """Image steps 15 cm too long against good layouts: the layouts' offsets stand, the steps' confidence falls."""
    xs = [r["camera_position"][0] for r in seq.frames]
    right, _ = _stitch_with(seq, range(0), [0.0] + list(np.diff(xs)))
    wmap, errs = _stitch_with(seq, range(0), [0.0] + list(np.diff(xs) + 0.15))
    assert max(errs) < 0.02
    later = wmap.steps[5:]
    assert all(s.method == "edges" for s in later)  # not blended: they disagree
    assert np.mean([s.confidence for s in later]) < 0.6 * np.mean([s.confidence for s in right.steps[5:]])


def test_motion_confidence_checked(seq):
    st = Stitcher(SPEC)
    st.push(seq.layouts[0], 0)
    with pytest.raises(LayoutError, match="motion_conf"):
        st.push(seq.layouts[1], 1, 0.1, 1.5)

"""Hand-held camera walks (waresynth.handheld) and the camera path on them: a walk with stops, uneven steps and a
step back maps the boxes the steady walk maps; a path that cannot be followed is said (a warning naming the
frames) and does not bend the map."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from layouts import InputError, LayoutSpec
from stitching.geometry import Cuboid, iou_matrix
from stitching.path_record import registration_warning
from stitching.pipeline import Stitcher
from stitching.synthetic import make_sequence, render_frame
from waresynth.handheld import HandheldWalk, handheld_indices, resample_sequence, steady_indices

SPEC = LayoutSpec(size=128)
ROOT = Path(__file__).resolve().parents[1]


def test_walks_are_seeded_and_hand_held():
    walks = [handheld_indices(100, seed) for seed in range(20)]
    assert walks[3] == handheld_indices(100, 3) and walks[3] != walks[4]
    for w in walks:
        assert w[0] == 0 and all(0 <= i < 100 for i in w)
        steps = np.diff(w)
        assert steps.max() <= 4  # up to twice the usual stride of 2
        assert (steps < 0).sum() == 1  # one step back
    # stops of 3-6 frames: the same frame repeated
    runs = [len(list(g)) for w in walks for _, g in __import__("itertools").groupby(w)]
    assert max(runs) >= 3 and max(runs) <= 6
    assert steady_indices(10) == [0, 2, 4, 6, 8]


def test_walk_settings_are_checked():
    with pytest.raises(InputError, match="stride"):
        HandheldWalk(stride=0)
    with pytest.raises(InputError, match="stop_frames"):
        HandheldWalk(stop_frames=(4, 2))
    with pytest.raises(InputError, match="num_frames"):
        handheld_indices(0)


def _cuboids(wmap) -> list[Cuboid]:
    return [Cuboid(b.center, b.size, b.yaw) for b in wmap.boxes()]


def _kept(steady, hand) -> float:
    """Share of the steady map's boxes the hand-held map finds again (one-to-one, 3D IoU >= 0.5)."""
    a, b = _cuboids(steady), _cuboids(hand)
    m = iou_matrix(a, b)
    ri, ci = linear_sum_assignment(-m)
    return sum(m[i, j] >= 0.5 for i, j in zip(ri, ci)) / len(a)


def _stitch(layouts, indices):
    st = Stitcher(SPEC)
    for k, i in enumerate(indices):
        st.push(layouts[i], k)
    return st.map()


@pytest.fixture(scope="module")
def fine():
    """A fine-step row (4 cm a frame, so the steady walk steps 8 cm and the hand-held one up to 16 cm)."""
    return make_sequence(seed=5, frames=120, spec=SPEC, step=0.04)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hand_held_walk_maps_what_the_steady_walk_maps(fine, seed):
    steady_idx, hand_idx = steady_indices(120), handheld_indices(120, seed)
    steady, hand = _stitch(fine.layouts, steady_idx), _stitch(fine.layouts, hand_idx)
    assert len(steady.boxes()) >= 10
    assert _kept(steady, hand) >= 0.9
    xs = [fine.frames[i]["camera_position"][0] - fine.frames[0]["camera_position"][0] for i in hand_idx]
    errs = [abs(s.offset - x) for s, x in zip(hand.steps, xs)]
    assert max(errs) < 0.05  # stops, speed changes and the step back are followed
    assert hand.meta["registration"]["trusted"] is True


def test_a_jump_no_estimator_confirms_is_warned_and_does_not_bend_the_map(fine):
    """Frames 30-33 see the row 0.6 m further on than the camera is and the frame-to-frame correlation cannot tell:
    they are placed by the prior, flagged, held back, and the map keeps the boxes the clean walk maps."""
    idx = steady_indices(120)
    xs = [r["camera_position"][0] for r in fine.frames]
    levels = list(range(len(fine.frames[0]["slots"])))
    st = Stitcher(SPEC)
    for k, i in enumerate(idx):
        fl = fine.layouts[i]
        if 30 <= k < 34:
            fl = render_frame(fine.scene, SPEC, xs[i] + 0.6 * (-1) ** k, levels)
            fl.visible = fine.layouts[i].visible
        st.push(fl, k)
    wmap, clean = st.map(), _stitch(fine.layouts, idx)
    errs = [abs(s.offset - (xs[i] - xs[0])) for s, i in zip(wmap.steps, idx)]
    assert max(errs[:30] + errs[34:]) < 0.03  # the path is not bent
    reg = wmap.meta["registration"]
    assert reg["trusted"] is False and set(range(30, 34)) <= set(reg["untrusted_frames"])
    assert _kept(clean, wmap) >= 0.95 and len(wmap.boxes()) <= len(clean.boxes()) + 1  # no ghost boxes
    said = registration_warning(reg, len(idx))
    assert said is not None and "30-33" in said and "of 60 frames" in said
    assert registration_warning(clean.meta["registration"]) is None


def test_held_back_frames_are_placed_between_the_trusted_ones(fine):
    """A stretch with no layouts to go by (blank frames) while the camera walks on: the frames are held back and
    placed on the line between the trusted frames around them, their records updated."""
    idx = steady_indices(120)
    xs = [r["camera_position"][0] for r in fine.frames]
    st = Stitcher(SPEC)
    for k, i in enumerate(idx):
        fl = fine.layouts[i]
        if 20 <= k < 24:
            fl = type(fl)(np.zeros_like(fl.top), np.zeros_like(fl.front), fl.visible)
        st.push(fl, k)
    wmap = st.map()
    untrusted = [s.frame for s in wmap.steps if not s.trusted]
    assert untrusted and set(untrusted) <= set(range(20, 25))
    errs = [abs(s.offset - (xs[i] - xs[0])) for s, i in zip(wmap.steps, idx)]
    assert max(errs) < 0.03
    assert wmap.meta["registration"]["untrusted_left_out"] == 0


def test_resampled_sequence_reads_as_a_sequence(tiny_dataset, tmp_path):
    from waresynth.dataset import Sequence, open_dataset

    seq = open_dataset(tiny_dataset).sequences()[0]
    out = resample_sequence(seq.root, tmp_path / "walk", [0, 2, 2, 2, 5, 3, 7], note={"walk": "test"})
    walked = Sequence(out, out.name, "unknown", seq.layout_folder.spec)
    assert walked.num_frames == 7
    assert walked.frame(3)["camera_position"] == seq.frame(2)["camera_position"]
    assert walked.frame(5)["index"] == 5
    assert np.array_equal(walked.rgb(4), seq.rgb(5))
    assert np.array_equal(walked.layouts(6).top, seq.layouts(7).top)
    assert json.loads((out / "meta.json").read_text())["resampled_from"]["frames"] == [0, 2, 2, 2, 5, 3, 7]
    with pytest.raises(InputError, match="not empty"):
        resample_sequence(seq.root, out, [0])
    with pytest.raises(InputError, match="indices"):
        resample_sequence(seq.root, tmp_path / "bad", [0, 99])


def test_eval_reconstruction_walks_hand_held(tiny_dataset, capsys):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mvracklay",
            "eval-reconstruction",
            str(tiny_dataset),
            "--handheld",
            "--json",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["summary"]["sequences"] == 3 and out["summary"]["recall"] > 0
    one = sorted(p for p in tiny_dataset.iterdir() if (p / "meta.json").is_file())[0]
    from mvracklay.cli import main

    capsys.readouterr()
    assert main(["eval-reconstruction", str(one), "--handheld", "--map", "x.json"]) == 2
    err = capsys.readouterr().err
    assert "--handheld" in err and len(err.strip().splitlines()) == 1

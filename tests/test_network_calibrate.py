"""Box-logit calibration: the offsets shift only the box class, are chosen by the scores they report,
travel in the checkpoint record, and every prediction path applies them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from layouts import BOX, VIEWS
from layouts.errors import InputError
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model, save_checkpoint
from network.inference.decision import apply_box_offset, check_offsets
from network.inference.layout_eval import evaluate_sequences
from network.inference.predictor import Predictor, sequence_camera
from network.inference.result import FramePrediction
from waresynth.dataset import open_dataset


def test_apply_box_offset_moves_only_the_box_logit() -> None:
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(3, 3, 8, 8, generator=g)
    out = apply_box_offset(logits, 0.7)
    assert torch.equal(out[:, :BOX], logits[:, :BOX]) and torch.allclose(out[:, BOX], logits[:, BOX] - 0.7)
    assert apply_box_offset(logits, 0.0) is logits
    # A large offset removes every box from the argmax; a negative one only adds boxes.
    assert not (apply_box_offset(logits, 100.0).argmax(1) == BOX).any()
    assert ((apply_box_offset(logits, -0.5).argmax(1) == BOX) >= (logits.argmax(1) == BOX)).all()


@pytest.mark.parametrize(
    "value",
    [{"top": "x", "front": 0.0}, {"top": 1.0}, {"top": float("nan"), "front": 0.0}, {"top": 9.0, "front": 0}, [1, 2]],
)
def test_bad_offsets_are_refused(value) -> None:
    with pytest.raises(InputError, match="box_logit_offset"):
        check_offsets(value, "rec.json")


@pytest.fixture(scope="module")
def calibrated(tiny_checkpoint: Path, tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The tiny checkpoint calibrated with the CLI on the tiny dataset (every frame scored)."""
    out = tmp_path_factory.mktemp("cal") / "cal.pt"
    scores = out.with_name("scores.json")
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--out", str(out)]
    assert run_stage("calibrate", [*args, "--every", "1", "--threads", "1", "--quiet", "--json-out", str(scores)]) == 0
    return {"path": out, "scores": json.loads(scores.read_text())}


def test_calibrate_picks_the_best_scoring_offset_and_records_it(
    calibrated, tiny_checkpoint: Path, tiny_dataset
) -> None:
    res = calibrated["scores"]
    model, record = load_model(calibrated["path"])
    assert record["box_logit_offset"] == res["box_logit_offset"] == model.box_logit_offset
    assert (
        record["calibration"]["frames"]
        == res["frames"]
        == sum(s.num_frames for s in open_dataset(tiny_dataset).sequences())
    )
    for v in VIEWS:
        means = {g: np.nanmean([c["rack"], c["box"]]) for g, c in res["scores"][v].items()}
        assert means[f"{res['box_logit_offset'][v]:g}"] == max(means.values())
    # The weights are untouched; the uncalibrated checkpoint still loads with zero offsets.
    a, b = load_checkpoint(tiny_checkpoint)[0]["model"], load_checkpoint(calibrated["path"])[0]["model"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert load_model(tiny_checkpoint)[0].box_logit_offset == {"top": 0.0, "front": 0.0}


def test_scores_match_evaluate_with_and_without_the_offset(calibrated, tiny_checkpoint, tiny_dataset) -> None:
    seqs = open_dataset(tiny_dataset).sequences()
    res = calibrated["scores"]
    # calibrate scores each frame alone, so the same without fusing neighbouring frames (network.inference.fusion)
    raw = evaluate_sequences(load_model(tiny_checkpoint)[0], seqs, mode="stream", progress=False, fuse_tau=0)["visible"]
    cal = evaluate_sequences(load_model(calibrated["path"])[0], seqs, mode="stream", progress=False, fuse_tau=0)[
        "visible"
    ]
    for v in VIEWS:
        at0, best = res["scores"][v]["0"], res["scores"][v][f"{res['box_logit_offset'][v]:g}"]
        for c in ("rack", "box"):
            np.testing.assert_allclose(raw[v][c]["miou"], at0[c], equal_nan=True)
            np.testing.assert_allclose(cal[v][c]["miou"], best[c], equal_nan=True)


def test_predictor_applies_the_recorded_offset(tiny_checkpoint: Path, tiny_dataset: Path, tmp_path: Path) -> None:
    payload, record = load_checkpoint(tiny_checkpoint)
    record = {k: v for k, v in record.items() if not k.startswith("format")}
    record["box_logit_offset"] = {"top": 0.5, "front": -1.25}
    path = tmp_path / "off.pt"
    save_checkpoint(path, {k: v for k, v in payload.items() if k != "record_json"}, record)
    seq = open_dataset(tiny_dataset).sequences()[0]
    frames = [seq.rgb(i) for i in range(3)]
    for mode in ("stream", "window"):
        plain = list(Predictor(load_model(tiny_checkpoint)[0], sequence_camera(seq)).run(frames, mode))
        shifted = list(Predictor(load_model(path)[0], sequence_camera(seq)).run(frames, mode))
        for p, s in zip(plain, shifted):
            for v, off in record["box_logit_offset"].items():
                torch.testing.assert_close(getattr(s, v)[:, :BOX], getattr(p, v)[:, :BOX])
                torch.testing.assert_close(getattr(s, v)[:, BOX], getattr(p, v)[:, BOX] - off)


def test_calibrate_bad_input_is_one_line(tiny_checkpoint: Path, tmp_path: Path, capsys) -> None:
    shutil.copy(tiny_checkpoint, tmp_path / "c.pt")
    assert run_stage("calibrate", ["--checkpoint", str(tmp_path / "c.pt"), "--data", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]


def test_calibrate_in_place_updates_the_record_and_its_json(
    tiny_checkpoint: Path, tiny_dataset: Path, tmp_path: Path
) -> None:
    ckpt = tmp_path / "c.pt"
    shutil.copy(tiny_checkpoint, ckpt)
    shutil.copy(tiny_checkpoint.with_suffix(".json"), ckpt.with_suffix(".json"))
    assert (
        run_stage("calibrate", ["--checkpoint", str(ckpt), "--data", str(tiny_dataset), "--every", "4", "--quiet"]) == 0
    )
    record = load_checkpoint(ckpt)[1]
    beside = json.loads(ckpt.with_suffix(".json").read_text())
    assert record["box_logit_offset"] == beside["box_logit_offset"] and set(record["box_logit_offset"]) == set(VIEWS)
    assert beside["calibration"]["every"] == 4 and beside["step"] == load_checkpoint(tiny_checkpoint)[1]["step"]


def test_a_model_that_reads_no_rack_depth_gets_offset_zero_not_a_failure(tiny_dataset, monkeypatch) -> None:
    from network.training import calibrate

    class Reads:  # rack heads present, yet no frame gives a reading
        back, uprights, rack_depth_offset = object(), None, 0.25

    def outputs(model, seqs, *a):
        for k, _ in enumerate(seqs):
            yield k, 0, FramePrediction(top=None, front=None)  # no rack depth read

    monkeypatch.setattr(calibrate, "_tuning_outputs", outputs)
    model = Reads()
    res = calibrate.fit_rack_depth_offset(model, open_dataset(tiny_dataset).sequences(None), progress=False)
    assert res["rack_depth_offset"] == 0.0 and res["frames"] == 0 and np.isnan(res["error_before"])
    assert model.rack_depth_offset == 0.25  # the model's own offset is put back

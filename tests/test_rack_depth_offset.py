"""The rack-depth offset: measured by `calibrate --target rack-depth` as the reader's median error on a
tuning set, carried in the record, added to every reading, and dropped or carried with the rack heads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from layouts.errors import InputError
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.inference.decision import DEPTH_OFFSET_LIMIT, check_depth_offset
from network.inference.predictor import Predictor, rack_depth_source, sequence_camera
from waresynth.dataset import open_dataset


@pytest.mark.parametrize("value", ["0.01", True, float("nan"), float("inf"), DEPTH_OFFSET_LIMIT + 0.01, [0.01]])
def test_bad_offsets_are_refused(value) -> None:
    with pytest.raises(InputError, match="rack_depth_offset"):
        check_depth_offset(value, "rec.json")


def test_no_offset_is_zero() -> None:
    assert check_depth_offset(None, "rec.json") == 0.0 and check_depth_offset(-0.05, "rec.json") == -0.05


def readings(path: Path, data: Path) -> list[tuple[float, float]]:
    """(read depth, true depth) of every streamed frame of ``data`` by the model at ``path``."""
    model, _ = load_model(path)
    out = []
    for seq in open_dataset(data).sequences():
        truth = float(seq.scene()["row"]["depth"])
        pred = Predictor(model, sequence_camera(seq))
        out += [(o.rack_depth, truth) for o in pred.run(seq.rgb(i) for i in range(seq.num_frames))]
    return out


@pytest.fixture(scope="module")
def with_heads(tiny_checkpoint: Path, tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny network with a fitted upright head (it reads a rack depth)."""
    out = tmp_path_factory.mktemp("rd") / "uprights.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--epochs", "2"]
    assert run_stage("fit-uprights", [*args, "--out", str(out), "--threads", "1", "--quiet"]) == 0
    return out


def fake_upright_scores(front, rear, view, distance, depths) -> np.ndarray:
    """Scores peaked at a depth that varies with the camera distance: a tiny head reads no depth of its own."""
    return -((depths - (0.85 + 0.2 * (distance % 1.0))) ** 2)


def test_calibrate_centres_the_reading_and_every_reading_moves_by_it(
    with_heads, tiny_dataset, tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr("network.heads.backedge.upright_depth_scores", fake_upright_scores)
    before = readings(with_heads, tiny_dataset)
    err = np.array([r - t for r, t in before if np.isfinite(r)])
    assert err.size and np.ptp(err) > 0  # depths read, errors that differ
    out, scores = tmp_path / "cal.pt", tmp_path / "cal.json"
    args = ["--target", "rack-depth", "--checkpoint", str(with_heads), "--data", str(tiny_dataset)]
    assert (
        run_stage(
            "calibrate",
            [*args, "--every", "1", "--out", str(out), "--json-out", str(scores), "--threads", "1", "--quiet"],
        )
        == 0
    )
    assert "rack depth: offset" in capsys.readouterr().out
    model, record = load_model(out)
    offset = record["rack_depth_offset"]
    assert offset == pytest.approx(-np.median(err)) and model.rack_depth_offset == offset
    res = json.loads(scores.read_text())
    assert res["frames"] == err.size and res["error_before"] == pytest.approx(np.abs(err).mean())
    assert record["rack_depth_calibration"]["data"] == str(tiny_dataset)
    # the record only gains the offset and its source, the weights are untouched, and every reading moves by
    # the offset (capped at the top view's depth)
    src_payload, src_record = load_checkpoint(with_heads)
    payload, _ = load_checkpoint(out)
    added = ("rack_depth_offset", "rack_depth_calibration")
    assert {k: v for k, v in record.items() if k not in added} == src_record
    assert all((payload["model"][k] == v).all() for k, v in src_payload["model"].items())
    z = model.cfg.spec.z_extent
    after = readings(out, tiny_dataset)
    for (r0, _), (r1, _) in zip(before, after):
        assert (np.isnan(r0) and np.isnan(r1)) or r1 == pytest.approx(min(r0 + offset, z))
    assert f"{100 * offset:+.1f} cm calibrated" in rack_depth_source(model)
    assert "calibrated" not in rack_depth_source(load_model(with_heads)[0])
    # a refitted rack head drops the offset (it was measured on the old one)
    refit = tmp_path / "refit.pt"
    common = ["--data", str(tiny_dataset), "--epochs", "1", "--threads", "1", "--quiet"]
    assert run_stage("fit-back-edges", ["--checkpoint", str(out), *common, "--out", str(refit)]) == 0
    assert "rack_depth_offset" not in load_checkpoint(refit)[1] and load_model(refit)[0].rack_depth_offset == 0.0


def test_a_model_that_reads_no_depth_is_refused(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    args = ["--target", "rack-depth", "--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset)]
    assert run_stage("calibrate", [*args, "--out", str(tmp_path / "x.pt"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "reads no rack depth" in err
    assert not (tmp_path / "x.pt").exists()

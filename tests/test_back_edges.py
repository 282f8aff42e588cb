"""The rack depth read from the boards' back edges: geometry, the reader, the head in the model,
inference that imposes it, and the `fit-back-edges` stage."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from layouts.canonical import CanonicalView
from layouts.codecs import LayoutFolder
from layouts.errors import InputError
from layouts.rackdepth import depth_rows
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.data import row_target
from network.heads.backedge import (
    DEPTH_STEP,
    MIN_OFFSET,
    NOMINAL_THICKNESS,
    DepthReader,
    back_edge_rows,
    depth_hypotheses,
    frame_depth_scores,
)
from network.inference.predictor import Predictor
from network.inference.result import frame_layouts
from network.model.config import ModelConfig
from network.model.net import MVRackLay
from network.preprocess import DEFAULT_DISTANCE
from network.training.fit_back_edges import FitConfig, cache_features, train_head
from stitching.warehouse_map import WarehouseMap
from waresynth.dataset import open_dataset

VIEW = CanonicalView(256, 256, 3.0)


def test_back_edges_follow_the_perspective():
    m, h0 = VIEW.metres_per_pixel, VIEW.height / 2
    fronts = [h0 + 1.0 / m, h0 - 1.2 / m, h0 + 0.1 / m]  # 1 m below, 1.2 m above, 0.1 m below the camera
    rows = back_edge_rows(fronts, VIEW, 2.5, 1.0)
    assert rows.shape == (1, 2)  # the board 0.1 m from the camera height shows no usable back edge
    rho = 2.5 / 3.5
    assert rows[0, 0] == pytest.approx(h0 + 1.0 * rho / m)  # top face: from the board's top
    assert rows[0, 1] == pytest.approx(h0 + (-1.2 + NOMINAL_THICKNESS) * rho / m)  # underside: a thickness lower
    deeper = back_edge_rows(fronts, VIEW, 2.5, np.array([0.8, 1.2]))
    assert deeper.shape == (2, 2)
    assert deeper[1, 0] < deeper[0, 0] and deeper[1, 1] > deeper[0, 1]  # deeper racks: back edges nearer the horizon
    assert back_edge_rows([h0 + MIN_OFFSET / m * 0.99], VIEW, 2.5, 1.0).shape == (1, 0)
    far_below = back_edge_rows([VIEW.height + 40.0], VIEW, 2.5, 0.01)  # its back edge is off the image
    assert np.isnan(far_below).all()


def _bumps(depth: float, fronts: list[float], distance: float) -> np.ndarray:
    rows = back_edge_rows(fronts, VIEW, distance, depth)[0]
    return 0.02 + 0.97 * row_target([float(r) for r in rows if np.isfinite(r)], VIEW.height)


def test_the_reader_recovers_a_depth_and_pools_frames():
    h0, m = VIEW.height / 2, VIEW.metres_per_pixel
    reader = DepthReader(VIEW, 1.4)
    assert reader.depth is None
    assert reader.add(np.full(VIEW.height, 0.01), [h0 + 0.05 / m], 2.6) is None  # no usable board: no evidence
    fronts = [h0 + 0.9 / m, h0 - 1.1 / m]
    for d, dist in ((0.93, 2.6), (0.93, 2.4)):
        got = reader.add(_bumps(d, fronts, dist), fronts, dist)
        assert got == pytest.approx(0.93, abs=DEPTH_STEP)
    assert reader.frames == 2
    # a frame pointing elsewhere is outvoted by the two before it, and moves the argmax only by summing
    reader.add(_bumps(1.2, fronts, 2.6), fronts, 2.6)
    assert reader.depth == pytest.approx(0.93, abs=DEPTH_STEP)
    scores = frame_depth_scores(_bumps(1.1, fronts, 2.6), fronts, VIEW, 2.6, np.array([0.9, 1.1]))
    assert scores is not None and scores[1] > scores[0]


def test_a_best_depth_on_the_end_of_the_hypotheses_is_no_reading():
    reader = DepthReader(VIEW, 1.4)
    ramp = np.linspace(0.0, 1.0, len(reader.depths))
    reader.scores, reader.frames = ramp.copy(), 1  # the scores still climb at the deepest hypothesis
    assert reader.depth is None
    reader.scores = ramp[::-1].copy()  # ... or at the shallowest
    assert reader.depth is None
    reader.scores = -((reader.depths - 0.9) ** 2)  # a peak inside
    assert reader.depth == pytest.approx(0.9, abs=DEPTH_STEP)


TINY = dict(encoder_width=8, hidden=16, decoder_width=8, memory_hidden=8, lstm_layers=1)


def _model(back: bool, variant: str = "mvracklay-disc-4") -> MVRackLay:
    torch.manual_seed(0)
    return MVRackLay(ModelConfig(variant=variant, spec=LayoutSpec(size=32), back_edges=back, **TINY)).eval()


def test_the_head_is_part_of_the_model_only_when_asked():
    with_head, without = _model(True), _model(False)
    assert any(k.startswith("back.") for k in with_head.state_dict())
    assert not any(k.startswith("back.") for k in without.state_dict())
    x = torch.rand(2, 3, 3, 128, 128)
    out = with_head(x)
    assert out["back"].shape == (2, 3, 128)
    assert "back" not in without(x)
    step, _ = with_head.step(x[:, 0])
    assert step["back"].shape == (2, 128)
    assert torch.allclose(step["back"], out["back"][:, 0], atol=1e-5)  # the first frame needs no memory
    cfg = ModelConfig.from_dict(with_head.cfg.to_dict())
    assert cfg.back_edges and not ModelConfig.from_dict(without.cfg.to_dict()).back_edges
    with pytest.raises(InputError, match="back_edges"):
        ModelConfig(back_edges="yes")  # type: ignore[arg-type]


@pytest.mark.parametrize("mode", ["stream", "window"])
def test_inference_reads_gives_or_skips_the_depth(mode, monkeypatch):
    model = _model(True)
    view = model.cfg.view
    h0, m = view.height / 2, view.metres_per_pixel
    fronts = [h0 + 0.9 / m, h0 - 1.0 / m]  # boards the row head "finds"; their back edges where a 1.05 m rack puts them
    back = back_edge_rows(fronts, view, DEFAULT_DISTANCE, 1.05)[0]
    prob = 0.02 + 0.96 * row_target([float(r) for r in back], view.height)
    logits = torch.from_numpy(np.log(prob / (1 - prob))).float()
    monkeypatch.setattr("network.inference.predictor.board_peaks", lambda p, v: fronts)
    monkeypatch.setattr(model.back, "forward", lambda pooled: logits.expand(pooled.shape[0], -1))
    frames = [np.random.default_rng(i).integers(0, 255, (96, 128, 3), np.uint8) for i in range(3)]
    read = list(Predictor(model).run(frames, mode))
    assert [o.rack_depth for o in read] == pytest.approx([1.05] * 3, abs=2 * DEPTH_STEP)
    spec = model.cfg.spec
    filled = [(t > 0).any(1) for t in read[-1].layouts(spec)["top"]]
    assert all(np.array_equal(f, depth_rows(spec, read[-1].rack_depth)) for f in filled if f.any())
    off = list(Predictor(model, read_depth=False).run(frames, mode))
    assert all(math.isnan(o.rack_depth) for o in off)
    plain = replace(read[-1], rack_depth=float("nan"))
    assert np.array_equal(off[-1].layouts(spec)["top"], plain.layouts(spec)["top"])
    given = list(Predictor(model, rack_depth=0.9).run(frames, mode))
    assert all(o.rack_depth == 0.9 for o in given)
    assert not Predictor(_model(False)).reads_depth


def test_a_depth_beyond_the_top_view_is_refused():
    model = _model(True)
    with pytest.raises(InputError, match="rack-depth|depth extent"):
        Predictor(model, rack_depth=5.0)
    out = {"top": torch.zeros(3, 3, 32, 32), "front": torch.zeros(3, 3, 32, 32), "rack_depth": torch.tensor(3.0)}
    with pytest.raises(InputError, match="depth extent"):
        frame_layouts(out, model.cfg.spec)
    for extent in (1.4, 1.2, 0.9):  # the deepest hypothesis is the extent itself, never a float step past it
        assert depth_hypotheses(extent).max() == extent


def test_the_head_learns_back_edges(tiny_checkpoint, tiny_dataset):
    model, _ = load_model(tiny_checkpoint)
    seqs = open_dataset(tiny_dataset).sequences()
    data = cache_features(model, seqs, progress=False)
    assert data.pooled.shape[0] == sum(s.num_frames for s in seqs)
    assert (data.target.amax(1) > 0.99).float().mean() > 0.5  # most frames show a board's back edge
    from network.heads.backedge import BackEdgeHead

    torch.manual_seed(0)
    head = BackEdgeHead(data.pooled.shape[1], model.cfg.input_height)
    losses = train_head(head, data, FitConfig(epochs=15, batch=8, lr=3e-3), progress=False)
    assert losses[-1] < 0.6 * losses[0]


def test_fit_back_edges_writes_a_model_that_reads_the_depth(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "with_head.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset)]
    # a bf16 trunk pass
    flags = ["--epochs", "2", "--out", str(out), "--threads", "1", "--quiet", "--precision", "bf16"]
    assert run_stage("fit-back-edges", [*args, "--val", str(tiny_dataset), *flags]) == 0
    said = capsys.readouterr().out
    assert "val   rack depth error" in said and f"wrote {out}" in said
    payload, record = load_checkpoint(out)
    src, _ = load_checkpoint(tiny_checkpoint)
    assert record["model_config"]["back_edges"] is True
    assert record["back_edges"]["train_sequences"] == 3 and record["back_edges"]["epochs"] == 2
    assert record["back_edges"]["precision"] == "bf16"
    assert all(torch.equal(payload["model"][k], v) for k, v in src["model"].items())  # the trunk is untouched
    assert load_model(out)[0].back is not None
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    common = ["--checkpoint", str(out), "--threads", "1"]
    assert main(["predict", str(seq), "--out", str(tmp_path / "p"), *common]) == 0
    assert "rack depth read from the boards' back edges" in capsys.readouterr().out
    assert LayoutFolder(tmp_path / "p").indices()
    assert main(["run", str(seq), "--out", str(tmp_path / "r"), "--no-rrd", "--quiet", *common]) == 0
    meta = WarehouseMap.load(tmp_path / "r" / "warehouse.json").meta
    assert meta["rack_depth_source"] == "read"
    assert main(["run", str(seq), "--out", str(tmp_path / "s"), "--no-rrd", "--quiet", "--no-depth-read", *common]) == 0
    meta = WarehouseMap.load(tmp_path / "s" / "warehouse.json").meta
    assert meta["rack_depth_source"] == "decoder" and meta["rack_depth"] is None
    capsys.readouterr()
    assert run_stage("fit-back-edges", [*args, "--epochs", "0", "--out", str(tmp_path / "x.pt"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--epochs" in err


def test_fitting_needs_generated_ground_truth(tiny_checkpoint):
    model, _ = load_model(tiny_checkpoint)

    class Folder:  # an image folder: frames but no scene
        name = "photos"
        num_frames = 2

    with pytest.raises(InputError, match="photos: fitting the back-edge head needs a generated dataset"):
        cache_features(model, [Folder()], progress=False)
    assert replace(FitConfig(), epochs=3).epochs == 3


def test_grafting_a_files_heads_onto_a_fine_tuned_network(tiny_checkpoint, tiny_dataset, tmp_path):
    """The graft stage: the network's tensors from NET, the heads' from HEADS, flags and fit records."""
    from network.checkpoint import save_checkpoint

    def graft(heads, net, out, *only):
        return run_stage("graft", ["--heads", heads, "--net", net, "--out", out, *(["--only", *only] if only else [])])

    heads = tmp_path / "heads.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--epochs", "1"]
    assert run_stage("fit-back-edges", [*args, "--out", str(heads), "--threads", "1", "--quiet"]) == 0
    # a "fine-tuned" network: the tiny one with every weight moved
    payload, record = load_checkpoint(tiny_checkpoint)
    moved = {k: (v + 0.01 if v.is_floating_point() else v) for k, v in payload["model"].items()}
    net = tmp_path / "net.pt"
    record = {k: v for k, v in record.items() if k not in ("format", "format_version")}
    record["rack_depth_offset"] = 0.03  # measured on NET's own rack heads: it goes when HEADS' come
    save_checkpoint(net, {**{k: v for k, v in payload.items() if k != "record_json"}, "model": moved}, record)
    out = tmp_path / "grafted.pt"
    assert graft(str(heads), str(net), str(out)) == 0
    got, rec = load_checkpoint(out)
    h_payload, h_record = load_checkpoint(heads)
    assert "rack_depth_offset" not in rec
    h_rest = {k: v for k, v in h_record.items() if k not in ("format", "format_version")}
    save_checkpoint(
        heads, {k: v for k, v in h_payload.items() if k != "record_json"}, {**h_rest, "rack_depth_offset": -0.01}
    )
    assert graft(str(heads), str(net), str(tmp_path / "g2.pt")) == 0
    assert load_model(tmp_path / "g2.pt")[0].rack_depth_offset == -0.01  # HEADS' offset comes with its heads
    assert rec["model_config"]["back_edges"] is True and rec["back_edges"] == h_record["back_edges"]
    assert rec["heads_grafted_from"] == str(heads)
    assert all(torch.equal(got["model"][k], v) for k, v in moved.items())
    back = [k for k in h_payload["model"] if k.startswith("back.")]
    assert back and all(torch.equal(got["model"][k], h_payload["model"][k]) for k in back)
    assert load_model(out)[0].back is not None
    assert graft(str(net), str(net), str(tmp_path / "none.pt")) == 2  # no heads to copy
    # --only: some of the heads (here the one it has), or none when HEADS lacks those asked for
    assert graft(str(heads), str(net), str(tmp_path / "only.pt"), "back_edges") == 0
    assert load_checkpoint(tmp_path / "only.pt")[1]["heads_grafted"] == ["back_edges"]
    assert graft(str(heads), str(net), str(tmp_path / "up.pt"), "uprights") == 2
    assert not (tmp_path / "up.pt").exists()

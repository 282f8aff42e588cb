"""The rack depth read from the rear uprights: geometry, the head in the model, the reader (alone and
with the back edges), the targets from the generator, the fit and the `fit-uprights` stage."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from layouts.canonical import CanonicalView
from layouts.codecs import LayoutFolder
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.heads.backedge import DepthReader, depth_hypotheses
from network.heads.uprights import REAR_FACE, UprightHead, column_offsets, upright_depth_scores
from network.inference.predictor import Predictor
from network.model.config import ModelConfig
from network.model.net import MVRackLay
from network.training.fit_back_edges import FitConfig
from network.training.fit_uprights import cache_features, train_head, upright_targets
from stitching.warehouse_map import WarehouseMap
from waresynth.dataset import open_dataset
from waresynth.semantics import RACK
from waresynth.visibility import REAR_UPRIGHT_FACE, upright_faces

VIEW = CanonicalView(256, 256, 3.0)


def marks(view: CanonicalView, distance: float, depth: float, xs: list[float], width: float = 0.08) -> np.ndarray:
    """Upright probabilities ``(2, W)`` of a frame with front uprights at front-plane offsets ``xs`` (metres,
    ``width`` wide) and their rear partners where a rack ``depth`` deep puts them."""
    x = column_offsets(view)
    rho = distance / (distance + depth - REAR_FACE)
    out = np.full((2, view.width), 0.02)
    for x0 in xs:
        out[0][(x >= x0) & (x < x0 + width)] = 0.97
        out[1][(x >= x0 * rho) & (x < (x0 + width) * rho)] = 0.97
    return out


def test_rear_uprights_give_the_depth():
    depths = depth_hypotheses(1.4)
    for true in (0.8, 1.0, 1.2):
        ups = marks(VIEW, 2.6, true, [-1.3, -0.2, 0.9])
        s = upright_depth_scores(ups[0], ups[1], VIEW, 2.6, depths)
        assert depths[int(np.argmax(s))] == pytest.approx(true, abs=0.03)
    # a front upright near the axis says nothing (its rear partner sits behind it); none at all: no evidence
    assert upright_depth_scores(*marks(VIEW, 2.6, 1.0, [0.05]), VIEW, 2.6, depths) is None
    assert upright_depth_scores(np.zeros(256), np.zeros(256), VIEW, 2.6, depths) is None


def test_the_reader_sums_frames_and_weighs_the_back_edges_less():
    reader = DepthReader(VIEW, 1.4)
    # frames with uprights at different offsets: each alone has spurious matches, the sum has one peak
    for xs in ([-1.2, 0.7], [-0.9, 1.1], [0.5, 1.3]):
        depth = reader.add(None, [], 2.5, marks(VIEW, 2.5, 0.95, xs))
    assert depth == pytest.approx(0.95, abs=0.02)
    # back edges that say 1.2 m do not outvote the uprights (weighted `BACK_EDGE_WEIGHT`)
    from network.data import row_target
    from network.heads.backedge import back_edge_rows

    h0, m = VIEW.height / 2, VIEW.metres_per_pixel
    fronts = [h0 + 0.9 / m]
    back = back_edge_rows(fronts, VIEW, 2.5, 1.2)[0]
    prob = 0.02 + 0.96 * row_target([float(r) for r in back], VIEW.height)
    both = DepthReader(VIEW, 1.4)
    for xs in ([-1.2, 0.7], [-0.9, 1.1], [0.5, 1.3]):
        depth = both.add(prob, fronts, 2.5, marks(VIEW, 2.5, 0.95, xs))
    assert depth == pytest.approx(0.95, abs=0.02)
    edges_only = DepthReader(VIEW, 1.4)
    assert edges_only.add(prob, fronts, 2.5) == pytest.approx(1.2, abs=0.05)  # what the edges alone say
    assert DepthReader(VIEW, 1.4).add(None, [], 2.5, None) is None
    # a calibrated offset moves every reading, never past the top view's depth, and gives none where none was
    plain, shifted = DepthReader(VIEW, 1.4), DepthReader(VIEW, 1.4, offset=0.013)
    capped = DepthReader(VIEW, 1.0, offset=0.2)
    for xs in ([-1.2, 0.7], [-0.9, 1.1], [0.5, 1.3]):
        ups = marks(VIEW, 2.5, 0.95, xs)
        assert shifted.add(None, [], 2.5, ups) == pytest.approx(plain.add(None, [], 2.5, ups) + 0.013)
        assert capped.add(None, [], 2.5, ups) == pytest.approx(1.0)
    assert DepthReader(VIEW, 1.4, offset=0.05).add(None, [], 2.5, None) is None


def test_the_head_is_in_the_model_and_its_reading_in_inference():
    from tiny_net import tiny_config

    spec = LayoutSpec(size=16)
    model = MVRackLay(tiny_config(spec, uprights=True)).eval()
    plain = MVRackLay(tiny_config(spec)).eval()
    assert model.uprights is not None and plain.uprights is None
    assert ModelConfig.from_dict(model.cfg.to_dict()).uprights
    x = torch.rand(2, 4, 3, 64, 64)
    out = model(x)
    assert out["uprights"].shape == (2, 4, 2, 64) and "uprights" not in plain(x)
    step, _ = model.step(x[:, 0])
    assert torch.allclose(step["uprights"], out["uprights"][:, 0], atol=1e-5)  # the first frame needs no memory
    head = UprightHead(10, 30)
    assert head(torch.rand(3, 10, 15)).shape == (3, 2, 30)
    frames = [np.random.default_rng(i).integers(0, 255, (64, 64, 3), np.uint8) for i in range(3)]
    pred = Predictor(model)
    assert pred.reads_depth and not Predictor(model, read_depth=False).reads_depth
    for mode in ("stream", "window"):
        outs = list(Predictor(model).run(frames, mode))
        assert all(o.maps["uprights"].shape == (2, 64) for o in outs)


def test_upright_faces_split_the_rack_by_depth():
    sem = np.full((4, 5), RACK, np.uint8)
    sem[:, 4] = 0
    depth = np.array([[2.5, 2.5 + 1.0 - REAR_UPRIGHT_FACE, 5.0, 2.55, 2.5]] * 4)
    front, rear = upright_faces(sem, depth, 2.5, 1.0)
    assert front[:, 0].all() and front[:, 3].all() and not front[:, [1, 2, 4]].any()
    assert rear[:, 1].all() and not rear[:, [0, 2, 3, 4]].any()
    with pytest.raises(Exception, match="differ in shape"):
        upright_faces(sem, depth[:2], 2.5, 1.0)


def test_the_head_learns_the_generators_uprights(tiny_checkpoint, tiny_dataset):
    model, _ = load_model(tiny_checkpoint)
    seqs = open_dataset(tiny_dataset).sequences()
    target, inside = upright_targets(seqs[0], 0, model.cfg.view, float(seqs[0].scene()["row"]["depth"]))
    assert target.shape == (2, model.cfg.view.width) and inside.any()
    data = cache_features(model, seqs, progress=False)
    assert data.pooled.shape[0] == sum(s.num_frames for s in seqs)
    assert (data.target[:, 0].amax(1) > 0.5).float().mean() > 0.5  # most frames show a front upright
    assert (data.target[:, 1].amax(1) > 0.5).float().mean() > 0.5  # and a rear one
    torch.manual_seed(0)
    head = UprightHead(data.pooled.shape[1], model.cfg.input_width)
    losses = train_head(head, data, FitConfig(epochs=15, batch=8, lr=3e-3, pos_weight=3.0), progress=False)
    assert losses[-1] < 0.6 * losses[0]


def test_fit_uprights_writes_a_model_that_reads_the_depth(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "with_uprights.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset)]
    assert (
        run_stage(
            "fit-uprights",
            [*args, "--val", str(tiny_dataset), "--epochs", "2", "--out", str(out), "--threads", "1", "--quiet"],
        )
        == 0
    )
    said = capsys.readouterr().out
    assert "val   rack depth error from the uprights" in said and "marks precision / recall" in said
    payload, record = load_checkpoint(out)
    src, _ = load_checkpoint(tiny_checkpoint)
    assert record["model_config"]["uprights"] is True and record["uprights"]["epochs"] == 2
    assert all(torch.equal(payload["model"][k], v) for k, v in src["model"].items())  # the trunk is untouched
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    common = ["--checkpoint", str(out), "--threads", "1"]
    assert main(["predict", str(seq), "--out", str(tmp_path / "p"), "--whole-sequence", *common]) == 0
    assert LayoutFolder(tmp_path / "p").indices()
    assert main(["run", str(seq), "--out", str(tmp_path / "r"), "--no-rrd", "--quiet", *common]) == 0
    assert WarehouseMap.load(tmp_path / "r" / "warehouse.json").meta["rack_depth_source"] == "read"
    capsys.readouterr()
    assert run_stage("fit-uprights", [*args, "--sequences", "0", "--out", str(tmp_path / "x.pt"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--sequences" in err

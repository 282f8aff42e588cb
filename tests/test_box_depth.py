"""Each box's depth read by a head and carried along the row: the redraw, the carried map, the head in
the model and inference, the fit, and the `fit-box-depth` stage."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.measure import label

from layouts import BOX, SHELF
from layouts.boxdepth import box_parts, cell_z, impose_box_backs
from layouts.codecs import LayoutFolder
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.heads.boxdepth import BINS, MIN_WEIGHT, BoxDepthReader, RowMap, decode, reading
from network.inference.predictor import Predictor
from network.inference.result import frame_layouts
from network.model.net import MVRackLay
from network.training.box_cache import Cache, Chain, FrameChoice, cache_inputs, column_targets
from network.training.fit_box_depth import FitConfig, train_head, with_box_head
from network.training.kept_box_cache import part_name
from network.training.toy import ToySequence
from stitching.warehouse_map import WarehouseMap
from waresynth.dataset import open_dataset
from waresynth.visibility import SeenTracker

SPEC = LayoutSpec(size=16)


def slot_with_box(spec: LayoutSpec, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray]:
    """One slot: the whole top view shelf with a box at ``rows`` x ``cols``; the front view shows it."""
    top = np.full((1, spec.size, spec.size), SHELF, np.uint8)
    top[0, rows, cols] = BOX
    front = np.zeros_like(top)
    front[0, -4:, cols] = BOX
    return top, front


def test_box_backs_move_the_back_and_keep_the_front():
    top, front = slot_with_box(SPEC, slice(10, 14), slice(3, 7))
    depth = 1.0
    zc = cell_z(SPEC, depth)
    (cols, zf, zb, _), *rest = list(box_parts(top[0], front[0], SPEC, depth))
    assert not rest and list(cols) == [3, 4, 5, 6]
    deeper = zb[0] + 0.3
    backs = np.full((1, SPEC.size), np.nan)
    backs[0, 3:6] = deeper  # column 6 unknown: it takes the box's back too (one cuboid)
    out = impose_box_backs(top, front, SPEC, depth, backs)
    for j in (3, 4, 5, 6):
        box = np.nonzero(out[0, :, j] == BOX)[0]
        assert box.max() == 13  # the front row stays
        assert zc[box.min()] == pytest.approx(deeper, abs=SPEC.z_extent / SPEC.size)  # the back moved deeper
        assert box.min() < 10
    cells = (out[0, :, 3:7] == BOX).sum(0).tolist()
    backs[0, 3:6] = [deeper, deeper, zb[0] - 1.0]  # one column read in front of the box's front
    out = impose_box_backs(top, front, SPEC, depth, backs)
    assert (label(out[0] == BOX, connectivity=1).max(), (out[0, :, 3:7] == BOX).sum(0).tolist()) == (1, cells)
    backs[0, 3:6] = zb[0] - 1.0  # every column in front of the box's front: the front cells stay a box
    assert (impose_box_backs(top, front, SPEC, depth, backs)[0] == BOX).sum(0)[3:7].tolist() == [1] * 4
    assert np.array_equal(top[0, 10:14, 3:7], np.full((4, 4), BOX))  # the input is not changed
    coarse = np.full((1, SPEC.size // 4), zb[0] - 0.1)  # a coarser grid of columns: a shallower box
    shallow = impose_box_backs(top, front, SPEC, depth, coarse)
    assert (shallow[0, :, 3:7] == BOX).sum() < (top[0, :, 3:7] == BOX).sum()
    with pytest.raises(ValueError, match="backs must be"):
        impose_box_backs(top, front, SPEC, depth, np.zeros(SPEC.size))
    with pytest.raises(ValueError, match="rack depth"):
        impose_box_backs(top, front, SPEC, float("nan"), backs)


def test_boxes_side_by_side_get_their_own_backs_where_their_heights_step():
    spec = LayoutSpec(size=64)
    depth = 1.0
    top, front = slot_with_box(spec, slice(40, 50), slice(10, 30))  # one component, two boxes touching
    front[0] = SHELF
    front[0, -20:, 10:20] = BOX  # the left box is twice as tall as the right one
    front[0, -10:, 20:30] = BOX
    backs = np.full((1, spec.size), np.nan)
    backs[0, 10:20], backs[0, 20:30] = 0.3, 0.6
    backs[0, 12] = 0.9  # one stray reading does not move its box's back
    zc = cell_z(spec, depth)
    cell = spec.z_extent / spec.size

    def back_of(out: np.ndarray, j: int) -> float:
        return float(zc[np.nonzero(out[0, :, j] == BOX)[0].min()] + cell / 2)

    out = impose_box_backs(top, front, spec, depth, backs)
    assert [back_of(out, j) for j in range(10, 20)] == pytest.approx([0.3] * 10, abs=cell)
    assert [back_of(out, j) for j in range(20, 30)] == pytest.approx([0.6] * 10, abs=cell)
    one = impose_box_backs(top, front, spec, depth, backs, split=False)  # one back per component
    assert len({back_of(one, j) for j in range(10, 30)}) == 1
    backs[0, 20:30] = np.nan  # a piece with no reading takes the component's
    out = impose_box_backs(top, front, spec, depth, backs)
    assert [back_of(out, j) for j in range(10, 30)] == pytest.approx([0.3] * 20, abs=cell)
    front[0, -20:, 20:30] = BOX  # equal heights: one box as far as the front view tells, one back
    backs[0, 20:30] = 0.6
    out = impose_box_backs(top, front, spec, depth, backs)
    assert len({back_of(out, j) for j in range(10, 30)}) == 1


def test_a_box_the_front_view_does_not_show_is_left():
    top, front = slot_with_box(SPEC, slice(10, 14), slice(3, 7))
    front[:] = SHELF
    out = impose_box_backs(top, front, SPEC, 1.0, np.full((1, SPEC.size), 0.2))
    assert np.array_equal(out, top)


def bins_around(depth: float, sigma: float = 0.08) -> np.ndarray:
    """``(K,)`` log-probabilities of a Gaussian reading over `BINS` centred at ``depth``."""
    lg = -0.5 * ((BINS - depth) / sigma) ** 2
    return lg - np.log(np.exp(lg).sum())


def test_the_row_map_carries_depths_with_the_camera():
    reader = BoxDepthReader(SPEC)
    k, d = len(BINS), SPEC.size
    log_q = np.broadcast_to(bins_around(0.4)[None, :, None], (1, k, d)).copy()
    p = np.zeros((1, d))
    p[0, 8] = 0.9  # only column 8 counts
    first = reader.add(log_q, p, np.array([True]))
    assert first[0, 8] == pytest.approx(0.4, abs=0.005) and np.isnan(np.delete(first[0], 8)).all()
    step = SPEC.x_extent / SPEC.size  # the camera moves one column along +X: the same shelf is one column left
    second = reader.add(np.zeros((1, k, d)), np.zeros((1, d)), np.array([True]), step)
    assert second[0, 7] == pytest.approx(first[0, 8]) and np.isnan(second[0, 8])
    assert np.isnan(reader.add(log_q, p, np.array([False]))).all()  # a slot without an anchor gets nothing
    assert np.isnan(reader.backs(-10.0, np.array([True]))).all()  # far away: never in view


def test_the_row_map_fuses_the_frames_by_how_sure_and_how_shown_each_is():
    m = RowMap()
    cell = np.array([3])
    flat = np.full((len(BINS), 1), -np.log(len(BINS)))
    # a flat guess changes nothing, however shown: the sharp reading decides
    m.add(cell, bins_around(0.4)[:, None], np.array([0.9]))
    assert m.update(cell, flat, np.array([0.9]))[0] == pytest.approx(0.4, abs=0.005)
    # two readings as sure: the product lands between them by their shown probabilities (0.9 and 0.3)
    m = RowMap()
    m.add(cell, bins_around(0.4)[:, None], np.array([0.9]))
    m.add(cell, bins_around(0.6)[:, None], np.array([0.3]))
    assert m.mean(cell)[0] == pytest.approx((0.9 * 0.4 + 0.3 * 0.6) / 1.2, abs=0.005)
    # the sharper of two readings weighs more (a product of Gaussians: precision-weighted)
    m = RowMap()
    m.add(cell, bins_around(0.4, 0.05)[:, None], np.array([0.5]))
    m.add(cell, bins_around(0.6, 0.10)[:, None], np.array([0.5]))
    assert m.mean(cell)[0] == pytest.approx((0.4 / 0.05**2 + 0.6 / 0.10**2) / (1 / 0.05**2 + 1 / 0.10**2), abs=0.005)
    # the map grows both ways along X; cells never in view, or shown less than MIN_WEIGHT in all, stay NaN
    m.add(np.array([-2, 10, 12]), np.stack([bins_around(0.3), bins_around(0.7), bins_around(0.7)], 1), [1.0, 0.0, 0.3])
    got = m.mean(np.array([-2, -1, 3, 10, 11, 12]))
    assert got[0] == pytest.approx(0.3, abs=0.005) and np.isnan(got[[1, 3, 4, 5]]).all() and np.isfinite(got[2])
    m.add(np.array([12]), bins_around(0.7)[:, None], np.array([MIN_WEIGHT - 0.3]))  # now shown enough
    assert m.mean(np.array([12]))[0] == pytest.approx(0.7, abs=0.005)


def test_decode_gives_the_expected_depth_and_shown_probability():
    logits = torch.full((1, len(BINS) + 1, 2), -30.0)
    logits[0, 3, 0] = logits[0, 7, 1] = 30.0
    logits[0, -1] = torch.tensor([5.0, -5.0])
    z, p = decode(logits)
    assert z[0] == pytest.approx([BINS[3], BINS[7]], abs=1e-4)
    log_q, shown = reading(logits)
    assert np.array_equal(shown, p)
    assert log_q.shape == (1, len(BINS), 2) and np.exp(log_q).sum(1) == pytest.approx(np.ones((1, 2)))
    assert log_q[0, 3, 0] == pytest.approx(0.0, abs=1e-6) and log_q[0, 4, 0] < -50
    assert p[0, 0] > 0.99 and p[0, 1] < 0.01


def test_the_head_is_part_of_the_model_and_inference_only_when_asked():
    from tiny_net import tiny_config

    plain = MVRackLay(tiny_config(SPEC)).eval()
    assert plain.box_depth is None
    torch.nn.init.constant_(plain.rows.net[-1].bias, 2.0)
    seq = ToySequence(SPEC, num_frames=4, image_size=(64, 64))
    frames = [seq.rgb(i) for i in range(4)]
    assert next(iter(Predictor(plain).run(frames))).box_back is None
    model = with_box_head(plain)
    assert model.box_depth is not None and plain.box_depth is None
    a, b = plain.state_dict(), model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)  # the trunk is the same
    for mode in ("stream", "window"):
        for flip in (False, True):
            outs = list(Predictor(model, flip=flip, rack_depth=0.8).run(frames, mode))
            assert all(o.box_back.shape == (SPEC.num_slots, SPEC.size) for o in outs)
            ref = list(Predictor(plain, flip=flip, rack_depth=0.8).run(frames, mode))
            assert all(torch.equal(o.top, r.top) for o, r in zip(outs, ref))  # the logits are the plain model's
    naive = list(Predictor(model, rack_depth=0.8).window(frames, recompute=True))  # the whole window re-run
    cached = list(Predictor(model, rack_depth=0.8).window(frames))
    assert all(np.allclose(n.box_back, c.box_back, atol=1e-4, equal_nan=True) for n, c in zip(naive, cached))
    off = list(Predictor(model, rack_depth=0.8, read_depth=False).run(frames))
    assert off[-1].box_back is None
    with torch.no_grad():  # a head that says every column is shown at 0.3 m: every box gets that back
        model.box_depth.out.weight.zero_()
        model.box_depth.out.bias.fill_(-20.0)
        model.box_depth.out.bias[int(np.argmin(np.abs(BINS - 0.3)))] = 20.0
        model.box_depth.out.bias[-1] = 20.0
    outs = list(Predictor(model, rack_depth=0.8).run(frames))
    valid = np.isfinite(outs[-1].anchors.numpy())
    assert valid.any() and np.allclose(outs[-1].box_back[valid], 0.3, atol=1e-3)
    assert np.isnan(outs[-1].box_back[~valid]).all()


def test_frame_layouts_move_every_box_to_the_carried_back():
    top, front = slot_with_box(SPEC, slice(10, 14), slice(3, 7))
    top, front = (np.repeat(v, SPEC.num_slots, 0) for v in (top, front))

    def logits(lay: np.ndarray) -> torch.Tensor:
        return 10.0 * torch.nn.functional.one_hot(torch.from_numpy(lay).long(), 3).permute(0, 3, 1, 2).float()

    depth = 1.0
    backs = np.full((SPEC.num_slots, SPEC.size), np.nan)
    backs[1] = 0.9  # slot 1 only: deeper than drawn
    out = {"top": logits(top), "front": logits(front), "rack_depth": torch.tensor(depth, dtype=torch.float64)}
    plain = frame_layouts(out, SPEC)["top"]
    moved = frame_layouts({**out, "box_back": torch.from_numpy(backs)}, SPEC)["top"]
    assert np.array_equal(moved[[0, 2]], plain[[0, 2]])
    ((_, _, zb_plain, _),) = box_parts(plain[1], front[1], SPEC, depth)
    ((_, _, zb, _),) = box_parts(moved[1], front[1], SPEC, depth)
    assert np.all(zb_plain < 0.8) and np.allclose(zb, 0.9, atol=SPEC.z_extent / SPEC.size)
    unknown = frame_layouts(
        {**out, "rack_depth": torch.tensor(float("nan")), "box_back": torch.from_numpy(backs)}, SPEC
    )
    assert np.array_equal(unknown["top"], frame_layouts({**out, "rack_depth": torch.tensor(float("nan"))}, SPEC)["top"])


def test_column_targets_pool_the_truth_to_the_model_columns():
    spec = LayoutSpec(size=8)
    top = np.full((1, 8, 8), SHELF, np.uint8)
    top[0, 5:8, 2:4] = BOX
    labels = np.full((1, 8), -1)
    labels[0, 2] = 2
    top[0, 7, 2] = SHELF  # column 2's box starts a row deeper (its setback)
    back, shown, front = column_targets(top, labels, spec, 1.0, 4)
    zc, half = cell_z(spec, 1.0), spec.z_extent / 16
    assert np.isnan(back[0, 0]) and back[0, 1] == pytest.approx(zc[5] + half) and np.isnan(back[0, 2:]).all()
    assert shown[0].tolist() == [False, True, False, False]
    # the front edge of the nearest box cell, behind the rack front, averaged over the two layout columns
    assert front[0, 1] == pytest.approx((zc[6] + zc[7]) / 2 - half) and np.isnan(front[0, [0, 2, 3]]).all()
    with pytest.raises(InputError, match="evenly"):
        column_targets(top, labels, spec, 1.0, 3)


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_the_head_learns_box_depths(tiny_checkpoint, tiny_dataset, tmp_path, precision):
    model = with_box_head(load_model(tiny_checkpoint)[0])
    seqs = open_dataset(tiny_dataset).sequences()
    data = cache_inputs(model, seqs, SeenTracker, tmp_path, progress=False)
    assert len(data) > 0 and data.win.dtype == np.float16 and np.isfinite(data.back).any()
    torch.manual_seed(0)
    from network.heads.boxdepth import BoxDepthHead

    head = BoxDepthHead(data.win.shape[1], data.extra.shape[1])
    losses = train_head(head, data, FitConfig(epochs=12, batch=8, lr=3e-3, precision=precision), progress=False)
    assert losses[-1] < 0.7 * losses[0]
    assert all(p.dtype == torch.float32 for p in head.parameters())  # bf16 autocast: the weights stay float32


def test_the_fit_refuses_an_unknown_precision_on_one_line():
    with pytest.raises(InputError, match="--precision must be one of fp32, bf16, got 'fp16'"):
        FitConfig(precision="fp16").validate()


def test_fit_box_depth_writes_a_model_that_reads_box_depths(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "with_head.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset)]
    common = ["--threads", "1", "--quiet"]
    assert (
        run_stage("fit-box-depth", [*args, "--epochs", "1", "--out", str(out), "--cache-dir", str(tmp_path), *common])
        == 0
    )
    assert f"wrote {out}" in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith("box-depth-")] == []  # the cache is removed
    payload, record = load_checkpoint(out)
    src, _ = load_checkpoint(tiny_checkpoint)
    assert record["model_config"]["box_depth"] is True and record["box_depth"]["train_sequences"] == 3
    assert all(torch.equal(payload["model"][k], v) for k, v in src["model"].items())  # the trunk is untouched
    assert load_model(out)[0].box_depth is not None
    again = tmp_path / "again.pt"  # refitting a model with the head replaces the head
    assert run_stage("fit-box-depth", ["--checkpoint", str(out), "--data", str(tiny_dataset), "--epochs", "1",
                 "--out", str(again), *common]) == 0  # fmt: skip
    assert load_model(again)[0].box_depth is not None
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    run = ["--checkpoint", str(out), "--threads", "1"]
    assert main(["predict", str(seq), "--out", str(tmp_path / "p"), "--rack-depth", "0.8", *run]) == 0
    assert LayoutFolder(tmp_path / "p").indices()
    assert main(["run", str(seq), "--out", str(tmp_path / "r"), "--no-rrd", "--quiet", *run]) == 0
    assert WarehouseMap.load(tmp_path / "r" / "warehouse.json").meta["box_depth_source"] == "read"
    capsys.readouterr()
    assert run_stage("fit-box-depth", [*args, "--epochs", "0", "--out", str(tmp_path / "x.pt"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--epochs" in err


def test_fitting_needs_depth_instance_and_scene(tiny_checkpoint, tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    from PIL import Image

    for i in range(2):
        Image.fromarray(np.zeros((64, 64, 3), np.uint8)).save(photos / f"{i:03d}.png")
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(photos), "--quiet"]
    assert run_stage("fit-box-depth", args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "photos" in err


def test_parallax_history_reads_the_depth_of_what_moved_and_nothing_at_a_start():
    """A texture on the front plane moves by the camera's full step: against the frames 1 and 3 back the
    plane with ratio 1 matches best; the first frame has no earlier one and gives zero maps."""
    from layouts.canonical import CanonicalView
    from network.heads.boxdepth import PARALLAX_BASELINES, PARALLAX_CHANNELS, ParallaxHistory
    from network.heads.parallax import RATIOS

    view = CanonicalView(64, 32, 3.0)
    g = torch.Generator().manual_seed(0)
    strip = torch.rand(1, 3, 1, 160, generator=g).expand(1, 3, 32, 160).contiguous()
    m, k = view.metres_per_pixel, len(RATIOS)
    hist = ParallaxHistory(view)
    maps = [hist.add(torch.roll(strip, -3 * i, dims=-1)[..., 32:96], 3 * m if i else 0.0) for i in range(5)]
    assert all(tuple(x.shape) == (1, PARALLAX_CHANNELS, 16, 32) for x in maps)
    assert float(maps[0].abs().max()) < 1e-4
    for j, _ in enumerate(PARALLAX_BASELINES):
        rel = maps[-1][0, j * (k + 1) : j * (k + 1) + k, 2:-2, 2:-2]
        best = torch.tensor(RATIOS)[rel.argmin(0)]
        assert (best == 1.0).float().mean() > 0.9
        assert float(maps[-1][0, j * (k + 1) + k].mean()) > 0.0  # the mean cost: there is texture to match
    wrong = ParallaxHistory(view)  # told the camera went the other way: the front plane is not found
    for i in range(4):
        out = wrong.add(torch.roll(strip, -3 * i, dims=-1)[..., 32:96], -3 * m if i else 0.0)
    rel = out[0, :k, 2:-2, 2:-2]
    assert (torch.tensor(RATIOS)[rel.argmin(0)] == 1.0).float().mean() < 0.5


def test_a_head_reading_parallax_fits_round_trips_and_needs_the_head(tiny_checkpoint, tiny_dataset, tmp_path):
    from dataclasses import replace

    from network.heads.boxdepth import PARALLAX_CHANNELS

    base = load_model(tiny_checkpoint)[0]
    with pytest.raises(InputError, match="box_parallax .* needs box_depth"):
        replace(base.cfg, box_parallax=True, box_depth=False)
    plain = with_box_head(base)
    model = with_box_head(plain, parallax=True)  # a head of the other kind is replaced
    assert model is not plain and model.cfg.box_parallax
    c_in = [next(m.box_depth.conv2d.parameters()).shape[1] for m in (plain, model)]
    assert c_in[1] == c_in[0] + PARALLAX_CHANNELS
    assert with_box_head(model, parallax=True) is model
    seqs = open_dataset(tiny_dataset).sequences()
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()  # each cache maps its own files
    data = cache_inputs(model, seqs[:1], SeenTracker, tmp_path / "a", progress=False)
    ref = cache_inputs(plain, seqs[:1], SeenTracker, tmp_path / "b", progress=False)
    assert data.win.shape[1] == ref.win.shape[1] + PARALLAX_CHANNELS
    np.testing.assert_array_equal(data.win[:, : ref.win.shape[1]], ref.win)  # the other inputs are the same
    assert np.abs(data.win[:, ref.win.shape[1] :].astype(np.float32)).max() > 0  # the camera moved: costs differ
    out = tmp_path / "par.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--parallax"]
    assert run_stage("fit-box-depth", [*args, "--epochs", "1", "--out", str(out), "--threads", "1", "--quiet"]) == 0
    loaded = load_model(out)[0]
    assert loaded.cfg.box_parallax and load_checkpoint(out)[1]["box_depth"]["parallax"] is True
    seq = seqs[0]
    frames = [seq.rgb(i) for i in range(seq.num_frames)]
    for mode in ("stream", "window"):
        outs = list(Predictor(loaded, rack_depth=0.8).run(frames, mode))
        assert all(o.box_back.shape == (SPEC.num_slots, loaded.cfg.spec.size) for o in outs)
        assert all(o.maps["box_parallax"].shape[1] == PARALLAX_CHANNELS for o in outs)
    assert "box_parallax" not in next(iter(Predictor(loaded, rack_depth=0.8, read_depth=False).run(frames))).maps


def test_a_kept_cache_is_reused_and_refused_for_another_model(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    keep = tmp_path / "cache"
    part = keep / part_name(tiny_dataset)
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--epochs", "1"]
    common = ["--threads", "1", "--quiet", "--keep-cache", str(keep)]
    assert run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "a.pt"), *common]) == 0
    assert "reused the inputs" not in capsys.readouterr().out and (part / "cache.json").is_file()
    assert run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "b.pt"), *common]) == 0
    assert f"reused the inputs cached in {keep} for 1 of 1 data folders" in capsys.readouterr().out
    a, b = (load_checkpoint(tmp_path / f"{k}.pt")[0]["model"] for k in "ab")
    heads = [k for k in a if k.startswith("box_depth.")]
    assert heads and all(torch.equal(a[k], b[k]) for k in heads)  # same inputs, same seed: the same head
    assert (
        run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "w.pt"), "--head-width", "12", *common]) == 0
    )  # a narrower head
    w = load_model(tmp_path / "w.pt")[0]
    assert w.cfg.box_width == 12 and w.box_depth.conv2d[0][0].out_channels == 12 and w.box_depth.out.in_channels == 24
    assert "reused the inputs" in capsys.readouterr().out
    assert run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "v.pt"), "--head-width", "2", *common]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--head-width must be an integer >= 4, got 2" in err
    assert (
        run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "d.pt"), "--parallax", *common]) == 2
    )  # other inputs: refused
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(part) in err and "another" in err
    (part / "cache.json").unlink()  # an unfinished cache is made again, not used
    assert run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "e.pt"), *common]) == 0
    assert "reused the inputs" not in capsys.readouterr().out and (part / "cache.json").is_file()


def test_a_kept_cache_grows_by_one_part_per_data_folder(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    """A fit on a second dataset reuses the first one's part and makes only the new one; the head equals a
    fit on both through a single temporary cache; a cache kept in the earlier one-folder layout is moved into
    its part and reused."""
    from waresynth.generate import DatasetSettings, generate_dataset

    more = generate_dataset(tmp_path / "more", DatasetSettings(num_sequences=2, frames=4, image_size=(128, 128), spec=LayoutSpec(size=64), seed=8, progress=False))  # fmt: skip
    keep = tmp_path / "cache"
    args = ["--checkpoint", str(tiny_checkpoint), "--epochs", "1", "--threads", "1", "--quiet"]
    assert (
        run_stage(
            "fit-box-depth",
            [*args, "--data", str(tiny_dataset), "--out", str(tmp_path / "a.pt"), "--keep-cache", str(keep)],
        )
        == 0
    )
    capsys.readouterr()
    both = ["--data", str(tiny_dataset), str(more)]
    assert run_stage("fit-box-depth", [*args, *both, "--out", str(tmp_path / "b.pt"), "--keep-cache", str(keep)]) == 0
    assert "for 1 of 2 data folders" in capsys.readouterr().out
    assert sorted(p.name for p in keep.iterdir()) == sorted([part_name(tiny_dataset), part_name(more)])
    assert (
        run_stage("fit-box-depth", [*args, *both, "--out", str(tmp_path / "c.pt")]) == 0
    )  # one temporary cache of both
    b, c = (load_checkpoint(tmp_path / f"{k}.pt")[0]["model"] for k in "bc")
    heads = [k for k in b if k.startswith("box_depth.")]
    assert heads and all(torch.equal(b[k], c[k]) for k in heads)
    assert load_checkpoint(tmp_path / "b.pt")[1]["box_depth"]["train_slots"] > 0
    old = keep / part_name(tiny_dataset)  # the earlier layout: one dataset's files in the folder itself
    for f in old.iterdir():
        f.rename(keep / f.name)
    old.rmdir()
    assert run_stage("fit-box-depth", [*args, *both, "--out", str(tmp_path / "d.pt"), "--keep-cache", str(keep)]) == 0
    assert "for 2 of 2 data folders" in capsys.readouterr().out and (old / "cache.json").is_file()
    d = load_checkpoint(tmp_path / "d.pt")[0]["model"]
    assert all(torch.equal(b[k], d[k]) for k in heads)


def test_a_frame_choice_streams_the_first_frames_and_keeps_the_later_ones(
    tiny_checkpoint, tiny_dataset, tmp_path, capsys
):
    """The first N frames stream as in a whole pass (the stream is causal), and --from-frame drops only the
    slots of the frames before it (a parallax head's maps of the kept frames unchanged though the frames
    before make none); the choice keys a kept cache, is recorded, and is checked on one line."""
    model = with_box_head(load_model(tiny_checkpoint)[0], parallax=True)
    seq = open_dataset(tiny_dataset).sequences()[:1]
    for name in ("all", "f3", "f3k1"):
        (tmp_path / name).mkdir()
    every = cache_inputs(model, seq, SeenTracker, tmp_path / "all", progress=False)
    first = cache_inputs(model, seq, SeenTracker, tmp_path / "f3", progress=False, choice=FrameChoice(3))
    later = cache_inputs(model, seq, SeenTracker, tmp_path / "f3k1", progress=False, choice=FrameChoice(3, 1))
    assert 0 < len(later) < len(first) < len(every)
    for k in ("win", "extra", "back", "shown"):
        a, b, c = (np.asarray(getattr(x, k)) for x in (every, first, later))
        np.testing.assert_array_equal(b, a[: len(b)])
        np.testing.assert_array_equal(c, b[len(b) - len(c) :])
    keep = tmp_path / "cache"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--epochs", "1",
            "--threads", "1", "--quiet", "--keep-cache", str(keep)]  # fmt: skip
    assert (
        run_stage("fit-box-depth", [*args, "--frames", "4", "--from-frame", "2", "--out", str(tmp_path / "a.pt")]) == 0
    )
    record = load_checkpoint(tmp_path / "a.pt")[1]["box_depth"]
    assert (record["frames"], record["from_frame"]) == (4, 2)
    capsys.readouterr()
    assert (
        run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "b.pt")]) == 2
    )  # every frame: another cache's inputs, refused
    assert "another" in capsys.readouterr().err
    too_late = ["--from-frame", "8"]  # the tiny sequences have 8 frames: none would be kept
    for bad, word in ((["--frames", "0"], "--frames"), (["--frames", "2", "--from-frame", "2"], "--from-frame"),
                      (too_late, "at most 8 frames")):  # fmt: skip
        assert run_stage("fit-box-depth", [*args, *bad, "--out", str(tmp_path / "c.pt")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and word in err


def test_a_chain_of_caches_reads_as_their_concatenation():
    rng = np.random.default_rng(0)

    def cache(n: int) -> Cache:
        return Cache(rng.random((n, 2, 3)), rng.random((n, 1)), rng.random((n, 4)), rng.random((n, 4)) > 0.5)

    parts = [cache(5), cache(0), cache(7), cache(3)]
    chain = Chain(parts)
    assert len(chain) == 15
    for idx in (np.arange(15), np.array([0, 4, 5, 11, 12, 14]), np.array([6]), np.array([], dtype=int)):
        got = chain.take(idx)
        for k in ("win", "extra", "back", "shown"):
            np.testing.assert_array_equal(getattr(got, k), np.concatenate([getattr(p, k) for p in parts])[idx])
    np.testing.assert_array_equal(chain.field("back"), np.concatenate([p.back for p in parts]))

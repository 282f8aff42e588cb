#!/usr/bin/env python3
"""How the box-depth head's per-frame readings are best fused along the row: Table I's top view per rule.

    .venv/bin/python research/box_fusion.py CKPT DATA [--mode window] [--sequences N]

CKPT is a checkpoint with the box-depth head (a training recipe's `fit-box-depth` stage). The model runs once over
DATA (as `mvracklay evaluate`: the rack depth read, windowed by default); each frame's head logits
and camera step are kept, and every rule below rebuilds the carried backs from them, over the frames
so far and over the whole sequence, then scores the top view (columns in view, mIoU):

* ``mean p>=0.5``: the shown-weighted mean of the expected depths of the frames whose shown probability
  is at least 0.5 (what `network.heads.boxdepth.BoxDepthReader` did before the product);
* ``mean``: the same without the threshold;
* ``inverse variance``: each frame's expected depth weighted by its shown probability over its variance;
* ``product``: the frames' distributions multiplied, each raised to its shown probability (`RowMap`,
  shipped); ``product x2``: the same with every exponent doubled (a sharper fused distribution);
* ``product, used from weight W``: the product used once a cell's summed shown probability reaches W
  (shipped 0.5, `network.heads.boxdepth.MIN_WEIGHT`; below it the decoder's back stays);
* ``product, Z m until shown``: the product, and a fixed back Z metres behind the rack front where the
  frames have not shown the depth enough yet, instead of the decoder's (box depths are drawn apart from
  anything a frame shows, so before one shows it a constant is the best guess it could make).

A head that reads fronts (the `fit-box-depth` stage's `--front`) has its fronts carried and imposed as the
pipeline does, under every rule.

Every rule gives each box one back, boxes side by side in one component told apart where the front
view's box height steps (`layouts.boxdepth.impose_box_backs`, shipped); ``product, one back per
component`` is the shipped product without that split.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.boxdepth import impose_box_backs  # noqa: E402
from layouts.metrics import FrameScorer  # noqa: E402
from layouts.rackdepth import impose_rack_depth  # noqa: E402
from layouts.spec import LayoutSpec  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.heads.boxdepth import BINS, BoxDepthReader, RowMap, front_reading, reading  # noqa: E402
from network.inference.predictor import Predictor, sequence_camera  # noqa: E402
from network.inference.result import logits_to_layout  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


class Keeping(Predictor):
    """A `Predictor` that also hands out each frame's head logits and camera step."""

    def _box_logits(self, out: dict, i: int) -> torch.Tensor:
        out["head_logits"] = super()._box_logits(out, i)
        return out["head_logits"]

    def _read_boxes(self, out: dict, boxes: BoxDepthReader, i: int, step: float) -> None:
        out["step"] = step
        super()._read_boxes(out, boxes, i, step)


class MeanMap(RowMap):
    """The mean rules: per cell a weighted mean of the frames' expected depths, the weights from ``weigh``
    (shown probability, variance); column 0 of ``logs`` holds the weighted sum of depths."""

    def __init__(self, weigh: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> None:
        super().__init__(np.zeros(1))  # one column: the weighted sum of depths
        self.weigh = weigh

    def add(self, cells: np.ndarray, log_q: np.ndarray, p: np.ndarray) -> None:
        q = np.exp(log_q)
        z = BINS @ q
        w = self.weigh(np.asarray(p), ((BINS[:, None] - z[None]) ** 2 * q).sum(0))
        self._cover(np.asarray(cells))
        idx = np.asarray(cells) - self.first
        np.add.at(self.logs[:, 0], idx, w * z)
        np.add.at(self.weight, idx, w)

    def mean(self, cells: np.ndarray) -> np.ndarray:
        idx = np.asarray(cells) - self.first
        out = np.full(idx.shape, np.nan)
        ok = (idx >= 0) & (idx < self.weight.size)
        ok[ok] = self.weight[idx[ok]] > 0
        out[ok] = self.logs[idx[ok], 0] / self.weight[idx[ok]]
        return out


class Doubled(RowMap):
    """The product with every frame's exponent doubled."""

    def add(self, cells: np.ndarray, log_q: np.ndarray, p: np.ndarray) -> None:
        super().add(cells, log_q, 2 * np.asarray(p))


class PriorBelow(RowMap):
    """The product, and where a cell in view has summed shown probability under ``min_weight`` (no frame
    has shown its depth enough yet) the fixed back ``prior`` (metres behind the rack front) instead of the
    decoder's: box depths are drawn independently of everything a frame shows, so before a frame shows one
    the best guess is a constant."""

    def __init__(self, prior: float) -> None:
        super().__init__()
        self.prior = prior

    def mean(self, cells: np.ndarray) -> np.ndarray:
        out = super().mean(cells)
        idx = np.asarray(cells, dtype=np.int64) - self.first
        seen = (idx >= 0) & (idx < self.weight.size)
        out[seen & ~np.isfinite(out)] = self.prior
        return out


#: name -> (map factory, split side-by-side boxes by the front view's heights)
RULES: dict[str, tuple[Callable[[], RowMap], bool]] = {
    "mean p>=0.5": (lambda: MeanMap(lambda p, v: np.where(p >= 0.5, p, 0.0)), True),
    "mean": (lambda: MeanMap(lambda p, v: p), True),
    "inverse variance": (lambda: MeanMap(lambda p, v: p / (v + 0.001)), True),
    "product (shipped)": (RowMap, True),
    "product x2": (Doubled, True),
    "product, one back per component": (RowMap, False),
    "product, used from weight 0.25": (lambda: RowMap(min_weight=0.25), True),
    "product, used from weight 0": (lambda: RowMap(min_weight=0.0), True),
    **{f"product, {p:.2f} m until shown": ((lambda p=p: PriorBelow(p)), True) for p in (0.45, 0.5, 0.55)},
}


def carried(
    frames: list[dict],
    spec_m: LayoutSpec,
    make: Callable[[], RowMap],
    whole: bool,
) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Each frame's ``(R, D)`` backs and fronts (None: a head without fronts) from ``frames`` (one sequence),
    the backs fused by the maps ``make`` builds, as `network.inference.predictor.Predictor` gives them (``whole``: every
    frame from the maps of the whole sequence)."""
    reader = BoxDepthReader(spec_m, make)
    out = []
    for f in frames:
        backs = reader.add(f["log_q"], f["p"], f["valid"], f["step"], f["front_q"])
        out.append((backs, reader.fronts(reader.camera_x, f["valid"]), reader.camera_x))
    if whole:
        return [(reader.backs(x, f["valid"]), reader.fronts(x, f["valid"])) for (_, _, x), f in zip(out, frames)]
    return [(backs, fronts) for backs, fronts, _ in out]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path, help="a checkpoint with the box-depth head")
    ap.add_argument("data", type=Path, help="generated sequences (any split)")
    ap.add_argument("--mode", choices=["window", "stream"], default="window")
    ap.add_argument("--sequences", type=int, default=None, help="only the first N sequences")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(args.checkpoint)
    if model.box_depth is None:
        ap.error(f"{args.checkpoint}: no box-depth head (a training recipe's fit-box-depth stage fits one)")
    seqs = open_dataset(args.data).sequences(None)[: args.sequences]
    runs = []
    for seq in tqdm(seqs, desc="sequences"):
        frames = []
        pred = Keeping(model, sequence_camera(seq))
        for i, out in enumerate(pred.run((seq.rgb(j) for j in range(seq.num_frames)), args.mode)):
            gt = seq.layouts(i)
            log_q, p = reading(out.maps["head_logits"])
            frames.append({
                "top": logits_to_layout(out.top, seq.spec.size), "front": logits_to_layout(out.front, seq.spec.size),
                "depth": out.rack_depth, "log_q": log_q, "p": p, "front_q": front_reading(out.maps["head_logits"]),
                "step": out.maps["step"], "valid": torch.isfinite(out.anchors).numpy(), "gt": gt,
            })  # fmt: skip
        runs.append((seq.spec, frames))
    print(
        f"{args.checkpoint} on {args.data}: {sum(len(f) for _, f in runs)} frames, {args.mode} mode; top rack / top box"
    )
    for whole in (False, True):
        for name, (make, split) in RULES.items():
            scorer = FrameScorer()
            for spec, frames in runs:
                last_depth = frames[-1]["depth"]
                for f, (backs, fronts) in zip(frames, carried(frames, model.cfg.spec, make, whole)):
                    depth = last_depth if whole else f["depth"]
                    top = f["top"]
                    if np.isfinite(depth):
                        top = impose_rack_depth(top, spec, depth)
                        top = impose_box_backs(top, f["front"], spec, depth, backs, split, fronts)
                    scorer.update({"top": top, "front": f["front"]}, f["gt"])
            v = scorer.result()["visible"]["top"]
            frames_from = "whole sequence" if whole else "frames so far"
            print(f"  {frames_from:<15} {name:<32} {100 * v['rack']['miou']:6.2f} / {100 * v['box']['miou']:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

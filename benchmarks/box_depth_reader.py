#!/usr/bin/env python3
"""A learnt reader of each box's depth, per frame and carried along the row: what it buys the top view.

    .venv/bin/python benchmarks/box_depth_reader.py weights/mvracklay-disc-4-256.pt \
        --train data/train256b --train-sequences 350 --eval data/heldout256 --out runs/box-depth-reader

`benchmarks/box_top_faces.py` measured, on the shipped predictions, that the true depth of every box
whose depth the frame shows (any face) would lift the 256x256 top box from 66.8 to 75.0, and of every
box some frame so far showed, to 81.2. This probe asks how much of that a small head on the frozen
network can read. Per shelf slot it takes the 1/2-scale pyramid features sampled over the slot's
front window at every column of that map, the decoder's front-view probabilities, and per column the
decoder's top-view box probabilities along depth, the camera's height above the board and its
distance; it gives per layout column a distribution over the box's back depth (behind the rack
front, `BINS`) and the probability that the frame shows that depth (`waresynth.visibility`, the
labels of the oracle rows). It is fitted on the generator's ground truth of training scenes (every
column with a box, the shown ones weighted up), the network frozen.

Scored on the evaluation set like `box_top_faces.py` (streamed, the rack depth read, Table I top view):
each predicted box's back moved to the head's depth per column (a) everywhere, (b) where the head
says the frame shows it, and (c) carried along the row: every column the head says is shown adds
its depth, weighted by that probability, to a per-slot map in world X (bins of one layout column),
and every box takes the map's mean where it has one; the camera's X from the poses or read from
the images (`network.motion.camera_shift`, what footage without poses has).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from box_top_faces import Table, box_parts, cell_z, seen_in  # noqa: E402  (benchmarks/, the script's own folder)
from layout_errors import SeenTracker  # noqa: E402

from layouts import BOX, LayoutSpec  # noqa: E402
from layouts.fileio import atomic_write_bytes, atomic_write_json  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.infer import Predictor, frame_layouts, sequence_camera  # noqa: E402
from network.motion import camera_shift, motion_signature  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402

BINS = np.arange(0.05, 1.401, 0.05)  #: back depths behind the rack front the head chooses among, metres
ROWS = 32  #: front-window rows sampled from the 1/2 map
SHOWN_WEIGHT = 4.0  #: depth loss weight of columns whose depth the frame shows


class DepthHead(nn.Module):
    """Per slot: ``(C, ROWS, W)`` window features + ``(E, D)`` column extras -> ``(len(BINS) + 1, D)`` logits."""

    def __init__(self, c2d: int, c1d: int, width: int = 32) -> None:
        super().__init__()

        def block(cin: int, cout: int, dil: tuple[int, int]) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(cin, cout, 3, padding=dil, dilation=dil), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
            )

        self.conv2d = nn.Sequential(block(c2d, width, (1, 1)), block(width, width, (1, 2)), block(width, width, (2, 4)))
        w1 = 2 * width

        def block1(cin: int, cout: int, dil: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv1d(cin, cout, 5, padding=2 * dil, dilation=dil), nn.BatchNorm1d(cout), nn.ReLU(inplace=True)
            )

        self.conv1d = nn.Sequential(block1(w1 + c1d, w1, 1), block1(w1, w1, 2), block1(w1, w1, 4))
        self.out = nn.Conv1d(w1, len(BINS) + 1, 1)

    def forward(self, win: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        x = self.conv2d(win)
        x = torch.cat([x.mean(2), x.amax(2)], 1)  # (N, 2w, W)
        x = F.avg_pool1d(x, x.shape[-1] // extra.shape[-1]) if x.shape[-1] != extra.shape[-1] else x
        return self.out(self.conv1d(torch.cat([x, extra], 1)))


def decode(logits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """``(R, K+1, D)`` logits -> expected back depth ``(R, D)`` and shown probability ``(R, D)``."""
    p = torch.softmax(logits[:, :-1].float(), 1)
    z = (p * torch.as_tensor(BINS, dtype=torch.float32)[None, :, None]).sum(1)
    return z.numpy(), torch.sigmoid(logits[:, -1].float()).numpy()


class Capture:
    """The pyramid's 1/2-scale map of the last frame run (a forward hook)."""

    def __init__(self, model) -> None:
        self.p1: torch.Tensor | None = None
        model.pyramid.register_forward_hook(self._hook)

    def _hook(self, module, inputs, output) -> None:
        self.p1 = output[0].detach()


def slot_inputs(model, cap: Capture, out: dict, distance: float) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """A frame's head inputs: window ``(R, C, ROWS, W)``, extras ``(R, E, D)`` (fp16) and the valid slots."""
    slots, view = model.slots, model.cfg.view
    anchors = out["anchors"].float()
    valid = torch.isfinite(anchors)
    a = torch.where(valid, anchors, torch.full_like(anchors, view.height / 2))
    p1 = cap.p1.float()
    d = model.cfg.spec.size
    offs = slots.front_fine.view(ROWS, -1).mean(1)  # ROWS heights over the front window
    win = slots._sample(p1, a[None], offs, p1.shape[-1])  # (R, C, ROWS, W)
    front = torch.softmax(out["front"].float(), 1)  # (R, 3, D, D), rows top to bottom of the window
    front = F.adaptive_avg_pool2d(front, (ROWS, d))
    front = front.repeat_interleave(p1.shape[-1] // d, -1)
    top = torch.softmax(out["top"].float(), 1)[:, BOX]  # (R, D depth rows, D cols)
    elev = ((a - view.height / 2) * view.metres_per_pixel).view(-1, 1, 1).expand(-1, 1, d)
    dist = torch.full_like(elev, distance)
    return (
        torch.cat([win, front], 1).half(),
        torch.cat([top, elev, dist - 1.5], 1).half(),
        valid.numpy(),
    )


def column_targets(truth_top: np.ndarray, labels: np.ndarray, spec: LayoutSpec, depth: float, d: int):
    """Per slot and model column (``d`` of them): the truth's box back behind the rack front (NaN: no box)
    and whether the frame shows that stack's depth."""
    g = truth_top == BOX  # (R, Dt, Dt), row 0 deepest
    zb = cell_z(spec, depth) + spec.z_extent / spec.size / 2
    has = g.any(1)
    first = np.argmax(g, 1)
    back = np.where(has, zb[first], np.nan)  # (R, Dt)
    k = spec.size // d
    back = back.reshape(back.shape[0], d, k)
    with np.errstate(all="ignore"):
        back = np.nanmean(back, 2)
    shown = (labels.reshape(labels.shape[0], d, k) >= 2).any(2)
    return back, shown


def run_sequences(model, seqs, every: int, with_targets: bool, desc: str):
    """Yield per scored frame: inputs, valid, out, motion, and (if asked) targets; runs every frame streamed."""
    cap = Capture(model)
    d = model.cfg.spec.size
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc=desc, unit="frame", leave=False)
    for si, seq in enumerate(seqs):
        camera = sequence_camera(seq)
        pred = Predictor(model, camera)
        seen = SeenTracker(seq)
        true_depth = float(seq.scene()["row"]["depth"])
        prev_sig, est_x = None, 0.0
        rgbs = [seq.rgb(i) for i in range(seq.num_frames)]
        for i, out in enumerate(pred.run(rgbs, "stream")):
            bar.update(1)
            sig = motion_signature(pred.preprocess(rgbs[i], i))
            if prev_sig is not None:
                est_x += float(camera_shift(prev_sig, sig, model.cfg.view)[0])
            prev_sig = sig
            seen.add(i)
            if i % every:
                continue
            dist = camera(i)[1]
            win, extra, valid = slot_inputs(model, cap, out, dist)
            rec = {"seq": si, "i": i, "win": win, "extra": extra, "valid": valid, "out": out, "distance": dist,
                   "cam_x": float(seq.frame(i)["camera_position"][0]), "est_x": est_x, "true_depth": true_depth,
                   "labels": seen.labels(i), "truth": seq.layouts(i), "spec": seq.spec}  # fmt: skip
            if with_targets:
                rec["back"], rec["shown"] = column_targets(rec["truth"].top, rec["labels"], seq.spec, true_depth, d)
            yield rec
    bar.close()


def fit(model, train_dir: Path, n_seq: int, epochs: int, seed: int, threads: int) -> tuple[DepthHead, dict]:
    seqs = open_dataset(train_dir).sequences()[:n_seq]
    t0 = time.time()
    wins, extras, backs, showns = [], [], [], []
    for rec in run_sequences(model, seqs, 1, True, "cache"):
        v = rec["valid"]
        wins.append(rec["win"][v])
        extras.append(rec["extra"][v])
        backs.append(torch.as_tensor(rec["back"][v], dtype=torch.float32))
        showns.append(torch.as_tensor(rec["shown"][v]))
    win, extra, back, shown = (torch.cat(t) for t in (wins, extras, backs, showns))
    del wins, extras
    cache_min = (time.time() - t0) / 60
    torch.manual_seed(seed)
    head = DepthHead(win.shape[1], extra.shape[1])
    opt = torch.optim.AdamW(head.parameters(), lr=2e-3, weight_decay=1e-2)
    n = len(win)
    steps = epochs * math.ceil(n / 64)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, 2e-3, total_steps=steps)
    has = torch.isfinite(back)
    bins = torch.as_tensor(BINS, dtype=torch.float32)
    t1 = time.time()
    g = torch.Generator().manual_seed(seed)
    for ep in range(epochs):
        perm = torch.randperm(n, generator=g)
        tot = 0.0
        for b in tqdm(perm.split(64), desc=f"epoch {ep + 1}/{epochs}", leave=False):
            logits = head(win[b].float(), extra[b].float())
            lz, ls = logits[:, :-1], logits[:, -1]
            m = has[b]
            loss = F.binary_cross_entropy_with_logits(ls[m], shown[b][m].float()) if m.any() else ls.sum() * 0
            if m.any():
                t = back[b].nan_to_num(0.0).clamp(float(BINS[0]), float(BINS[-1]))
                pos = (t[..., None] - bins).abs()  # (B, D, K): two-hot target between the nearest bins
                w = (1 - pos / 0.05).clamp(min=0)
                logp = torch.log_softmax(lz, 1).permute(0, 2, 1)  # (B, D, K)
                ce = -(w * logp).sum(-1)
                wt = torch.where(shown[b], SHOWN_WEIGHT, 1.0)
                loss = loss + (ce * wt)[m].sum() / wt[m].sum()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            tot += float(loss.detach())
        print(f"epoch {ep + 1}: loss {tot / math.ceil(n / 64):.3f}", flush=True)
    info = {"train": str(train_dir), "sequences": len(seqs), "slots": n, "epochs": epochs, "seed": seed,
            "cache_minutes": round(cache_min, 1), "fit_minutes": round((time.time() - t1) / 60, 1),
            "threads": threads, "c2d": win.shape[1], "c1d": extra.shape[1]}  # fmt: skip
    return head, info


class RowMap:
    """One slot's depths shown so far along the row: world-X bin -> (sum of p * depth, sum of p)."""

    def __init__(self, min_shown: float) -> None:
        self.min_shown = min_shown
        self.acc: dict[int, list[float]] = {}

    def update(self, bins: np.ndarray, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Adds a frame's columns (world-X ``bins``, depths ``z``, shown probabilities ``p``) where
        ``p >= min_shown``; returns the map's mean depth at each column (NaN: nothing shown there yet)."""
        for b, zj, pj in zip(bins, z, p):
            if pj >= self.min_shown:
                s = self.acc.setdefault(int(b), [0.0, 0.0])
                s[0] += pj * zj
                s[1] += pj
        out = np.full(len(bins), np.nan)
        for j, b in enumerate(bins):
            s = self.acc.get(int(b))
            if s is not None and s[1] > 0:
                out[j] = s[0] / s[1]
        return out


def evaluate(model, head: DepthHead, eval_dir: Path, n_seq: int | None, every: int, min_shown: float) -> None:
    seqs = open_dataset(eval_dir).sequences()[:n_seq]
    head.eval()
    frames = []
    maps: dict[tuple[str, int, int], RowMap] = {}
    for rec in run_sequences(model, seqs, 1, False, "evaluate"):
        spec, out = rec["spec"], rec["out"]
        with torch.no_grad():
            z, p = decode(head(rec["win"].float(), rec["extra"].float()))
        d = z.shape[1]
        spec_model = model.cfg.spec
        xs = spec_model.col_to_x(np.arange(d) + 0.5)
        carried = {}
        for key in ("cam_x", "est_x"):
            cz = np.full_like(z, np.nan)
            bins = np.round((rec[key] + xs) / (spec_model.x_extent / d)).astype(int)
            for r in np.nonzero(rec["valid"])[0]:
                cz[r] = maps.setdefault((key, rec["seq"], r), RowMap(min_shown)).update(bins, z[r], p[r])
            carried[key] = cz
        if rec["i"] % every:
            continue
        read = float(out["rack_depth"])
        frames.append({"pred": frame_layouts(out, spec), "truth": rec["truth"], "anchors": out["anchors"].numpy(),
                       "spec": spec, "depth": read if np.isfinite(read) else rec["true_depth"],
                       "distance": rec["distance"], "seen": rec["labels"], "z": z, "p": p,
                       "carry_pose": carried["cam_x"], "carry_image": carried["est_x"]})  # fmt: skip
    view = model.cfg.view
    print(f"{eval_dir}: {len(frames)} frames of {len(seqs)} sequences; top view, mIoU")
    line = Table(frames, view, width=58).line

    def head_cols(f, cols):
        return cols * f["z"].shape[1] // f["spec"].size

    def from_head(key: str | None, gate: bool):
        def choose(f, r, cols, zf, h_top, c, back, has):
            j = head_cols(f, cols)
            if key is not None:
                z = f[key][r, j]
                return z if np.isfinite(z).any() else None
            if gate and f["p"][r, j].mean() < min_shown:
                return None
            return f["z"][r, j]

        return choose

    def decoder_back(f, r, cols):
        for c2, _, zb, _ in box_parts(f["pred"]["top"][r], f["pred"]["front"][r], f["spec"], f["depth"]):
            if np.array_equal(c2, cols):
                return zb
        return None

    def decoder(gate: bool):
        def choose(f, r, cols, zf, h_top, c, back, has):
            if gate and f["p"][r, head_cols(f, cols)].mean() < min_shown:
                return None
            return decoder_back(f, r, cols)

        return choose

    line("prediction", lambda *a: None)
    line("prediction, its error on every box", decoder(False))
    line(f"prediction, its error where the head says shown (p >= {min_shown:g})", decoder(True))
    line("head's depth, every box", from_head(None, False))
    line(f"head's depth where it says the frame shows it (p >= {min_shown:g})", from_head(None, True))
    line("carried along the row, camera X from the poses", from_head("carry_pose", False))
    line("carried along the row, camera X read from the images", from_head("carry_image", False))
    line("oracle: true depth where this frame shows it", seen_in(2))
    line("oracle: true depth where this or an earlier frame showed it", seen_in(1))
    shown_p = np.concatenate([f["p"].ravel() for f in frames])
    print(f"head says shown (p >= {min_shown:g}) for {100 * (shown_p >= min_shown).mean():.1f} % of slot columns")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("--train", type=Path, help="generated training scenes (with depth, instance, scene.json)")
    ap.add_argument("--train-sequences", type=int, default=350)
    ap.add_argument("--epochs", type=int, default=6)
    ap.add_argument("--eval", type=Path, required=True, help="generated evaluation scenes")
    ap.add_argument("--sequences", type=int, default=None, help="only the first N evaluation sequences")
    ap.add_argument("--every", type=int, default=2, help="score every N-th frame (all frames are run)")
    ap.add_argument("--min-shown", type=float, default=0.5)
    ap.add_argument("--out", type=Path, required=True, help="folder for the fitted head (reused when present)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(args.checkpoint)
    model.eval()
    path = args.out / "head.pt"
    if path.exists():
        info = json.loads((args.out / "head.json").read_text())
        head = DepthHead(info["c2d"], info["c1d"])
        head.load_state_dict(torch.load(path, weights_only=True))
    else:
        if args.train is None:
            ap.error(f"--train is needed: no fitted head in {args.out}")
        head, info = fit(model, args.train, args.train_sequences, args.epochs, args.seed, args.threads)
        args.out.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        torch.save(head.state_dict(), buf)
        atomic_write_bytes(path, buf.getvalue())
        atomic_write_json(args.out / "head.json", info)
    print(f"head: {info}")
    evaluate(model, head, args.eval, args.sequences, args.every, args.min_shown)
    return 0


if __name__ == "__main__":
    sys.exit(main())

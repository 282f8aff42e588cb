#!/usr/bin/env python3
"""Would averaging views help? Table I of per-frame predictions fused over the last K frames.

    .venv/bin/python research/frame_fusion.py runs/mvracklay-disc-4/calibrated.pt data/tune128 [--k 1 2 4 8]

Each frame's class probabilities (streaming, box offsets of the checkpoint applied) are shifted
by the *true* camera motion into the current frame's layout columns (a column is
``x_extent / D`` metres) and averaged with the current frame's over the columns each frame saw;
the argmax of the average is scored (`layouts.metrics.FrameScorer`, columns in view, mIoU, every
2nd frame). K = 1 is the model alone. If the per-frame errors were independent noise, the
fused scores would climb with K; if they are a bias shared by neighbouring views of a scene,
they stay close to K = 1. ``--motion images`` shifts by the camera motion read from the
canonical images (`network.model.motion`, what the slot memory uses) instead of the truth: what such a
fusion would give on footage without poses.

``--tau T [T ...]`` scores the shipped fusion instead (`network.inference.fusion`, what ``--fuse-frames T`` does):
the whole pipeline of ``mvracklay evaluate`` (windowed, depth heads, every frame), each frame's logits
fused with weights exp(-frames apart / T) (T = 0: each frame alone), the camera motion read from the
images (the same figures as ``evaluate --fuse-frames T``) or, with ``--motion truth``, the true steps;
``--whole-sequence`` takes the later frames and the depths from all frames too.

    .venv/bin/python research/frame_fusion.py mvracklay/models/mvracklay-disc-4-256.pt data/tune256 --tau 0 1 2 4 --motion truth
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import VIEWS  # noqa: E402
from layouts.metrics import FrameScorer  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.inference.fusion import LayoutFusion, check_tau, fuse_sequence, seen_columns  # noqa: E402
from network.inference.predictor import Predictor, sequence_camera  # noqa: E402
from network.inference.result import resize_logits  # noqa: E402
from network.model.motion import camera_shift, motion_signature  # noqa: E402
from network.training.train_data import open_data  # noqa: E402


def shift_columns(p: torch.Tensor, seen: np.ndarray, s: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(..., D)`` moved ``s`` columns to the right (column c -> c + s) and its seen-mask, zeros where nothing lands."""
    d = p.shape[-1]
    out, m = torch.zeros_like(p), torch.zeros(d)
    v = torch.from_numpy(seen.astype(np.float32))
    if abs(s) >= d:
        return out, m
    if s >= 0:
        out[..., s:], m[s:] = p[..., : d - s], v[: d - s]
    else:
        out[..., : d + s], m[: d + s] = p[..., -s:], v[-s:]
    return out, m


def print_table(args: argparse.Namespace, title: str, key: str, scorers: dict, digits: int) -> None:
    """One row of top/front x rack/box mIoU (columns in view) per setting ``key`` of ``scorers``."""
    print(f"{args.checkpoint} on {args.data}: mIoU, columns in view, {title}")
    print(f"{key:>5s} {'top rack':>9s} {'top box':>8s} {'front rack':>11s} {'front box':>10s}")
    for k, sc in scorers.items():
        r = sc.result()["visible"]
        cells = [100 * r[v][c]["miou"] for v in ("top", "front") for c in ("rack", "box")]
        print(f"{k:5g} {cells[0]:9.{digits}f} {cells[1]:8.{digits}f} {cells[2]:11.{digits}f} {cells[3]:10.{digits}f}")


def shipped_fusion(model: torch.nn.Module, seqs: list, args: argparse.Namespace) -> int:
    """Table I (columns in view) of the shipped pipeline with `network.inference.fusion` at each of ``args.tau``."""
    for t in args.tau:
        check_tau(t, "--tau")
    scorers = {t: FrameScorer() for t in args.tau}
    x_extent = model.cfg.spec.x_extent
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc="fuse", unit="frame", leave=False)
    for seq in seqs:
        pred = Predictor(model, sequence_camera(seq), fuse_tau=0, whole_sequence=args.whole_sequence)
        frames = [seq.rgb(i) for i in range(seq.num_frames)]  # read once: signatures and the pass
        truths = [seq.layouts(i) for i in range(seq.num_frames)]
        sig = [motion_signature(pred.preprocess(f, i)) for i, f in enumerate(frames)]
        if args.motion == "truth":
            x = seq.camera_positions()[:, 0]
            steps = np.diff(x, prepend=x[0]).tolist()
        else:  # what the Predictor reads
            steps = [0.0] + [float(camera_shift(a, b, model.cfg.view)[0]) for a, b in zip(sig, sig[1:])]
        outs = list(pred.run(frames, "window"))
        raw = [{v: getattr(o, v) for v in VIEWS} for o in outs]
        seen = [seen_columns(s, raw[0]["top"].shape[-1]) for s in sig]
        for t in args.tau:
            if t == 0:
                fused = raw
            elif args.whole_sequence:
                fused = fuse_sequence(raw, steps, seen, t, x_extent)
            else:
                fusion = LayoutFusion(t, x_extent)
                fused = [fusion.add(r, st, sn) for r, st, sn in zip(raw, steps, seen)]
            for o, f, gt in zip(outs, fused, truths):
                scorers[t].update(replace(o, **f).layouts(seq.spec), gt)
        bar.update(seq.num_frames)
    bar.close()
    title = f"network.inference.fusion (motion: {args.motion}{', whole sequence' if args.whole_sequence else ''})"
    print_table(args, title, "tau", scorers, 2)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a dataset with ground truth and camera positions")
    ap.add_argument("--k", type=int, nargs="+", default=[1, 2, 4, 8], help="window lengths to fuse")
    ap.add_argument("--every", type=int, default=2, help="score every N-th frame")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--motion", choices=["truth", "images"], default="truth", help="camera motion: ground truth or read from images"
    )
    ap.add_argument("--tau", type=float, nargs="+", help="score the shipped fusion at these taus (frames) instead")
    ap.add_argument("--whole-sequence", action="store_true", help="with --tau: later frames and depths from all")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(args.checkpoint)
    seqs = open_data(args.data).sequences()
    if args.tau:
        return shipped_fusion(model, seqs, args)
    scorers = {k: FrameScorer() for k in args.k}
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc="fuse", unit="frame", leave=False)
    for seq in seqs:
        d = seq.spec.size
        col = seq.spec.x_extent / d
        xs = seq.camera_positions()[:, 0]
        hist: list[tuple[float, dict[str, torch.Tensor], np.ndarray]] = []
        frames = (seq.rgb(i) for i in range(seq.num_frames))
        pred = Predictor(model, sequence_camera(seq), fuse_tau=0)  # its own fusion
        if args.motion == "images":  # the camera's X from the frame-to-frame shifts, from the first frame's
            sig = [motion_signature(pred.preprocess(seq.rgb(i), i)) for i in range(seq.num_frames)]
            steps = [camera_shift(a, b, model.cfg.view).item() for a, b in zip(sig, sig[1:])]
            xs = np.concatenate([[0.0], np.cumsum(steps)])
        for i, out in enumerate(pred.run(frames, "stream")):
            bar.update(1)
            gt = seq.layouts(i)
            probs = {v: resize_logits(getattr(out, v).float(), d).softmax(1) for v in VIEWS}
            seen = gt.visible if gt.visible is not None else np.ones(d, bool)
            hist = [*hist[-max(args.k) + 1 :], (float(xs[i]), probs, seen)]
            if i % args.every:
                continue
            for k in args.k:
                acc = {v: torch.zeros_like(probs[v]) for v in VIEWS}
                weight = torch.zeros(d)
                for x, p, vis in hist[-k:]:
                    s = int(round((x - xs[i]) / col))
                    for v in VIEWS:
                        moved, m = shift_columns(p[v], vis, s)
                        acc[v] += moved * m
                    weight += m
                pred = {
                    v: torch.where(weight > 0, acc[v] / weight.clamp(min=1e-6), probs[v])
                    .argmax(1)
                    .to(torch.uint8)
                    .numpy()
                    for v in VIEWS
                }
                scorers[k].update(pred, gt)
    bar.close()
    print_table(args, f"probabilities fused over the last K frames (motion: {args.motion})", "K", scorers, 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

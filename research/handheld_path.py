#!/usr/bin/env python3
"""Steady vs hand-held walks, and the stitcher on standard / dim sets, from cached layouts.

    .venv/bin/python research/handheld_path.py walks /tmp/h/fine --layouts gt
    .venv/bin/python research/handheld_path.py walks /tmp/h/fine --layouts net --checkpoint mvracklay-disc-4
    .venv/bin/python research/handheld_path.py standard data/heldout128 --layouts net --checkpoint mvracklay-disc-4

``walks``: each sequence of a fine-step dataset is written as its steady walk (every 2nd frame) and a hand-held
walk (`waresynth.handheld`, seed = the sequence's position) under ``--work``; both are stitched (ground-truth
layouts, or the network's predicted on the walk's own frames, cached under ``--work``) and scored against
scene.json; the table gives the share of the steady map's boxes the hand-held map finds again (3D IoU >= 0.5),
recall / precision / end drift of both, and whether the run flagged its path (untrusted frames).
``standard``: every sequence stitched as it is (the network's layouts cached the same way). Predicted layouts
are cached, so a second run times the stitcher alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.codecs import LayoutFolder  # noqa: E402
from mvracklay.reconstruction import open_sequence  # noqa: E402
from mvracklay.reconstruction_eval import evaluate_sequence  # noqa: E402
from stitching.geometry import Cuboid, iou_matrix  # noqa: E402
from stitching.pipeline import StitchConfig  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.handheld import handheld_indices, resample_sequence, steady_indices  # noqa: E402


def _cuboids(wmap) -> list[Cuboid]:
    return [Cuboid(b.center, b.size, b.yaw) for r in wmap.racks for s in r.shelves for b in s.boxes]


def kept(steady, hand) -> tuple[int, int]:
    """Boxes of the steady map found again in the hand-held map (one-to-one, 3D IoU >= 0.5), of all."""
    a, b = _cuboids(steady), _cuboids(hand)
    if not a or not b:
        return 0, len(a)
    m = iou_matrix(a, b)
    ri, ci = linear_sum_assignment(-m)
    return int(sum(m[i, j] >= 0.5 for i, j in zip(ri, ci))), len(a)


_MODEL: dict = {}


def layouts_for(seq_root: Path, cache: Path, checkpoint: str | None) -> LayoutFolder | None:
    if checkpoint is None:
        return None
    if not (cache / "spec.json").is_file():
        from mvracklay.inference import predict_folder
        from mvracklay.models import checkpoint_arg
        from mvracklay.use_settings import PredictSettings
        from network.checkpoint import load_model

        if checkpoint not in _MODEL:
            import torch

            torch.set_num_threads(2)
            _MODEL[checkpoint] = load_model(checkpoint_arg(checkpoint))
        model, record = _MODEL[checkpoint]
        predict_folder(model, record, PredictSettings(seq_dir=seq_root, out=cache, quiet=True), source=checkpoint)
    return LayoutFolder(cache)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=("walks", "standard"))
    p.add_argument("data")
    p.add_argument("--layouts", choices=("gt", "net"), default="gt")
    p.add_argument("--checkpoint", default="mvracklay-disc-4")
    p.add_argument("--work", default="/tmp/h/work")
    p.add_argument("--limit", type=int, default=0)
    p.add_argument("--json", help="also write the rows here")
    a = p.parse_args()
    ckpt = a.checkpoint if a.layouts == "net" else None
    config = StitchConfig.noisy() if ckpt else StitchConfig()
    data = Path(a.data)
    seqs = open_dataset(data).sequences()
    seqs = seqs[: a.limit] if a.limit else seqs
    work = Path(a.work) / data.name
    rows = []
    tag = Path(ckpt).stem if ckpt else "gt"
    for k, seq in enumerate(seqs):
        if a.what == "standard":
            folder = layouts_for(seq.root, work / "pred" / tag / seq.name, ckpt)
            res, wmap = evaluate_sequence(seq, folder, config)
            reg = wmap.meta.get("registration", {})
            rows.append(
                dict(
                    seq=seq.name,
                    tp=res.tp,
                    fp=res.fp,
                    fn=res.fn,
                    drift=res.drift_end,
                    warned=reg.get("untrusted_count", 0),
                    exact=res.count_exact,
                    shelves=res.shelves,
                )
            )
            r = rows[-1]
            print(
                f"{seq.name} tp {r['tp']:3d} fp {r['fp']:3d} fn {r['fn']:3d} drift {r['drift'] * 100:6.1f} cm "
                f"untrusted {r['warned']}",
                flush=True,
            )
            continue
        out = {}
        for walk, idx in (("steady", steady_indices(seq.num_frames)), ("hand", handheld_indices(seq.num_frames, k))):
            root = work / walk / seq.name
            if not (root / "meta.json").is_file():
                resample_sequence(seq.root, root, idx)
            wseq = open_sequence(root)
            folder = layouts_for(root, work / "pred" / tag / walk / seq.name, ckpt)
            res, wmap = evaluate_sequence(wseq, folder, config)
            out[walk] = (res, wmap)
        (rs, ms), (rh, mh) = out["steady"], out["hand"]
        got, of = kept(ms, mh)
        reg = mh.meta.get("registration", {})
        row = dict(
            seq=seq.name,
            kept=got,
            of=of,
            rec_s=rs.recall,
            rec_h=rh.recall,
            prec_s=rs.precision,
            prec_h=rh.precision,
            drift_s=rs.drift_end,
            drift_h=rh.drift_end,
            untrusted=reg.get("untrusted_count", 0),
        )
        rows.append(row)
        print(
            f"{seq.name} kept {got:3d}/{of:<3d} recall {rs.recall:.3f}/{rh.recall:.3f} prec {rs.precision:.3f}/"
            f"{rh.precision:.3f} drift {rs.drift_end * 100:5.1f}/{rh.drift_end * 100:6.1f} cm untrusted {row['untrusted']}",
            flush=True,
        )
    if a.what == "walks":
        k = [r["kept"] / max(r["of"], 1) for r in rows]
        print(
            f"kept: min {min(k):.3f} mean {np.mean(k):.3f}; hand-held drift max {max(r['drift_h'] for r in rows) * 100:.1f} cm"
        )
    else:
        tp, fp, fn = (sum(r[x] for r in rows) for x in ("tp", "fp", "fn"))
        d = np.array([r["drift"] for r in rows]) * 100
        print(
            f"pooled precision {tp / max(tp + fp, 1):.3f} recall {tp / max(tp + fn, 1):.3f}; drift p90 {np.percentile(d, 90):.1f} "
            f"max {d.max():.1f} mean {d.mean():.1f} cm; exact counts "
            f"{sum(r['exact'] for r in rows) / max(sum(r['shelves'] for r in rows), 1):.1%}; over 10 cm unwarned: "
            f"{sum(1 for r in rows if r['drift'] > 0.1 and not r['warned'])}"
        )
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

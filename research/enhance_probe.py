"""Probe: dim footage brightened (and denoised) before the network, on a copy of a dataset.

    python research/enhance_probe.py data/shifted256 /tmp/shifted_gain --mode gain
    mvracklay evaluate --checkpoint mvracklay-disc-4-256 --data /tmp/shifted_gain --split all

``gain``: one gain per sequence bringing its first frames' median luminance to TARGET (never below 1 when
the median is inside the training range); ``gain+denoise``: then a 3x3 median filter per channel.
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

import numpy as np
from PIL import Image, ImageFilter

TARGET = 0.29


def lum(a: np.ndarray) -> np.ndarray:
    return (a[..., :3].astype(np.float32) / 255) @ np.array([0.299, 0.587, 0.114], np.float32)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--mode", choices=("gain", "gain+denoise"), default="gain")
    a = ap.parse_args()
    a.dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(a.src / "manifest.json", a.dst / "manifest.json")
    for seq in sorted(a.src.glob("seq_*")):
        out = a.dst / seq.name
        out.mkdir(exist_ok=True)
        for item in seq.iterdir():
            if item.name != "rgb" and not (out / item.name).exists():
                os.symlink(item.resolve(), out / item.name)
        (out / "rgb").mkdir(exist_ok=True)
        paths = sorted((seq / "rgb").glob("*.png"))
        med = float(np.median([np.median(lum(np.asarray(Image.open(p)))) for p in paths[:12]]))
        gain = max(1.0, TARGET / max(med, 1e-3)) if med < 0.18 else 1.0
        for p in paths:
            img = Image.open(p).convert("RGB")
            if a.mode == "gain+denoise":
                img = img.filter(ImageFilter.MedianFilter(3))
            arr = np.clip(np.asarray(img, np.float32) * gain, 0, 255).round().astype(np.uint8)
            Image.fromarray(arr).save(out / "rgb" / p.name)
        print(seq.name, f"median {med:.3f} gain {gain:.2f}")


if __name__ == "__main__":
    main()

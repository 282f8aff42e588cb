"""YOLO export: ``images/<split>/...png``, ``labels/<split>/...txt`` (``class cx cy w h`` normalised to
[0, 1], or YOLO-seg polygons ``class x1 y1 x2 y2 ...``), ``<split>.txt`` image lists and ``data.yaml``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from layouts.fileio import atomic_write_json, atomic_write_text
from waresynth.exporters.common import EXPORT_VERSION, run_staged, source_record, split_frames, split_names
from waresynth.exporters.objects import CATEGORIES, mask_bbox


def yolo_box(bbox: tuple[int, int, int, int], width: int, height: int) -> tuple[float, float, float, float]:
    """Pixel box ``(x0, y0, x1, y1)`` (x1/y1 exclusive) -> normalised ``(cx, cy, w, h)`` in [0, 1]."""
    x0, y0, x1, y1 = bbox
    return ((x0 + x1) / 2 / width, (y0 + y1) / 2 / height, (x1 - x0) / width, (y1 - y0) / height)


def mask_polygon(mask: np.ndarray, tolerance: float = 0.75) -> np.ndarray:
    """Outline of a bool mask as one polygon ``(N, 2)`` of continuous ``(x, y)`` pixel coordinates.

    Each 8-connected piece is traced along its pixel edges (marching squares at level 0.5) and
    simplified (Douglas-Peucker, ``tolerance`` pixels); pieces are joined into one ring by a
    there-and-back bridge between their nearest vertices, as single-polygon formats such as
    YOLO-seg need. Holes are not represented.
    """
    from skimage.measure import approximate_polygon, find_contours

    if not np.any(mask):
        raise ValueError("mask_polygon of an empty mask")
    x0, y0, x1, y1 = mask_bbox(mask)
    labels, _ = ndimage.label(mask[y0:y1, x0:x1], structure=np.ones((3, 3), bool))
    poly: np.ndarray | None = None
    for k, box in enumerate(ndimage.find_objects(labels), 1):
        padded = np.pad(labels[box] == k, 1).astype(np.float64)  # the piece's bounding box only
        rings = find_contours(padded, 0.5)
        ring = max(rings, key=len)[:-1]  # closed ring: drop the repeated end point
        ring = approximate_polygon(ring, tolerance) if len(ring) > 4 else ring
        # (row, col) of the padded crop -> continuous (x, y) of the image (pixel c spans [c, c+1)).
        ring = ring[:, ::-1] + (x0 + box[1].start - 0.5, y0 + box[0].start - 0.5)
        if poly is None:
            poly = ring
            continue
        d = ((poly[:, None, :] - ring[None, :, :]) ** 2).sum(-1)
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        rolled = np.roll(ring, -j, axis=0)
        poly = np.concatenate([poly[: i + 1], rolled, rolled[:1], poly[i:]])
    assert poly is not None
    return poly


def _export_yolo(dataset: Any, tmp: Path, progress: bool, segments: bool = False) -> dict:
    """YOLO detection (or YOLO-seg polygons): per-image label files, split image lists and data.yaml."""
    w, h = dataset.image_size
    cls = {n: k for k, n in enumerate(CATEGORIES)}
    splits = split_names(dataset)
    counts: dict[str, dict[str, int]] = {}
    for split in splits:
        listing: list[str] = []
        per_cat = dict.fromkeys(CATEGORIES, 0)
        for _, _, stem, objects in split_frames(dataset, split, "yolo", tmp, progress):
            lines = []
            for obj in objects:
                if segments:
                    xy = np.clip(mask_polygon(obj.mask) / (w, h), 0.0, 1.0)
                    coords = " ".join(f"{v:.6f}" for v in xy.ravel())
                else:
                    coords = " ".join(f"{v:.6f}" for v in yolo_box(obj.bbox, w, h))
                lines.append(f"{cls[obj.category]} {coords}\n")
                per_cat[obj.category] += 1
            atomic_write_text(tmp / "labels" / split / f"{stem}.txt", "".join(lines))
            listing.append(f"./images/{split}/{stem}.png\n")
        atomic_write_text(tmp / f"{split}.txt", "".join(listing))
        counts[split] = {"images": len(listing), **per_cat}
    task = "segmentation (labels: class x1 y1 x2 y2 ... polygon" if segments else "detection (labels: class cx cy w h"
    yaml = [
        f"# WareSynth dataset exported for YOLO {task}, normalised to [0, 1]).",
        "# Paths are relative to this file's folder.",
    ]
    yaml += [f"{s}: {s}.txt" for s in splits]
    yaml.append(f"nc: {len(CATEGORIES)}")
    yaml.append("names:")
    yaml += [f"  {k}: {n}" for k, n in enumerate(CATEGORIES)]
    atomic_write_text(tmp / "data.yaml", "\n".join(yaml) + "\n")
    summary = {
        "format": "yolo",
        "task": "segment" if segments else "detect",
        "version": EXPORT_VERSION,
        "source": source_record(dataset),
        "counts": counts,
        "splits": splits,
    }
    atomic_write_json(tmp / "export.json", summary)
    return summary


def export_yolo(
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    overwrite: bool = False,
    progress: bool = True,
    segments: bool = False,
) -> Path:
    """Write YOLO labels (boxes, or polygons with ``segments=True``), image lists and ``data.yaml``."""

    def build(dataset: Any, tmp: Path, progress: bool) -> dict:
        return _export_yolo(dataset, tmp, progress, segments)

    return run_staged(build, dataset_dir, out_dir, overwrite, progress)

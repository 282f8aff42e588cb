"""COCO instance segmentation export: ``images/<split>/<seq>_<frame>.png`` and
``annotations/instances_<split>.json`` with compressed-RLE masks for the categories box, shelf and rack."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from layouts.fileio import atomic_write_json, atomic_write_text
from waresynth.exporters.common import EXPORT_VERSION, run_staged, source_record, split_frames, split_names
from waresynth.exporters.objects import CATEGORIES


def rle_counts(mask: np.ndarray) -> list[int]:
    """Uncompressed COCO RLE counts of a bool mask: alternating run lengths in column-major
    order, starting with a (possibly empty) run of zeros."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    if flat.size == 0:
        return [0]
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    counts = np.diff(bounds).tolist()
    if flat[0]:
        counts = [0, *counts]
    return [int(c) for c in counts]


def rle_string(counts: list[int]) -> str:
    """COCO's compressed RLE string (the LEB128-like code of ``maskApi.c rleToString``)."""
    out = bytearray()
    for i, c in enumerate(counts):
        x = int(c) - (int(counts[i - 2]) if i > 2 else 0)
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = (x != -1) if (ch & 0x10) else (x != 0)
            if more:
                ch |= 0x20
            out.append(ch + 48)
    return out.decode("ascii")


def mask_to_rle(mask: np.ndarray) -> dict[str, Any]:
    """COCO compressed RLE ``{"size": [h, w], "counts": str}`` of a bool mask."""
    h, w = mask.shape
    return {"size": [int(h), int(w)], "counts": rle_string(rle_counts(mask))}


def _export_coco(dataset: Any, tmp: Path, progress: bool) -> dict:
    """COCO instance segmentation: one annotation file per split, compressed-RLE masks."""
    w, h = dataset.image_size
    categories = [{"id": k + 1, "name": n, "supercategory": "warehouse"} for k, n in enumerate(CATEGORIES)]
    cat_id = {n: k + 1 for k, n in enumerate(CATEGORIES)}
    summary: dict[str, Any] = {"format": "coco", "version": EXPORT_VERSION, "source": source_record(dataset)}
    counts: dict[str, dict[str, int]] = {}
    image_id = ann_id = 0
    for split in split_names(dataset):
        images: list[dict[str, Any]] = []
        anns: list[dict[str, Any]] = []
        per_cat = dict.fromkeys(CATEGORIES, 0)
        for seq, i, stem, objects in split_frames(dataset, split, "coco", tmp, progress):
            image_id += 1
            name = f"{stem}.png"
            images.append(
                {"id": image_id, "file_name": name, "width": int(w), "height": int(h), "sequence": seq.name, "frame": i}
            )
            for obj in objects:
                ann_id += 1
                x0, y0, x1, y1 = obj.bbox
                ann: dict[str, Any] = {
                    "id": ann_id,
                    "image_id": image_id,
                    "category_id": cat_id[obj.category],
                    "segmentation": mask_to_rle(obj.mask),
                    "area": int(obj.mask.sum()),
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "iscrowd": 0,
                }
                if obj.instance_id is not None:
                    ann["instance_id"] = obj.instance_id
                if obj.object_id is not None:
                    ann["object_id"] = obj.object_id
                anns.append(ann)
                per_cat[obj.category] += 1
        coco = {
            "info": {
                "description": f"WareSynth dataset {Path(dataset.root).name}, split {split}",
                "version": str(EXPORT_VERSION),
            },
            "licenses": [],
            "images": images,
            "annotations": anns,
            "categories": categories,
        }
        text = json.dumps(coco, separators=(",", ":"), sort_keys=True) + "\n"
        atomic_write_text(tmp / "annotations" / f"instances_{split}.json", text)
        counts[split] = {"images": len(images), **per_cat}
    summary["counts"] = counts
    summary["splits"] = list(counts)
    atomic_write_json(tmp / "export.json", summary)
    return summary


def export_coco(
    dataset_dir: str | os.PathLike, out_dir: str | os.PathLike, *, overwrite: bool = False, progress: bool = True
) -> Path:
    """Write COCO instance segmentation (images + ``annotations/instances_<split>.json``) to ``out_dir``."""
    return run_staged(_export_coco, dataset_dir, out_dir, overwrite, progress)

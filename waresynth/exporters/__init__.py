"""Export a WareSynth dataset to the RackLay/MVRackLay layout, COCO instance segmentation or YOLO.

Every exporter (modules `coco`, `yolo` and `racklay`; the frame objects they annotate in `objects`,
the staging folder and other shared parts in `staging`) reads the dataset with
`waresynth.dataset.open_dataset`, builds the whole export in a temporary sibling folder and renames
it into place at the end, so an interrupted run leaves no half export under the final name. Output
bytes depend only on the dataset (no dates, no absolute paths, sorted JSON keys), so the same
dataset always exports to the same bytes; the RackLay split lists alone name the output folder's
absolute path, as the reference loaders need.

Formats (see docs/export.md for the folder trees):

``racklay``
    the reference code's layout: ``img/NNNNNN.png``, ``topLayouts/topNNNNNN.npy`` and
    ``topLayouts/frontNNNNNN.npy`` (``(S, D, D)`` uint8 with RackLay's codes 0 / 115 / 255, S slots,
    4 unless told), numbered by one running index over all sequences;
    ``splits/warehouse/{train,val}_files.txt`` (RackLay: absolute image paths) and
    ``..._temporal_files.txt`` (MVRackLay: the same, each sequence closed by a ``,``), to copy under
    the reference code's ``splits/warehouse/``; ``visible.npy`` ``(N, D)`` bool, the layout columns in view per frame;
    ``cameras.json``, what RackLay's format lacks and training needs (intrinsics, board heights,
    per-frame camera records). `load_racklay_export` reads it back, as frames or as sequences.
``coco``
    ``images/<split>/<seq>_<frame>.png`` and ``annotations/instances_<split>.json`` with
    compressed-RLE masks for the categories box, shelf and rack.
``yolo``
    ``images/<split>/...png``, ``labels/<split>/...txt`` (``class cx cy w h`` normalised to
    [0, 1], or YOLO-seg polygons ``class x1 y1 x2 y2 ...``), ``<split>.txt`` image lists and
    ``data.yaml``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from layouts.errors import InputError
from waresynth.exporters.coco import export_coco
from waresynth.exporters.racklay import export_racklay
from waresynth.exporters.yolo import export_yolo

EXPORT_FORMATS: tuple[str, ...] = ("coco", "yolo", "racklay")
_EXPORTERS: dict[str, Callable[..., Path]] = {"coco": export_coco, "yolo": export_yolo, "racklay": export_racklay}


def export_dataset(
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    fmt: str,
    *,
    overwrite: bool = False,
    progress: bool = True,
    yolo_segments: bool = False,
    slots: int | None = None,
) -> Path:
    """Export the WareSynth dataset at ``dataset_dir`` to ``out_dir`` in format ``fmt`` (one of
    `EXPORT_FORMATS`); ``yolo_segments`` writes YOLO-seg polygons instead of boxes; ``slots``: shelf
    slots per RackLay stack (None: 4, the reference code's ``--num_racks``). Returns the output folder."""
    if fmt not in _EXPORTERS:
        raise InputError(f"format must be one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    if yolo_segments and fmt != "yolo":
        raise InputError(f"polygon labels (segment task) exist only for the yolo format, not {fmt!r}")
    if slots is not None and fmt != "racklay":
        raise InputError(f"--slots sets the RackLay stacks' slot count, not one of the {fmt!r} format")
    if fmt == "racklay" and slots is not None:
        return export_racklay(dataset_dir, out_dir, overwrite=overwrite, progress=progress, slots=slots)
    if fmt == "yolo":
        return export_yolo(dataset_dir, out_dir, overwrite=overwrite, progress=progress, segments=yolo_segments)
    return _EXPORTERS[fmt](dataset_dir, out_dir, overwrite=overwrite, progress=progress)

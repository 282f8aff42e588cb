"""The split lists of the RackLay export, written as the authors' code reads them.

RackLay (``racklay/dataloader.py`` at its HEAD) and MVRackLay (``racklay/dataloader.py``,
``eval_vracklay.py``, branch ``VideoLayout``) read ``splits/warehouse/{train,val}_files.txt`` and
``{train,val}_temporal_files.txt`` beside their code and use each listed image path as written (their
``--data_path`` builds no path); the layouts are found with ``path.replace("img/", "topLayouts/top")``
(front: ``"topLayouts/front"``) then ``.replace("png", "npy")``. So the lists hold absolute paths of
``OUT/img/NNNNNN.png``, and an ``OUT`` whose path would be changed by those replaces is refused.
Their evaluation reads ``val`` only: `list_plan` always fills it (which sequences, it records).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from layouts.errors import InputError

#: the folder under the reference code (and under the export) that holds the lists: ``--split warehouse``
LIST_DIR = "splits/warehouse"
IMAGE_DIR = "img"
LAYOUT_DIR = "topLayouts"  #: both views: ``topNNNNNN.npy`` and ``frontNNNNNN.npy``, as their loader builds them
#: their ``eval_vracklay.py`` / ``eval.py`` default ``--num_racks``: the slots a stack holds unless told
DEFAULT_SLOTS = 4


def image_name(index: int) -> str:
    return f"{index:06d}.png"


def reference_layout_path(image_path: str, view: str) -> str:
    """The layout path the reference loaders build from a listed image path (their exact strings)."""
    return image_path.replace("img/", f"topLayouts/{view}").replace("png", "npy")


def check_out_path(out: Path) -> str:
    """``out``'s absolute path (posix), refused when the reference code could not find files under it:
    its replace rule must map ``OUT/img/N.png`` to ``OUT/topLayouts/topN.npy``, and the temporal lists
    are split on ``,`` and newlines."""
    root = out.resolve().as_posix()
    img = f"{root}/{IMAGE_DIR}/{image_name(0)}"
    for view in ("top", "front"):
        if reference_layout_path(img, view) != f"{root}/{LAYOUT_DIR}/{view}{0:06d}.npy":
            raise InputError(
                f"--out {root}: the reference loaders find layouts with path.replace('img/', 'topLayouts/{view}')"
                ".replace('png', 'npy'), which would also change this folder's path (it holds 'img/' or 'png'); "
                "choose another output folder"
            )
    if any(c in root for c in ",\n\r"):
        raise InputError(f"--out {root!r}: the reference split lists cannot hold a path with ',' or a line break")
    return root


def list_plan(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Which sequences each reference list holds: ``{list: {"from": what, "sequences": [names]}}``.

    ``train`` and ``test`` are the dataset's splits; ``val`` is the val split when it has sequences,
    else the test split, else the last train sequence, held back from the train list when train has
    another (a one-sequence dataset lists it in both)."""
    by = {s: [r["name"] for r in records if r["split"] == s] for s in ("train", "val", "test")}
    plan: dict[str, dict[str, Any]] = {}
    train = list(by["train"])
    if by["val"]:
        val = {"from": "val", "sequences": by["val"]}
    elif by["test"]:
        val = {"from": "test", "sequences": by["test"]}
    elif train:
        held = train[-1]
        if len(train) > 1:
            train = train[:-1]
        val = {"from": f"train sequence {held}", "sequences": [held]}
    else:
        val = {"from": "none", "sequences": []}
    plan["train"] = {"from": "train", "sequences": train}
    plan["val"] = val
    if by["test"]:
        plan["test"] = {"from": "test", "sequences": by["test"]}
    return plan


def list_texts(records: list[dict[str, Any]], root: str) -> tuple[dict[str, str], dict[str, dict[str, Any]]]:
    """``({file name: text}, plan)``: RackLay's ``<list>_files.txt`` (one absolute image path a line) and
    MVRackLay's ``<list>_temporal_files.txt`` (the same paths in frame order, every sequence closed by ``,``)."""
    plan = list_plan(records)
    first = {r["name"]: (int(r["first"]), int(r["frames"])) for r in records}
    texts = {}
    for name, entry in plan.items():
        flat, temporal = [], []
        for seq in entry["sequences"]:
            start, n = first[seq]
            lines = [f"{root}/{IMAGE_DIR}/{image_name(k)}\n" for k in range(start, start + n)]
            flat += lines
            temporal += [*lines, ","]
        texts[f"{name}_files.txt"] = "".join(flat)
        texts[f"{name}_temporal_files.txt"] = "".join(temporal)
    return texts, plan


def list_frame(line: str, source: Any) -> int:
    """The export frame index of one listed line: an image path ``.../NNNNNN.png`` or a bare index."""
    name = line.rsplit("/", 1)[-1]
    stem = name[: -len(".png")] if name.endswith(".png") else name
    try:
        return int(stem)
    except ValueError:
        raise InputError(f"{source}: not an image of this export: {line!r}") from None

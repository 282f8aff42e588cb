"""WareSynth exporters: COCO loads in pycocotools with exact masks, YOLO boxes match the instance
masks, RackLay exports read back to the same layouts, bytes are deterministic, bad input is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from layouts.errors import InputError
from layouts.fileio import atomic_save_npy
from mvracklay.cli import main
from waresynth import semantics
from waresynth.dataset import open_dataset
from waresynth.exporters import export_dataset
from waresynth.exporters.coco import mask_to_rle, rle_counts
from waresynth.exporters.objects import CATEGORIES, MIN_COMPONENT_PIXELS, frame_objects, instance_table, mask_bbox
from waresynth.exporters.racklay import load_racklay_export
from waresynth.exporters.yolo import yolo_box


@pytest.fixture(scope="module")
def exports(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("exports")
    return {f: export_dataset(tiny_dataset, base / f, f, progress=False) for f in ("coco", "yolo", "racklay")}


def _tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_rle_matches_pycocotools() -> None:
    mask_utils = pytest.importorskip("pycocotools.mask")
    rng = np.random.default_rng(3)
    masks = [np.zeros((5, 7), bool), np.ones((5, 7), bool), rng.random((40, 33)) < 0.5]
    corner = np.zeros((9, 9), bool)
    corner[0, 0] = corner[8, 8] = True
    masks.append(corner)
    blob = np.zeros((300, 200), bool)
    blob[10:290, 5:150] = True  # long runs: multi-byte codes
    masks.append(blob)
    for m in masks:
        ref = mask_utils.encode(np.asfortranarray(m.astype(np.uint8)))
        ours = mask_to_rle(m)
        assert ours["counts"] == ref["counts"].decode("ascii")
        assert ours["size"] == list(ref["size"])
        assert sum(rle_counts(m)) == m.size


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_coco_loads_and_masks_reproduce_instances(tiny_dataset: Path, exports: dict[str, Path]) -> None:
    coco_mod = pytest.importorskip("pycocotools.coco")
    mask_utils = pytest.importorskip("pycocotools.mask")
    ds = open_dataset(tiny_dataset)
    out = exports["coco"]
    splits = sorted({s.split for s in ds.sequences()})
    assert sorted(p.name for p in (out / "annotations").iterdir()) == [f"instances_{s}.json" for s in splits]
    seen_boxes = 0
    for split in splits:
        coco = coco_mod.COCO(str(out / "annotations" / f"instances_{split}.json"))
        assert [c["name"] for c in coco.loadCats(coco.getCatIds())] == list(CATEGORIES)
        cat = {c["name"]: c["id"] for c in coco.loadCats(coco.getCatIds())}
        sem_of = {cat["box"]: semantics.BOX, cat["shelf"]: semantics.SHELF, cat["rack"]: semantics.RACK}
        images = coco.loadImgs(coco.getImgIds())
        assert len(images) == sum(s.num_frames for s in ds.sequences(split))
        for img in images:
            seq = ds.sequence(img["sequence"])
            table = instance_table(seq)
            assert table, f"{seq.root}: no instances table"
            i = img["frame"]
            assert (out / "images" / split / img["file_name"]).read_bytes() == seq.rgb_path(i).read_bytes()
            inst = seq.instance(i)
            sem = seq.semantic(i)
            anns = coco.loadAnns(coco.getAnnIds(imgIds=img["id"]))
            union = np.zeros(sem.shape, bool)
            for a in anns:
                m = coco.annToMask(a).astype(bool)
                assert a["area"] == int(m.sum()) >= 1
                assert np.allclose(a["bbox"], mask_utils.toBbox(a["segmentation"]))
                if "instance_id" in a:  # the mask is exactly that instance's pixels
                    assert np.array_equal(m, inst == a["instance_id"])
                    listed = table.get(a["instance_id"])
                    assert a.get("object_id") == (listed.object_id if listed else None)
                # Every pixel of a box / shelf / rack annotation has that semantic class.
                assert (sem[m] == sem_of[a["category_id"]]).all()
                assert not (m & union).any()
                union |= m
            # Together the annotations cover the mapped row's box, shelf and rack pixels.
            target = np.isin(sem, list(sem_of.values()))
            assert (target & ~union).sum() < MIN_COMPONENT_PIXELS * 20
            boxes = [a for a in anns if a["category_id"] == cat["box"]]
            want = sorted(k for k in np.unique(inst).tolist() if k in table and table[k].semantic == "box")
            assert sorted(a["instance_id"] for a in boxes) == want
            seen_boxes += len(boxes)
    assert seen_boxes > 0


def test_yolo_boxes_normalised_and_match_instance_masks(tiny_dataset: Path, exports: dict[str, Path]) -> None:
    ds = open_dataset(tiny_dataset)
    out = exports["yolo"]
    w, h = ds.image_size
    yaml = (out / "data.yaml").read_text()
    for k, name in enumerate(CATEGORIES):
        assert f"  {k}: {name}" in yaml
    for seq in ds.sequences():
        listing = (out / f"{seq.split}.txt").read_text().splitlines()
        for i in range(seq.num_frames):
            stem = f"{seq.name}_{i:06d}"
            assert f"./images/{seq.split}/{stem}.png" in listing
            assert (out / "images" / seq.split / f"{stem}.png").is_file()
            rows = [line.split() for line in (out / "labels" / seq.split / f"{stem}.txt").read_text().splitlines()]
            vals = np.array([[float(v) for v in r[1:]] for r in rows]).reshape(-1, 4)
            assert ((vals >= 0) & (vals <= 1)).all()
            # Every box line is the bounding box of one instance mask.
            inst = seq.instance(i)
            table = instance_table(seq)
            box_ids = [k for k in np.unique(inst).tolist() if k in table and table[k].semantic == "box"]
            want = sorted(yolo_box(mask_bbox(inst == k), w, h) for k in box_ids)
            got = sorted(tuple(v) for r, v in zip(rows, vals) if r[0] == "0")
            assert len(got) == len(want)
            assert np.allclose(got, want, atol=1e-6)
            # One line per exported object, in the same order.
            objs = frame_objects(seq, i)
            assert [int(r[0]) for r in rows] == [CATEGORIES.index(o.category) for o in objs]


def test_racklay_round_trip(tiny_dataset: Path, exports: dict[str, Path]) -> None:
    ds = open_dataset(tiny_dataset)
    ex = load_racklay_export(exports["racklay"])
    assert ex.spec == ds.spec
    assert len(ex) == sum(s.num_frames for s in ds.sequences())
    top = np.load(exports["racklay"] / "topLayouts" / "top000000.npy", allow_pickle=False)
    # 4 slots (the reference code's --num_racks), the slots past the dataset's R all 0
    assert top.dtype == np.uint8 and top.shape == (4, *ds.spec.shape[1:]) and set(np.unique(top)) <= {0, 115, 255}
    assert ds.spec.num_slots == 3 and not top[3].any()
    for rec, seq in zip(ex.records, ds.sequences()):
        assert (rec.name, rec.split, rec.frames) == (seq.name, seq.split, seq.num_frames)
        for k, i in zip(rec.indices, range(seq.num_frames)):
            a, b = ex.layouts(k), seq.layouts(i)
            assert np.array_equal(a.top, b.top) and np.array_equal(a.front, b.front)
            assert (a.visible is None) == (b.visible is None)
            if b.visible is not None:
                assert np.array_equal(a.visible, b.visible)
            assert np.array_equal(ex.rgb(k), seq.rgb(i))
    assert ex.lists == ex.splits == ["train", "val", "test"]  # every split has a sequence: lists as the splits
    for split in ex.splits:
        seqs = [r for r in ex.records if r.split == split]
        assert ex.split_indices(split) == [k for r in seqs for k in r.indices]
        assert ex.temporal_sequences(split) == [r.indices for r in seqs]
        wins = ex.windows(split, 4)
        assert len(wins) == sum(r.frames for r in seqs)
        first = seqs[0].indices
        assert wins[0] == [first[0]] * 4 and wins[3] == first[:4]
        assert all(len(w) == 4 for w in wins)
    # The temporal file has MVRackLay's shape: image paths a line, each sequence closed by ",".
    text = (exports["racklay"] / "splits" / "warehouse" / f"{ex.splits[0]}_temporal_files.txt").read_text()
    assert text.endswith("\n,") and text.count(",") == sum(r.split == ex.splits[0] for r in ex.records)


def test_exports_are_deterministic(tiny_dataset: Path, exports: dict[str, Path], tmp_path: Path) -> None:
    for fmt, first in exports.items():
        again = export_dataset(tiny_dataset, tmp_path / fmt, fmt, progress=False)
        a, b = _tree_bytes(again), _tree_bytes(first)
        if fmt == "racklay":  # the reference lists name the folder's absolute path, and nothing else does
            lists = {k for k in a if k.startswith("splits/") or k == "racklay_export.json"}
            a = {k: v.replace(str(again.resolve()).encode(), b"OUT") for k, v in a.items()}
            b = {k: v.replace(str(first.resolve()).encode(), b"OUT") for k, v in b.items()}
            assert lists and all(str(first.resolve()).encode() in _tree_bytes(first)[k] for k in lists)
        assert a == b, fmt


def test_racklay_reader_refuses_bad_files(exports: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        load_racklay_export(tmp_path / "nope")
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(exports["racklay"], broken)
    atomic_save_npy(broken / "topLayouts" / "top000001.npy", np.full((3, 4, 4), 7, np.uint8))
    ex = load_racklay_export(broken)
    with pytest.raises(InputError, match=r"top000001\.npy: values must be 0, 115 or 255"):
        ex.layouts(1)
    with pytest.raises(InputError, match="frame index"):
        ex.layouts(len(ex))
    (broken / "racklay_export.json").write_text(json.dumps({"format": "racklay", "version": 99}))
    with pytest.raises(InputError, match="version"):
        load_racklay_export(broken)


def _one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mvracklay export: error: ") and "\n" not in err
    return err


def test_export_cli_bad_paths_are_one_line_errors(
    tiny_dataset: Path, exports: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert "not found" in _one_line_error(
        capsys, ["export", str(tmp_path / "missing"), "--format", "coco", "--out", str(tmp_path / "o")]
    )
    (tmp_path / "plain").mkdir()
    assert "manifest.json" in _one_line_error(
        capsys, ["export", str(tmp_path / "plain"), "--format", "yolo", "--out", str(tmp_path / "o")]
    )
    (tmp_path / "afile").write_text("x")
    assert "not a folder" in _one_line_error(
        capsys, ["export", str(tiny_dataset), "--format", "yolo", "--out", str(tmp_path / "afile"), "--quiet"]
    )
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "keep.txt").write_text("x")
    assert "--overwrite" in _one_line_error(
        capsys, ["export", str(tiny_dataset), "--format", "yolo", "--out", str(busy), "--quiet"]
    )
    assert (busy / "keep.txt").exists()
    assert "lies inside the input DIR" in _one_line_error(
        capsys, ["export", str(tiny_dataset), "--format", "coco", "--out", str(tiny_dataset / "coco"), "--quiet"]
    )
    assert main(["export", str(tiny_dataset), "--format", "racklay", "--out", str(busy), "--overwrite", "--quiet"]) == 0
    assert not (busy / "keep.txt").exists() and (busy / "racklay_export.json").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging folder left behind
    with pytest.raises(InputError, match="format must be one of"):
        export_dataset(tiny_dataset, tmp_path / "x", "kitti")


def test_export_images_decode(exports: dict[str, Path]) -> None:
    first = sorted((exports["racklay"] / "img").iterdir())[0]
    with Image.open(first) as im:
        assert im.mode in ("RGB", "RGBA")


def test_yolo_segment_polygons_cover_the_masks(tiny_dataset: Path, tmp_path: Path) -> None:
    from skimage.draw import polygon2mask

    ds = open_dataset(tiny_dataset)
    out = export_dataset(tiny_dataset, tmp_path / "seg", "yolo", progress=False, yolo_segments=True)
    assert json.loads((out / "export.json").read_text())["task"] == "segment"
    w, h = ds.image_size
    ious = []
    for seq in ds.sequences():
        for i in (0, seq.num_frames - 1):
            rows = (out / "labels" / seq.split / f"{seq.name}_{i:06d}.txt").read_text().splitlines()
            objs = frame_objects(seq, i)
            assert len(rows) == len(objs)
            for row, obj in zip(rows, objs):
                cls, *vals = row.split()
                assert int(cls) == CATEGORIES.index(obj.category)
                xy = np.array(vals, float).reshape(-1, 2)
                assert len(xy) >= 3 and ((xy >= 0) & (xy <= 1)).all()
                if obj.mask.sum() >= 100:
                    poly = np.stack([xy[:, 1] * h - 0.5, xy[:, 0] * w - 0.5], axis=1)
                    filled = polygon2mask((h, w), poly)
                    ious.append((filled & obj.mask).sum() / (filled | obj.mask).sum())
    assert ious and np.median(ious) > 0.85 and min(ious) > 0.5
    with pytest.raises(InputError, match="only for the yolo format"):
        export_dataset(tiny_dataset, tmp_path / "x", "coco", yolo_segments=True)

"""WareSynth writer: determinism, resumability, refusal of foreign folders, reader and CLI."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from waresynth import semantics
from waresynth.dataset import open_dataset
from waresynth.generate import DatasetSettings, assign_splits, generate_dataset

SMALL = dict(num_sequences=2, frames=2, image_size=(64, 48), spec=LayoutSpec(size=32), seed=3, progress=False)


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_any_worker_count(tmp_path):
    a = generate_dataset(tmp_path / "a", DatasetSettings(**SMALL))
    b = generate_dataset(tmp_path / "b", DatasetSettings(**{**SMALL, "workers": 2}))
    ta, tb = tree_bytes(a), tree_bytes(b)
    assert len(ta) == 2 * (4 * 2 + 2 + 3) + 1  # per sequence: 4 images x 2 frames, 2 layouts, spec/meta/scene
    assert ta == tb
    c = generate_dataset(tmp_path / "c", DatasetSettings(**{**SMALL, "seed": 4}))
    assert tree_bytes(c)[str(Path("seq_00000/rgb/000000.png"))] != ta[str(Path("seq_00000/rgb/000000.png"))]


def test_resume_skips_complete_and_restores_missing(tmp_path):
    root = generate_dataset(tmp_path / "d", DatasetSettings(**SMALL))
    before = tree_bytes(root)
    keep = (root / "seq_00000" / "meta.json").stat().st_mtime_ns
    shutil.rmtree(root / "seq_00001")
    (root / ".seq_00001.tmp" / "rgb").mkdir(parents=True)  # an interrupted write
    assert not open_dataset(root).complete()
    generate_dataset(root, DatasetSettings(**SMALL))
    assert tree_bytes(root) == before
    assert (root / "seq_00000" / "meta.json").stat().st_mtime_ns == keep
    assert open_dataset(root).complete()


def test_refuses_foreign_or_different_folders(tmp_path):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="not a WareSynth dataset"):
        generate_dataset(foreign, DatasetSettings(**SMALL))
    assert (foreign / "notes.txt").exists()
    root = generate_dataset(tmp_path / "e", DatasetSettings(**SMALL))
    with pytest.raises(InputError, match="different WareSynth dataset.*seed"):
        generate_dataset(root, DatasetSettings(**{**SMALL, "seed": 5}))
    generate_dataset(foreign, DatasetSettings(**{**SMALL, "num_sequences": 1, "frames": 1}, overwrite=True))
    assert not (foreign / "notes.txt").exists() and open_dataset(foreign).complete()
    # overwrite keeps (resumes) the very same dataset instead of rendering it again
    keep = (root / "seq_00000" / "meta.json").stat().st_mtime_ns
    generate_dataset(root, DatasetSettings(**SMALL, overwrite=True))
    assert (root / "seq_00000" / "meta.json").stat().st_mtime_ns == keep
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(InputError, match="exists and is not a folder"):
        generate_dataset(afile, DatasetSettings(**SMALL))


@pytest.mark.parametrize(
    "config, match",
    [
        ({"camera": {"fov": 60}}, "unknown key 'camera.fov'"),
        ({"camera": {"distance": [3.0, 2.0]}}, "camera.distance must be \\[low, high\\] with low <= high"),
        ({"camera": {"distance": "far"}}, "camera.distance must be \\[low, high\\]"),
        ({"camera": {"hfov_deg": 500}}, "camera.hfov_deg must lie in"),
        ({"rack": {"levels": [2.5, 4]}}, "rack.levels must be an integer"),
        ({"boxes": {"textures": ["marble"]}}, "boxes.textures must be a non-empty list of textures"),
        ({"floor": {"colours": [[300, 0, 0]]}}, "floor.colours must be a non-empty list"),
        (
            {"boxes": {"density": {"dense": {"weight": 0}, "moderate": {"weight": 0}, "sparse": {"weight": 0}}}},
            "weights",
        ),
        ({"rack": "tall"}, "rack must be an object"),
        ([1, 2], "config must be a dict"),
    ],
)
def test_bad_config_one_line_error(tmp_path, config, match):
    with pytest.raises(InputError, match=match) as e:
        generate_dataset(tmp_path / "x", DatasetSettings(**SMALL, config=config))
    assert "\n" not in str(e.value)
    assert not (tmp_path / "x").exists()


def test_config_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="bad.json: not valid JSON"):
        generate_dataset(tmp_path / "x", DatasetSettings(**SMALL, config=bad))
    with pytest.raises(InputError, match="missing.json: config file not found"):
        generate_dataset(tmp_path / "x", DatasetSettings(**SMALL, config=tmp_path / "missing.json"))
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"_doc": "comment", "camera": {"step": [0.1, 0.1], "reverse_probability": 0.0}}))
    root = generate_dataset(tmp_path / "y", DatasetSettings(**{**SMALL, "num_sequences": 1}, config=good))
    ds = open_dataset(root)
    assert ds.config["camera"]["step"] == [0.1, 0.1]
    assert ds.sequences()[0].meta["step"] == pytest.approx(0.1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_sequences": 0}, "num_sequences"),
        ({"frames": -1}, "frames"),
        ({"image_size": (8, 8)}, "image width"),
        ({"workers": 0}, "workers"),
        ({"splits": (0.5, 0.5, 0.5)}, "splits"),
        ({"spec": {"size": 3}}, "spec must be a LayoutSpec"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, match):
    with pytest.raises(InputError, match=match):
        generate_dataset(tmp_path / "x", DatasetSettings(**{**SMALL, **kwargs}))


def test_splits_by_sequence():
    labels = assign_splits(0, 400, (0.9, 0.05, 0.05))
    assert [labels.count(s) for s in ("train", "val", "test")] == [360, 20, 20]
    assert sorted(assign_splits(1, 3, (0.9, 0.05, 0.05))) == ["test", "train", "val"]
    assert assign_splits(1, 10, (1.0, 0.0, 0.0)) == ["train"] * 10


def test_reader_api_and_images_agree(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    assert ds.seed == 7 and ds.image_size == (128, 128) and ds.spec == LayoutSpec(size=64)
    seqs = ds.sequences()
    assert [s.name for s in seqs] == ["seq_00000", "seq_00001", "seq_00002"]
    assert sum(len(ds.sequences(s)) for s in ("train", "val", "test")) == 3
    seq = seqs[0]
    assert seq.num_frames == 8 and seq.intrinsics.width == 128
    assert seq.camera_positions().shape == (8, 3)
    steps = np.diff(seq.camera_positions()[:, 0])
    assert np.allclose(steps, seq.meta["step"]) and np.allclose(np.diff(seq.camera_positions()[:, 1:], axis=0), 0)
    scene = seq.scene()
    names = {i["instance_id"]: i["semantic"] for i in scene["instances"]}
    for i in (0, seq.num_frames - 1):
        rgb, depth, sem, inst = seq.rgb(i), seq.depth(i), seq.semantic(i), seq.instance(i)
        assert rgb.shape == (128, 128, 3) and rgb.dtype == np.uint8
        assert depth.dtype == np.float32 and sem.dtype == np.uint8 and inst.dtype == np.int32
        assert np.array_equal(depth > 0, sem != semantics.VOID)
        assert sem.max() < semantics.NUM_SEMANTIC and (sem == semantics.BOX).any()
        for iid in np.unique(inst[inst > 0])[:50]:
            kinds = np.unique(sem[inst == iid])
            assert [semantics.SEMANTIC_NAMES[int(k)] for k in kinds] == [names[int(iid)]]
        lay = seq.layouts(i)
        assert lay.top.shape == (3, 64, 64) and lay.visible.shape == (64,)
        assert seq.rgb_path(i).name == f"{i:06d}.png"
    assert seq.layout_folder.indices() == list(range(8))
    # Depth in metres matches the box geometry: the nearest box face is not nearer than the rack front.
    box_depth = seq.depth(0)[seq.semantic(0) == semantics.BOX]
    assert box_depth.min() >= seq.frame(0)["distance"] - 0.01


def test_reader_errors(tiny_dataset, tmp_path):
    with pytest.raises(InputError, match="dataset folder not found"):
        open_dataset(tmp_path / "nope")
    with pytest.raises(InputError, match="no manifest.json"):
        open_dataset(tmp_path)
    ds = open_dataset(tiny_dataset)
    with pytest.raises(InputError, match="no sequence named"):
        ds.sequence("seq_99999")
    with pytest.raises(InputError, match="split must be one of"):
        ds.sequences("training")
    with pytest.raises(InputError, match="frame index"):
        ds.sequences()[0].rgb(8)


def test_cli_generate(tmp_path, capsys):
    out = tmp_path / "cli"
    args = ["generate", str(out), "--sequences", "1", "--frames", "2", "--size", "32", "--layout-size", "16"]
    assert main([*args, "--no-progress"]) == 0
    assert "1 sequences x 2 frames" in capsys.readouterr().out
    assert open_dataset(out).spec.size == 16
    bad = tmp_path / "bad.json"
    bad.write_text('{"camera": {"distance": [3, 2]}}')
    assert main([*args, "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "camera.distance" in err and "bad.json" in err
    assert main(["generate", str(tmp_path / "z"), "--size", "4"]) == 2
    assert "--size must be in" in capsys.readouterr().err
    # --format also exports; a re-run resumes and keeps the export
    assert main([*args, "--no-progress", "--format", "yolo"]) == 0
    assert (tmp_path / "cli_yolo").is_dir()
    assert main([*args, "--no-progress", "--format", "yolo"]) == 0
    assert "kept" in capsys.readouterr().out


def test_a_pool_of_workers_finishes_every_time(tmp_path):
    """Two workers, many runs in a row: the pool is joined, never terminated while a worker holds its queue
    (a terminated Pool hung about one run in ten). Each run in a subprocess with a timeout, so a hang fails."""
    import subprocess
    import sys

    script = (
        "import sys; from pathlib import Path; from layouts.spec import LayoutSpec; "
        "from waresynth.generate import DatasetSettings, generate_dataset\n"
        "for k in range(12):\n"
        "    generate_dataset(Path(sys.argv[1]) / str(k), DatasetSettings(num_sequences=3, frames=1, "
        "image_size=(32, 24), spec=LayoutSpec(size=16), seed=k, workers=2, progress=False))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert r.returncode == 0, r.stderr
    assert all((tmp_path / str(k) / "seq_00002" / "meta.json").is_file() for k in range(12))

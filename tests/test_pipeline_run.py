"""`mvracklay run` end to end on a tiny generated sequence with a tiny trained checkpoint."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from layouts.codecs import LayoutFolder
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from stitching.export_gltf import load_glb_cuboid_bounds
from stitching.rerun_log import read_entities
from stitching.warehouse_map import WarehouseMap
from waresynth.dataset import open_dataset


@pytest.fixture(scope="module")
def checkpoint(tiny_checkpoint: Path) -> Path:
    return tiny_checkpoint


@pytest.fixture(scope="module")
def seq_dir(tiny_dataset: Path) -> Path:
    return tiny_dataset / "seq_00000"


@pytest.fixture(scope="module")
def run_out(seq_dir: Path, checkpoint: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pipeline_run") / "out"
    argv = ["run", str(seq_dir), "--out", str(out), "--checkpoint", str(checkpoint), "--layout-size", "64"]
    assert main([*argv, "--threads", "1", "--quiet"]) == 0
    return out


def test_run_writes_all_outputs(run_out: Path, seq_dir: Path):
    for name in ("warehouse.json", "warehouse.glb", "warehouse.rrd", "layouts/spec.json"):
        assert (run_out / name).is_file(), name
    folder = LayoutFolder(run_out / "layouts")
    assert folder.indices() == list(range(8))
    fl = folder.read(0)
    assert fl.top.shape == (3, 64, 64) and fl.visible is not None and fl.visible.any()
    assert not [p for p in run_out.parent.iterdir() if ".partial-" in p.name]


def test_outputs_load_and_agree_with_the_map(run_out: Path):
    wmap = WarehouseMap.load(run_out / "warehouse.json")
    assert len(wmap.steps) == 8 and wmap.origin_world is not None
    assert wmap.meta["input_kind"] == "sequence" and wmap.meta["frames"] == 8
    # the .glb holds one mesh node per shelf board and box of the map (and the racks' drawn uprights and beams)
    nodes = load_glb_cuboid_bounds(run_out / "warehouse.glb")
    want = {s.id for s in wmap.shelves()} | {b.id for b in wmap.boxes()}
    drawn = {k for k in nodes if "/upright_" in k or "/beam_" in k}
    assert want and set(nodes) - drawn == want
    scene = trimesh.load(str(run_out / "warehouse.glb"), force="scene")
    assert len(scene.geometry) == len(nodes)
    for b in wmap.boxes():
        v = nodes[b.id]
        assert np.allclose(v.mean(0), b.cuboid.center, atol=1e-4)
    # the recording holds the logged entities, one map batch per slot
    ents = read_entities(run_out / "warehouse.rrd")
    for e in ("/camera/rgb", "/world/frame/boxes", "/world/map/shelves", "/world/camera/path"):
        assert e in ents
    assert {f"/world/map/slot_{r}" for r in range(3)} <= ents
    assert {f"/layouts/{v}/slot_{r}" for v in ("top", "front") for r in range(3)} <= ents


def test_layouts_feed_reconstruct(run_out: Path, tmp_path: Path):
    out = tmp_path / "rec"
    assert main(["reconstruct", str(run_out / "layouts"), "--out", str(out), "--no-rrd", "--noisy", "--quiet"]) == 0
    a = WarehouseMap.load(out / "warehouse.json")
    b = WarehouseMap.load(run_out / "warehouse.json")
    assert sorted(x.id for x in a.boxes()) == sorted(x.id for x in b.boxes())


def test_run_prints_free_space_table(seq_dir: Path, checkpoint: Path, tmp_path: Path, capsys):
    out = tmp_path / "o"
    argv = ["run", str(seq_dir), "--out", str(out), "--checkpoint", str(checkpoint), "--no-rrd", "--quiet"]
    assert main([*argv, "--max-frames", "3", "--mode", "window", "--flip-average", "--precision", "bf16"]) == 0
    text = capsys.readouterr().out
    wmap = WarehouseMap.load(out / "warehouse.json")
    assert "free_len" in text and len(wmap.steps) == 3
    assert "predict" in text and "rerun" not in text.split("speed:")[1].splitlines()[0]  # nothing logged, no rate
    assert wmap.meta["mode"] == "window" and wmap.meta["flip_average"] is True and wmap.meta["precision"] == "bf16"
    for s in wmap.shelves():
        assert s.id in text
    assert not (out / "warehouse.rrd").exists()


def test_same_input_same_bytes(run_out: Path, seq_dir: Path, checkpoint: Path, tmp_path: Path):
    out = tmp_path / "again"
    argv = ["run", str(seq_dir), "--out", str(out), "--checkpoint", str(checkpoint), "--layout-size", "64"]
    assert main([*argv, "--threads", "1", "--quiet", "--no-rrd"]) == 0
    for name in ("warehouse.glb", "layouts/000005.npz"):
        assert (out / name).read_bytes() == (run_out / name).read_bytes(), name
    a, b = json.loads((out / "warehouse.json").read_text()), json.loads((run_out / "warehouse.json").read_text())
    assert a["racks"] == b["racks"] and a["steps"] == b["steps"]


def test_image_folder_input(seq_dir: Path, checkpoint: Path, tmp_path: Path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, p in enumerate(sorted((seq_dir / "rgb").glob("*.png"))[:5]):
        (frames / f"img{i}.png").write_bytes(p.read_bytes())  # natural order: img2 before img10
    out = tmp_path / "o"
    argv = ["run", str(frames), "--out", str(out), "--checkpoint", str(checkpoint), "--quiet"]
    assert main(argv) == 0
    wmap = WarehouseMap.load(out / "warehouse.json")
    assert wmap.meta["input_kind"] == "images" and len(wmap.steps) == 5 and wmap.origin_world is None
    said = capsys.readouterr()
    assert "camera: default" in said.out
    # footage's angles are read; from frames this small the pitch and yaw are unsure, and it says so
    width = Image.open(frames / "img0.png").width
    assert width < 256 and f"read from frames {width} px wide" in said.err
    assert main([*argv, "--yaw", "0", "--pitch", "0"]) == 0
    assert "px wide" not in capsys.readouterr().err


def test_video_input(seq_dir: Path, checkpoint: Path, tmp_path: Path):
    import av

    from waresynth.imageio import read_png

    video = tmp_path / "walk.mp4"
    with av.open(str(video), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 128, 128, "yuv420p"
        for p in sorted((seq_dir / "rgb").glob("*.png"))[:6]:
            frame = av.VideoFrame.from_ndarray(read_png(p, np.uint8, 3), format="rgb24")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    out = tmp_path / "o"
    argv = ["run", str(video), "--out", str(out), "--checkpoint", str(checkpoint), "--quiet", "--max-frames", "4"]
    assert main(argv) == 0
    wmap = WarehouseMap.load(out / "warehouse.json")
    assert wmap.meta["input_kind"] == "video" and len(wmap.steps) == 4
    assert LayoutFolder(out / "layouts").indices() == [0, 1, 2, 3]


def test_camera_json_and_mismatch_warning(seq_dir: Path, checkpoint: Path, tmp_path: Path, capsys):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": 40.0, "fy": 40.0, "cx": 64.0, "cy": 64.0, "width": 128, "height": 128}))
    out = tmp_path / "o"
    argv = ["run", str(seq_dir), "--out", str(out), "--checkpoint", str(checkpoint), "--camera", str(cam)]
    assert main([*argv, "--quiet", "--no-rrd", "--max-frames", "2"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "warning: camera" in line]
    assert len(err) == 1 and "horizontal FOV" in err[0] and "trained" in err[0]
    assert "camera.hfov_deg 116.0" in err[0] and "further back" not in err[0]  # wider: no distance helps
    assert WarehouseMap.load(out / "warehouse.json").meta["intrinsics"]["fx"] == 40.0


def test_rerun_replaces_earlier_outputs_and_keeps_other_files(seq_dir: Path, checkpoint: Path, tmp_path: Path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    base = ["run", str(seq_dir), "--out", str(out), "--checkpoint", str(checkpoint), "--quiet", "--no-rrd"]
    base.append("--overwrite")  # OUT holds another file (tests/test_run_outputs.py: refused without it)
    assert main([*base, "--max-frames", "4"]) == 0
    assert main([*base, "--max-frames", "2"]) == 0
    assert LayoutFolder(out / "layouts").indices() == [0, 1]
    assert (out / "notes.txt").read_text() == "mine"


def test_camera_advice_says_how_far_back_a_narrower_camera_stands():
    from layouts import Intrinsics
    from mvracklay.camera import camera_advice

    trained = Intrinsics.from_fov(128, 128, 60.0)
    said = camera_advice(Intrinsics.from_fov(640, 480, 51.4), trained)
    assert "about 1.20x further back" in said and "camera.hfov_deg 51.4" in said


def test_a_model_trained_on_a_range_of_cameras_is_checked_against_the_nearest():
    from layouts import Intrinsics
    from mvracklay.camera import camera_advice, camera_mismatch

    mid = Intrinsics.from_fov(128, 128, 55.0)
    inside, narrow = Intrinsics.from_fov(256, 256, 47.0), Intrinsics.from_fov(256, 256, 36.0)
    assert camera_mismatch(inside, mid) is not None  # one camera: 8 degrees off
    assert camera_mismatch(inside, mid, hfov_range=[45.0, 65.0]) is None  # within the trained range
    why = camera_mismatch(narrow, mid, hfov_range=[45.0, 65.0])
    assert why is not None and "36.0 deg vs 45.0" in why  # compared with the range's narrowest
    # stand back by the tangent ratio to the range's narrowest camera, not to the middle one
    said = camera_advice(narrow, mid, [45.0, 65.0])
    assert f"about {math.tan(math.radians(22.5)) / math.tan(math.radians(18.0)):.2f}x further back" in said
    assert camera_mismatch(inside, mid, hfov_range="wide") is not None  # a malformed record: the one camera
    # one camera recorded as a range of nothing: taken as recorded (its own fy, not a square-pixel copy)
    tall = Intrinsics(fx=110.0, fy=80.0, cx=64.0, cy=64.0, width=128, height=128)
    assert camera_mismatch(tall, tall, hfov_range=[tall.hfov_deg, tall.hfov_deg]) is None


def test_training_records_the_range_of_its_cameras(tmp_path: Path):
    from network.training.train_data import hfov_range
    from waresynth.generate import DatasetSettings, generate_dataset

    root = generate_dataset(
        tmp_path / "d",
        DatasetSettings(
            num_sequences=3,
            frames=1,
            image_size=(64, 48),
            spec=LayoutSpec(size=32),
            seed=3,
            progress=False,
            config={"camera": {"hfov_deg": [45, 65]}},
        ),
    )
    seqs = open_dataset(root).sequences()
    lo, hi = hfov_range(seqs)
    fovs = sorted(json.loads(p.read_text())["camera"]["hfov_deg"] for p in root.glob("seq_*/meta.json"))
    assert lo == pytest.approx(fovs[0]) and hi == pytest.approx(fovs[-1]) and 45 <= lo < hi <= 65


def test_predict_warns_about_a_camera_outside_the_trained_ones(seq_dir: Path, checkpoint: Path, tmp_path: Path, capsys):
    argv = ["predict", str(seq_dir), "--checkpoint", str(checkpoint), "--out", str(tmp_path / "p"), "--quiet"]
    assert main([*argv, "--threads", "1", "--intrinsics", "140,140,64,64"]) == 0  # 49 degrees, the model's 60
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(err) == 1 and err[0].startswith("mvracklay predict: warning: camera differs from the ones")
    assert "horizontal FOV 49.1 deg vs 60.0" in err[0] and "further back" in err[0]


def test_predict_without_a_checkpoint_runs_the_shipped_default(seq_dir: Path, tmp_path: Path):
    from mvracklay import models

    frames = tmp_path / "frames"
    frames.mkdir()
    for i, p in enumerate(sorted((seq_dir / "rgb").glob("*.png"))[:2]):
        (frames / f"{i}.png").write_bytes(p.read_bytes())
    out = tmp_path / "lay"
    assert main(["predict", str(frames), "--out", str(out), "--threads", "1", "--quiet"]) == 0
    named = tmp_path / "named"
    argv = ["predict", str(frames), "--out", str(named), "--checkpoint", models.DEFAULT_MODEL]
    assert main([*argv, "--threads", "1", "--quiet"]) == 0
    a, b = LayoutFolder(out), LayoutFolder(named)
    assert len(a) == len(b) == 2
    for i in a.indices():  # the very layouts of the default model named
        x, y = a.read(i), b.read(i)
        assert np.array_equal(x.top, y.top) and np.array_equal(x.front, y.front)


def test_each_frame_carries_the_angles_it_was_levelled_by_into_the_sinks(seq_dir: Path, checkpoint: Path, tmp_path):
    """The frames the run's sinks take carry the camera angles they were levelled by (here given: the same for each),
    the recording and ``on_frame`` follow the row map in order, and the map's meta keeps their median."""
    from mvracklay.frames import open_source
    from mvracklay.pipeline import RunConfig, run_pipeline
    from mvracklay.settings import InferenceSettings

    seen: list[tuple[int, tuple[float, float, float], int]] = []
    cfg = RunConfig(checkpoint=checkpoint, inference=InferenceSettings(roll=2.0, pitch=1.0, yaw=0.0), threads=1,
                    progress=False, rrd=False)  # fmt: skip
    res = run_pipeline(
        open_source(seq_dir),
        tmp_path / "out",
        cfg,
        on_frame=lambda f, st: seen.append((f.index, f.angles, len(st.map().steps))),
    )
    assert [i for i, _, _ in seen] == list(range(res.frames))
    assert all(angles == (2.0, 1.0, 0.0) for _, angles, _ in seen)
    assert [steps for _, _, steps in seen] == [i + 1 for i in range(res.frames)]  # each in the map before on_frame
    meta = res.map.meta
    assert (meta["camera_roll_deg"], meta["camera_pitch_deg"], meta["camera_yaw_deg"]) == (2.0, 1.0, 0.0)
    assert meta["camera_roll_source"] == "given" and meta["camera_yaw_source"] == "level"

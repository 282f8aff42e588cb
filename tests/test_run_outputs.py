"""`run` / `reconstruct` / `free-space` as users expect: the OUT overwrite rule, Ctrl-C and SIGTERM (no staging
folder left), `free-space OUT_DIR`, the fit answer in CSV, "no racks found", and `run --every N`."""

from __future__ import annotations

import csv
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from layouts.codecs import LayoutFolder
from layouts.publish import stage
from mvracklay.cli import main
from stitching.free_space import format_table
from stitching.warehouse_map import WarehouseMap

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--threads", "1", "--quiet", "--no-rrd"]


@pytest.fixture(scope="module")
def base(tiny_dataset: Path, tiny_checkpoint: Path) -> list[str]:
    return ["run", str(tiny_dataset / "seq_00000"), "--checkpoint", str(tiny_checkpoint), *FAST]


@pytest.fixture(scope="module")
def run_dir(base: list[str], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("run_outputs") / "out"
    assert main([*base, "--out", str(out), "--max-frames", "3"]) == 0
    return out


def test_run_refuses_a_folder_with_other_files_unless_overwrite(base, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "warehouse.json").write_text("{}")  # not a map: someone's file
    assert main([*base, "--out", str(out), "--max-frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.txt" in err[0] and "--overwrite" in err[0] and "another --out" in err[0]
    assert (out / "warehouse.json").read_text() == "{}" and not (out / "layouts").exists()
    assert main([*base, "--out", str(out), "--max-frames", "2", "--overwrite"]) == 0
    assert (out / "notes.txt").read_text() == "mine"  # nothing else touched
    assert WarehouseMap.load(out / "warehouse.json").meta["frames"] == 2


def test_run_replaces_an_earlier_run_and_fills_an_empty_folder(base, tmp_path):
    out = tmp_path / "walk"
    out.mkdir()  # empty: allowed
    assert main([*base, "--out", str(out), "--max-frames", "3"]) == 0
    assert main([*base, "--out", str(out), "--max-frames", "2"]) == 0  # an earlier run's folder: replaced
    assert LayoutFolder(out / "layouts").indices() == [0, 1]
    lone = tmp_path / "lone"
    (lone / "layouts").mkdir(parents=True)  # only layouts/, no map: not recognisably a run
    assert main([*base, "--out", str(lone), "--max-frames", "2"]) == 2


def test_reconstruct_follows_the_same_rule(run_dir, tmp_path, capsys):
    assert main(["reconstruct", str(run_dir / "layouts"), "--out", str(run_dir), "--no-rrd", "--quiet"]) == 0
    other = tmp_path / "other"
    other.mkdir()
    (other / "data.csv").write_text("x")
    argv = ["reconstruct", str(run_dir / "layouts"), "--out", str(other), "--no-rrd", "--quiet"]
    assert main(argv) == 2 and "--overwrite" in capsys.readouterr().err
    assert main([*argv, "--overwrite"]) == 0 and (other / "data.csv").read_text() == "x"


def test_stage_removes_stale_folders_of_dead_processes(tmp_path):
    out = tmp_path / "out"
    dead = tmp_path / ".out.partial-999999999"  # above any PID the kernel hands out
    alive = tmp_path / f".out.partial-{os.getppid()}"
    other = tmp_path / ".other.partial-999999999"
    for d in (dead, alive, other):
        d.mkdir()
    st = stage(out)
    assert st.name == f".out.partial-{os.getpid()}" and st.is_dir()
    assert not dead.exists() and alive.exists() and other.exists()


@pytest.mark.parametrize(
    "sig, status, said", [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")]
)
def test_a_signalled_run_leaves_no_staging_folder(tiny_dataset, tiny_checkpoint, tmp_path, sig, status, said):
    frames = tmp_path / "frames"  # a long input, so the run is still going when the signal comes
    frames.mkdir()
    first = sorted((tiny_dataset / "seq_00000" / "rgb").glob("*.png"))
    for i in range(600):
        (frames / f"{i:05d}.png").symlink_to(first[i % len(first)])
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "mvracklay", "run", str(frames), "--out", str(out)]
    argv += ["--checkpoint", str(tiny_checkpoint), "--threads", "1", "--no-rrd"]
    argv += ["--distance", "2.6", "--roll", "0", "--pitch", "0", "--yaw", "0"]  # frames mapped from the first on
    # a shell running this suite in the background ignores SIGINT, and children inherit that: reset it, as a
    # terminal's Ctrl-C finds it
    proc = subprocess.Popen(
        argv,
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob(".out.partial-*")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    while not list(tmp_path.glob(".out.partial-*/layouts/000001.npz")) and proc.poll() is None:
        time.sleep(0.05)  # frames flowing
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err[-2000:]
    said_lines = [line for line in err.replace("\r", "\n").splitlines() if line.startswith("mvracklay run: ")]
    assert said_lines == [f"mvracklay run: {said} (OUT left as it was; run it again to start over)"], err[-2000:]
    assert "resume" not in err and "Traceback" not in err
    assert not list(tmp_path.glob(".out.partial-*")) and not out.exists()


def test_free_space_reads_a_run_folder_and_keeps_the_fit_answer_in_csv(run_dir, tiny_dataset, tmp_path, capsys):
    assert main(["free-space", str(run_dir)]) == 0
    table = capsys.readouterr().out
    assert main(["free-space", str(run_dir / "warehouse.json")]) == 0
    assert capsys.readouterr().out == table
    gt = tmp_path / "gt"  # the ground truth's map: shelves with gaps
    assert main(["reconstruct", str(tiny_dataset / "seq_00000"), "--out", str(gt), "--no-rrd", "--quiet"]) == 0
    capsys.readouterr()
    wmap = WarehouseMap.load(gt / "warehouse.json")
    run_dir = gt
    assert main(["free-space", str(run_dir), "--box", "0.1x0.1x0.1", "--csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(rows) == len(wmap.shelves())
    assert {"fits", "fit_centre_x", "fit_centre_x_turned"} <= set(rows[0])
    assert any(r["fits"] == "yes" and ".." in r["fit_centre_x"] for r in rows)
    assert main(["free-space", str(run_dir), "--box", "9x9x9", "--csv"]) == 0
    assert all(r["fits"] == "no" for r in csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert main(["free-space", str(run_dir), "--box", "0.1x0.1x0.1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["box"]["fits"]


def test_free_space_of_a_folder_without_a_map_fails_in_one_line(tmp_path, capsys):
    assert main(["free-space", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no warehouse.json" in err[0]


def test_no_racks_found_is_said(tmp_path, capsys):
    empty = tmp_path / "out"
    empty.mkdir()
    WarehouseMap(racks=[], steps=[], board_thickness=0.06).save(empty / "warehouse.json")
    assert main(["free-space", str(empty)]) == 0
    assert "no racks found" in capsys.readouterr().out
    assert format_table([]).splitlines()[-1].startswith("no racks found")
    assert "2 racks found, but no shelves" in format_table([], racks=2)


def test_run_every_nth_frame(base, tmp_path):
    out = tmp_path / "o"
    assert main([*base, "--out", str(out), "--every", "3"]) == 0  # frames 0, 3, 6 of 8
    wmap = WarehouseMap.load(out / "warehouse.json")
    assert wmap.meta["frames"] == 3 and wmap.meta["every"] == 3 and len(wmap.steps) == 3
    assert LayoutFolder(out / "layouts").indices() == [0, 1, 2]
    assert main([*base, "--out", str(out), "--every", "2", "--max-frames", "2"]) == 0
    assert WarehouseMap.load(out / "warehouse.json").meta["frames"] == 2
    assert main([*base, "--out", str(out), "--every", "0"]) == 2


def test_predict_every_nth_frame(tiny_dataset, tiny_checkpoint, tmp_path, capsys):
    argv = ["predict", str(tiny_dataset / "seq_00000"), "--checkpoint", str(tiny_checkpoint), "--threads", "1"]
    assert main([*argv, "--out", str(tmp_path / "p"), "--every", "3", "--quiet"]) == 0  # frames 0, 3, 6 of 8
    assert LayoutFolder(tmp_path / "p").indices() == [0, 1, 2]
    assert main([*argv, "--out", str(tmp_path / "q"), "--every", "0"]) == 2
    assert "--every" in capsys.readouterr().err


def test_every_nth_of_a_video_keeps_frames_0_n_2n(tmp_path):
    import av
    import numpy as np

    from mvracklay.frames import every_nth, open_source

    video = tmp_path / "v.mp4"
    with av.open(str(video), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 32, 32, "yuv420p"
        for i in range(7):
            img = np.full((32, 32, 3), 30 * i, np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    src = every_nth(open_source(video), 3)
    means = [round(float(f.mean()) / 30) for f in src.frames()]
    assert means == [0, 3, 6]
    assert [round(float(f.mean()) / 30) for f in src.frames(2)] == [0, 3]

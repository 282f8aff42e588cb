"""Faults a careful user or a hostile input brings, one class per test group, on small generated data.

Each case asserts the one-line error (exit status 2) or the right answer, and that the earlier outputs and
the inputs are byte-identical afterwards:

* permissions: a read-only OUT or parent (as an unprivileged user), a move that fails half-way;
* other filesystems: OUT a mount point (simulated by refusing moves across OUT, and a real tmpfs where
  this machine lets us mount one);
* an output over an input (run, reconstruct, predict, inspect, generate --export-out);
* bad values per file format (map, camera, config, recipe, meta.json distance, JSON nesting and 1e400);
* frames in odd image modes (16-bit, palette, alpha, CMYK); a checkpoint of NaN weights;
* stdout closed early (``| head``); the Python API given wrong types.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from layouts.errors import InputError
from mvracklay.cli import main

ROOT = Path(__file__).resolve().parents[1]
QUIET = ["--quiet", "--no-rrd"]


# --- helpers ---------------------------------------------------------------------------------------------------


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file's bytes and every folder (None) under ``root``, by relative path."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(Path(root).rglob("*"))}


def one_line(capsys: pytest.CaptureFixture[str], rc: int, command: str, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"mvracklay {command}: error: "), err
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def no_stage_left(*folders: Path) -> None:
    for f in folders:
        if f.is_dir():
            assert not [p.name for p in f.iterdir() if ".partial" in p.name or p.name.endswith(".old")], f


@pytest.fixture(scope="module")
def seq(tiny_dataset: Path) -> Path:
    return tiny_dataset / "seq_00000"


@pytest.fixture(scope="module")
def earlier(seq: Path, tiny_checkpoint: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An earlier run's output folder (layouts/, warehouse.json, warehouse.glb): copied before each use."""
    out = tmp_path_factory.mktemp("earlier") / "out"
    argv = ["run", str(seq), "--out", str(out), "--checkpoint", str(tiny_checkpoint), "--threads", "1", *QUIET]
    assert main([*argv, "--max-frames", "4"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["layouts", "warehouse.glb", "warehouse.json"]
    return out


@pytest.fixture(scope="module")
def map_doc(seq: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The map the ground-truth layouts give (racks, shelves and boxes), as parsed JSON."""
    out = tmp_path_factory.mktemp("gt_map") / "out"
    assert main(["reconstruct", str(seq), "--out", str(out), *QUIET]) == 0
    doc = json.loads((out / "warehouse.json").read_text())
    assert doc["racks"] and any(s["boxes"] for r in doc["racks"] for s in r["shelves"])
    return doc


def copy_of(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


# --- permissions ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def shared(seq: Path, tiny_checkpoint: Path) -> Path:
    """A world-readable folder holding a copy of the sequence and the checkpoint (the test folders are 0700)."""
    base = Path(tempfile.mkdtemp(prefix="mvracklay-faults-"))
    base.chmod(0o755)
    shutil.copytree(seq, base / "seq")
    shutil.copy2(tiny_checkpoint, base / "net.pt")
    for p in base.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    yield base
    shutil.rmtree(base, ignore_errors=True)


def _as_nobody(argv: list[str]) -> tuple[int, str]:
    """``(exit status, stderr)`` of ``mvracklay ARGV`` run in a forked child as an unprivileged user (root reads
    and writes anything, so the test would pass trivially; as another user the child keeps our identity).
    In process: the child needs nothing it cannot read, the modules are loaded already."""
    import contextlib
    import io

    import mvracklay.pipeline  # noqa: F401 - loaded before the fork: the child may not read them
    from mvracklay.cli import build_parser

    build_parser()  # imports every command module

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child
        rc, err = 99, ""
        try:
            os.close(r)
            if os.geteuid() == 0:
                os.setgid(65534)
                os.setuid(65534)
            buf = io.StringIO()
            with contextlib.redirect_stderr(buf), contextlib.redirect_stdout(io.StringIO()):
                rc = main(argv)
            err = buf.getvalue()
        except BaseException as e:  # noqa: BLE001 - reported to the parent
            err = f"child: {type(e).__name__}: {e}"
        finally:
            os.write(w, json.dumps([rc, err]).encode())
            os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    os.waitpid(pid, 0)
    rc, err = json.loads(data)
    return rc, err


@pytest.mark.parametrize("command", ["reconstruct", "run"])
def test_read_only_earlier_output_is_one_line_and_kept(command, shared: Path, earlier: Path):
    prev = copy_of(earlier, shared / f"prev-{command}")
    for p in [prev, *prev.rglob("*")]:
        p.chmod(0o555 if p.is_dir() else 0o444)
    before = snapshot(prev)
    argv = [command, str(shared / "seq"), "--out", str(prev), *QUIET]
    if command == "run":
        argv += ["--checkpoint", str(shared / "net.pt"), "--threads", "1"]
    rc, err = _as_nobody(argv)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert "cannot write there" in lines[0] and str(prev) in lines[0]
    assert snapshot(prev) == before
    no_stage_left(prev, shared)


def test_out_under_a_read_only_parent_is_one_line(shared: Path):
    ro = shared / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    argv = ["run", str(shared / "seq"), "--out", str(ro / "new" / "out"), "--checkpoint", str(shared / "net.pt")]
    rc, err = _as_nobody([*argv, *QUIET])
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "cannot write there" in lines[0], err
    assert list(ro.iterdir()) == []


@pytest.fixture
def read_only_mount(tmp_path: Path, earlier: Path):
    """An earlier output on a filesystem mounted read-only (even root cannot write it), where we may mount."""
    mnt = tmp_path / "ro"
    mnt.mkdir()
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(mnt)], capture_output=True)
    except OSError:
        pytest.skip("no mount command")
    if r.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    for p in earlier.iterdir():
        (shutil.copytree if p.is_dir() else shutil.copy2)(p, mnt / p.name)
    subprocess.run(["mount", "-o", "remount,ro", str(mnt)], check=True, capture_output=True)
    yield mnt
    subprocess.run(["umount", str(mnt)], capture_output=True)


def test_a_read_only_filesystem_out(read_only_mount: Path, seq: Path, capsys):
    before = snapshot(read_only_mount)
    rc = main(["reconstruct", str(seq), "--out", str(read_only_mount), *QUIET])
    one_line(capsys, rc, "reconstruct", "cannot write there (Read-only file system)")
    rc = main(["run", str(seq), "--out", str(read_only_mount / "sub"), "--no-rrd", "--quiet"])
    one_line(capsys, rc, "run", "cannot write there (Read-only file system)")
    assert snapshot(read_only_mount) == before


@pytest.mark.parametrize("fault", ["disk full", "Ctrl-C"])
def test_a_move_failing_half_way_leaves_the_earlier_outputs_whole(fault, seq, earlier, tmp_path, monkeypatch, capsys):
    import layouts.publish as publish

    prev = copy_of(earlier, tmp_path / "prev")
    (prev / "warehouse.rrd").write_bytes(b"an earlier recording")  # an output this run does not write: stale
    before = snapshot(prev)
    calls = []
    real = os.replace

    def flaky(src, dst, *a, **k):
        if Path(dst).parent.resolve() == prev.resolve() or Path(dst).parent.name.endswith("-old"):
            calls.append((src, dst))  # a swap into OUT or aside
            if len(calls) == 3:  # an earlier output went aside and a new one came in: then the fault
                raise OSError(errno.ENOSPC, "No space left on device") if fault == "disk full" else KeyboardInterrupt
        return real(src, dst, *a, **k)

    monkeypatch.setattr(publish.os, "replace", flaky)
    rc = main(["reconstruct", str(seq), "--out", str(prev), *QUIET])
    if fault == "disk full":
        one_line(capsys, rc, "reconstruct", "cannot write there", "No space left", "earlier outputs are kept")
    else:
        assert rc == 130 and "interrupted" in capsys.readouterr().err
    assert len(calls) >= 3 and snapshot(prev) == before
    no_stage_left(prev, tmp_path)
    monkeypatch.undo()
    assert main(["reconstruct", str(seq), "--out", str(prev), *QUIET]) == 0  # and it works once the disk does
    assert sorted(p.name for p in prev.iterdir()) == ["layouts", "warehouse.glb", "warehouse.json"]


# --- other filesystems: OUT a mount point -------------------------------------------------------------------


def _mount_point(monkeypatch, out: Path) -> list:
    """Make every rename across OUT's boundary fail with EXDEV, as where OUT is a mount point."""
    crossed = []
    real_replace, real_rename = os.replace, os.rename
    inside = os.path.realpath(out) + os.sep

    def guard(real):
        def move(src, dst, *a, **k):
            a_in = os.path.realpath(src).startswith(inside)
            b_in = os.path.realpath(os.path.dirname(os.path.abspath(dst))).rstrip(os.sep) + os.sep
            b_in = b_in.startswith(inside)
            if a_in != b_in or os.path.realpath(src) == inside.rstrip(os.sep):
                crossed.append((src, dst))
                raise OSError(errno.EXDEV, "Invalid cross-device link")
            return real(src, dst, *a, **k)

        return move

    monkeypatch.setattr(os, "replace", guard(real_replace))
    monkeypatch.setattr(os, "rename", guard(real_rename))
    return crossed


def test_reconstruct_onto_a_mount_point_replaces_its_outputs_whole(seq, earlier, tmp_path, monkeypatch, capsys):
    prev = copy_of(earlier, tmp_path / "mnt")
    fresh = tmp_path / "fresh"
    assert main(["reconstruct", str(seq), "--out", str(fresh), *QUIET, "--board-thickness", "0.05"]) == 0
    (prev / "warehouse.rrd").write_bytes(b"stale")
    crossed = _mount_point(monkeypatch, prev)
    rc = main(["reconstruct", str(seq), "--out", str(prev), *QUIET, "--board-thickness", "0.05"])
    monkeypatch.undo()
    assert rc == 0, capsys.readouterr().err
    assert crossed == []  # nothing even tried to cross
    assert (prev / "warehouse.json").read_bytes() == (fresh / "warehouse.json").read_bytes()
    assert (prev / "warehouse.glb").read_bytes() == (fresh / "warehouse.glb").read_bytes()
    assert not (prev / "warehouse.rrd").exists()  # the stale recording went with the old map
    assert snapshot(prev / "layouts") == snapshot(earlier / "layouts")
    no_stage_left(prev, tmp_path)


def test_export_onto_a_mount_point_leaves_nothing_beside_it(tiny_dataset, tmp_path, monkeypatch, capsys):
    out = tmp_path / "mnt"
    assert main(["export", str(tiny_dataset), "--format", "yolo", "--out", str(out), "--quiet"]) == 0
    want = snapshot(out)
    (out / "keep.txt").write_text("replaced by --overwrite")
    crossed = _mount_point(monkeypatch, out)
    for _ in range(2):  # every try
        rc = main(["export", str(tiny_dataset), "--format", "yolo", "--out", str(out), "--overwrite", "--quiet"])
        assert rc == 0, capsys.readouterr().err
    monkeypatch.undo()
    assert crossed == [] and snapshot(out) == want
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mnt"]


@pytest.fixture
def tmpfs(tmp_path: Path):
    """A real tmpfs mount point, where this machine lets us mount one."""
    mnt = tmp_path / "tmpfs"
    mnt.mkdir()
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(mnt)], capture_output=True)
    except OSError:
        pytest.skip("no mount command")
    if r.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    yield mnt
    subprocess.run(["umount", str(mnt)], capture_output=True)


def test_a_real_tmpfs_out(seq, earlier, tmpfs: Path, tiny_dataset, tmp_path, capsys):
    for p in earlier.iterdir():
        (shutil.copytree if p.is_dir() else shutil.copy2)(p, tmpfs / p.name)
    assert main(["reconstruct", str(seq), "--out", str(tmpfs), *QUIET, "--board-thickness", "0.05"]) == 0
    fresh = tmp_path / "fresh"
    assert main(["reconstruct", str(seq), "--out", str(fresh), *QUIET, "--board-thickness", "0.05"]) == 0
    assert (tmpfs / "warehouse.json").read_bytes() == (fresh / "warehouse.json").read_bytes()
    assert snapshot(tmpfs / "layouts") == snapshot(earlier / "layouts")
    assert main(["export", str(tiny_dataset), "--format", "coco", "--out", str(tmpfs), "--overwrite", "--quiet"]) == 0
    assert (tmpfs / "export.json").is_file() and not (tmpfs / "warehouse.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fresh", "tmpfs"]  # nothing left beside the mount


# --- an output over an input ------------------------------------------------------------------------------------


def test_run_never_writes_into_its_input(seq, tiny_checkpoint, tmp_path, capsys):
    own = copy_of(seq, tmp_path / "seq")
    before = snapshot(own)
    ck = ["--checkpoint", str(tiny_checkpoint), "--threads", "1", *QUIET]
    rc = main(["run", str(own), "--out", str(own), "--overwrite", *ck])
    one_line(capsys, rc, "run", "lies inside the input INPUT")
    rc = main(["run", str(own / "rgb"), "--out", str(own / "rgb" / "out"), *ck])
    one_line(capsys, rc, "run", "lies inside the input INPUT")
    assert snapshot(own) == before
    rc = main(["run", str(own), "--out", str(own / "layouts" / "x"), "--overwrite", *ck])
    one_line(capsys, rc, "run", "lies inside the input INPUT")
    # an OUT holding the input is fine: only run's own outputs there are written, the input stays as it was
    assert main(["run", str(own), "--out", str(tmp_path), "--overwrite", "--max-frames", "2", *ck]) == 0
    assert snapshot(own) == before and (tmp_path / "warehouse.json").is_file()


def test_predict_and_reconstruct_never_write_over_their_input(seq, earlier, tiny_checkpoint, tmp_path, capsys):
    own = copy_of(seq, tmp_path / "seq")
    before = snapshot(own)
    argv = ["predict", str(own), "--out", str(own / "layouts"), "--checkpoint", str(tiny_checkpoint), "--quiet"]
    one_line(capsys, main(argv), "predict", "lies inside the input INPUT")
    lay = copy_of(earlier / "layouts", tmp_path / "lay")
    rc = main(["reconstruct", str(lay), "--out", str(lay), "--overwrite", *QUIET])
    one_line(capsys, rc, "reconstruct", "lies inside the input layouts")
    assert snapshot(own) == before
    # an OUT holding an input it leaves alone stays allowed: re-stitching a run's own layouts in place
    prev = copy_of(earlier, tmp_path / "prev")
    assert main(["reconstruct", str(prev / "layouts"), "--out", str(prev), *QUIET]) == 0


def test_inspect_never_writes_over_a_frame(tiny_dataset, tmp_path, capsys):
    frame = tiny_dataset / "seq_00000" / "rgb" / "000000.png"
    before = frame.read_bytes()
    rc = main(["inspect", str(tiny_dataset), "--out", str(frame), "--quiet"])
    one_line(capsys, rc, "inspect", "lies inside the input DIR")
    assert frame.read_bytes() == before


def test_generate_export_out_is_not_the_dataset(tiny_dataset, tmp_path, capsys):
    ds = copy_of(tiny_dataset, tmp_path / "ds")
    before = snapshot(ds)
    base = ["generate", str(ds), "--sequences", "3", "--frames", "8", "--size", "128", "--layout-size", "64"]
    for dest in (ds, ds / "coco", tmp_path):
        rc = main([*base, "--seed", "7", "--format", "coco", "--export-out", str(dest), "--quiet"])
        one_line(capsys, rc, "generate", "--export-out", "the input OUT")
    assert snapshot(ds) == before


# --- bad values per file format ---------------------------------------------------------------------------------


def _mutate(doc: dict, where: str, value) -> dict:
    d = json.loads(json.dumps(doc))
    shelf = next(s for r in d["racks"] for s in r["shelves"] if s["boxes"])
    box = shelf["boxes"][0]
    target = {"box": box, "shelf": shelf, "rack": d["racks"][0], "map": d}[where.split(".")[0]]
    key = where.split(".")[1]
    if key == "dup":
        shelf["boxes"].append(dict(box))
    elif key == "twin":  # the same box again under another id
        shelf["boxes"].append({**box, "id": f"{box['id']}_again"})
    elif key == "outside":
        box["center"][0] = shelf["x_range"][1] + 5.0
    else:
        target[key] = value(target[key]) if callable(value) else value
    return d


MAP_FAULTS = {
    "yaw NaN": ("box.yaw", "NaN", "yaw: Input should be a finite number"),
    "centre beside its shelf": ("box.outside", None, "wholly outside its shelf"),
    "clear height negative": ("shelf.clear_height", -0.5, "clear_height"),
    "box size negative": ("box.size", [-0.3, 0.3, 0.3], "size[0]"),
    "confidence -5": ("box.confidence", -5, "confidence"),
    "x_range reversed": ("shelf.x_range", lambda v: [v[1], v[0]], "reversed"),
    "x_range 1e308 wide": ("rack.x_range", [-1e308, 1e308], "x_range[0]"),
    "slot 1e400": ("shelf.slot", "1e400", "out of range"),
    "observations 1e400": ("box.observations", "1e400", "out of range"),
    "box ids repeated": ("box.dup", None, "appears more than once"),
    # a row map edited by hand: each names the element, racks[i].shelves[j](.boxes[k])
    "the same box twice": ("box.twin", None, ("].boxes[", "covers 100% of box", "the same box twice")),
    "a 50 m box": ("box.size", [50.0, 0.3, 0.3], ("].boxes[0]: box", "along X: longer than its shelf")),
    "a box 50 m deep": ("box.size", [0.3, 0.3, 50.0], ("].boxes[0]: box", "reaches", "than its shelf (")),  # turned
    "a box 50 m tall": ("box.size", [0.3, 50.0, 0.3], ("].boxes[0]: box", "taller than its shelf's clear height")),
    "shelf outside its rack": (
        "shelf.x_range",
        lambda v: [v[1] + 1.0, v[1] + 3.0],
        ("].x_range: shelf", "outside its rack"),
    ),
}


@pytest.mark.parametrize("fault", list(MAP_FAULTS))
def test_free_space_refuses_an_impossible_map(fault, map_doc, tmp_path, capsys):
    where, value, needle = MAP_FAULTS[fault]
    raw = value if isinstance(value, str) else None
    d = _mutate(map_doc, where, "@RAW@" if raw else value)
    text = json.dumps(d).replace('"@RAW@"', raw) if raw else json.dumps(d)
    path = tmp_path / "warehouse.json"
    path.write_text(text)
    rc = main(["free-space", str(path), "--box", "0.4x0.3x0.3"])
    one_line(capsys, rc, "free-space", str(path), *(needle if isinstance(needle, tuple) else (needle,)))
    assert path.read_text() == text


def test_the_untouched_map_answers(map_doc, tmp_path, capsys):
    path = tmp_path / "warehouse.json"
    path.write_text(json.dumps(map_doc))
    assert main(["free-space", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)
    for flag in (["--near", "01-L-01-01"], ["--with-recount"]):  # a building map's options, refused on a row map
        one_line(capsys, main(["free-space", str(path), "--box", "0.4x0.3x0.3", *flag]), "free-space", flag[0])


DEEP = "[" * 100_000 + "]" * 100_000


@pytest.mark.parametrize("flag", ["map", "--camera", "--config", "generate --config", "recipe"])
@pytest.mark.parametrize("text", [DEEP, '{"fx": 1e400}'], ids=["nested", "1e400"])
def test_json_nesting_and_overflow_are_one_line(flag, text, seq, tiny_checkpoint, tmp_path, capsys):
    f = tmp_path / ("bad.toml" if flag == "recipe" else "bad.json")
    f.write_text(
        text if flag != "recipe" else ("x = " + "[" * 100_000 + "]" * 100_000 if text == DEEP else "x = 1e400")
    )
    out = tmp_path / "out"
    run = ["run", str(seq), "--out", str(out), "--checkpoint", str(tiny_checkpoint), *QUIET]
    argv = {
        "map": ["free-space", str(f)],
        "--camera": [*run, "--camera", str(f)],
        "--config": [*run, "--config", str(f)],
        "generate --config": ["generate", str(out), "--sequences", "1", "--frames", "1", "--config", str(f), "--quiet"],
        "recipe": ["recipe", str(f), "--dry-run"],
    }[flag]
    if flag == "recipe":
        from mvracklay.training.recipe import load_recipe

        with pytest.raises(InputError, match="nested too deep|out of range") as e:
            load_recipe(str(f))
        assert "\n" not in str(e.value)
        return
    rc = main(argv)
    one_line(capsys, rc, argv[0], "bad.json")
    assert not out.exists()


def test_inline_camera_is_checked_as_the_file_is(tmp_path):
    from mvracklay.camera import parse_camera_option as _parse_intrinsics

    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": 100.0, "fy": 100.0, "cx": 3200.0, "cy": 64.0, "width": 128, "height": 128}))
    with pytest.raises(InputError) as from_file:
        _parse_intrinsics(str(cam), 128, 128)
    with pytest.raises(InputError) as inline:
        _parse_intrinsics("100,100,3200,64", 128, 128)
    assert "cx = 3200 is outside the image" in str(from_file.value)
    assert "cx = 3200 is outside the image" in str(inline.value)
    for bad in ("100,100,nan,64", "100,-1,64,64", "100,100,64,1e400"):
        with pytest.raises(InputError):
            _parse_intrinsics(bad, 128, 128)
    intr, lens = _parse_intrinsics("100,100,64,64", 128, 128)
    assert (intr.cx, intr.width, lens) == (64.0, 128, None)


def test_distance_out_of_range_refused_or_warned(seq, tiny_checkpoint, tmp_path, capsys):
    ck = ["--checkpoint", str(tiny_checkpoint), "--quiet"]
    rc = main(["predict", str(seq), "--out", str(tmp_path / "a"), "--distance", "1e9", *ck])
    one_line(capsys, rc, "predict", "--distance", "out of range")
    assert main(["predict", str(seq), "--out", str(tmp_path / "b"), "--distance", "20", *ck]) == 0
    err = capsys.readouterr().err
    assert "outside the range the model was trained for" in err and "20 m" in err
    own = copy_of(seq, tmp_path / "seq")
    meta = json.loads((own / "meta.json").read_text())
    for fr in meta["frames"]:
        fr["distance"] = 1e9
    (own / "meta.json").write_text(json.dumps(meta))
    before = snapshot(own)
    rc = main(["run", str(own), "--out", str(tmp_path / "c"), *ck, "--no-rrd", "--threads", "1"])
    one_line(capsys, rc, "run", "meta.json", "out of range")
    assert snapshot(own) == before and not (tmp_path / "c").exists()


META_FAULTS = {
    "distance NaN": (("frames", 1, "distance"), float("nan"), "frames[1].distance"),
    "distance negative": (("frames", 1, "distance"), -3.0, "frames[1].distance"),
    "visible fraction 5": (("frames", 0, "visible_fraction"), 5, "frames[0].visible_fraction"),
    "clear height negative": (("frames", 0, "slots", 0, "clear_height"), -1, "clear_height"),
    "camera position short": (("frames", 2, "camera_position"), [0.0, 1.0], "camera_position"),
    "image size 0": (("image_size",), [0, 128], "image_size[0]"),
}


@pytest.mark.parametrize("fault", list(META_FAULTS))
@pytest.mark.parametrize("command", ["reconstruct", "run"])
def test_an_impossible_meta_json_is_one_line(fault, command, seq, tiny_checkpoint, tmp_path, capsys):
    keys, value, needle = META_FAULTS[fault]
    own = copy_of(seq, tmp_path / "seq")
    meta = json.loads((own / "meta.json").read_text())
    target = meta
    for k in keys[:-1]:
        target = target[k]
    target[keys[-1]] = value
    (own / "meta.json").write_text(json.dumps(meta))
    before = snapshot(own)
    argv = [command, str(own), "--out", str(tmp_path / "out"), *QUIET]
    if command == "run":
        argv += ["--checkpoint", str(tiny_checkpoint), "--threads", "1"]
    one_line(capsys, main(argv), command, "meta.json", "malformed meta.json", needle)
    assert snapshot(own) == before and not (tmp_path / "out").exists()


# --- frames in odd image modes ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def grey8(seq: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sequence's first 4 frames as 8-bit greyscale PNGs."""
    out = tmp_path_factory.mktemp("grey8")
    for i, p in enumerate(sorted((seq / "rgb").glob("*.png"))[:4]):
        with Image.open(p) as im:
            im.convert("L").save(out / f"f{i}.png")
    return out


def _as(folder: Path, dst: Path, convert) -> Path:
    dst.mkdir()
    for p in sorted(folder.glob("*.png")):
        with Image.open(p) as im:
            convert(np.asarray(im), dst / p.name)
    return dst


def _sixteen(a, path):
    Image.fromarray(a.astype(np.uint16) * 257).save(path)


def _palette(a, path):
    im = Image.fromarray(a).convert("L")
    im = im.copy()
    pal = Image.new("P", im.size)
    pal.putpalette([v for i in range(256) for v in (i, i, i)])
    pal.putdata(list(np.asarray(im).ravel()))
    pal.save(path)


def _la(a, path):
    Image.fromarray(np.stack([a, np.full_like(a, 255)], -1)).save(path)


def _frames(folder: Path) -> list[np.ndarray]:
    from mvracklay.frames import open_source

    return list(open_source(folder).frames())


@pytest.mark.parametrize("convert", [_sixteen, _palette, _la], ids=["16-bit", "palette", "LA opaque"])
def test_odd_modes_read_as_the_8_bit_frames(convert, grey8, tmp_path):
    want = _frames(grey8)
    got = _frames(_as(grey8, tmp_path / "odd", convert))
    assert len(got) == len(want) and all(g.dtype == np.uint8 and g.shape[2] == 3 for g in got)
    assert all(np.array_equal(g, w) for g, w in zip(got, want, strict=True))


def test_16_bit_frames_give_the_8_bit_map(grey8, tiny_checkpoint, tmp_path, capsys):
    sixteen = _as(grey8, tmp_path / "sixteen", _sixteen)
    ck = ["--checkpoint", str(tiny_checkpoint), "--threads", "1", "--distance", "2.5", *QUIET]
    assert main(["run", str(grey8), "--out", str(tmp_path / "a"), *ck]) == 0
    assert main(["run", str(sixteen), "--out", str(tmp_path / "b"), *ck]) == 0
    a, b = (json.loads((tmp_path / x / "warehouse.json").read_text()) for x in "ab")
    assert a["racks"] == b["racks"] and a["steps"] == b["steps"]


@pytest.mark.parametrize("mode, needle", [("RGBA", "transparent pixels"), ("CMYK", "CMYK image")])
def test_modes_not_read_faithfully_are_refused(mode, needle, grey8, tiny_checkpoint, tmp_path, capsys):
    folder = tmp_path / "odd"
    folder.mkdir()
    with Image.open(sorted(grey8.glob("*.png"))[0]) as im:
        a = np.asarray(im)
    for i in range(2):
        if mode == "RGBA":
            Image.fromarray(np.stack([a, a, a, np.where(a > 128, 255, 0).astype(np.uint8)], -1)).save(
                folder / f"f{i}.png"
            )
        else:
            Image.fromarray(a).convert("CMYK").save(folder / f"f{i}.jpg")
    argv = ["run", str(folder), "--out", str(tmp_path / "out"), "--checkpoint", str(tiny_checkpoint), *QUIET]
    one_line(capsys, main(argv), "run", needle)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("mode", ["F", "I", "I;16 beyond", "HSV"])
def test_rgb8_converts_or_refuses_every_mode(mode):
    from layouts.images import rgb8

    a = np.arange(64, dtype=np.uint8).reshape(8, 8)
    im = {
        "F": lambda: Image.fromarray(a.astype(np.float32)),
        "I": lambda: Image.fromarray(a.astype(np.int32) * 1000),  # 32-bit, not from a PNG
        "I;16 beyond": lambda: Image.fromarray(a.astype(np.int32) * 100000),
        "HSV": lambda: Image.fromarray(np.stack([a, a, a], -1)).convert("HSV"),
    }[mode]()
    with pytest.raises(InputError) as e:
        rgb8(im, "frame.png")
    assert str(e.value).startswith("frame.png: ") and "\n" not in str(e.value)
    for ok in ("RGB", "L", "1", "YCbCr"):
        got = rgb8(Image.fromarray(np.stack([a, a, a], -1)).convert(ok), "x")
        assert got.dtype == np.uint8 and got.shape == (8, 8, 3)


# --- a checkpoint of non-finite weights -------------------------------------------------------------------------


def test_nan_weights_are_refused(seq, tiny_checkpoint, tmp_path, capsys):
    import torch

    from network.checkpoint import load_checkpoint, save_checkpoint

    payload, record = load_checkpoint(tiny_checkpoint)
    state = {k: (torch.full_like(v, float("nan")) if v.is_floating_point() else v) for k, v in payload["model"].items()}
    bad = tmp_path / "nan.pt"
    save_checkpoint(bad, {**{k: v for k, v in payload.items() if k != "record_json"}, "model": state}, record)
    out = tmp_path / "out"
    rc = main(["run", str(seq), "--out", str(out), "--checkpoint", str(bad), *QUIET])
    one_line(capsys, rc, "run", "nan.pt", "NaN or infinite")
    assert not out.exists()


# --- stdout closed early; the Python API ------------------------------------------------------------------------


def test_a_closed_pipe_ends_quietly(earlier: Path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "mvracklay", "free-space", str(earlier / "warehouse.json"), "--json"]
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    p.stdout.close()  # the reader is gone before anything is written (as `| head -c 10` once it has its bytes)
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 141 and err == ""


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        ({"distance": "2.5"}, "distance: want a number or None, got str '2.5'"),
        ({"threads": "two"}, "threads: want an integer, got str 'two'"),
        ({"camera_height": [1.0]}, "camera_height"),
        ({"quality": None}, "quality"),
        ({"out": 5}, "out: want a string or a path or None"),
        ({"flip": "yes"}, "flip: want True or False"),
    ],
)
def test_api_wrong_types_are_input_errors(kwargs, needle):
    import mvracklay

    frames = [np.zeros((64, 64, 3), np.uint8)] * 2
    with pytest.raises(mvracklay.InputError) as e:
        mvracklay.reconstruct(frames, **kwargs)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_evaluate_json_never_replaces_an_input(tiny_dataset, tiny_checkpoint, capsys):
    manifest = tiny_dataset / "manifest.json"
    before = manifest.read_bytes()
    for argv in (
        ["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--json-out", str(manifest)],
        ["evaluate-baseline", "--data", str(tiny_dataset), "--json-out", str(manifest)],
    ):
        one_line(capsys, main(argv), argv[0], "--json-out", "lies inside the input --data")
    assert manifest.read_bytes() == before


@pytest.mark.parametrize("option", [["--margin", "inf"], ["--margin", "nan"], ["--box", "1e400x0.3x0.3"]])
def test_free_space_options_must_be_finite(option, map_doc, tmp_path, capsys):
    path = tmp_path / "warehouse.json"
    path.write_text(json.dumps(map_doc))
    argv = ["free-space", str(path), *(["--box", "0.4x0.3x0.3"] if option[0] != "--box" else []), *option]
    one_line(capsys, main(argv), "free-space", option[0])


# --- a write failing while the outputs are staged (a full disk) -------------------------------------------------


def _disk_fills(monkeypatch, after: int) -> list[str]:
    """Writes through `layouts.fileio` into a stage or a sequence being generated fail with ENOSPC once
    ``after`` of them went through (every file the commands write goes through it)."""
    import tempfile as real

    from layouts import fileio

    written: list[str] = []

    class Full:
        def __getattr__(self, name):
            return getattr(real, name)

        @staticmethod
        def mkstemp(*a, dir=None, **k):
            if dir is not None and (".partial-" in str(dir) or ".tmp" in str(dir)):
                written.append(str(dir))
                if len(written) > after:
                    raise OSError(errno.ENOSPC, "No space left on device")
            return real.mkstemp(*a, dir=dir, **k)

    monkeypatch.setattr(fileio, "tempfile", Full())
    return written


@pytest.mark.parametrize("command", ["run", "reconstruct", "export"])
def test_a_full_disk_while_staging_is_one_line_and_keeps_the_earlier_outputs(
    command, seq, earlier, tiny_dataset, tiny_checkpoint, tmp_path, monkeypatch, capsys
):
    prev = tmp_path / "prev"
    argv = {
        "run": ["run", str(seq), "--checkpoint", str(tiny_checkpoint), "--max-frames", "4", *QUIET],
        "reconstruct": ["reconstruct", str(seq), *QUIET],
        "export": ["export", str(tiny_dataset), "--format", "yolo", "--overwrite", "--quiet"],
    }[command] + ["--out", str(prev)]
    if command == "export":
        assert main(["export", str(tiny_dataset), "--format", "yolo", "--out", str(prev), "--quiet"]) == 0
    else:
        copy_of(earlier, prev)
    before = snapshot(prev)
    written = _disk_fills(monkeypatch, after=1)
    rc = main(argv)
    one_line(capsys, rc, command, f"--out {prev}" if command != "export" else str(prev), "cannot write there",
             "(No space left on device); the earlier outputs are kept")  # fmt: skip
    assert len(written) > 1 and snapshot(prev) == before
    no_stage_left(prev, tmp_path)


def test_a_full_disk_while_generating_is_one_line_and_resumes(tmp_path, monkeypatch, capsys):
    out = tmp_path / "data"
    argv = ["generate", str(out), "--sequences", "2", "--frames", "1", "--size", "64", "--layout-size", "16", "--quiet"]
    written = _disk_fills(monkeypatch, after=12)  # the first sequence is written whole, then the disk is full
    said = one_line(capsys, main(argv), "generate", str(out), "cannot write there (No space left on device)")
    assert "the sequences finished so far are kept: run the same command again to resume" in said
    assert len(written) > 12 and (out / "seq_00000" / "meta.json").is_file()
    kept = (out / "seq_00000" / "meta.json").read_bytes()
    monkeypatch.undo()
    assert main(argv) == 0 and (out / "seq_00001" / "meta.json").is_file()
    assert (out / "seq_00000" / "meta.json").read_bytes() == kept and not list(out.glob(".seq_*"))


def test_a_full_disk_under_any_command_is_one_line(tiny_dataset, tmp_path, capsys, monkeypatch):
    """A command that stages nothing (inspect) meeting a full disk: one line naming the file, exit 2."""
    import errno
    import tempfile as real

    from layouts import fileio

    class Full:  # every file the commands write goes through layouts.fileio's temporary file
        def __getattr__(self, name):
            return getattr(real, name)

        def mkstemp(self, *a, **k):
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "sheet.png"))

    monkeypatch.setattr(fileio, "tempfile", Full())
    rc = main(["inspect", str(tiny_dataset), "--out", str(tmp_path / "sheet.png")])
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if line.startswith("mvracklay inspect")]
    assert rc == 2 and len(said) == 1 and "No space left on device" in said[0] and "Traceback" not in err

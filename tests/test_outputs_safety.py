"""Nothing lost: every command's outputs land inside its --out, never into or over an input, staged and swapped in
whole, one writer per --out, and a recording the disk could not hold is one line, never a truncated file.

Each case checks the one-line error (exit status 2) or the right answer, and that the inputs and the earlier
outputs are byte-identical afterwards (`snapshot`)."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from test_faults import one_line, snapshot

from layouts.errors import InputError
from layouts.publish import lock, write_failed
from mvracklay.building_job import MapSettings, map_building, pass_folder
from mvracklay.cli import main
from mvracklay.settings import ComputeSettings, OutputSettings, RunConfig
from stitching import rerun_log

QUIET = ["--quiet"]


def no_stage_left(*folders: Path) -> None:
    for f in folders:
        if f.is_dir():
            assert not [p.name for p in f.iterdir() if ".partial" in p.name or p.name.endswith(".lock")], f


@pytest.fixture
def building(tiny_building: Path, tmp_path: Path) -> Path:
    """A copy of the tiny building (3 MB): a test that failed could write into it."""
    return Path(shutil.copytree(tiny_building, tmp_path / "building"))


def _own_route(building: Path, where: Path, sequence) -> Path:
    """A route file at ``where`` over one face of ``building``, each pass named by ``sequence(path)``."""
    doc = json.loads((building / "route.json").read_text())
    face = (doc["passes"][0]["aisle"], doc["passes"][0]["side"])
    mine = [p for p in doc["passes"] if (p["aisle"], p["side"]) == face]
    route = {
        "faces": [f for f in doc["faces"] if (f["aisle"], f["side"]) == face],
        "passes": [
            {"sequence": sequence(building / p["sequence"]), "aisle": p["aisle"], "side": p["side"],
             "start": p["start"], "first_level": p["levels"][0]}
            for p in mine
        ],
    }  # fmt: skip
    where.mkdir(parents=True, exist_ok=True)
    (where / "route.json").write_text(json.dumps(route))
    return where / "route.json"


# --- map: a pass's outputs inside MAP, never in its input --------------------------------------------------------


def test_pass_folders_never_lead_out_of_the_map():
    assert pass_folder(0, "pass_003") == "pass_003"
    assert pass_folder(2, "/data/walk/seq_7") == "pass_002-seq_7"
    assert pass_folder(1, "../../b/seq_1") == "pass_001-seq_1"
    assert pass_folder(4, "..") == "pass_004-pass"
    assert pass_folder(5, "a b/c:d") == "pass_005-c_d"


@pytest.mark.parametrize("how", ["absolute", "../../"])
def test_a_pass_given_by_an_absolute_or_climbing_path_writes_only_into_map(how, building, tmp_path):
    where = tmp_path / "deep" / "er"
    if how == "absolute":
        route = _own_route(building, where, lambda p: str(p))
    else:
        route = _own_route(building, where, lambda p: os.path.relpath(p, where))
        assert json.loads(route.read_text())["passes"][0]["sequence"].startswith("../../")
    before = snapshot(building)
    out = tmp_path / "m"
    res = map_building(route, out, MapSettings(layouts="gt"), outputs=OutputSettings(rrd=False, quiet=True))
    assert res.map.box_count() > 0
    assert snapshot(building) == before  # nothing written into the passes' folders
    passes = sorted(p.name for p in (out / "passes").iterdir())
    assert passes and all(p.startswith("pass_") for p in passes)
    assert all((out / "passes" / p / "warehouse.json").is_file() for p in passes)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["building", "deep", "m"]  # nothing beside MAP
    again = map_building(
        route, out, MapSettings(layouts="gt"), outputs=OutputSettings(rrd=False, quiet=True)
    )  # the passes reused
    assert again.mapped == 0 and again.map.to_dict() == res.map.to_dict()


def test_a_pass_mapped_by_the_network_keeps_its_ground_truth_layouts(building, tiny_checkpoint, tmp_path):
    """With the network, a pass given by an absolute path once had its layouts/ replaced by predictions."""
    route = _own_route(building, tmp_path / "r", lambda p: str(p))
    first = json.loads(route.read_text())["passes"][:1]
    route.write_text(json.dumps({**json.loads(route.read_text()), "passes": first}))
    seq = Path(first[0]["sequence"])
    assert (seq / "layouts").is_dir()
    before = snapshot(building)
    run = RunConfig(checkpoint=tiny_checkpoint)
    settings = MapSettings(layouts="net", run=run)
    map_building(route, tmp_path / "m", settings, ComputeSettings(threads=1), OutputSettings(rrd=False, quiet=True))
    assert snapshot(building) == before
    (mapped,) = (tmp_path / "m" / "passes").iterdir()
    assert (mapped / "layouts").is_dir() and (mapped / "warehouse.json").is_file()


# --- map and diff: never into or over an input, other files kept unless --overwrite ------------------------------


def test_map_refuses_an_out_that_is_or_lies_in_or_holds_an_input(building, tmp_path, capsys):
    before = snapshot(building)
    argv = ["map", str(building), "--layouts", "gt", "--no-rrd", *QUIET]
    one_line(capsys, main([*argv, "--out", str(building)]), "map", "is the input DATASET")
    one_line(capsys, main([*argv, "--out", str(building / "maps" / "m")]), "map", "lies inside the input DATASET")
    seq = building / "pass_000"
    route = _own_route(building, tmp_path / "r", lambda p: str(p))
    one_line(capsys, main(["map", str(route), "--layouts", "gt", "--out", str(seq), *QUIET]), "map", "input pass")
    one_line(capsys, main(["map", str(route), "--layouts", "gt", "--out", str(tmp_path), *QUIET]), "map", "holds")
    assert snapshot(building) == before


def test_map_keeps_a_users_files_unless_overwrite(tiny_building, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "inventory.csv").write_text("my own inventory\n")
    (out / "notes.txt").write_text("mine\n")
    before = snapshot(out)
    argv = ["map", str(tiny_building), "--out", str(out), "--layouts", "gt", "--no-rrd", *QUIET]
    one_line(capsys, main(argv), "map", f"--out {out}: holds other files (notes.txt)", "--overwrite")
    assert snapshot(out) == before
    assert main([*argv, "--overwrite"]) == 0
    assert (out / "notes.txt").read_text() == "mine\n"  # only the map's files replaced
    assert (out / "inventory.csv").read_text() != "my own inventory\n" and (out / "building.json").is_file()
    no_stage_left(out, tmp_path)


def test_diff_never_writes_into_a_map_it_compares(tiny_building_map, tmp_path, capsys):
    a = Path(shutil.copytree(tiny_building_map, tmp_path / "a"))
    before = snapshot(a)
    one_line(capsys, main(["diff", str(a), str(a), "--out", str(a)]), "diff", "is the input OLD_MAP")
    one_line(capsys, main(["diff", str(a / "building.json"), str(a), "--out", str(a)]), "diff", "holds the input")
    one_line(capsys, main(["diff", str(a), str(a), "--out", str(a / "changes")]), "diff", "lies inside the input")
    assert snapshot(a) == before


def test_diff_keeps_a_users_files_unless_overwrite_and_replaces_its_own(tiny_building_map, tmp_path, capsys):
    out = tmp_path / "d"
    out.mkdir()
    (out / "changes.csv").write_text("my own changes\n")
    (out / "building.json").write_text("{}\n")
    before = snapshot(out)
    argv = ["diff", str(tiny_building_map), str(tiny_building_map), "--out", str(out), "--no-rrd"]
    one_line(capsys, main(argv), "diff", "holds other files (building.json)", "--overwrite")
    assert snapshot(out) == before
    assert main([*argv, "--overwrite"]) == 0
    assert (out / "building.json").read_text() == "{}\n" and (out / "changes.json").is_file()
    fresh = tmp_path / "fresh"
    assert main([*argv[:-3], "--out", str(fresh)]) == 0  # and an earlier diff's folder is simply replaced
    assert main([*argv[:-3], "--out", str(fresh)]) == 0
    files = ["changes.csv", "changes.glb", "changes.json", "changes.rrd", "location_changes.csv"]
    assert sorted(p.name for p in fresh.iterdir()) == files
    capsys.readouterr()
    no_stage_left(out, fresh, tmp_path)


# --- one writer per --out ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["reconstruct", "run", "export", "map", "diff"])
def test_a_second_writer_into_the_same_out_is_refused(
    command, tiny_dataset, tiny_checkpoint, tiny_building, tiny_building_map, tmp_path, capsys
):
    out = tmp_path / "out"
    argv = {
        "reconstruct": ["reconstruct", str(tiny_dataset / "seq_00000"), "--no-rrd", "--quiet"],
        "run": ["run", str(tiny_dataset / "seq_00000"), "--checkpoint", str(tiny_checkpoint), "--max-frames", "2",
                "--threads", "1", "--no-rrd", "--quiet"],
        "export": ["export", str(tiny_dataset), "--format", "yolo", "--quiet"],
        "map": ["map", str(tiny_building), "--layouts", "gt", "--no-rrd", "--quiet"],
        "diff": ["diff", str(tiny_building_map), str(tiny_building_map), "--no-rrd"],
    }[command] + ["--out", str(out)]  # fmt: skip
    with lock(out):  # another command writing there
        one_line(capsys, main(argv), command, str(out), "another command is writing there now")
    assert not out.exists() and not list(tmp_path.iterdir())  # nothing made, the lock file gone
    assert main(argv) == 0  # once it is done, the same command works
    capsys.readouterr()
    no_stage_left(out, tmp_path)


def test_a_lock_on_an_existing_out_is_the_folder_itself(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    with lock(out):
        with pytest.raises(InputError, match="another command is writing there now"):
            with lock(out):
                pass
        assert list(tmp_path.iterdir()) == [out] and list(out.iterdir()) == []
    with lock(out):  # released
        pass


# --- a full disk: verified before the swap, one line, the earlier outputs kept -----------------------------------


@pytest.fixture(scope="module")
def earlier(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An earlier reconstruct's output folder with its recording."""
    out = tmp_path_factory.mktemp("earlier") / "out"
    assert main(["reconstruct", str(tiny_dataset / "seq_00000"), "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["warehouse.glb", "warehouse.json", "warehouse.rrd"]
    return out


def _disk_full_in_the_recording(monkeypatch) -> list[int]:
    """Every write into an .rrd fails with ENOSPC (as a full disk makes it)."""
    tries: list[int] = []

    def full(fd: int, data: bytes) -> None:
        tries.append(len(data))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rerun_log, "_write", full)
    return tries


@pytest.mark.parametrize("command", ["reconstruct", "run"])
def test_a_recording_the_disk_cannot_hold_is_one_line_and_keeps_the_earlier_outputs(
    command, earlier, tiny_dataset, tiny_checkpoint, tmp_path, monkeypatch, capsys
):
    prev = Path(shutil.copytree(earlier, tmp_path / "prev"))
    before = snapshot(prev)
    argv = [command, str(tiny_dataset / "seq_00000"), "--out", str(prev), "--quiet", "--overwrite"]
    if command == "run":
        argv += ["--checkpoint", str(tiny_checkpoint), "--threads", "1"]
    tries = _disk_full_in_the_recording(monkeypatch)
    said = one_line(capsys, main(argv), command, f"--out {prev}: cannot write there (No space left on device: "
                    "warehouse.rrd", "bytes free); the earlier outputs are kept")  # fmt: skip
    assert tries and "Traceback" not in said
    assert snapshot(prev) == before
    no_stage_left(prev, tmp_path)


def test_rerun_giving_up_is_an_os_error_naming_the_file(tmp_path):
    """Rerun's file sink raising (``File-writer thread shut down prematurely``) never reaches the user as a
    traceback: the recording says which file failed."""

    class GaveUp:
        disconnected = False

        def flush(self, timeout_sec: float) -> None:
            assert timeout_sec < float("inf")  # never waits forever on a writer that is gone
            raise RuntimeError("File-writer thread shut down prematurely")

        def disconnect(self) -> None:
            self.disconnected = True

    rec = rerun_log.Recording(GaveUp(), tmp_path / "w.rrd", None, True)
    with pytest.raises(OSError) as e:
        rec.disconnect()
    assert e.value.filename == str(tmp_path / "w.rrd") and "shut down prematurely" in e.value.strerror
    assert write_failed(e.value, tmp_path).args[0].startswith(f"--out {tmp_path}: cannot write there (")


def test_a_recording_cut_short_or_without_its_footer_is_refused(earlier, tmp_path):
    whole = (earlier / "warehouse.rrd").read_bytes()
    rerun_log.verify_rrd(earlier / "warehouse.rrd")
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(OSError, match="not a whole Rerun recording"):
        rerun_log.verify_rrd(cut)


def test_a_recording_written_whole_reads_back(tmp_path):
    import numpy as np

    rr = rerun_log.sdk()
    rec = rerun_log.start("whole", save=tmp_path / "w.rrd", num_slots=1)
    for i in range(5):
        rec.set_time("frame", sequence=i)
        rec.log("img", rr.Image(np.full((16, 16, 3), i, np.uint8)))
    rec.disconnect()
    assert "/img" in rerun_log.read_entities(tmp_path / "w.rrd")
    assert list(tmp_path.iterdir()) == [tmp_path / "w.rrd"]


@pytest.fixture
def small_disk(tmp_path: Path):
    """A 2 MiB tmpfs (root only, where mounting is allowed); unmounted after."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / "small"
    mnt.mkdir()
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)], capture_output=True)
    except OSError:
        pytest.skip("no mount command")
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip()[:80]})")
    yield mnt
    subprocess.run(["umount", str(mnt)], capture_output=True)


@pytest.mark.parametrize("command", ["reconstruct", "run"])
def test_a_nearly_full_disk_keeps_the_earlier_outputs(
    command, small_disk, earlier, tiny_dataset, tiny_checkpoint, capsys
):
    """A real nearly full disk: the run's recording does not fit; one line, the earlier outputs whole."""
    prev = Path(shutil.copytree(earlier, small_disk / "prev"))
    before = snapshot(prev)
    free = shutil.disk_usage(small_disk).free
    # room for the map and half its recording: Rerun's own writer once left a truncated .rrd here, exit status 0
    room = sum((earlier / n).stat().st_size for n in ("warehouse.json", "warehouse.glb", "warehouse.rrd")) // 2
    (small_disk / "filler").write_bytes(b"\0" * max(0, free - room))
    argv = [command, str(tiny_dataset / "seq_00000"), "--out", str(prev), "--quiet"]
    if command == "run":
        argv += ["--checkpoint", str(tiny_checkpoint), "--threads", "1"]
    one_line(capsys, main(argv), command, f"--out {prev}: cannot write there (No space left on device",
             "the earlier outputs are kept")  # fmt: skip
    assert snapshot(prev) == before
    no_stage_left(prev, small_disk)

"""Every command that writes a folder follows the same rules (`layouts.publish`): an input is never its OUT, a write
that fails leaves an earlier OUT byte-identical, and a second writer of the same OUT is refused. Each case checks the
one-line error (exit status 2) and the bytes of the inputs and of the earlier OUT afterwards (`snapshot`)."""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import pytest
from test_faults import one_line, snapshot

from layouts import fileio
from layouts.publish import lock, output_folder
from mvracklay.cli import main

COMMANDS = ["run", "reconstruct", "predict", "export", "map", "diff", "generate", "merge-shards"]
#: a small dataset of `generate` (seconds)
SMALL = ["--sequences", "2", "--frames", "2", "--size", "32", "--layout-size", "16", "--quiet"]


class Case:
    """One command: its argv with OUT where it goes (``argv(out)``), its input (the folder or file an OUT must never
    be), the options that make a second run rewrite an earlier OUT (``again``) and how many files that run writes
    before the disk is full (``room``)."""

    def __init__(self, command: str, tmp: Path, tiny_dataset: Path, tiny_building: Path, tiny_building_map: Path,
                 tiny_checkpoint: Path) -> None:  # fmt: skip
        self.command = command
        seq = lambda: Path(shutil.copytree(tiny_dataset / "seq_00000", tmp / "in" / "seq"))  # noqa: E731
        net = ["--checkpoint", str(tiny_checkpoint), "--threads", "1"]
        self.again, self.room = ["--overwrite"], 0
        if command == "run":
            self.input = seq()
            self.head, self.tail = ["run", str(self.input), *net, "--max-frames", "2", "--no-rrd", "--quiet"], []
        elif command == "reconstruct":
            self.input = seq()
            self.head, self.tail = ["reconstruct", str(self.input), "--no-rrd", "--quiet"], []
        elif command == "predict":
            self.input = seq()
            self.head, self.tail = ["predict", str(self.input), *net, "--quiet"], []
            self.again, self.room = ["--layout-size", "32"], 1  # other layouts: the disk full after the first file
        elif command == "export":
            self.input = Path(shutil.copytree(tiny_dataset, tmp / "in" / "data"))
            self.head, self.tail = ["export", str(self.input), "--format", "yolo", "--quiet"], []
        elif command == "map":
            self.input = Path(shutil.copytree(tiny_building, tmp / "in" / "building"))
            self.head, self.tail = ["map", str(self.input), "--layouts", "gt", "--no-rrd", "--quiet"], []
        elif command == "diff":
            self.input = Path(shutil.copytree(tiny_building_map, tmp / "in" / "map"))
            self.head, self.tail = ["diff", str(self.input), str(self.input), "--no-rrd"], []
        elif command == "generate":
            self.input = tmp / "in" / "config.json"
            self.input.parent.mkdir(parents=True)
            self.input.write_text("{}\n")
            self.head, self.tail = ["generate"], ["--config", str(self.input), *SMALL]
            self.again = ["--overwrite", "--seed", "6"]  # another dataset: replaces the earlier one whole
        else:
            shards = [tmp / "in" / f"shard{i}" for i in (0, 1)]
            for i, d in enumerate(shards):
                assert main(["generate", str(d), *SMALL, "--shard", f"{i}/2"]) == 0
            self.input = shards[0]
            self.head, self.tail, self.again = ["merge-shards"], [*map(str, shards), "--link", "--quiet"], []

    def argv(self, out: Path, *extra: str) -> list[str]:
        if self.command in ("generate", "merge-shards"):  # OUT is their first argument
            return [*self.head, str(out), *self.tail, *extra]
        return [*self.head, *self.tail, "--out", str(out), *extra]


@pytest.fixture(params=COMMANDS)
def case(request, tmp_path, tiny_dataset, tiny_building, tiny_building_map, tiny_checkpoint) -> Case:
    return Case(request.param, tmp_path, tiny_dataset, tiny_building, tiny_building_map, tiny_checkpoint)


def test_an_input_is_never_out(case, tmp_path, capsys):
    where = case.input.parent if case.input.is_file() else case.input  # a file input: OUT the folder holding it
    before = snapshot(tmp_path / "in")
    extra = ["--overwrite"] if "--overwrite" in case.again else []  # refused even so
    one_line(capsys, main(case.argv(where, *extra)), case.command, str(where), "the input")
    assert snapshot(tmp_path / "in") == before


def test_a_failed_write_leaves_the_earlier_out_byte_identical(case, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    assert main(case.argv(out)) == 0
    capsys.readouterr()
    before, inputs = snapshot(out), snapshot(tmp_path / "in")

    made, mkstemp = [], fileio.tempfile.mkstemp

    def full(*args, **kwargs):
        made.append(kwargs.get("dir"))
        if len(made) <= case.room:
            return mkstemp(*args, **kwargs)
        raise OSError(errno.ENOSPC, "No space left on device", str(Path(kwargs.get("dir", tmp_path)) / "x"))

    monkeypatch.setattr(fileio.tempfile, "mkstemp", full)  # every file the command writes: a full disk
    one_line(capsys, main(case.argv(out, *case.again)), case.command, "No space left on device")
    monkeypatch.undo()
    assert snapshot(out) == before and snapshot(tmp_path / "in") == inputs
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no stage or lock file left


def test_a_second_writer_of_the_same_out_is_refused(case, tmp_path, capsys):
    out = tmp_path / "out"
    with lock(out):  # another command writing there
        one_line(capsys, main(case.argv(out)), case.command, str(out), "another command is writing there now")
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["in"]


# --- the rules themselves -----------------------------------------------------------------------------------------


def _never(folder: Path) -> bool:
    return False


def test_output_folder_takes_an_earlier_output_and_refuses_other_files(tmp_path):
    out = tmp_path / "out"
    with output_folder(out, ("a.json",), command="cmd", earlier=lambda d: (d / "a.json").is_file()) as st:
        (st / "a.json").write_text(json.dumps(1))
    with output_folder(out, ("a.json",), command="cmd", earlier=lambda d: (d / "a.json").is_file()) as st:
        (st / "a.json").write_text(json.dumps(2))  # an earlier output of the same command: replaced
    assert json.loads((out / "a.json").read_text()) == 2
    (out / "mine.txt").write_text("mine")
    with pytest.raises(Exception, match=r"holds other files \(mine.txt\), not an earlier cmd's output folder"):
        with output_folder(out, ("a.json",), command="cmd", earlier=lambda d: True):
            pass
    with output_folder(out, ("a.json",), command="cmd", earlier=_never, overwrite=True) as st:
        (st / "a.json").write_text(json.dumps(3))
    assert (out / "mine.txt").read_text() == "mine" and json.loads((out / "a.json").read_text()) == 3


def test_output_folder_owning_all_of_out_replaces_it_whole(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(Exception, match="give --overwrite to replace everything there"):
        with output_folder(out, None, command="export", earlier=_never):
            pass
    with output_folder(out, None, command="export", earlier=_never, overwrite=True) as st:
        (st / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]


def test_output_folder_may_hold_an_input_only_when_told(tmp_path):
    out, data = tmp_path / "out", tmp_path / "out" / "layouts"
    data.mkdir(parents=True)
    with pytest.raises(Exception, match="holds the input layouts"):
        with output_folder(out, ("w.json",), command="c", earlier=_never, inputs={"layouts": data}, overwrite=True):
            pass
    with output_folder(out, ("w.json",), command="c", earlier=_never, inputs={"layouts": data}, overwrite=True,
                       may_hold_inputs=True) as st:  # fmt: skip
        (st / "w.json").write_text("{}")
    assert sorted(p.name for p in out.iterdir()) == ["layouts", "w.json"]


def test_output_folder_made_first_keeps_what_was_written_in_place(tmp_path):
    """``make``: OUT is there (and held) while the stage fills, so a command writes part of its work into OUT in place
    (`map`'s passes); a later failure publishes nothing and keeps that part, an empty OUT is removed again."""
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with output_folder(out, ("b.json",), command="c", earlier=_never, untouched=("part",), make=True):
            raise RuntimeError("before anything was written")
    assert not out.exists()
    with pytest.raises(RuntimeError):
        with output_folder(out, ("b.json",), command="c", earlier=_never, untouched=("part",), make=True) as st:
            assert out.is_dir() and st.parent == out
            (out / "part").mkdir()
            (st / "b.json").write_text("{}")
            raise RuntimeError("after the part")
    assert sorted(p.name for p in out.iterdir()) == ["part"]  # alone in OUT: counts as empty
    with output_folder(out, ("b.json",), command="c", earlier=_never, untouched=("part",), make=True) as st:
        (st / "b.json").write_text("{}")
    assert sorted(p.name for p in out.iterdir()) == ["b.json", "part"]

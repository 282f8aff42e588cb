"""What `mvracklay map` says: how many passes it mapped and kept, its speed, and each pass's warnings named by the
pass on a line of their own (never glued to the progress bar, never as `mvracklay run`)."""

from __future__ import annotations

import re
from pathlib import Path

from mvracklay.building_job import mapped_line, pass_warnings
from mvracklay.cli import main


def test_a_fresh_map_keeps_nothing_and_says_its_speed_a_second_keeps_every_pass(tiny_building, tmp_path, capsys):
    out = tmp_path / "m"
    argv = ["map", str(tiny_building), "--out", str(out), "--layouts", "gt", "--no-rrd"]
    assert main(argv) == 0
    said = capsys.readouterr()
    n = len(list((out / "passes").iterdir()))
    assert f"mvracklay map: {n} passes mapped\n" in said.err and "kept" not in said.err
    assert re.search(rf"^speed: \d+\.\d s, \d+\.\d\d s a pass mapped \({n}\) \(wall, this machine\)$", said.out, re.M)
    assert main(argv) == 0
    said = capsys.readouterr()
    assert f"mvracklay map: no pass mapped, all {n} kept from {out / 'passes'}\n" in said.err
    assert re.search(r"^speed: \d+\.\d s, no pass mapped \(wall, this machine\)$", said.out, re.M)
    assert main([*argv, "--quiet"]) == 0
    assert capsys.readouterr().err == ""  # --quiet: nothing but the summary


def test_the_passes_line_says_the_rest_kept_only_when_some_were():
    kept = Path("M/passes")
    assert mapped_line(24, 24, kept) == "24 passes mapped"
    assert mapped_line(3, 24, kept) == "3 of 24 passes mapped, the rest kept from M/passes"
    assert mapped_line(0, 24, kept) == "no pass mapped, all 24 kept from M/passes"


def test_a_pass_warning_loses_the_command_it_was_printed_as():
    said = "mvracklay run: warning: the camera's place is a guess\n\nmvracklay map: warning: camera differs\nplain\n"
    assert pass_warnings(said) == ["warning: the camera's place is a guess", "warning: camera differs", "plain"]


def test_a_passs_warnings_are_named_by_the_pass_on_their_own_line(tiny_building, tiny_checkpoint, tmp_path, capsys):
    out = tmp_path / "m"
    argv = ["map", str(tiny_building), "--out", str(out), "--checkpoint", str(tiny_checkpoint), "--threads", "1",
            "--no-rrd"]  # fmt: skip
    assert main(argv) == 0
    err = capsys.readouterr().err
    passes = {p.name for p in (out / "passes").iterdir()}
    lines = [line.split("\r")[-1] for line in err.split("\n") if "warning:" in line]
    assert lines, err  # the tiny network's passes give warnings (the camera's place a guess)
    for line in lines:  # after the bar's last carriage return: the warning alone, never behind the bar
        m = re.match(r"mvracklay map: (\S+): warning: ", line)
        assert m and m.group(1) in passes, line
    assert "mvracklay run" not in err

"""`mvracklay --help` and `mvracklay free-space` start without torch (nor open3d, rerun, trimesh): the CLI
reads the commands' names and help from their source and imports only the command that runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap

HEAVY = ("torch", "open3d", "rerun", "trimesh")
ROOT = Path(__file__).resolve().parents[1]


def _loaded(*argv: str) -> tuple[int, list[str], str]:
    """Run ``mvracklay ARGV`` in a fresh interpreter: its exit status, the heavy modules loaded, its stdout."""
    code = (
        "import json, sys\n"
        "from mvracklay.cli import main\n"
        "try:\n"
        f"    rc = main({list(argv)!r})\n"
        "except SystemExit as e:\n"
        "    rc = e.code or 0\n"
        f"print(json.dumps([rc, [m for m in {HEAVY!r} if m in sys.modules]]))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    *out, last = r.stdout.strip().splitlines()
    rc, heavy = json.loads(last)
    return rc, heavy, "\n".join(out)


def _map(path: Path) -> Path:
    box = MapBox("rack_00/shelf_00/box_000", (0.25, -0.2, 0.0), (0.5, 0.4, 0.6), 0.0, 0.9, 5)
    shelf = MapShelf("rack_00/shelf_00", 0, 0.0, 0.9, (0.0, 2.0), (-0.5, 0.5), 1.0, [box])
    WarehouseMap([MapRack("rack_00", (0.0, 2.0), [shelf])], [StepRecord(0, 0, 0, 0, 1, "first", 0)], 0.05).save(path)
    return path


def test_help_lists_the_commands_in_groups_without_heavy_imports():
    rc, heavy, out = _loaded("--help")
    assert rc == 0 and heavy == []
    heads = [line for line in out.splitlines() if line.startswith("commands, ")]
    assert heads == ["commands, using it:", "commands, data:", "commands, models:"]
    blocks = out.split("commands, ")[1:]
    names = [
        [line.split()[0] for line in b.splitlines()[1:] if line.startswith("  ") and line[2] != " "] for b in blocks
    ]
    assert names[0] == ["run", "reconstruct", "free-space", "predict", "map", "diff"]
    assert names[1] == ["generate", "inspect", "export", "merge-shards"]
    assert names[2][:4] == ["train", "evaluate", "evaluate-baseline", "eval-reconstruction"]


@pytest.mark.parametrize("argv", [["free-space", "--help"], ["run", "--help"], ["predict", "--help"]])
def test_a_commands_help_imports_no_torch(argv):
    rc, heavy, out = _loaded(*argv)
    assert rc == 0 and heavy == [] and "usage: mvracklay" in out


def test_a_free_space_query_imports_no_torch(tmp_path):
    rc, heavy, out = _loaded("free-space", str(_map(tmp_path / "warehouse.json")), "--box", "0.3x0.3x0.3")
    assert rc == 0 and heavy == []
    assert "rack_00/shelf_00" in out and "fits on rack_00/shelf_00" in out


def test_every_command_module_declares_its_group():
    from mvracklay.cli import GROUPS, _literals, command_infos

    infos = command_infos()
    for info in infos:
        path = ROOT / (info.module.replace(".", "/") + ".py")
        assert _literals(path).get("GROUP") in GROUPS, f"{path}: GROUP missing or unknown"


def test_the_help_constants_equal_the_librarys():
    from mvracklay import options
    from network.inference.fusion import FUSE_TAU
    from network.precision import PRECISIONS

    assert options.FUSE_TAU == FUSE_TAU and options.PRECISIONS == PRECISIONS


def test_interrupted_says_resume_only_for_commands_that_resume(monkeypatch, capsys):
    from mvracklay import cli
    from mvracklay.commands import free_space, generate

    def interrupt(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(generate, "run", interrupt)
    monkeypatch.setattr(free_space, "run", interrupt)
    assert cli.main(["generate", "out"]) == 130
    assert "re-run the same command to resume" in capsys.readouterr().err
    assert cli.main(["free-space", "m.json"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "mvracklay free-space: interrupted" and "resume" not in err

"""benchmarks/bench_building.py describes every option, and its default work folder lies under the system's
temporary folder and is gone afterwards unless ``--keep``."""

from __future__ import annotations

import importlib.util
import shutil
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def bench():
    spec = importlib.util.spec_from_file_location("bench_building", ROOT / "benchmarks" / "bench_building.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_option_is_described(bench):
    options = [a for a in bench.parser()._actions if a.option_strings and "--help" not in a.option_strings]
    assert {o for a in options for o in a.option_strings} >= {"--aisles", "--workers", "--work", "--keep", "--no-ray"}
    assert all(a.help and len(a.help) > 20 for a in options), [a.option_strings for a in options if not a.help]


@pytest.mark.parametrize("keep", [False, True])
def test_the_default_work_folder_is_temporary_unless_kept(bench, keep, monkeypatch, capsys):
    seen = []

    def run(args):  # the benchmark itself, stood in for: what it leaves in the work folder
        (args.work / "building_1").mkdir()
        seen.append(args.work)
        return 0

    monkeypatch.setattr(bench, "run", run)
    assert bench.main(["--no-ray", *(["--keep"] if keep else [])]) == 0
    (work,) = seen
    assert Path(tempfile.gettempdir()).resolve() in work.resolve().parents and ROOT not in work.resolve().parents
    assert work.exists() == keep
    if keep:
        assert f"work folder kept: {work}" in capsys.readouterr().out
        shutil.rmtree(work)


def test_a_given_work_folder_is_kept(bench, tmp_path, monkeypatch):
    monkeypatch.setattr(bench, "run", lambda args: (args.work / "map_1").mkdir() or 0)
    assert bench.main(["--work", str(tmp_path / "w"), "--no-ray"]) == 0
    assert (tmp_path / "w" / "map_1").is_dir()

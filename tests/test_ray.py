"""Work as Ray tasks (`mvracklay.parallel`, ``--ray``): one local Ray of 2 CPUs for the module; a dataset and a
building generated through it hold the same bytes as from local processes, and the building's passes mapped
through it give the same building map; a task's error comes back as itself;
bad addresses and a missing Ray are one line."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from mvracklay.parallel import TaskFailed, check_ray_address, run_tasks, task_map
from waresynth.building_generate import generate_building
from waresynth.generate import generate_dataset

SMALL = dict(image_size=(32, 32), spec=LayoutSpec(size=16), seed=3, progress=False)
BUILDING = {
    "aisles": 1, "bays": [2, 3], "bay_width": [1.6, 2.0], "levels": [2, 3], "pass_length": 4.0,
    "overlap": [1.5, 1.5], "twice_share": 0.5,
}  # fmt: skip
CONFIG = {"camera": {"step": [2.0, 2.0]}}  # two or three frames a pass


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def square(x: int) -> int:
    if x == 13:
        os._exit(1)  # the worker dies
    if x < 0:
        raise InputError(f"item {x}: negative")
    if x == 0:
        raise KeyError("zero")
    return x * x


def test_a_dataset_through_ray_is_byte_identical_to_one_made_here(ray_local, tmp_path):
    local = generate_dataset(tmp_path / "local", num_sequences=3, frames=2, **SMALL)  # in this process
    args = ["--sequences", "3", "--frames", "2", "--size", "32", "--layout-size", "16", "--seed", "3", "--quiet"]
    assert main(["generate", str(tmp_path / "ray"), *args, "--ray", ray_local]) == 0
    assert tree_bytes(tmp_path / "ray") == tree_bytes(local)


def test_a_building_through_ray_is_byte_identical(ray_local, tmp_path):
    kw = dict(building=BUILDING, config=CONFIG, **SMALL)
    local = generate_building(tmp_path / "local", workers=2, **kw)
    stats: list[dict] = []
    ray = generate_building(tmp_path / "ray", tasks=task_map(ray=ray_local), stats=stats, **kw)
    assert tree_bytes(ray) == tree_bytes(local)
    passes = sorted(p.parent.name for p in ray.glob("*/meta.json"))
    assert len(passes) >= 3 and sorted(s["name"] for s in stats) == passes
    # its passes mapped as Ray tasks: the building map local processes give
    from mvracklay.building_job import map_building

    here = map_building(local, tmp_path / "map_here", layouts="gt", progress=False)
    there = map_building(ray, tmp_path / "map_ray", layouts="gt", ray=ray_local, progress=False)
    assert there.mapped == len(passes) and there.map.box_count() > 0
    assert (tmp_path / "map_ray/inventory.csv").read_bytes() == (tmp_path / "map_here/inventory.csv").read_bytes()
    assert [f.map.to_dict() for f in there.map.faces] == [f.map.to_dict() for f in here.map.faces]


def test_results_come_back_with_their_keys_and_errors_as_themselves(ray_local):
    items = [(f"k{i}", i) for i in range(1, 6)]
    assert sorted(run_tasks(square, items, ray=ray_local)) == [(f"k{i}", i * i) for i in range(1, 6)]
    with pytest.raises(InputError) as bad:
        list(run_tasks(square, [("a", 1), ("b", -2)], ray=ray_local))
    assert str(bad.value) == "item -2: negative"  # what the command prints, one line
    with pytest.raises(KeyError) as err:
        list(run_tasks(square, [("z", 0)], ray=ray_local))
    assert any("'z'" in note for note in err.value.__notes__)  # the note names the task
    with pytest.raises(TaskFailed, match=r"^task 'dies' could not finish on the Ray cluster: \S+") as lost:
        list(run_tasks(square, [("dies", 13)], ray=ray_local, retries=0))
    assert "\n" not in str(lost.value)


@pytest.mark.parametrize("workers", [1, 2])
def test_local_processes_give_the_same_results_and_errors(workers):
    items = [(i, i) for i in range(1, 5)]
    assert sorted(run_tasks(square, items, workers=workers, progress="square")) == [(i, i * i) for i in range(1, 5)]
    with pytest.raises(InputError, match="item -1"):
        list(run_tasks(square, [(1, 1), (2, -1)], workers=workers))


@pytest.mark.parametrize("bad", ["", "nowhere", "host:99999", "http://h:1", 7, None])
def test_a_bad_address_is_one_line(bad):
    with pytest.raises(InputError, match="--ray must be auto, local, HOST:PORT"):
        check_ray_address(bad)


@pytest.mark.parametrize("good", ["auto", "local", "10.0.0.5:6379", "head.cluster:6379", "ray://head:10001"])
def test_good_addresses(good):
    assert check_ray_address(good) == good


def test_without_ray_installed_the_command_says_how_to_install_it(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    assert main(["generate", str(tmp_path / "out"), "--sequences", "1", "--frames", "1", "--ray", "auto"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "pip install 'mvracklay[ray]'" in err
    assert not (tmp_path / "out").exists()  # refused before anything is written


def test_a_worker_that_writes_elsewhere_is_one_line(tmp_path):
    def elsewhere(fn, items):  # a cluster whose workers write on their own disks
        for key, (_, entry, *_rest) in items:
            yield key, {"name": key, "frames": entry["frames"]}

    with pytest.raises(InputError, match="every worker sees at the same path"):
        generate_dataset(tmp_path / "d", num_sequences=1, frames=1, tasks=elsewhere, **SMALL)

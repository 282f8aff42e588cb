"""Work as Ray tasks (`mvracklay.parallel`, ``--ray``): one local Ray of 2 CPUs for the module; a dataset and a
building generated through it hold the same bytes as from local processes, and the building's passes mapped
through it give the same building map; a task's error comes back as itself;
bad addresses, a missing Ray and a cluster that does not answer are one line, within the deadline, naming the address
given; the token of a local Ray is readable by its owner only."""

from __future__ import annotations

import os
import socket
import stat
import sys
import threading
import time
from pathlib import Path

import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from mvracklay.parallel import TaskFailed, check_ray_address, connect, private_token, run_tasks, task_map
from waresynth.building.generate import generate_building
from waresynth.generate import DatasetSettings, generate_dataset

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
    local = generate_dataset(tmp_path / "local", DatasetSettings(num_sequences=3, frames=2, **SMALL))  # in this process
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
    from mvracklay.building_job import MapSettings, map_building
    from mvracklay.settings import ComputeSettings, OutputSettings

    here = map_building(local, tmp_path / "map_here", MapSettings(layouts="gt"), outputs=OutputSettings(quiet=True))
    there = map_building(
        ray, tmp_path / "map_ray", MapSettings(layouts="gt"), ComputeSettings(ray=ray_local), OutputSettings(quiet=True)
    )
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
        generate_dataset(tmp_path / "d", DatasetSettings(num_sequences=1, frames=1, **SMALL), tasks=elsewhere)


# --- a cluster that does not answer, and the local token ----------------------------------------------------------
def _closed_port() -> int:
    with socket.socket() as s:  # a loopback port nothing listens on
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def not_connected(monkeypatch):
    """This process as one not yet connected to Ray (the module's local Ray, if started, is left as it is: the
    addresses below are refused before Ray is asked)."""
    ray = pytest.importorskip("ray")
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setenv("MVRACKLAY_RAY_TIMEOUT", "3")


@pytest.mark.parametrize("where", ["closed", "nosuchhost.invalid:6379"])
def test_a_cluster_that_does_not_answer_is_one_line_naming_the_address_given(
    not_connected, tmp_path, capfd, where, tiny_building
):
    address = f"127.0.0.1:{_closed_port()}" if where == "closed" else where
    runs = {
        "generate": ["generate", str(tmp_path / "gen"), "--sequences", "1", "--frames", "1", "--ray", address],
        "map": ["map", str(tiny_building), "--out", str(tmp_path / "map"), "--layouts", "gt", "--ray", address],
    }
    for command, argv in runs.items():
        start = time.monotonic()
        rc = main(argv)
        assert time.monotonic() - start < 30  # the 3 s deadline, never Ray's retries of minutes
        err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]  # Ray's own log included
        assert rc == 2 and len(err) == 1, err
        why = "connection refused" if where == "closed" else "host nosuchhost.invalid not found"
        assert err[0].startswith(f"mvracklay {command}: error: --ray {address}: no Ray cluster answered within 3 s")
        assert why in err[0]
    assert not (tmp_path / "gen").exists() and not (tmp_path / "map").exists()


def test_auto_at_a_cluster_gone_is_one_line(not_connected, tmp_path, monkeypatch):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setenv("RAY_TMPDIR", str(tmp_path))  # where `ray start` leaves the address of its cluster
    (tmp_path / "ray").mkdir()
    (tmp_path / "ray" / "ray_current_cluster").write_text(f"127.0.0.1:{_closed_port()}\n")  # stopped since
    with pytest.raises(InputError, match=r"^--ray auto: no Ray cluster answered within 3 s \(connection refused\)$"):
        connect("auto")


@pytest.mark.parametrize("reply", [b"", b"HTTP/1.1 400 Bad Request\r\n\r\n"], ids=["silent", "not-grpc"])
def test_a_port_that_answers_but_not_as_ray_is_one_line_within_the_deadline(not_connected, reply):
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)
    held = []

    def serve():
        conn, _ = server.accept()
        held.append(conn)
        if reply:
            conn.recv(64)
            conn.sendall(reply)
            conn.close()

    threading.Thread(target=serve, daemon=True).start()
    address = f"127.0.0.1:{server.getsockname()[1]}"
    try:
        with pytest.raises(InputError, match=f"^--ray {address}: no Ray cluster answered within 1 s") as e:
            connect(address, timeout_s=1)
    finally:
        server.close()
        for c in held:
            c.close()
    assert ("timed out" if not reply else "not as a Ray cluster's (gRPC) does") in str(e.value)


def test_a_bad_deadline_is_one_line(not_connected, monkeypatch):
    monkeypatch.setenv("MVRACKLAY_RAY_TIMEOUT", "soon")
    with pytest.raises(
        InputError, match="^MVRACKLAY_RAY_TIMEOUT must be a number of seconds in \\(0, 3600\\], got 'soon'"
    ):
        connect(f"127.0.0.1:{_closed_port()}")


def test_the_token_of_a_local_ray_is_readable_by_its_owner_only(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    for k in ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_AUTH_MODE"):
        monkeypatch.delenv(k, raising=False)
    token = private_token()  # what `connect("local")` makes before Ray would make it, readable by all
    assert token == tmp_path / ".ray" / "auth_token"
    assert stat.S_IMODE(token.stat().st_mode) == 0o600 and stat.S_IMODE(token.parent.stat().st_mode) == 0o700
    text = token.read_text()
    assert len(text) == 64 and int(text, 16) >= 0 and [p.name for p in token.parent.iterdir()] == ["auth_token"]
    assert private_token() == token and token.read_text() == text  # kept
    token.chmod(0o644)  # as an earlier Ray made it
    assert private_token() == token and stat.S_IMODE(token.stat().st_mode) == 0o600 and token.read_text() == text
    monkeypatch.setenv("HOME", str(tmp_path / "other"))
    monkeypatch.setenv("RAY_AUTH_TOKEN", "given")  # a token from elsewhere: nothing written
    assert private_token() is None and not (tmp_path / "other").exists()

"""Sharded generation: disjoint deterministic shards, merged byte-identical to an unsharded run."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from waresynth.dataset import open_dataset
from waresynth.generate import DatasetSettings, generate_dataset, parse_shard
from waresynth.shards import merge_shards

SMALL = dict(num_sequences=3, frames=2, image_size=(48, 32), spec=LayoutSpec(size=16), seed=5, progress=False)
CLI = ["--sequences", "3", "--frames", "2", "--size", "32", "--layout-size", "16", "--seed", "5", "--no-progress"]


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def full(tmp_path_factory) -> Path:
    return generate_dataset(tmp_path_factory.mktemp("full") / "ds", DatasetSettings(**SMALL))


@pytest.fixture()
def shards(tmp_path) -> list[Path]:
    return [generate_dataset(tmp_path / f"s{i}", DatasetSettings(**SMALL, shard=(i, 2))) for i in range(2)]


def test_shards_are_disjoint_round_robin_partial_datasets(shards, full):
    names = [[s.name for s in open_dataset(d).sequences()] for d in shards]
    assert names == [["seq_00000", "seq_00002"], ["seq_00001"]]
    ref = tree_bytes(full)
    for d in shards:  # each shard's sequences are the unsharded run's bytes
        for rel, data in tree_bytes(d).items():
            if rel != "manifest.json":
                assert ref[rel] == data, rel
    assert json.loads((shards[1] / "manifest.json").read_text())["shard"] == {
        "index": 1,
        "count": 2,
        "num_sequences": 3,
    }


def test_merge_moves_equals_unsharded(shards, full, tmp_path):
    out = merge_shards(tmp_path / "merged", shards, progress=False)
    assert tree_bytes(out) == tree_bytes(full)
    assert open_dataset(out).complete()
    assert sorted(p.name for p in shards[0].iterdir()) == ["manifest.json"]


def test_merge_link_keeps_shards_and_resumes(shards, full, tmp_path):
    out = tmp_path / "merged"
    (out / ".seq_00000.tmp").mkdir(parents=True)  # leftover of an interrupted merge
    shutil.copytree(shards[1] / "seq_00001", out / "seq_00001")  # already merged before the interruption
    shutil.rmtree(shards[1] / "seq_00001")
    merge_shards(out, shards, link=True, progress=False)
    assert tree_bytes(out) == tree_bytes(full)
    assert (shards[0] / "seq_00000" / "meta.json").is_file()


def test_cli_shard_and_merge(tmp_path, full, capsys):
    for i in range(2):
        assert main(["generate", str(tmp_path / f"c{i}"), *CLI, "--shard", f"{i}/2"]) == 0
    assert "shard 1/2" in capsys.readouterr().out
    assert main(["merge-shards", str(tmp_path / "m"), str(tmp_path / "c1"), str(tmp_path / "c0"), "--no-progress"]) == 0
    ref = generate_dataset(tmp_path / "ref", DatasetSettings(**{**SMALL, "image_size": (32, 32)}))
    assert tree_bytes(tmp_path / "m") == tree_bytes(ref)


@pytest.mark.parametrize("text", ["2/2", "1", "a/b", "-1/3", "0/0"])
def test_bad_shard_spec(text):
    with pytest.raises(InputError, match="shard"):
        parse_shard(text)


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    return err


def test_merge_refusals(shards, tmp_path, capsys):
    other = generate_dataset(tmp_path / "other", DatasetSettings(**{**SMALL, "seed": 6}, shard=(1, 2)))
    three = generate_dataset(tmp_path / "three", DatasetSettings(**SMALL, shard=(1, 3)))
    cases = [
        ([shards[0], other], "other settings.*seed differ"),
        ([shards[0], three], "other settings.*shard.count"),
        ([shards[0]], "sequences missing from the shards given: seq_00001"),
        ([shards[0], shards[0], shards[1]], "given twice"),
        ([shards[0], tmp_path / "nope"], "shard folder not found"),
    ]
    for dirs, match in cases:
        assert main(["merge-shards", str(tmp_path / "out"), *map(str, dirs), "--no-progress"]) == 2
        assert re.search(match, _err(capsys)), match
        assert not (tmp_path / "out").exists()  # nothing written on refusal
    unsharded = generate_dataset(tmp_path / "plain", DatasetSettings(**SMALL))
    assert main(["merge-shards", str(tmp_path / "out"), str(unsharded), "--no-progress"]) == 2
    assert "not a shard" in _err(capsys)
    # an overlapping shard: sequence seq_00000 claimed by a second shard's manifest
    m = json.loads((shards[1] / "manifest.json").read_text())
    m0 = json.loads((shards[0] / "manifest.json").read_text())
    m["sequences"].append(m0["sequences"][0])
    (shards[1] / "manifest.json").write_text(json.dumps(m))
    assert main(["merge-shards", str(tmp_path / "out"), *map(str, shards), "--no-progress"]) == 2
    assert "overlapping" in _err(capsys)
    # an incomplete sequence in a shard
    (shards[1] / "manifest.json").write_text(json.dumps({**m, "sequences": m["sequences"][:1]}))
    shutil.rmtree(shards[0] / "seq_00002" / "rgb")
    (shards[0] / "seq_00002" / "meta.json").unlink()
    assert main(["merge-shards", str(tmp_path / "out"), *map(str, shards), "--no-progress"]) == 2
    assert "seq_00002: sequence incomplete" in _err(capsys)
    # a non-empty foreign OUT
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("x")
    assert main(["merge-shards", str(tmp_path / "busy"), *map(str, shards), "--no-progress"]) == 2
    assert "not empty" in _err(capsys)


def test_shard_refuses_export(tmp_path, capsys):
    assert main(["generate", str(tmp_path / "x"), *CLI, "--shard", "0/2", "--format", "yolo"]) == 2
    assert "merge-shards" in _err(capsys)
    assert not (tmp_path / "x").exists()

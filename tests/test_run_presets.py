"""`mvracklay run --quality fast|default|offline` and `--config FILE`: what each sets, what wins, what is refused."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from mvracklay import cli
from mvracklay.options import FUSE_TAU
from mvracklay.pipeline import RunConfig
from mvracklay.settings import LIVE_GROUP
from stitching.warehouse_map import WarehouseMap


class Captured(Exception):
    """Raised instead of running the pipeline: carries the settings `run` built."""


@pytest.fixture()
def settings(tiny_dataset: Path, tmp_path: Path, monkeypatch):
    """``settings(*argv)``: the `RunConfig` `mvracklay run SEQ --out OUT ARGV` would run with."""
    import mvracklay.pipeline
    import mvracklay.threads

    def capture(source, out, cfg):
        raise Captured(cfg)

    monkeypatch.setattr(mvracklay.pipeline, "run_pipeline", capture)
    # --threads auto reads how busy the cores are: a quiet machine here, so the settings do not depend on load
    monkeypatch.setattr(mvracklay.threads, "busy_cores", lambda cpus, *a, **k: 0.0)
    ckpt = tmp_path / "c.pt"
    ckpt.write_bytes(b"")  # only its presence is checked before the pipeline

    def run(*argv: str) -> RunConfig:
        base = ["run", str(tiny_dataset / "seq_00000"), "--out", str(tmp_path / "out"), "--checkpoint", str(ckpt)]
        with pytest.raises(Captured) as got:
            cli.main([*base, *argv])
        return got.value.args[0]

    return run


def test_the_default_preset_is_the_run_defaults(settings):
    cfg = settings()
    assert cfg == settings("--quality", "default")
    plain = RunConfig()
    assert cfg.inference == plain.inference
    for name in ("mode", "rgb", "map_every", "opening", "precision"):
        assert getattr(cfg, name) == getattr(plain, name), name
    from mvracklay.threads import AUTO_MAX, usable_cores

    assert cfg.device == "auto" and cfg.threads == min(len(usable_cores()), AUTO_MAX)  # auto: every free core


def test_offline_and_fast_presets(settings):
    off = settings("--quality", "offline")
    assert (
        off.inference.whole_sequence
        and off.inference.flip
        and off.inference.fuse_tau == FUSE_TAU
        and off.inference.read_depth
    )
    fast = settings("--quality", "fast")
    assert not fast.inference.read_depth and not fast.rgb and fast.map_every == 10
    assert not fast.inference.flip and not fast.inference.whole_sequence and fast.inference.fuse_tau == 0
    # the command line still wins over a preset
    assert settings("--quality", "offline", "--no-flip-average", "--fuse-frames", "0").inference.flip is False
    assert settings("--quality", "offline", "--fuse-frames", "0").inference.fuse_tau == 0


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_a_config_file_sets_options_by_their_long_names(settings, tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    if suffix == ".json":
        path.write_text(json.dumps({"quality": "offline", "rack-depth": 1.1, "flip-average": False, "threads": 1}))
    else:
        path.write_text('quality = "offline"\nrack-depth = 1.1\nflip-average = false\nthreads = 1\n')
    cfg = settings("--config", str(path))
    assert (
        cfg.inference.whole_sequence and not cfg.inference.flip and cfg.inference.rack_depth == 1.1 and cfg.threads == 1
    )
    # the command line wins over the file, the file over the preset
    cfg = settings("--config", str(path), "--threads", "2", "--quality", "fast")
    assert (
        cfg.threads == 2
        and not cfg.inference.read_depth
        and not cfg.inference.whole_sequence
        and cfg.inference.rack_depth == 1.1
    )


@pytest.mark.parametrize(
    "content, said",
    [
        ({"flip_average": True}, "unknown option 'flip_average' (did you mean 'flip-average'?)"),
        ({"help": True}, "unknown option 'help'"),
        ({"threads": "two"}, "threads: not a valid value: 'two'"),
        ({"mode": "batch"}, "mode must be one of stream, window"),
        ({"whole-sequence": 1}, "whole-sequence is a switch"),
        ({"quality": "best"}, "quality must be one of fast, default, offline"),
        ([1, 2], "want a table of option names"),
    ],
)
def test_a_bad_config_is_refused_in_one_line(tmp_path, capsys, content, said):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    assert cli.main(["run", str(tmp_path), "--out", str(tmp_path / "out"), "--config", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and said in err, err
    assert not (tmp_path / "out").exists()


def test_run_help_shows_a_dozen_options_and_help_all_the_rest(capsys):
    parser = cli.build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    run = sub.choices["run"]
    live = {a for g in run._action_groups if g.title == LIVE_GROUP for a in g._group_actions}
    shown = [a for a in run._actions if a.option_strings and a.help != argparse.SUPPRESS and a not in live]
    assert len(shown) <= 14  # -h and --help-all besides the dozen
    assert {a.option_strings[0] for a in live} == {"--idle-timeout", "--serve"}  # a live source's own, apart
    with pytest.raises(SystemExit):
        cli.main(["run", "--help-all"])
    text = capsys.readouterr().out
    assert "--whole-sequence" in text and "--board-thickness" in text and "--fuse-frames" in text


def test_offline_from_a_config_file_and_fast_end_to_end(tiny_dataset, tiny_checkpoint, tmp_path):
    seq = str(tiny_dataset / "seq_00000")
    conf = tmp_path / "offline.toml"
    conf.write_text(f'quality = "offline"\ncheckpoint = "{tiny_checkpoint}"\nmax-frames = 4\nno-rrd = true\n')
    assert (
        cli.main(["run", seq, "--out", str(tmp_path / "off"), "--config", str(conf), "--threads", "1", "--quiet"]) == 0
    )
    meta = WarehouseMap.load(tmp_path / "off" / "warehouse.json").meta
    assert meta["flip_average"] and meta["depths_from"] == "the whole sequence" and meta["fuse_frames"] == FUSE_TAU
    assert meta["frames"] == 4 and not (tmp_path / "off" / "warehouse.rrd").exists()
    argv = ["run", seq, "--out", str(tmp_path / "fast"), "--checkpoint", str(tiny_checkpoint), "--quality", "fast"]
    assert cli.main([*argv, "--max-frames", "4", "--threads", "1", "--quiet"]) == 0
    meta = WarehouseMap.load(tmp_path / "fast" / "warehouse.json").meta
    assert not meta["flip_average"] and meta["fuse_frames"] == 0 and meta["box_depth_source"] == "decoder"
    assert (tmp_path / "fast" / "warehouse.rrd").is_file()

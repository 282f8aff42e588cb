"""Depth heads fitted on compressed frames (`mvracklay fit-* --jpeg P --jpeg-quality LOW HIGH`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layouts import InputError
from mvracklay.training.stages import run_stage
from network.data import CompressedSequence, compress_share, jpeg_round_trip
from network.training.kept_box_cache import cache_key, part_name
from waresynth.dataset import open_dataset


def test_a_compressed_sequence_changes_only_its_pixels(tiny_dataset):
    seq = open_dataset(tiny_dataset).sequences()[1]
    comp = CompressedSequence(seq, 30)
    assert np.array_equal(comp.rgb(3), jpeg_round_trip(seq.rgb(3), 30))
    assert not np.array_equal(comp.rgb(3), seq.rgb(3))
    assert comp.root == seq.root and comp.num_frames == seq.num_frames and comp.scene() == seq.scene()
    assert np.array_equal(comp.layouts(3).top, seq.layouts(3).top)


def test_the_share_and_qualities_are_drawn_per_sequence_from_the_seed(tiny_dataset):
    seqs = open_dataset(tiny_dataset).sequences() * 30  # 90 entries: enough draws to see the share
    assert compress_share(seqs, 0.0, (30, 95), 0) == seqs
    every = compress_share(seqs, 1.0, (40, 45), 0)
    assert all(isinstance(s, CompressedSequence) and 40 <= s.jpeg_quality <= 45 for s in every)
    half = compress_share(seqs, 0.5, (30, 95), 0)
    picked = [getattr(s, "jpeg_quality", None) for s in half]
    assert 25 <= sum(q is not None for q in picked) <= 65
    assert picked == [getattr(s, "jpeg_quality", None) for s in compress_share(seqs, 0.5, (30, 95), 0)]
    assert picked[:10] == [getattr(s, "jpeg_quality", None) for s in compress_share(seqs[:10], 0.5, (30, 95), 0)]
    assert picked != [getattr(s, "jpeg_quality", None) for s in compress_share(seqs, 0.5, (30, 95), 1)]
    for bad in ((90, 30), (30,), 40):
        with pytest.raises(InputError, match="jpeg_quality"):
            compress_share(seqs, 0.5, bad, 0)


def test_a_cache_key_names_the_quality_of_compressed_sequences_only(tiny_dataset):
    seqs = open_dataset(tiny_dataset).sequences()
    model = {"trunk_sha256": "x"}
    plain = cache_key(model, seqs)["sequences"]
    assert plain == [[str(s.root.resolve()), s.num_frames] for s in seqs]  # the key of caches made before --jpeg
    comp = cache_key(model, compress_share(seqs, 1.0, (50, 50), 0))["sequences"]
    assert comp == [[*k, 50] for k in plain]


def test_fits_record_the_setting_and_refuse_bad_flags(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    base = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--epochs", "1", "--quiet"]
    jpeg = ["--jpeg", "1.0", "--jpeg-quality", "35", "35"]
    assert run_stage("fit-back-edges", [*base, *jpeg, "--out", str(tmp_path / "be.pt")]) == 0
    assert json.loads((tmp_path / "be.json").read_text())["back_edges"]["jpeg_quality"] == [35, 35]
    keep = tmp_path / "cache"
    assert run_stage("fit-box-depth", [*base, *jpeg, "--keep-cache", str(keep), "--out", str(tmp_path / "bd.pt")]) == 0
    rec = json.loads((tmp_path / "bd.json").read_text())["box_depth"]
    assert rec["jpeg"] == 1.0 and rec["jpeg_quality"] == [35, 35]
    # the kept inputs are those of compressed frames: a fit on sharp ones is refused them, not handed them
    key = json.loads((keep / part_name(tiny_dataset) / "cache.json").read_text())["key"]
    assert all(k[-1] == 35 for k in key["sequences"])
    capsys.readouterr()
    assert run_stage("fit-box-depth", [*base, "--keep-cache", str(keep), "--out", str(tmp_path / "x.pt")]) == 2
    assert "another" in capsys.readouterr().err
    for cmd in ("fit-back-edges", "fit-uprights", "fit-box-depth"):
        for bad, flag in (
            (["--jpeg", "nan"], "--jpeg "),
            (["--jpeg", "0.5", "--jpeg-quality", "0", "20"], "--jpeg-quality"),
        ):
            assert run_stage(cmd, [*base, *bad, "--out", str(tmp_path / "bad.pt")]) == 2
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and flag in err, (cmd, err)
    assert not (tmp_path / "bad.pt").exists()

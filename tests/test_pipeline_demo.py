"""The demo job (`make demo`) on a tiny sequence: generate, preview, reconstruct, score, say where outputs are."""

from __future__ import annotations

from pathlib import Path

from mvracklay import demo_job, pipeline

TINY = ["--frames", "6", "--size", "64", "--layout-size", "32", "--seed", "3", "--quiet"]


def test_demo_without_shipped_model_uses_ground_truth(tmp_path: Path, capsys, monkeypatch):
    monkeypatch.setattr(pipeline, "DEFAULT_CHECKPOINT", tmp_path / "absent-model.pt")
    out = tmp_path / "demo"
    assert demo_job.main(["--out", str(out), *TINY]) == 0
    text = capsys.readouterr().out
    assert "no trained model is shipped yet" in text and "GROUND-TRUTH" in text
    for name in ("preview.png", "run/warehouse.glb", "run/warehouse.rrd", "run/warehouse.json"):
        assert (out / name).is_file(), name
        assert str(out / name) in text
    assert "free_len" in text and "recall" in text and f"rerun {out / 'run' / 'warehouse.rrd'}" in text
    # a second run reuses the generated sequence and gives the same map
    glb = (out / "run/warehouse.glb").read_bytes()
    assert demo_job.main(["--out", str(out), *TINY, "--ground-truth"]) == 0
    assert (out / "run/warehouse.glb").read_bytes() == glb


def test_demo_bad_checkpoint_is_one_line(tmp_path: Path, capsys):
    rc = demo_job.main(["--out", str(tmp_path / "d"), *TINY, "--checkpoint", str(tmp_path / "none.pt")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "none.pt" in err[0]
    assert not (tmp_path / "d").exists()

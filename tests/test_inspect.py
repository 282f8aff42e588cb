"""``mvracklay inspect``: summary figures, a preview sheet PNG of the documented size, one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mvracklay.cli import main
from waresynth.dataset import open_dataset
from waresynth.preview import depth_colour, instance_colour, sheet_size, summarise


def test_inspect_writes_sheet_of_expected_size(
    tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds = open_dataset(tiny_dataset)
    seq = ds.sequences()[-1]
    out = tmp_path / "sheets" / "sheet.png"
    argv = ["inspect", str(tiny_dataset), "--sequence", seq.name, "--frame", str(seq.num_frames - 1)]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert f"sequences    {len(ds.sequences())}" in text
    assert "layout spec" in text and "boxes per shelf" in text and str(out) in text
    with Image.open(out) as im:
        assert im.format == "PNG" and im.mode == "RGB"
        assert im.size == sheet_size(ds.image_size, ds.spec.num_slots)
        arr = np.asarray(im)
    assert len(np.unique(arr.reshape(-1, 3), axis=0)) > 20  # images and layouts were drawn, not a blank page
    # Same frame -> same bytes.
    again = tmp_path / "again.png"
    assert main([*argv, "--out", str(again), "--quiet", "--no-sheet"]) == 0 and not again.exists()
    assert main([*argv, "--out", str(again), "--quiet"]) == 0
    assert again.read_bytes() == out.read_bytes()


def test_summary_fractions(tiny_dataset: Path) -> None:
    ds = open_dataset(tiny_dataset)
    s = summarise(ds, max_frames=5, progress=False)
    assert s["frames_measured"] == 5
    assert s["frames"] == sum(q.num_frames for q in ds.sequences())
    assert sum(s["semantic_fractions"].values()) == pytest.approx(1.0)
    for view in ("top", "front"):
        assert sum(s["layout_fractions"][view].values()) == pytest.approx(1.0)
    assert sum(d["sequences"] for d in s["splits"].values()) == len(ds.sequences())


def test_colour_maps() -> None:
    rgb, (lo, hi) = depth_colour(np.array([[0.0, 1.0, 2.0, 3.0]]))
    assert rgb[0, 0].tolist() == [0, 0, 0]  # no hit
    assert lo < hi and rgb[0, 1].sum() > rgb[0, 3].sum()  # near is brighter than far
    inst = instance_colour(np.array([[0, 5, 5, 9]]))
    assert inst[0, 1].tolist() == inst[0, 2].tolist() != inst[0, 3].tolist()


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--sequence", "no_such_seq"], "--sequence"),
        (["--frame", "9999"], "--frame"),
        (["--frame", "-1"], "--frame"),
        (["--max-frames", "0"], "--max-frames"),
    ],
)
def test_inspect_bad_arguments_are_one_line_errors(
    tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], needle: str
) -> None:
    argv = ["inspect", str(tiny_dataset), "--out", str(tmp_path / "s.png"), "--quiet", *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mvracklay inspect: error: ") and "\n" not in err and needle in err


def test_inspect_missing_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(tmp_path / "nowhere"), "--out", str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "not found" in err and "\n" not in err
    (tmp_path / "empty").mkdir()
    assert main(["inspect", str(tmp_path / "empty"), "--out", str(tmp_path / "s.png")]) == 2
    assert "manifest.json" in capsys.readouterr().err


def test_inspect_refuses_non_png_before_work(
    tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["inspect", str(tiny_dataset), "--out", str(tmp_path / "sheet.jpg"), "--quiet"]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and ".png" in cap.err and "\n" not in cap.err.strip()

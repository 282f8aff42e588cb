"""Learning-curve PNG: one line per run, warm-started runs shifted by their source's minutes."""

from __future__ import annotations

import json

import pytest
from PIL import Image

from layouts import InputError
from network.training.curves import plot_curves, start_offset


def _entry(minutes: float, iou: float) -> dict:
    cell = {"miou": iou}
    return {"train_cpu_minutes": minutes, "val_visible": {v: {"rack": cell, "box": cell} for v in ("top", "front")}}


def _run(path, entries, init=None):
    path.mkdir()
    (path / "metrics.jsonl").write_text("".join(json.dumps(e) + "\n" for e in entries))
    if init is not None:
        (path / "last.json").write_text(json.dumps({"init_from": init}))
    return path


def test_curves_png_and_warm_start_offset(tmp_path):
    a = _run(tmp_path / "a", [_entry(1, 0.2), _entry(2, 0.5)])
    b = _run(tmp_path / "b", [_entry(1, 0.6), _entry(2, 0.7)], init={"train_cpu_minutes": 2.0, "variant": "racklay"})
    assert start_offset(a) == 0.0 and start_offset(b) == 2.0
    out = tmp_path / "c.png"
    plot_curves({"a": a, "b": b}, out)
    img = Image.open(out).convert("RGB")
    assert img.size == (840, 560)
    # Run b (second colour) is drawn out to x = 4 minutes, the right edge; run a stops half way.
    red = (214, 39, 40)
    xs = [x for x in range(img.width // 2) for y in range(img.height // 2) if img.getpixel((x, y)) == red]
    assert xs and max(xs) > 400 - 5
    blue = (31, 119, 180)
    xs_a = [x for x in range(img.width // 2) for y in range(img.height // 2) if img.getpixel((x, y)) == blue]
    assert xs_a and max(xs_a) < 260
    with pytest.raises(InputError, match="metrics file not found"):
        plot_curves({"x": tmp_path / "missing"}, tmp_path / "d.png")


def test_x_axis_rounds_up_to_round_ticks():
    from network.training.curves import _round_up

    assert _round_up(196.0) == 200.0
    assert _round_up(4.0) == 4.0
    assert _round_up(41.0) == 50.0
    assert _round_up(0.3) == 0.4


def test_from_minutes_drops_earlier_points_and_starts_the_axis_there(tmp_path):
    a = _run(tmp_path / "a", [_entry(1, 0.2), _entry(2, 0.5), _entry(3, 0.52), _entry(4, 0.55)])
    full, late = tmp_path / "full.png", tmp_path / "late.png"
    plot_curves({"a": a}, full)
    plot_curves({"a": a}, late, x_from=2.0)
    blue = (31, 119, 180)

    def blue_xs(path):
        img = Image.open(path).convert("RGB")
        return [x for x in range(img.width // 2) for y in range(img.height // 2) if img.getpixel((x, y)) == blue]

    # Full axis 0..4: the line starts a quarter of the way in. From 2: the line starts at the left edge.
    assert min(blue_xs(full)) > 50 + 80
    assert min(blue_xs(late)) < 50 + 5
    with pytest.raises(InputError, match="x_from"):
        plot_curves({"a": a}, late, x_from=-1.0)


def test_legend_wraps_so_every_label_is_drawn(tmp_path):
    runs = {f"run{i}": _run(tmp_path / f"r{i}", [_entry(1, 0.5), _entry(2, 0.6)]) for i in range(6)}
    out = tmp_path / "c.png"
    plot_curves(runs, out)
    img = Image.open(out).convert("RGB")
    assert img.height == 560 + 20  # a second legend row
    # The fifth and sixth colours' swatches lie inside the image.
    for colour in [(255, 127, 14), (23, 190, 207)]:
        assert any(img.getpixel((x, y)) == colour for x in range(img.width) for y in range(540, img.height))


def test_steps_axis_from_the_command_line(tmp_path, capsys):
    from mvracklay.training.stages import run_stage

    def main(argv):  # the recipe stage `curves` (the command line of the curves)
        return run_stage("curves", argv)

    a = _run(tmp_path / "a", [{**_entry(1, 0.2), "step": 100}, {**_entry(2, 0.5), "step": 1000}])
    b = _run(tmp_path / "b", [{**_entry(10, 0.6), "step": 500}], init={"step": 500, "train_cpu_minutes": 5.0})
    out = tmp_path / "s.png"
    assert main([str(out), f"a={a}", f"b={b}", "--x", "steps"]) == 0
    img = Image.open(out).convert("RGB")
    # x axis 0..1000 steps: b's only point sits at 500 + 500 warm-start steps, the right edge; a's first at 100.
    red, blue = (214, 39, 40), (31, 119, 180)
    panel = [(x, y) for x in range(img.width // 2) for y in range(img.height // 2)]
    assert max(x for x, y in panel if img.getpixel((x, y)) == red) > 400 - 5
    assert min(x for x, y in panel if img.getpixel((x, y)) == blue) < 50 + 0.1 * 355 + 5
    # A run without step numbers is refused with one line, as is a run argument without a label.
    c = _run(tmp_path / "c", [_entry(1, 0.2)])
    assert main([str(tmp_path / "t.png"), f"c={c}", "--x", "steps"]) == 2
    assert "no number under 'step'" in capsys.readouterr().err
    assert main([str(out), "nolabel"]) == 2
    assert "not LABEL=RUN_DIR: 'nolabel'" in capsys.readouterr().err

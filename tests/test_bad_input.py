"""Bad input through the CLI entry points (and the public loaders): one line on stderr naming the
file and the problem, a non-zero exit code, nothing half-written, and no pickle ever unpickled."""

from __future__ import annotations

import json
import pickle
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from tiny_net import TINY_NET

from layouts.codecs import load_frame, load_racklay
from layouts.errors import InputError
from layouts.fileio import load_npy, npz_bytes
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from network.checkpoint import load_checkpoint
from waresynth.generate import DatasetSettings, generate_dataset

#: a valid checkpoint, trained for the table by the `checkpoint` fixture (never the shipped weights)
_VALID: dict[str, Path] = {}
SEQ = "seq_00000"


class Payload:
    """Unpickling this creates the file ``marker``: proof that a pickle ran."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture(scope="module")
def checkpoint(base: Path, tmp_path_factory) -> Path:
    """A valid checkpoint for the table, trained for two steps on ``base`` (a few seconds)."""
    out = tmp_path_factory.mktemp("bad_net") / "run"
    tiny = [*TINY_NET, "--frames-per-step", "2"]
    assert (
        main(["train", "--data", str(base), "--out", str(out), "--epochs", "1", "--steps-per-epoch", "2", *tiny]) == 0
    )
    _VALID["ckpt"] = out / "best.pt"
    return out / "best.pt"


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """One sequence x 3 frames, 64x64 images, layouts D=32."""
    out = tmp_path_factory.mktemp("bad") / "ds"
    return generate_dataset(
        out,
        DatasetSettings(
            num_sequences=1, frames=3, image_size=(64, 64), spec=LayoutSpec(size=32), seed=2, progress=False
        ),
    )


# ------------------------------------------------------------------------- corruptions
def truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def pickled_npz(path: Path, marker: Path) -> None:
    """An .npz whose ``top`` array is pickled objects (``path`` ends in .npz, so np.savez keeps it)."""
    np.savez(path, top=np.array([Payload(marker)], object), front=np.zeros((3, 32, 32), np.uint8))


def layout_file(ds: Path, i: int = 1) -> Path:
    return ds / SEQ / "layouts" / f"{i:06d}.npz"


def write_layout(ds: Path, top: np.ndarray, i: int = 1) -> None:
    front = np.zeros((3, 32, 32), np.uint8)
    layout_file(ds, i).write_bytes(npz_bytes(top=top, front=front, visible=np.ones(32, bool)))


def edit_manifest(ds: Path, fn: Callable[[dict], None]) -> None:
    m = json.loads((ds / "manifest.json").read_text())
    fn(m)
    (ds / "manifest.json").write_text(json.dumps(m))


def set_name(name: str) -> Callable[[dict], None]:
    def fn(m: dict) -> None:
        m["sequences"][0]["name"] = name

    return fn


def pickled_checkpoint(path: Path, marker: Path) -> None:
    torch.save({"model": Payload(marker), "record_json": "{}"}, path)


def truncated_checkpoint(path: Path, marker: Path) -> None:
    data = _VALID["ckpt"].read_bytes()
    path.write_bytes(data[: len(data) // 2])


# ------------------------------------------------------------------------- the table
# (id, corrupt(ds, tmp), argv(ds, tmp) with OUT = tmp/"out", file named in the error, problem regex)
def _inspect(ds, t):
    return ["inspect", str(ds), "--out", str(t / "out" / "sheet.png"), "--quiet"]


def _baseline(ds, t):
    return [
        "evaluate-baseline",
        "--data",
        str(ds),
        "--split",
        "all",
        "--json-out",
        str(t / "out" / "r.json"),
        "--quiet",
    ]


def _reconstruct(ds, t):
    return ["reconstruct", str(ds / SEQ), "--out", str(t / "out"), "--quiet"]


def _reconstruct_layouts(ds, t):
    return ["reconstruct", str(ds / SEQ / "layouts"), "--out", str(t / "out"), "--quiet", "--no-rrd"]


def _run(ds, t, ckpt=None):
    argv = ["run", str(ds / SEQ), "--out", str(t / "out"), "--quiet", "--threads", "1", "--no-rrd"]
    return argv + ["--checkpoint", str(ckpt or _VALID["ckpt"])]


def _evaluate(ds, t):
    argv = ["evaluate", "--checkpoint", str(t / "bad.pt"), "--data", str(ds), "--split", "all"]
    return argv + ["--json-out", str(t / "out" / "r.json"), "--quiet"]


def _predict(ds, t):
    return ["predict", str(ds / SEQ), "--checkpoint", str(t / "bad.pt"), "--out", str(t / "out"), "--quiet"]


CASES = [
    # truncated PNG in a sequence
    (
        "png-inspect",
        lambda d, t: truncate(d / SEQ / "rgb" / "000000.png"),
        _inspect,
        "rgb/000000.png",
        "not a readable",
    ),
    (
        "png-baseline",
        lambda d, t: truncate(d / SEQ / "depth" / "000001.png"),
        _baseline,
        "depth/000001.png",
        "not a readable",
    ),
    (
        "png-reconstruct",
        lambda d, t: truncate(d / SEQ / "rgb" / "000001.png"),
        _reconstruct,
        "rgb/000001.png",
        "not a readable",
    ),
    ("png-run", lambda d, t: truncate(d / SEQ / "rgb" / "000001.png"), _run, "rgb/000001.png", "not a readable"),
    # a depth PNG of the wrong kind (RGB, not 16-bit)
    (
        "depth-kind-baseline",
        lambda d, t: shutil.copy(d / SEQ / "rgb" / "000000.png", d / SEQ / "depth" / "000000.png"),
        _baseline,
        "depth/000000.png",
        "expected a uint16 image|single-channel",
    ),
    # layout arrays of the wrong dtype / shape, NaN in a float layout
    (
        "layout-dtype",
        lambda d, t: write_layout(d, np.zeros((3, 32, 32), np.int64)),
        _reconstruct_layouts,
        "000001.npz",
        "dtype must be uint8",
    ),
    (
        "layout-shape",
        lambda d, t: write_layout(d, np.zeros((3, 16, 32), np.uint8)),
        _reconstruct_layouts,
        "000001.npz",
        "shape",
    ),
    (
        "layout-nan",
        lambda d, t: write_layout(d, np.full((3, 32, 32), np.nan, np.float32)),
        _reconstruct_layouts,
        "000001.npz",
        "dtype must be uint8",
    ),
    (
        "layout-dtype-baseline",
        lambda d, t: write_layout(d, np.zeros((3, 32, 32), np.float64)),
        _baseline,
        "000001.npz",
        "dtype must be uint8",
    ),
    # a pickled .npz layout file
    (
        "layout-pickle",
        lambda d, t: pickled_npz(layout_file(d), t / "marker"),
        _reconstruct_layouts,
        "000001.npz",
        "pickled",
    ),
    (
        "layout-pickle-baseline",
        lambda d, t: pickled_npz(layout_file(d), t / "marker"),
        _baseline,
        "000001.npz",
        "pickled",
    ),
    # pickled or truncated checkpoints
    (
        "ckpt-pickle-run",
        lambda d, t: pickled_checkpoint(t / "bad.pt", t / "marker"),
        lambda d, t: _run(d, t, t / "bad.pt"),
        "bad.pt",
        "pickled",
    ),
    (
        "ckpt-trunc-run",
        lambda d, t: truncated_checkpoint(t / "bad.pt", t / "marker"),
        lambda d, t: _run(d, t, t / "bad.pt"),
        "bad.pt",
        "truncated or corrupted checkpoint",
    ),
    (
        "ckpt-pickle-evaluate",
        lambda d, t: pickled_checkpoint(t / "bad.pt", t / "marker"),
        _evaluate,
        "bad.pt",
        "pickled",
    ),
    (
        "ckpt-trunc-evaluate",
        lambda d, t: truncated_checkpoint(t / "bad.pt", t / "marker"),
        _evaluate,
        "bad.pt",
        "truncated or corrupted checkpoint",
    ),
    (
        "ckpt-pickle-predict",
        lambda d, t: pickled_checkpoint(t / "bad.pt", t / "marker"),
        _predict,
        "bad.pt",
        "pickled",
    ),
    (
        "ckpt-trunc-predict",
        lambda d, t: truncated_checkpoint(t / "bad.pt", t / "marker"),
        _predict,
        "bad.pt",
        "truncated or corrupted checkpoint",
    ),
    # a manifest pointing outside its dataset
    (
        "manifest-dotdot-inspect",
        lambda d, t: edit_manifest(d, set_name("../seq_00000")),
        _inspect,
        "manifest.json",
        "not a plain folder name",
    ),
    (
        "manifest-abs-inspect",
        lambda d, t: edit_manifest(d, set_name(str(d / SEQ))),
        _inspect,
        "manifest.json",
        "not a plain folder name",
    ),
    (
        "manifest-dotdot-baseline",
        lambda d, t: edit_manifest(d, set_name("../x")),
        _baseline,
        "manifest.json",
        "not a plain folder name",
    ),
    # empty sequences and folders
    (
        "empty-manifest-inspect",
        lambda d, t: edit_manifest(d, lambda m: m.update(sequences=[])),
        _inspect,
        "ds",
        "no sequences",
    ),
    (
        "empty-manifest-baseline",
        lambda d, t: edit_manifest(d, lambda m: m.update(sequences=[])),
        _baseline,
        "ds",
        "no 'all' sequences",
    ),
    (
        "empty-layouts-reconstruct",
        lambda d, t: [p.unlink() for p in (d / SEQ / "layouts").glob("*.npz")],
        _reconstruct,
        "layouts",
        "no per-frame layout files",
    ),
    (
        "empty-folder-run",
        lambda d, t: shutil.rmtree(d / SEQ) or (d / SEQ).mkdir(),
        _run,
        SEQ,
        "no images|no frames|empty",
    ),
    (
        "empty-folder-reconstruct",
        lambda d, t: shutil.rmtree(d / SEQ) or (d / SEQ).mkdir(),
        _reconstruct,
        SEQ,
        "no layouts/spec.json",
    ),
    # missing frames
    (
        "missing-rgb-inspect",
        lambda d, t: (d / SEQ / "rgb" / "000000.png").unlink(),
        _inspect,
        "rgb/000000.png",
        "not found",
    ),
    (
        "missing-rgb-run",
        lambda d, t: (d / SEQ / "rgb" / "000001.png").unlink(),
        _run,
        "000001.png",
        "missing|not found",
    ),
    ("missing-layout-baseline", lambda d, t: layout_file(d).unlink(), _baseline, "000001.npz", "not found"),
    (
        "missing-layout-reconstruct",
        lambda d, t: layout_file(d).unlink(),
        _reconstruct,
        "000001.npz",
        "missing|not found",
    ),
    # a wrong LayoutSpec
    (
        "spec-size0-reconstruct",
        lambda d, t: (d / SEQ / "layouts" / "spec.json").write_text('{"size": 0}'),
        _reconstruct_layouts,
        "spec.json",
        "size",
    ),
    (
        "spec-unknown-reconstruct",
        lambda d, t: (d / SEQ / "layouts" / "spec.json").write_text('{"size": 32, "colour": 1}'),
        _reconstruct_layouts,
        "spec.json",
        "unknown layout spec keys",
    ),
    (
        "spec-size0-manifest",
        lambda d, t: edit_manifest(d, lambda m: m["spec"].update(size=0)),
        _baseline,
        "manifest.json",
        "size",
    ),
    (
        "spec-unknown-manifest",
        lambda d, t: edit_manifest(d, lambda m: m["spec"].update(depth=3)),
        _inspect,
        "manifest.json",
        "unknown layout spec keys",
    ),
]

XFAIL: dict[str, str] = {}


def _params():
    for case in CASES:
        marks = [pytest.mark.xfail(strict=True, reason=XFAIL[case[0]])] if case[0] in XFAIL else []
        yield pytest.param(*case[1:], id=case[0], marks=marks)


@pytest.mark.parametrize("corrupt, argv, names, problem", list(_params()))
def test_bad_input_one_line(base, checkpoint, tmp_path, capsys, corrupt, argv, names, problem):
    ds = tmp_path / "ds"
    shutil.copytree(base, ds)
    corrupt(ds, tmp_path)
    capsys.readouterr()
    rc = main(argv(ds, tmp_path))
    err = capsys.readouterr().err.strip()
    assert rc != 0
    assert err.count("\n") == 0, err
    assert names in err and re.search(problem, err), err
    written = sorted(str(p) for p in (tmp_path / "out").rglob("*") if not p.is_dir())
    assert written == [], "output half-written"
    assert not (tmp_path / "marker").exists(), "a pickle ran"


# ------------------------------------------------------------------------- public loaders
@pytest.mark.parametrize(
    "make, load, problem",
    [
        (lambda p, m: np.save(p, np.array([Payload(m)], object), allow_pickle=True), load_npy, "pickled"),
        (lambda p, m: np.save(p, np.array([Payload(m)], object), allow_pickle=True), load_racklay, "pickled"),
        (lambda p, m: np.save(p, np.full((3, 8, 8), "x")), load_racklay, "numeric array expected"),
        (lambda p, m: np.save(p, np.full((3, 8, 8), 7, np.uint8)), load_racklay, "values must be"),
        (lambda p, m: np.save(p, np.full((3, 8, 8), np.nan)), load_racklay, "NaN"),
        (lambda p, m: np.save(p, np.zeros((8,), np.uint8)), load_racklay, "shape"),
        (lambda p, m: p.write_bytes(b"\x93NUMPY\x01\x00"), load_npy, "not a readable"),
    ],
    ids=[
        "npy-pickle",
        "racklay-pickle",
        "racklay-dtype",
        "racklay-values",
        "racklay-nan",
        "racklay-shape",
        "npy-truncated",
    ],
)
def test_public_npy_loaders(tmp_path, make, load, problem):
    path = tmp_path / "layout.npy"
    make(path, tmp_path / "marker")
    with pytest.raises(InputError, match=problem) as e:
        load(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "marker").exists()


def test_pickles_never_run(tmp_path):
    """The layout and checkpoint loaders refuse a malicious pickle before anything in it runs."""
    marker = tmp_path / "marker"
    npz = tmp_path / "000000.npz"
    pickled_npz(npz, marker)
    with pytest.raises(InputError, match="pickled"):
        load_frame(npz)
    ckpt = tmp_path / "x.pt"
    pickled_checkpoint(ckpt, marker)
    with pytest.raises(InputError, match="x.pt: holds pickled"):
        load_checkpoint(ckpt)
    with pytest.raises(pickle.UnpicklingError):
        torch.load(ckpt, weights_only=True)
    assert not marker.exists()
    torch.load(ckpt, weights_only=False)  # the payload is real: a plain unpickle does run it
    assert marker.exists()


def test_nan_depth_refused(base):
    """Depth PNGs cannot hold NaN; the depth-projection API refuses a float depth map that does."""
    from mvracklay.baselines.depth_projection import depth_projection_layouts
    from waresynth.dataset import open_dataset

    seq = open_dataset(base).sequences()[0]
    depth = seq.depth(0)
    depth[5, 5] = np.nan
    z_front = float(seq.scene()["row"]["z_front"])
    with pytest.raises(InputError, match="depth contains NaN"):
        depth_projection_layouts(depth, seq.semantic(0), seq.intrinsics, seq.frame(0), z_front, seq.spec)

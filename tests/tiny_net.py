"""A network small enough to train for a few steps in seconds (shared by tests), and the fixed tiny checkpoint.

The tests' tiny checkpoint (`TINY_CHECKPOINT`) is data, not trained per run: weights trained on one CPU differ from
those trained on another (oneDNN and ATen pick other kernels per instruction set), so every layout downstream would.
Remake it after a change of the network or the checkpoint format with ``.venv/bin/python tests/tiny_net.py``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

TINY_NET: list[str] = [
    *("--input-size", "64", "64", "--layout-size", "16"),
    *("--encoder-width", "8", "--hidden", "16", "--decoder-width", "8"),
    *("--threads", "1", "--quiet"),
]

#: `waresynth.generate.generate_dataset` options of the tests' tiny dataset: 3 sequences x 8 frames, 128x128
#: images, layouts D=64 (``spec`` is `LayoutSpec(size=64)`), seed 7
TINY_DATASET = {"num_sequences": 3, "frames": 8, "image_size": (128, 128), "layout_size": 64, "seed": 7}

#: the fixed tiny checkpoint (fp16 weights and their record; the JSON beside it repeats the record)
TINY_CHECKPOINT = Path(__file__).parent / "data" / "tiny_net.pt"

#: how it was trained: 40 steps of `mvracklay train` on the tiny dataset (then `train --export`: fp16 weights only)
TINY_TRAIN: list[str] = [
    *("--epochs", "1", "--steps-per-epoch", "40", "--frames-per-step", "4", "--lr", "3e-3", *TINY_NET)
]


def tiny_dataset(out: Path) -> Path:
    """Generate the tests' tiny dataset (`TINY_DATASET`) into ``out``; returns it."""
    from layouts.spec import LayoutSpec
    from waresynth.generate import DatasetSettings, generate_dataset

    opts = dict(TINY_DATASET)
    spec = LayoutSpec(size=opts.pop("layout_size"))
    return generate_dataset(out, DatasetSettings(spec=spec, progress=False, **opts))


def make_tiny_checkpoint(dst: Path = TINY_CHECKPOINT) -> Path:
    """Train the tiny network on a fresh tiny dataset and export its fp16 weights to ``dst`` (and its JSON)."""
    from mvracklay.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        data = tiny_dataset(Path(tmp) / "tiny")
        run = Path(tmp) / "run"
        if main(["train", "--data", str(data), "--out", str(run), *TINY_TRAIN]) != 0:
            raise SystemExit("training the tiny network failed")
        note = "the tests' tiny network: remade by tests/tiny_net.py (40 steps on the tests' tiny dataset)"
        if main(["train", "--export", str(run / "last.pt"), "--out", str(dst), "--note", note]) != 0:
            raise SystemExit("exporting the tiny network failed")
    return dst


def tiny_config(spec, variant: str = "mvracklay-disc-4", **options):
    """The `ModelConfig` of `TINY_NET` for ``spec`` (64x64 input), with model ``options`` (e.g. ``parallax``)."""
    from network.model.config import ModelConfig

    return ModelConfig(
        variant=variant,
        input_width=64,
        input_height=64,
        spec=spec,
        encoder_width=8,
        hidden=16,
        decoder_width=8,
        **options,
    )


def lift_row_head(path, bias: float = 2.0) -> None:
    """Make a barely trained checkpoint's row head find boards, so its (noisy) slots decode to content.

    An untrained row head starts at a low board probability everywhere (no slots, empty layouts);
    tests of the plumbing after the network want layouts with shelves and boxes in them.
    """
    from network.checkpoint import load_checkpoint, save_checkpoint

    payload, record = load_checkpoint(path)
    state = dict(payload["model"])
    last = max(
        (k for k in state if k.startswith("rows.net.") and k.endswith(".bias")), key=lambda k: int(k.split(".")[2])
    )
    state[last] = state[last].clone().fill_(bias)
    payload["model"] = state
    payload.pop("record_json", None)
    record = {k: v for k, v in record.items() if k not in ("format", "format_version")}
    save_checkpoint(path, payload, record)


def cached_and_naive_windows(model, spec, num_frames: int = 6):
    """A model's windowed predictions over a toy sequence, cached and re-encoded (``recompute=True``).

    Lifts the row head's bias first (as `lift_row_head` does for a checkpoint) so slots decode.
    Returns ``(predictor, frames, cached, naive)``.
    """
    import torch

    from network.inference.predictor import Predictor
    from network.training.toy import ToySequence

    torch.nn.init.constant_(model.rows.net[-1].bias, 2.0)
    seq = ToySequence(spec, num_frames=num_frames, image_size=(64, 64))
    frames = [seq.rgb(i) for i in range(num_frames)]
    pred = Predictor(model, fuse_tau=0)  # each frame's own outputs (network.inference.fusion aside)
    return pred, frames, list(pred.window(frames)), list(pred.window(frames, recompute=True))


def fixed_steps(step: float):
    """A stand-in for `network.model.motion.StepReader` (patched into the predictor): ``step`` metres for every
    frame after the first (0 for the first), confidence 1."""
    import torch

    class FixedSteps:
        def __init__(self, view) -> None:
            self.seen = 0

        def __call__(self, sig):
            self.seen += 1
            return torch.tensor([step if self.seen > 1 else 0.0]), torch.ones(1)

    return FixedSteps


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages
    print(make_tiny_checkpoint(Path(sys.argv[1]) if len(sys.argv) > 1 else TINY_CHECKPOINT))

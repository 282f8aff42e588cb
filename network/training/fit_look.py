"""Hold a trained network's features across looks (stage ``fit-look`` of ``mvracklay train``).

Everything a model computes from a frame goes through its trunk's pyramid maps (`network.model.frozen.
trunk_maps`: encoder, reduce, temporal, pyramid): the row head, the slot decoders, the memory and the
depth heads read nothing else. This fit tunes the trunk alone so that its maps of a frame in another look
(dim, uneven, tinted, noisy, blurred, compressed: a ``restyle`` callable, `waresynth.restyle.Restyler`)
match the untouched model's maps of the same frame in the look it was trained on. Everything after the
trunk stays as trained, the heads included, and the standard look keeps its figures (a share of the
samples shows the student the original frame: there the target is its own old output). Batch norm runs on
its trained statistics (eval mode) throughout.

The loss: the mean squared difference of each map, per channel over the teacher's spread on the validation
batch, plus ``ROW_WEIGHT`` times the row head's divergence from the teacher's (the shelf boards every slot
is anchored on: a board lost there loses the slot, whatever the maps), plus ``layout_weight`` times the
single-frame layouts' divergence (the slot decoders on the teacher's anchors, per pixel over the classes):
what the maps are for, where detail the noise has erased cannot be matched and need not be. Samples are seeded by (seed, step), so a run is reproducible; the state is saved every
``SAVE_EVERY`` steps beside ``out`` and a rerun of the same command resumes from it.
"""

from __future__ import annotations

import copy
import io
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from layouts.camera import Intrinsics
from layouts.canonical import CanonicalView
from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from network.checkpoint import load_checkpoint, model_from, save_updated
from network.model.decoders import anchors_from_rows
from network.model.frozen import PARTS, trunk_maps
from network.preprocess import canonical_image, frame_camera, sequence_angles, to_tensor

#: ``restyle(rgb, rng, intrinsics, step_px, labels) -> rgb``: a frame in another look, the scene unmoved
#: (``labels``: its semantic and instance images, or None)
Restyle = Callable[[np.ndarray, np.random.Generator, Intrinsics, float, Any], np.ndarray]
#: steps between two saves of the fit's state (`fit_look` resumes from the last)
SAVE_EVERY = 50
#: the frames of the validation batch
VAL_FRAMES = 32
#: the weight of the row head's term in the loss
ROW_WEIGHT = 0.5


def trunk_parameters(model: torch.nn.Module) -> list[torch.nn.Parameter]:
    """The trunk's parameters (what `fit_look` tunes)."""
    return [p for name in PARTS["trunk"].modules for p in getattr(model, name).parameters()]


def _frames(sequences: list[Any]) -> list[tuple[Any, int, float]]:
    """(sequence, frame, the camera's step to the next frame in metres) of every frame."""
    out = []
    for seq in sequences:
        x = np.asarray(seq.camera_positions(), np.float64)[:, 0]
        step = float(np.median(np.abs(np.diff(x)))) if len(x) > 1 else 0.0
        out.extend((seq, i, step) for i in range(seq.num_frames))
    if not out:
        raise InputError("fit-look: no frames to fit on (are the data folders' splits empty?)")
    return out


def make_pairs(
    frames: list[tuple[Any, int, float]],
    view: CanonicalView,
    restyle: Restyle,
    rng: np.random.Generator,
    batch: int,
    clean_share: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Canonical images ``(B, 3, H, W)``: the frames as recorded (the teacher's input) and restyled (the
    student's; a ``clean_share`` of them left as recorded), mirrored together at random."""
    teach, learn = [], []
    for k in rng.integers(0, len(frames), batch):
        seq, i, step = frames[int(k)]
        intr, dist = frame_camera(seq, i)
        rgb = seq.rgb(i)
        if rng.random() < clean_share:
            alt = rgb
        else:
            labels = (seq.semantic(i), seq.instance(i)) if hasattr(seq, "semantic") else None
            alt = restyle(rgb, rng, intr, step * intr.fx / dist, labels)
        angles = sequence_angles(seq)
        a, b = canonical_image(rgb, view, intr, dist, *angles), canonical_image(alt, view, intr, dist, *angles)
        if rng.random() < 0.5:
            a, b = a[:, ::-1], b[:, ::-1]
        teach.append(a)
        learn.append(b)
    return to_tensor(np.stack(teach)), to_tensor(np.stack(learn))


def map_loss(student: tuple[torch.Tensor, ...], teacher: tuple[torch.Tensor, ...], scale: list[torch.Tensor]):
    """Mean over the maps of the squared difference per channel in units of the teacher's spread."""
    return sum(((s - t) / sc).pow(2).mean() for s, t, sc in zip(student, teacher, scale)) / len(student)


def _layouts(model: torch.nn.Module, maps: tuple[torch.Tensor, torch.Tensor], anchors: torch.Tensor) -> torch.Tensor:
    """Single-frame layout logits ``(N, R, 2, C, D, D)`` (top, front) of the slot decoders on ``anchors``."""
    out = model.slots(*maps, anchors)
    return torch.stack([out["top"], out["front"]], 2)


class Target:
    """The teacher's outputs for a batch: its pyramid maps, its row head's probabilities and anchors, and its
    single-frame layouts' class probabilities (entropies kept, so that a term is 0 where the student matches)."""

    def __init__(self, teacher: torch.nn.Module, images: torch.Tensor, layouts: bool) -> None:
        with torch.no_grad():
            self.maps = trunk_maps(teacher, images)
            logits = teacher.rows(*self.maps)
            self.rows = torch.sigmoid(logits)
            self.entropy = F.binary_cross_entropy_with_logits(logits, self.rows)
            self.anchors = self.layouts = None
            if layouts:
                cfg = teacher.cfg
                self.anchors = anchors_from_rows(logits, cfg.view, cfg.spec.num_slots)
                self.valid = torch.isfinite(self.anchors)
                lay = _layouts(teacher, self.maps, self.anchors)
                self.layouts = lay.softmax(3)
                self.layout_entropy = _cross_entropy(lay, self.layouts, self.valid)


def _cross_entropy(logits: torch.Tensor, probs: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean over the valid slots' pixels of the cross entropy of ``logits`` against ``probs`` (0 if none)."""
    ce = -(probs * logits.log_softmax(3)).sum(3).mean((-2, -1)).mean(2)  # (N, R)
    return (ce * valid).sum() / valid.sum().clamp(min=1)


def look_loss(
    student: torch.nn.Module, images: torch.Tensor, target: Target, scale: list[torch.Tensor], layout_weight: float
) -> torch.Tensor:
    """`map_loss` of the student's maps of ``images`` plus ``ROW_WEIGHT`` x its row head's divergence plus
    ``layout_weight`` x its layouts' divergence."""
    maps = trunk_maps(student, images)
    rows = F.binary_cross_entropy_with_logits(student.rows(*maps), target.rows) - target.entropy
    loss = map_loss(maps, target.maps, scale) + ROW_WEIGHT * rows
    if layout_weight > 0 and target.layouts is not None:
        lay = _layouts(student, maps, target.anchors)
        loss = loss + layout_weight * (_cross_entropy(lay, target.layouts, target.valid) - target.layout_entropy)
    return loss


def _spread(maps: tuple[torch.Tensor, ...]) -> list[torch.Tensor]:
    return [m.std(dim=(0, 2, 3), keepdim=True).clamp(min=1e-3) for m in maps]


def fit_look(
    checkpoint: Path,
    train: list[Any],
    val: list[Any],
    out: Path,
    restyle: Restyle,
    *,
    steps: int = 1500,
    minutes: float | None = None,
    batch: int = 12,
    lr: float = 1e-4,
    clean_share: float = 0.25,
    layout_weight: float = 0.0,
    seed: int = 0,
    threads: int = 2,
    info: dict[str, Any] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Fit ``checkpoint``'s trunk on ``train`` sequences (default look) restyled by ``restyle``; write the
    model to ``out`` and return the fit's record (also kept in the file's record under ``look_fit``).

    ``minutes`` stops the fit early at that wall time (the learning rate then ends where it is). The
    validation figure is the loss on ``VAL_FRAMES`` restyled frames of ``val`` before and after."""
    if steps < 1 or batch < 2 or not 0.0 <= clean_share < 1.0 or lr <= 0 or layout_weight < 0:
        raise InputError(
            f"fit-look: steps >= 1, batch >= 2, lr > 0, 0 <= clean share < 1, layout weight >= 0; got {steps}, {batch}, {lr}, "
            f"{clean_share}, {layout_weight}"
        )
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    payload, record = load_checkpoint(checkpoint)
    teacher = model_from(payload, record, checkpoint)
    student = copy.deepcopy(teacher).eval()  # eval: batch norm keeps its trained statistics
    for p in student.parameters():
        p.requires_grad_(False)
    params = trunk_parameters(student)
    for p in params:
        p.requires_grad_(True)
    cfg = teacher.cfg
    view = CanonicalView(cfg.input_width, cfg.input_height, cfg.spec.x_extent)
    frames, vframes = _frames(train), _frames(val)
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=0.0)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: float(0.5 * (1 + np.cos(np.pi * min(s, steps) / steps))))
    vt, vs = make_pairs(vframes, view, restyle, np.random.default_rng([seed, 1 << 30]), VAL_FRAMES, 0.0)
    vtarget = Target(teacher, vt, layout_weight > 0)
    scale = _spread(vtarget.maps)
    with torch.no_grad():
        val_before = float(look_loss(student, vs, vtarget, scale, layout_weight))
    state_path = out.with_name(out.name + ".fit-state.pt")
    settings = [str(checkpoint), steps, batch, lr, clean_share, layout_weight, seed, ROW_WEIGHT, len(frames)]
    start, losses = 0, []
    if state_path.is_file():
        st = torch.load(state_path, map_location="cpu", weights_only=True)
        if st.get("settings") == settings:
            student.load_state_dict(st["model"])
            opt.load_state_dict(st["opt"])
            sched.load_state_dict(st["sched"])
            start, losses = int(st["step"]), list(st["losses"])
            print(f"fit-look: resuming at step {start} of {steps} ({state_path})", file=sys.stderr)
    t0 = time.perf_counter()
    step = start
    bar = _bar(steps, start, progress)
    while step < steps:
        if minutes is not None and (time.perf_counter() - t0) / 60 >= minutes:
            break
        rng = np.random.default_rng([seed, step])
        xt, xs = make_pairs(frames, view, restyle, rng, batch, clean_share)
        loss = look_loss(student, xs, Target(teacher, xt, layout_weight > 0), scale, layout_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        step += 1
        losses.append(float(loss.detach()))
        bar.update(1)
        bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
        if step % SAVE_EVERY == 0 and step < steps:
            _save_state(state_path, student, opt, sched, step, losses, settings)
    bar.close()
    with torch.no_grad():
        val_after = float(look_loss(student, vs, vtarget, scale, layout_weight))
    fit = {
        "from": Path(checkpoint).name,
        "steps": step,
        "planned_steps": steps,
        "batch": batch,
        "lr": lr,
        "clean_share": clean_share,
        "seed": seed,
        "train_frames": len(frames),
        "wall_minutes": (time.perf_counter() - t0) / 60,
        "loss_first_last": [float(np.mean(losses[:20])), float(np.mean(losses[-20:]))] if losses else [],
        "val_loss": [val_before, val_after],
        "row_weight": ROW_WEIGHT,
        "layout_weight": layout_weight,
        **(info or {}),
    }
    trunk = tuple(f"{name}." for name in PARTS["trunk"].modules)
    weights = {k: v for k, v in student.state_dict().items() if k.startswith(trunk)}
    save_updated(out, payload, record, weights, look_fit=fit)
    state_path.unlink(missing_ok=True)
    return fit


def _save_state(path: Path, model, opt, sched, step: int, losses: list[float], settings: list[Any]):
    buf = io.BytesIO()
    torch.save(
        {
            "model": model.state_dict(),
            "opt": opt.state_dict(),
            "sched": sched.state_dict(),
            "step": step,
            "losses": losses,
            "settings": settings,
        },
        buf,
    )
    atomic_write_bytes(path, buf.getvalue())


def _bar(total: int, initial: int, show: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="fit-look", unit="step", disable=not show, file=sys.stderr)

"""Fitting the box-depth head (`network.heads.boxdepth`) to a trained model, the rest of the network frozen.

One streamed pass of the frozen model over the training sequences (`Predictor`, as at inference)
gives each frame's head inputs per valid slot; they are cached on disk (memory-mapped: a thousand
scenes are ~4 GB of fp16 windows) with the targets from the generator's ground truth: per model
column the truth's box back behind the rack front (the top-view layout, the scene's rack depth)
and whether the frame shows that stack's depth (``labels``: `waresynth.visibility.SeenTracker`).
The head is then fitted with a two-hot cross entropy over the depth bins (columns whose depth is
shown weighted `FitConfig.shown_weight`) plus a binary cross entropy on the shown logit; a head with
fronts adds a two-hot cross entropy over the front bins (the truth's box front behind the rack front,
every box column).
`kept_cache` keeps the inputs in a folder, one part per dataset folder, each with a record of what it
depends on (`cache_key`), so later fits of other seeds, epochs or head designs on the same trunk, or on
more datasets, skip the streamed passes already made. `cache_part` splits a pass over processes of one
thread each (``workers``): the pass is one frame after another, so two single-thread processes stream
nearly twice the frames of one process on two threads. A pass can also stop at a ``deadline``: inside a
training budget the head then takes as many scenes as the machine streams in the minutes left.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import multiprocessing as mp
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from layouts import BOX, LayoutSpec
from layouts.boxdepth import cell_z
from layouts.errors import InputError
from layouts.fileio import atomic_write_json
from network.heads.boxdepth import (
    BIN_STEP,
    BINS,
    BOX_WIDTH,
    FRONT_BINS,
    FRONT_STEP,
    BoxDepthHead,
    frame_head_inputs,
    split_logits,
)
from network.inference.predictor import sequence_camera
from network.model.config import ModelConfig
from network.model.net import MVRackLay
from network.precision import check_precision, forward_autocast
from network.training.head_inputs import HeadInputPredictor


@dataclass(frozen=True)
class FitConfig:
    """How the head is fitted (defaults: what was measured, docs/network.md)."""

    epochs: int = 3
    batch: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-2
    shown_weight: float = 4.0  #: depth loss weight of the columns whose depth the frame shows
    seed: int = 0
    #: the head's forward passes: fp32, or bf16 autocast (the loss in fp32). With native bf16 (AVX512-BF16) a
    #: batch of 64 slots took 1,030-1,100 -> 520 ms on one thread, the first epoch's loss within 0.1 %
    precision: str = "fp32"

    def validate(self) -> None:
        for name in ("epochs", "batch"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise InputError(f"--{name} must be a positive integer, got {v!r}")
        for name in ("lr", "shown_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"--{name.replace('_', '-')} must be a positive number, got {v!r}")
        v = self.weight_decay
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"--weight-decay must be a number >= 0, got {v!r}")
        check_precision(self.precision)


def box_head_config(
    cfg: ModelConfig, parallax: bool = False, width: int = BOX_WIDTH, front: bool = False
) -> ModelConfig:
    """``cfg`` with a box-depth head of that kind (``parallax``: it reads the plane-sweep maps; ``width``: its
    channels; ``front``: it also reads each box's front): what a fitted head's checkpoint records."""
    return replace(cfg, box_depth=True, box_parallax=parallax, box_width=width, box_front=front)


def with_box_head(model: MVRackLay, parallax: bool = False, width: int = BOX_WIDTH, front: bool = False) -> MVRackLay:
    """``model`` itself if it has a box-depth head of that kind (``parallax``: it reads the plane-sweep maps;
    ``width``: its channels; ``front``: it reads fronts too), else a copy with a fresh one (same weights
    otherwise)."""
    cfg = model.cfg
    if model.box_depth is not None and (cfg.box_parallax, cfg.box_width, cfg.box_front) == (parallax, width, front):
        return model
    out = MVRackLay(box_head_config(cfg, parallax, width, front))
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("box_depth.")}
    missing, unexpected = out.load_state_dict(state, strict=False)
    if unexpected or any(not k.startswith("box_depth.") for k in missing):
        raise InputError(f"model weights do not fit the model with a box-depth head: {unexpected or missing}")
    out.box_logit_offset = dict(model.box_logit_offset)
    out.rack_depth_offset = model.rack_depth_offset
    out.graph_precision = model.graph_precision
    return out.to(next(model.parameters()).device).eval()


def column_targets(
    truth_top: np.ndarray, labels: np.ndarray, spec: LayoutSpec, depth: float, d: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per slot and model column (``d`` of them): the truth's box back and front behind the rack front
    (metres, the means over the layout columns it covers; NaN: no box) and whether the frame shows that
    stack's depth (``labels`` ``(R, D)``: 2 = shown in this frame, `waresynth.visibility.SeenTracker.labels`)."""
    if spec.size % d:
        raise InputError(f"layouts of size {spec.size} do not cover the model's {d} columns evenly")
    g = truth_top == BOX  # (R, D, D), row 0 deepest
    half = spec.z_extent / spec.size / 2
    zc = cell_z(spec, depth)
    has = g.any(1)
    back = np.where(has, zc[np.argmax(g, 1)] + half, np.nan)  # (R, D)
    front = np.where(has, zc[spec.size - 1 - np.argmax(g[:, ::-1], 1)] - half, np.nan)
    k = spec.size // d
    with warnings.catch_warnings():  # columns without a box: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        back, front = (np.nanmean(v.reshape(v.shape[0], d, k), 2) for v in (back, front))
    shown = (np.asarray(labels).reshape(labels.shape[0], d, k) >= 2).any(2)
    return back, shown, front


#: a cache's fields; ``front`` is absent from caches kept before it (read as unknown: NaN)
CACHE_FIELDS = ("win", "extra", "back", "shown", "front")
CACHE_RECORD = "cache.json"  #: in a kept cache part's folder: what it holds (`cache_key`) and how many slots
NO_SLOTS = "no frame of the training sequences has a shelf slot to fit the box-depth head on"  #: one pass or every shard of one found no valid slot


@dataclass
class Cache:
    """Per valid slot: window, extras (fp16), back targets (metres, NaN: no box), shown flags, front targets
    (metres; None: unknown, NaN like ``back``)."""

    win: np.ndarray
    extra: np.ndarray
    back: np.ndarray
    shown: np.ndarray
    front: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.front is None:
            self.front = np.full(np.shape(self.back), np.nan, np.float32)

    def __len__(self) -> int:
        return len(self.win)

    def take(self, idx: np.ndarray) -> Cache:
        """Slots ``idx`` (sorted ascending: a memory map reads forward) as arrays in memory."""
        return Cache(*(np.asarray(getattr(self, k)[idx]) for k in CACHE_FIELDS))

    def field(self, name: str) -> np.ndarray:
        """One field over every slot, in memory (as `Chain.field`)."""
        return np.asarray(getattr(self, name))


class Chain:
    """Several caches read as one, in order (a kept cache has one part per folder of sequences)."""

    def __init__(self, parts: list[Cache]) -> None:
        if not parts:
            raise ValueError("a chain of caches needs at least one part")
        self.parts = parts
        self.ends = np.cumsum([len(c) for c in parts])

    def __len__(self) -> int:
        return int(self.ends[-1])

    def take(self, idx: np.ndarray) -> Cache:
        """Slots ``idx`` (sorted ascending) of the chain, as `Cache.take`."""
        starts = np.concatenate([[0], self.ends[:-1]])
        pieces = [
            c.take(i - s)
            for c, i, s in zip(self.parts, np.split(idx, np.searchsorted(idx, self.ends[:-1])), starts)
            if len(i)
        ]
        if not pieces:
            return self.parts[0].take(idx)
        return Cache(*(np.concatenate([getattr(c, k) for c in pieces]) for k in CACHE_FIELDS))

    def field(self, name: str) -> np.ndarray:
        """One field over every slot, in memory (the small ones: ``back``, ``shown``)."""
        return np.concatenate([np.asarray(getattr(c, name)) for c in self.parts])


@dataclass(frozen=True)
class FrameChoice:
    """Which frames of each training sequence the cache pass streams and keeps: the first ``frames`` (None:
    all), of which the slots of frames ``from_frame`` on are kept (the earlier ones only build the stream's
    memory, the parallax history and what has been seen). Fewer frames per scene buy more scenes for the same
    minutes, and the head is short of scenes rather than of frames (docs/network.md).

    ``cold``: the frames before ``from_frame`` skip the network (`network.training.head_inputs.HeadInputPredictor`'s ``trunk_from``):
    they only enter the motion estimate, the parallax history and what has been seen, and the memory starts
    at ``from_frame``. The network's memory changes few of its cells, and a skipped frame costs a fraction
    of a streamed one, so the same minutes cover more scenes again."""

    frames: int | None = None
    from_frame: int = 0
    cold: bool = False

    def validate(self) -> None:
        if self.frames is not None and (isinstance(self.frames, bool) or self.frames < 1):
            raise InputError(f"--frames must be a positive integer, got {self.frames!r}")
        if isinstance(self.from_frame, bool) or self.from_frame < 0:
            raise InputError(f"--from-frame must be >= 0, got {self.from_frame!r}")
        if self.frames is not None and self.from_frame >= self.frames:
            raise InputError(f"--from-frame {self.from_frame} keeps no frame of the first --frames {self.frames}")
        if self.cold and not self.from_frame:
            raise InputError("--cold-start skips the frames before --from-frame K: give K >= 1")

    def streamed(self, seq: Any) -> int:
        """How many frames of ``seq`` are streamed."""
        return seq.num_frames if self.frames is None else min(self.frames, seq.num_frames)

    def key(self) -> dict[str, Any]:
        """Its part of `cache_key` (nothing for the default: caches made before it keep their keys)."""
        if self == FrameChoice():
            return {}
        return {"frames": self.frames, "from_frame": self.from_frame, **({"cold": True} if self.cold else {})}


def cache_inputs(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    progress: bool = True,
    choice: FrameChoice = FrameChoice(),
) -> Cache:
    """Streams the frames of ``seqs`` ``choice`` names (all by default) through ``model`` (it has the head) and
    memory-maps the head's inputs and targets in ``folder``. ``labels(seq)``: an object with ``add(i)`` and
    ``labels(i)`` (frames in order)."""
    return timed_inputs(model, seqs, labels, folder, progress, choice)[0]


def timed_inputs(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    progress: bool = True,
    choice: FrameChoice = FrameChoice(),
    deadline: float | None = None,
) -> tuple[Cache, int]:
    """`cache_inputs`, no sequence started after ``deadline`` (a `time.monotonic` time; the first is always
    streamed), and how many sequences were streamed."""
    bar = tqdm(total=sum(choice.streamed(s) for s in seqs), desc="box depth: cache", unit="frame", disable=not progress)
    data, streamed = stream_slots(model, seqs, labels, folder, choice, lambda: bar.update(1), deadline)
    bar.close()
    if data is None:
        raise InputError(NO_SLOTS)
    return data, streamed


def stream_slots(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    choice: FrameChoice,
    tick: Callable[[], None],
    deadline: float | None = None,
) -> tuple[Cache | None, int]:
    """`cache_inputs`' pass (``tick()`` after each frame; no sequence but the first started after
    ``deadline``, a `time.monotonic` time): the cache (None when no kept frame has a valid slot) and how many
    sequences it streamed."""
    r, d = model.cfg.spec.num_slots, model.cfg.spec.size
    cap = sum(choice.streamed(s) for s in seqs) * r  # an upper bound on the valid slots
    arrays: dict[str, np.ndarray] = {}
    n = streamed = 0
    for seq in seqs:
        if streamed and deadline is not None and time.monotonic() >= deadline:
            break
        streamed += 1
        camera = sequence_camera(seq)
        seen = labels(seq)
        depth = float(seq.scene()["row"]["depth"])
        pred = HeadInputPredictor(  # each frame's own layouts; no plane sweeps for the frames whose slots are not kept
            model, camera, read_depth=False, box_inputs_from=choice.from_frame, fuse_tau=0,
            trunk_from=choice.from_frame if choice.cold else 0,
        )  # fmt: skip
        for i, out in enumerate(pred.stream(seq.rgb(j) for j in range(choice.streamed(seq)))):
            tick()
            seen.add(i)
            if i < choice.from_frame:
                continue
            win, extra = frame_head_inputs(out, model.cfg.view, camera(i)[1])
            back, shown, front = column_targets(seq.layouts(i).top, seen.labels(i), seq.spec, depth, d)
            v = torch.isfinite(out["anchors"]).cpu().numpy()
            parts = {"win": win[v].half().numpy(), "extra": extra[v].half().numpy(),
                     "back": back[v].astype(np.float32), "shown": shown[v], "front": front[v].astype(np.float32)}  # fmt: skip
            if not arrays:
                arrays = {
                    k: np.lib.format.open_memmap(folder / f"{k}.npy", "w+", a.dtype, (cap, *a.shape[1:]))
                    for k, a in parts.items()
                }
            m = int(v.sum())
            for k, a in parts.items():
                arrays[k][n : n + m] = a
            n += m
    if not n:
        return None, streamed
    for a in arrays.values():
        a.flush()
    return Cache(*(arrays[k][:n] for k in CACHE_FIELDS)), streamed


SHARD_RECORD = "shard.json"  #: in a shard's folder, written last: its slots and sequences, or the error that stopped it


def shard_name(k: int) -> str:
    """The folder of a part's ``k``-th shard (`cache_part`)."""
    return f"shard-{k}"


def split_contiguous(seqs: list[Any], count: int, choice: FrameChoice) -> list[list[Any]]:
    """``seqs`` in at most ``count`` contiguous runs of about equal streamed frames (none empty)."""
    frames = np.cumsum([choice.streamed(s) for s in seqs])
    cuts = np.searchsorted(frames, frames[-1] * np.arange(1, count) / count, side="right")
    bounds = [0, *sorted(set(int(c) for c in cuts if 0 < c < len(seqs))), len(seqs)]
    return [seqs[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def _shard_worker(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    choice: FrameChoice,
    counter: Any,
    deadline: float | None,
) -> None:
    """One process of `cache_part`: one torch thread, its shard's slots, then its record."""
    torch.set_num_threads(1)

    def tick() -> None:
        with counter.get_lock():
            counter.value += 1

    try:
        data, streamed = stream_slots(model, seqs, labels, folder, choice, tick, deadline)
        rec: dict[str, Any] = {"slots": 0 if data is None else len(data), "sequences": streamed}
    except Exception as e:  # noqa: BLE001 - reported by the parent as one line
        rec = {"error": f"{type(e).__name__}: {e}"}
    atomic_write_json(folder / SHARD_RECORD, rec)


def open_shard(folder: Path, n: int) -> Cache | None:
    """The ``n`` slots memory-mapped from a shard (or a single part's) ``folder``; None for an empty shard."""
    if n == 0:
        return None
    fields = [k for k in CACHE_FIELDS if k != "front" or (folder / "front.npy").is_file()]
    try:
        arrays = [np.load(folder / f"{k}.npy", mmap_mode="r", allow_pickle=False)[:n] for k in fields]
    except (OSError, ValueError) as e:
        raise InputError(f"{folder}: unreadable box-depth input cache ({e}); remove the folder to rebuild it") from None
    if any(len(a) != n for a in arrays):
        raise InputError(f"{folder}: box-depth cache files shorter than its record; remove the folder to rebuild it")
    return Cache(*arrays)


def cache_part(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    progress: bool = True,
    choice: FrameChoice = FrameChoice(),
    workers: int = 1,
    deadline: float | None = None,
) -> tuple[list[Cache], list[int] | None, int]:
    """``(caches, shard_slots, streamed)``: `cache_inputs` over ``seqs`` into ``folder``, or, with ``workers``
    > 1, split into that many contiguous shards streamed by forked processes of one torch thread each
    (``folder/shard-K``; their slots in the order of ``seqs``, as one pass would give them; one pass where the
    platform cannot fork or there is one sequence). ``shard_slots``: each shard's slot count (None for one
    pass). ``deadline`` (a `time.monotonic` time): no process starts a sequence after it but its first, so each
    shard holds a leading run of its sequences; ``streamed`` counts the sequences streamed in all."""
    folder.mkdir(parents=True, exist_ok=True)
    runs = split_contiguous(seqs, workers, choice) if workers > 1 else [seqs]
    if len(runs) < 2 or "fork" not in mp.get_all_start_methods():
        data, streamed = timed_inputs(model, seqs, labels, folder, progress, choice, deadline)
        return [data], None, streamed
    ctx = mp.get_context("fork")  # the model and the label factory are inherited, nothing is pickled
    counter = ctx.Value("q", 0)
    dirs = [folder / shard_name(k) for k in range(len(runs))]
    for sub in dirs:
        sub.mkdir(parents=True, exist_ok=True)
        (sub / SHARD_RECORD).unlink(missing_ok=True)
    procs = [
        ctx.Process(target=_shard_worker, args=(model, run, labels, sub, choice, counter, deadline), daemon=True)
        for run, sub in zip(runs, dirs)
    ]
    total = sum(choice.streamed(s) for s in seqs)
    bar = tqdm(total=total, desc=f"box depth: cache ({len(procs)} processes)", unit="frame", disable=not progress)
    try:
        for p in procs:
            p.start()
        while any(p.is_alive() for p in procs):
            time.sleep(0.5)
            bar.update(counter.value - bar.n)
            if any(p.exitcode not in (None, 0) for p in procs):
                break
        bar.update(counter.value - bar.n)
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join()
        bar.close()
    counts, streamed = [], 0
    for p, sub in zip(procs, dirs):
        try:
            rec = json.loads((sub / SHARD_RECORD).read_text())
        except (OSError, ValueError):
            raise InputError(f"box-depth cache: the process for {sub} stopped (exit code {p.exitcode})") from None
        if "error" in rec:
            raise InputError(f"box-depth cache: {sub}: {rec['error']}")
        counts.append(int(rec["slots"]))
        streamed += int(rec["sequences"])
    caches = [c for c in (open_shard(sub, n) for sub, n in zip(dirs, counts)) if c is not None]
    if not caches:
        raise InputError(NO_SLOTS)
    return caches, counts, streamed


def model_key(model: MVRackLay) -> dict[str, Any]:
    """What a cache of head inputs takes from the model: the frozen trunk's weights (a digest), the inputs the
    head reads (parallax maps or not), the box-logit offsets and, when not fp32, the trunk graph's precision
    (`network.inference.frozen.set_precision`; caches made before it keep their keys)."""
    digest = hashlib.sha256()
    for k, v in sorted(model.state_dict().items()):
        if not k.startswith("box_depth."):
            digest.update(k.encode())
            digest.update(v.detach().cpu().contiguous().view(-1).view(torch.uint8).numpy().tobytes())
    return {
        "trunk_sha256": digest.hexdigest(),
        "parallax": bool(model.cfg.box_parallax),
        "box_logit_offset": {k: float(v) for k, v in sorted(model.box_logit_offset.items())},
        **({} if model.graph_precision == "fp32" else {"precision": model.graph_precision}),
    }


def cache_key(
    model: MVRackLay | dict[str, Any], seqs: list[Any], choice: FrameChoice = FrameChoice()
) -> dict[str, Any]:
    """What a cache of head inputs depends on: the model's part (`model_key`, or the model to take it from),
    the training sequences (folders, frame counts and, for one seen through JPEG, its quality), in order, and
    which of their frames (`FrameChoice`)."""
    base = model if isinstance(model, dict) else model_key(model)
    return {**base, "sequences": [sequence_key(s) for s in seqs], **choice.key()}


def sequence_key(seq: Any) -> list[Any]:
    """A sequence's part of `cache_key`: its folder and frame count, and its JPEG quality when compressed
    (`network.data.CompressedSequence`; plain sequences keep the keys of caches made before it)."""
    key: list[Any] = [str(Path(seq.root).resolve()), int(seq.num_frames)]
    quality = getattr(seq, "jpeg_quality", None)
    return key if quality is None else [*key, int(quality)]


def open_kept_cache(folder: Path, key: dict[str, Any]) -> list[Cache] | None:
    """The complete cache in ``folder`` (one piece, or one per shard of a pass split over processes) if it
    was made for ``key``; None if the folder holds none (or an unfinished one); a one-line error if it holds
    another model's or other data's inputs."""
    path = folder / CACHE_RECORD
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text())
        n = int(rec["slots"])
        shards = [int(k) for k in rec.get("shards", [])]
        same = rec["key"] == key
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not a box-depth input cache record ({e})") from None
    if not same:
        raise InputError(
            f"--keep-cache {folder}: holds the inputs of another checkpoint, head inputs, trunk precision, training "
            "sequences or choice of frames; give another --keep-cache folder (or remove this one)"
        )
    if not shards:
        return [open_shard(folder, n)]
    if sum(shards) != n:
        raise InputError(f"{path}: its shards' slots do not add up to its own; remove the folder to rebuild it")
    return [c for c in (open_shard(folder / shard_name(k), m) for k, m in enumerate(shards)) if c is not None]


def part_name(folder: Path) -> str:
    """The name of the kept-cache part that holds the inputs of the sequences in ``folder``: readable (the
    folder's name) and unique (a digest of its resolved path)."""
    path = str(Path(folder).resolve())
    return f"{Path(path).name}-{hashlib.sha256(path.encode()).hexdigest()[:8]}"


def by_folder(seqs: list[Any]) -> list[tuple[Path, list[Any]]]:
    """``seqs`` in runs of the same parent folder (a dataset), in order."""
    runs: list[tuple[Path, list[Any]]] = []
    for s in seqs:
        parent = Path(s.root).resolve().parent
        if runs and runs[-1][0] == parent:
            runs[-1][1].append(s)
        else:
            runs.append((parent, [s]))
    return runs


def move_single_part(folder: Path) -> None:
    """A cache kept in the earlier layout (its files and record in ``folder`` itself, one dataset's sequences)
    is moved into its part's folder, where `kept_cache` looks for it (renames only: nothing is rewritten)."""
    record = folder / CACHE_RECORD
    if not record.is_file():
        return
    try:
        first = json.loads(record.read_text())["key"]["sequences"][0][0]
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        raise InputError(f"{record}: not a box-depth input cache record ({e})") from None
    sub = folder / part_name(Path(first).parent)
    if sub.exists():
        raise InputError(f"--keep-cache {folder}: holds a cache both in {folder} and in {sub}; remove one")
    sub.mkdir()
    for k in CACHE_FIELDS:
        if (folder / f"{k}.npy").is_file():
            (folder / f"{k}.npy").rename(sub / f"{k}.npy")
    record.rename(sub / CACHE_RECORD)  # last: the part counts as finished only with all its files


def kept_cache(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    progress: bool = True,
    choice: FrameChoice = FrameChoice(),
    workers: int = 1,
) -> tuple[Chain, int]:
    """``(chain, reused)``: the inputs of ``seqs`` kept in ``folder``, one part (`part_name`) per folder the
    sequences sit in, so a fit on more data reuses the parts already made. A part with a finished cache for
    this model and its sequences is reused (``reused`` counts them), an absent or unfinished one is made
    (`cache_part` with ``workers``, its record written last: an interrupted pass is redone, never used)."""
    move_single_part(folder)
    parts, reused = [], 0
    base = model_key(model)  # the trunk's digest once, not per part
    for parent, group in by_folder(seqs):
        sub = folder / part_name(parent)
        key = cache_key(base, group, choice)
        kept = open_kept_cache(sub, key)
        if kept is not None:
            parts.extend(kept)
            reused += 1
            continue
        sub.mkdir(parents=True, exist_ok=True)
        made, shards, _ = cache_part(model, group, labels, sub, progress, choice, workers)
        rec: dict[str, Any] = {"key": key, "slots": sum(len(c) for c in made)}
        atomic_write_json(sub / CACHE_RECORD, rec if shards is None else {**rec, "shards": shards})
        parts.extend(made)
    return Chain(parts), reused


def train_head(head: BoxDepthHead, data: Cache | Chain, cfg: FitConfig, progress: bool = True) -> list[float]:
    """Fit ``head`` to the cached targets (AdamW, one-cycle schedule); returns the mean loss per epoch."""
    cfg.validate()
    opt = torch.optim.AdamW(head.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    n = len(data)
    per_epoch = math.ceil(n / cfg.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, cfg.lr, total_steps=cfg.epochs * per_epoch)
    bins = torch.as_tensor(BINS, dtype=torch.float32)
    front_bins = torch.as_tensor(FRONT_BINS, dtype=torch.float32)
    if head.front and not np.isfinite(data.field("front")).any():
        raise InputError("the cached inputs hold no box fronts (a cache kept before them); fit --front on a new cache")
    gen = torch.Generator().manual_seed(cfg.seed)
    head.train()
    losses = []
    for ep in range(cfg.epochs):
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for idx in tqdm(perm.split(cfg.batch), desc=f"box depth: epoch {ep + 1}/{cfg.epochs}", disable=not progress):
            b = np.sort(idx.numpy())  # sorted: the memory map reads forward
            batch = data.take(b)
            with forward_autocast("cpu", cfg.precision):
                logits = head(torch.from_numpy(batch.win).float(), torch.from_numpy(batch.extra).float())
            lz, ls, lf = split_logits(logits.float())
            tb, sb = torch.from_numpy(batch.back), torch.from_numpy(batch.shown)
            m = torch.isfinite(tb)
            loss = F.binary_cross_entropy_with_logits(ls[m], sb[m].float()) if m.any() else ls.sum() * 0
            if m.any():
                wt = torch.where(sb, cfg.shown_weight, 1.0)
                loss = loss + (two_hot_ce(lz, tb, bins, BIN_STEP) * wt)[m].sum() / wt[m].sum()
            if lf is not None:
                tf = torch.from_numpy(np.asarray(batch.front, dtype=np.float32))
                mf = torch.isfinite(tf)
                if mf.any():
                    loss = loss + two_hot_ce(lf, tf, front_bins, FRONT_STEP)[mf].mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach())
        losses.append(total / per_epoch)
    head.eval()
    return losses


def two_hot_ce(logits: torch.Tensor, target: torch.Tensor, bins: torch.Tensor, step: float) -> torch.Tensor:
    """``(N, K, D)`` bin logits against ``(N, D)`` targets (metres; NaN anywhere, masked by the caller): the
    cross entropy with the target's two neighbouring bins weighted by nearness, ``(N, D)``."""
    t = target.nan_to_num(0.0).clamp(float(bins[0]), float(bins[-1]))
    w = (1 - (t[..., None] - bins).abs() / step).clamp(min=0)
    return -(w * torch.log_softmax(logits, 1).permute(0, 2, 1)).sum(-1)


def fit_box_depth(
    model: MVRackLay,
    train: list[Any],
    labels: Callable[[Any], Any],
    cfg: FitConfig,
    cache_dir: Path | None = None,
    progress: bool = True,
    parallax: bool = False,
    keep_cache: Path | None = None,
    choice: FrameChoice = FrameChoice(),
    workers: int = 1,
    pass_minutes: float | None = None,
    width: int = BOX_WIDTH,
    front: bool = False,
) -> tuple[BoxDepthHead, dict[str, Any]]:
    """A fitted head for ``model`` (its trunk unchanged; ``parallax``: the head also reads plane-sweep maps,
    `network.heads.boxdepth.ParallaxHistory`; ``width``, ``front``: `BoxDepthHead`'s) and a summary for the
    checkpoint's record. The cache lives in a temporary folder (under ``cache_dir`` if given) removed at the
    end, or in ``keep_cache``, kept one part per dataset folder and reused by a later fit of the same trunk
    (`kept_cache`): heads of other seeds, epochs or designs, or on more data, skip the passes already made.
    ``choice``: which frames of each sequence are streamed and kept (`FrameChoice`; all by default);
    ``workers``: processes of one thread each that share the streamed pass (`cache_part`); ``pass_minutes``:
    no sequence is started that many minutes after the pass began (each process streams at least one), and
    the head is fitted on those streamed by then (not with ``keep_cache``: what such a pass holds depends on the
    machine, and a kept cache is keyed on its sequences)."""
    cfg.validate()
    check_pass_minutes(pass_minutes, keep_cache)
    t0 = time.perf_counter()
    check_width(width)
    model = _ready(model, train, choice, workers, parallax, width, front)
    streamed = len(train)
    with contextlib.ExitStack() as stack:
        if keep_cache is None:
            tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="box-depth-", dir=cache_dir))
            deadline = None if pass_minutes is None else time.monotonic() + 60 * pass_minutes
            caches, _, streamed = cache_part(model, train, labels, Path(tmp), progress, choice, workers, deadline)
            data, reused = Chain(caches), 0
        else:
            data, reused = kept_cache(model, train, labels, Path(keep_cache), progress, choice, workers)
        t1 = time.perf_counter()
        torch.manual_seed(cfg.seed)
        first = data.parts[0]
        head = BoxDepthHead(first.win.shape[1], first.extra.shape[1], width=width, front=front)
        losses = train_head(head, data, cfg, progress)
        summary = _summary(data, train, choice, parallax, reused, workers, model.graph_precision)
        del data, first  # the memory maps closed before the temporary folder goes
    if pass_minutes is not None:
        summary.update(train_sequences=streamed, sequences_given=len(train), pass_minutes=pass_minutes)
    summary.update(
        width=width, front=front, epochs=cfg.epochs, seed=cfg.seed, lr=cfg.lr, weight_decay=cfg.weight_decay,
        fit_precision=cfg.precision, losses=losses,
        cache_minutes=(t1 - t0) / 60, fit_minutes=(time.perf_counter() - t1) / 60,
    )  # fmt: skip
    return head, summary


def keep_box_inputs(
    model: MVRackLay,
    train: list[Any],
    labels: Callable[[Any], Any],
    keep_cache: Path,
    progress: bool = True,
    parallax: bool = False,
    choice: FrameChoice = FrameChoice(),
    workers: int = 1,
) -> dict[str, Any]:
    """Only the streamed pass of `fit_box_depth`, kept in ``keep_cache`` (`kept_cache`) for later fits of the
    same checkpoint: the pass can then take every core and the fit one thread beside other work. Returns the
    summary of the cache (slots, shown fraction, minutes)."""
    t0 = time.perf_counter()
    model = _ready(model, train, choice, workers, parallax)
    data, reused = kept_cache(model, train, labels, Path(keep_cache), progress, choice, workers)
    summary = _summary(data, train, choice, parallax, reused, workers, model.graph_precision)
    del data
    return {**summary, "cache_minutes": (time.perf_counter() - t0) / 60}


def check_width(width: int) -> None:
    """``width`` (the head's channels) is an integer >= 4."""
    if isinstance(width, bool) or not isinstance(width, int) or width < 4:
        raise InputError(f"--head-width must be an integer >= 4, got {width!r}")


def check_pass_minutes(pass_minutes: float | None, keep_cache: Path | None) -> None:
    """``pass_minutes`` is None or a positive number of minutes, and not given with ``keep_cache``."""
    if pass_minutes is None:
        return
    number = isinstance(pass_minutes, (int, float)) and not isinstance(pass_minutes, bool)
    if not (number and math.isfinite(pass_minutes) and pass_minutes > 0):
        raise InputError(f"--pass-minutes must be a positive number, got {pass_minutes!r}")
    if keep_cache is not None:
        raise InputError(
            "--pass-minutes cannot be used with --keep-cache: the sequences a pass cut by the clock holds depend "
            "on the machine, and a kept cache is reused by its sequences"
        )


def _ready(
    model: MVRackLay,
    train: list[Any],
    choice: FrameChoice,
    workers: int,
    parallax: bool,
    width: int = BOX_WIDTH,
    front: bool = False,
) -> MVRackLay:
    """The checks shared by `fit_box_depth` and `keep_box_inputs`; ``model`` given a fresh head to read with."""
    choice.validate()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"--cache-workers must be a positive integer, got {workers!r}")
    if not train:
        raise InputError("no training sequences to fit the box-depth head on")
    longest = max(choice.streamed(s) for s in train)
    if choice.from_frame >= longest:
        raise InputError(f"--from-frame {choice.from_frame}: the training sequences stream at most {longest} frames")
    return with_box_head(model, parallax, width, front)


def _summary(
    data: Chain, train: list[Any], choice: FrameChoice, parallax: bool, reused: int, workers: int, precision: str
) -> dict[str, Any]:
    """What a fit's or a cache's record says of its inputs (``precision``: the streamed pass's trunk graph's)."""
    back = data.field("back")
    return {
        "train_sequences": len(train),
        **choice.key(),
        "parallax": parallax,
        "cache_parts": len(by_folder(train)),
        "cache_reused": reused,
        "cache_workers": workers,
        "precision": precision,
        "train_slots": len(data),
        "shown_fraction": float(np.mean(data.field("shown")[np.isfinite(back)])),
    }

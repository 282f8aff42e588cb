"""The box-depth head's inputs from one streamed pass of the frozen model, memory-mapped on disk.

One streamed pass of the frozen model over the training sequences (`HeadInputPredictor`, as at inference)
gives each frame's head inputs per valid slot; they are cached on disk (memory-mapped: a thousand scenes
are ~4 GB of fp16 windows) with the targets from the generator's ground truth (`column_targets`): per
model column the truth's box back and front behind the rack front and whether the frame shows that
stack's depth. `FrameChoice` names which frames of each sequence are streamed and kept, `StreamedPass` how
they are streamed. `cache_part` splits a pass over processes of one thread each (``workers``): the pass is one frame after another, so
two single-thread processes stream nearly twice the frames of one process on two threads. A pass can
also stop at a ``deadline``: inside a training budget the head then takes as many scenes as the machine
streams in the minutes left. Caches kept between fits: `network.training.kept_box_cache`.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from layouts import BOX, LayoutSpec
from layouts.boxdepth import cell_z
from layouts.errors import InputError
from layouts.fileio import atomic_write_json
from network.heads.boxdepth import frame_head_inputs
from network.inference.predictor import sequence_camera
from network.model.net import MVRackLay
from network.training.head_inputs import HeadInputPredictor


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


#: the default `FrameChoice`: every frame of each sequence streamed and kept
ALL_FRAMES = FrameChoice()


@dataclass(frozen=True)
class StreamedPass:
    """How the head's inputs are streamed: through ``model`` (frozen, with the head), ``labels(seq)`` saying
    what each frame shows (an object with ``add(i)`` and ``labels(i)``, frames in order, e.g.
    `waresynth.visibility.SeenTracker`), the frames ``choice`` names, with a progress bar or not, over
    ``workers`` processes of one torch thread each (`cache_part`), no sequence but each process's first
    started after ``deadline`` (a `time.monotonic` time; None: no limit)."""

    model: MVRackLay
    labels: Callable[[Any], Any]
    choice: FrameChoice = ALL_FRAMES
    progress: bool = True
    workers: int = 1
    deadline: float | None = None


def cache_inputs(
    model: MVRackLay,
    seqs: list[Any],
    labels: Callable[[Any], Any],
    folder: Path,
    progress: bool = True,
    choice: FrameChoice = ALL_FRAMES,
) -> Cache:
    """Streams the frames of ``seqs`` ``choice`` names (all by default) through ``model`` (it has the head) and
    memory-maps the head's inputs and targets in ``folder`` (one pass, `StreamedPass`, `cache_part`)."""
    return cache_part(StreamedPass(model, labels, choice, progress), seqs, folder)[0][0]


def stream_slots(
    job: StreamedPass, seqs: list[Any], folder: Path, tick: Callable[[], None]
) -> tuple[Cache | None, int]:
    """One process's pass over ``seqs`` into ``folder`` (``tick()`` after each frame; ``job.workers`` not read):
    the cache (None when no kept frame has a valid slot) and how many sequences it streamed."""
    model, choice, deadline = job.model, job.choice, job.deadline
    r, d = model.cfg.spec.num_slots, model.cfg.spec.size
    cap = sum(choice.streamed(s) for s in seqs) * r  # an upper bound on the valid slots
    arrays: dict[str, np.ndarray] = {}
    n = streamed = 0
    for seq in seqs:
        if streamed and deadline is not None and time.monotonic() >= deadline:
            break
        streamed += 1
        camera = sequence_camera(seq)
        seen = job.labels(seq)
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
            win, extra = frame_head_inputs(out.head_inputs(), model.cfg.view, camera(i)[1])
            back, shown, front = column_targets(seq.layouts(i).top, seen.labels(i), seq.spec, depth, d)
            v = torch.isfinite(out.anchors).cpu().numpy()
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


def _shard_worker(job: StreamedPass, seqs: list[Any], folder: Path, counter: Any) -> None:
    """One process of `cache_part`: one torch thread, its shard's slots, then its record."""
    torch.set_num_threads(1)

    def tick() -> None:
        with counter.get_lock():
            counter.value += 1

    try:
        data, streamed = stream_slots(job, seqs, folder, tick)
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


def cache_part(job: StreamedPass, seqs: list[Any], folder: Path) -> tuple[list[Cache], list[int] | None, int]:
    """``(caches, shard_slots, streamed)``: the head's inputs of ``seqs`` streamed as ``job`` says into
    ``folder``, in one pass, or, with ``job.workers`` > 1, split into that many contiguous shards streamed by
    forked processes of one torch thread each (``folder/shard-K``; their slots in the order of ``seqs``, as one
    pass would give them; one pass where the platform cannot fork or there is one sequence). ``shard_slots``:
    each shard's slot count (None for one pass). With ``job.deadline`` no process starts a sequence after it
    but its first, so each shard holds a leading run of its sequences; ``streamed`` counts the sequences
    streamed in all."""
    choice, progress = job.choice, job.progress
    folder.mkdir(parents=True, exist_ok=True)
    runs = split_contiguous(seqs, job.workers, choice) if job.workers > 1 else [seqs]
    if len(runs) < 2 or "fork" not in mp.get_all_start_methods():
        total = sum(choice.streamed(s) for s in seqs)
        bar = tqdm(total=total, desc="box depth: cache", unit="frame", disable=not progress)
        data, streamed = stream_slots(job, seqs, folder, lambda: bar.update(1))
        bar.close()
        if data is None:
            raise InputError(NO_SLOTS)
        return [data], None, streamed
    ctx = mp.get_context("fork")  # the model and the label factory are inherited, nothing is pickled
    counter = ctx.Value("q", 0)
    dirs = [folder / shard_name(k) for k in range(len(runs))]
    for sub in dirs:
        sub.mkdir(parents=True, exist_ok=True)
        (sub / SHARD_RECORD).unlink(missing_ok=True)
    procs = [
        ctx.Process(target=_shard_worker, args=(job, run, sub, counter), daemon=True) for run, sub in zip(runs, dirs)
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

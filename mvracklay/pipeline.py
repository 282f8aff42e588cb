"""The main job: frames -> network (streaming) -> layouts -> stitching -> .glb / .json / .rrd / free space.

>>> from mvracklay.frames import open_source
>>> result = run_pipeline(open_source("my_frames/"), "out/mine")   # doctest: +SKIP
>>> print(format_table(result.free_space))                          # doctest: +SKIP

Frames stream through (`mvracklay.inference.FrameStream`): each is decoded, predicted (one encoder pass, ConvLSTM
state carried) and handed, with the distance and the camera angles it was levelled by, to the sinks in turn
(`RunSinks`): written to ``OUT/layouts/``, stitched into the growing map, logged to Rerun, then dropped.
Everything is written into a staging folder on OUT's filesystem and moved into OUT only when the run
succeeds (`layouts.publish.staged`: OUT held by one command at a time), so a failed run leaves OUT as it was.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from layouts import Intrinsics, LayoutSpec
from layouts.codecs import LayoutFolder
from layouts.errors import InputError
from layouts.publish import staged
from layouts.rackdepth import check_rack_depth
from mvracklay import models
from mvracklay.camera import FrameDistances, default_distance, run_camera
from mvracklay.frames import FrameSource, every_nth
from mvracklay.inference import FrameStream, PredictedFrame
from mvracklay.live_source import LIVE_KEEP_STEPS
from mvracklay.outputs import OUTPUTS
from mvracklay.reconstruction import stitch_settings
from mvracklay.recording import RunRecording
from mvracklay.settings import RunConfig
from network.heads.uprights import FRONT_THRESHOLD
from network.inference.distance import DistanceReading
from network.inference.loading import load_for_inference
from network.inference.roll import angle_warnings
from network.model.frozen import trunk_precision
from stitching.box_colours import BoxColours
from stitching.export_gltf import export_glb
from stitching.free_space import ShelfFreeSpace, free_space
from stitching.path_record import registration_warning
from stitching.pipeline import Stitcher
from stitching.warehouse_map import WarehouseMap

if TYPE_CHECKING:
    from network.model.net import MVRackLay
    from stitching.lift import FrameReconstruction

DEFAULT_CHECKPOINT = models.default_checkpoint()  #: the shipped default model (`mvracklay.models`)


@dataclass
class RunResult:
    """What a run wrote and found."""

    out: Path
    frames: int
    map: WarehouseMap
    free_space: list[ShelfFreeSpace]
    intrinsics: Intrinsics
    intrinsics_source: str
    warnings: list[str] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    angles_read: dict[str, list[float]] = field(default_factory=dict)  #: roll / pitch / yaw read, frame by frame
    distance: DistanceReading | None = None  #: the camera distance used and where it came from

    @property
    def paths(self) -> dict[str, Path]:
        return {name: self.out / name for name in OUTPUTS if (self.out / name).exists()}


def resolve_checkpoint(path: str | os.PathLike | None) -> Path:
    """The checkpoint to run: ``path`` (or a shipped model's name), else the shipped default model
    (one-line error when there is none)."""
    return models.resolve_checkpoint(path, default=DEFAULT_CHECKPOINT)


#: a live run's bound (`run_pipeline`'s ``bounded``): box-colour samples kept per place (and the camera steps kept:
#: `mvracklay.live_source.LIVE_KEEP_STEPS`)
LIVE_COLOUR_SAMPLES = 64

#: called with each frame once it is in the map (its layouts written, stitched, logged) and the stitcher
OnFrame = Callable[[PredictedFrame, Stitcher], None]
#: a loaded model: ``(checkpoint, model, record)`` (`load_model`)
Loaded = tuple[Path, "MVRackLay", dict[str, Any]]


def run_pipeline(
    source: FrameSource,
    out: str | os.PathLike,
    cfg: RunConfig | None = None,
    *,
    loaded: Loaded | None = None,
    on_frame: OnFrame | None = None,
    sinks: tuple = (),
    bounded: bool = False,
) -> RunResult:
    """Run the whole job on ``source`` and write OUT/layouts, warehouse.{json,glb,rrd}.

    Four stages: the model, the camera, the distances and the frame stream (`mvracklay.inference.FrameStream`)
    are set up; the predicted frames flow into the run's sinks (`RunSinks`: the layout folder, the row map, the
    recording, ``on_frame``); the map is finished and exported into a staging folder; that folder is published as
    OUT. A live run (`mvracklay.live`) passes the model it loaded before opening its stream (``loaded``), follows
    each frame into the map (``on_frame``) and streams the recording to a viewer too (``sinks``, Rerun sinks
    beside the .rrd file) and bounds what it keeps per frame (``bounded``: the newest `LIVE_COLOUR_SAMPLES`
    box-colour samples per place, the last `LIVE_KEEP_STEPS` camera steps in warehouse.json, a thinned camera
    path in the recording and its .rrd without Rerun's footer), so its memory is bounded by the map, not by the
    stream's length.
    """
    cfg = cfg or RunConfig()
    cfg.validate()
    source = every_nth(source, cfg.every)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    warnings: list[str] = []
    t0 = time.perf_counter()
    ckpt, model, record = loaded or load_model(cfg)
    spec = _layout_spec(model, cfg)
    intr, intr_source, lens = run_camera(source, cfg.camera, record, str(ckpt), warnings)
    dists = FrameDistances(source, intr, cfg.distance, cfg.camera_height, default_distance(record), cfg.distance_reader)
    # a generated sequence's camera rotation is recorded; footage's is read from the frames
    stream = FrameStream.open(source, model, cfg.inference, (intr, lens, dists), spec)
    origin, cam_y, cam_z = stream.placement
    seconds = {"load": time.perf_counter() - t0}

    with staged(out, OUTPUTS) as stage:  # OUT held, the outputs staged and swapped in whole (`layouts.publish`)
        run = RunSinks.open(stage, model, spec, intr, cfg, bounded)
        try:
            recording = None
            if cfg.rrd:
                recording = RunRecording(f"mvracklay-run-{out.name}", stage / "warehouse.rrd", spec.num_slots,
                                         (cam_y, cam_z), cfg.rgb, cfg.map_every, sinks, bounded=bounded)  # fmt: skip
            run.follow(recording, on_frame)
            n, depth = run.take(stream, cfg)
            t1 = time.perf_counter()
            meta = _map_meta(stream, cfg, n, (ckpt, model), depth)
            # the camera used: where its intrinsics came from and the lens the frames were undistorted through
            meta.update(intrinsics_source=intr_source, lens=lens.to_dict() if lens is not None else None)
            wmap = run.finish(origin, {**meta, **(dists.reading.to_record() if dists.reading else {})}, n, cfg.progress)
        except BaseException:
            run.abort()
            raise
    seconds.update(run.seconds, export=time.perf_counter() - t1)
    warnings.extend(source.warnings + dists.warnings)  # the frame source's and the distance's (printed as they came)
    read = stream.read_angles()
    path_said = registration_warning(wmap.meta.get("registration"), n)
    for said in [*angle_warnings(read, width=intr.width), *([path_said] if path_said else [])]:
        warnings.append(said)
        print(f"mvracklay run: warning: {said}", file=sys.stderr)
    return RunResult(out, n, wmap, free_space(wmap), intr, intr_source, warnings, seconds, read, dists.reading)


def load_model(cfg: RunConfig) -> tuple[Path, MVRackLay, dict[str, Any]]:
    """The checkpoint to run, its model (on ``cfg.device``, in ``cfg.precision``) and its record."""
    ckpt = resolve_checkpoint(cfg.checkpoint)
    model, record = load_for_inference(ckpt, "run", cfg.device, cfg.precision, cfg.threads)
    return ckpt, model, record


def _layout_spec(model: MVRackLay, cfg: RunConfig) -> LayoutSpec:
    """The written layouts' spec: the model's, at ``--layout-size`` when given (a known rack depth checked
    against it)."""
    spec = model.cfg.spec
    if cfg.layout_size and cfg.layout_size != spec.size:
        spec = replace(spec, size=cfg.layout_size)
    if cfg.inference.rack_depth is not None:
        check_rack_depth(cfg.inference.rack_depth, spec)
    return spec


@dataclass(frozen=True)
class MappedFrame:
    """A predicted frame once it is in the row map: its reconstruction, the camera's offset along the row and
    the map so far (the ``stitcher``), for the sinks that follow the map."""

    frame: PredictedFrame
    reconstruction: FrameReconstruction
    offset: float
    stitcher: Stitcher


@dataclass
class RunSinks:
    """The run's stages, each frame taken by each in turn: the layout folder, the row map (``stitcher``, each
    box's colour sampled from the frames' pixels by ``colours``, through the camera ``intr``), then the sinks
    that follow the map (`follow`: the recording, a live run's ``on_frame``). `take` streams the frames in,
    `finish` makes the map and writes it out beside the layouts."""

    folder: LayoutFolder
    stitcher: Stitcher
    colours: BoxColours
    intr: Intrinsics
    recording: RunRecording | None = None
    followers: list[Callable[[MappedFrame], None]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)  #: predicting, stitching and logging

    @classmethod
    def open(
        cls, stage: Path, model: MVRackLay, spec: LayoutSpec, intr: Intrinsics, cfg: RunConfig, bounded: bool
    ) -> RunSinks:
        """The stages of a run staged in ``stage``: layouts at ``spec``, colours read through ``model``'s view and
        the camera ``intr`` (a live run's ``bounded``)."""
        keep_steps = LIVE_KEEP_STEPS if bounded else 0
        stitcher = Stitcher(spec, stitch_settings(cfg.board_thickness, noisy=cfg.opening, keep_steps=keep_steps))
        colours = BoxColours(model.cfg.view, LIVE_COLOUR_SAMPLES if bounded else None)
        return cls(LayoutFolder.create(stage / "layouts", spec), stitcher, colours, intr)

    def follow(self, recording: RunRecording | None, on_frame: OnFrame | None) -> None:
        """The sinks after the map: the ``recording`` (kept to be closed with the map) and ``on_frame``."""
        self.recording = recording
        if recording is not None:
            self.followers.append(lambda m: recording.log(m.frame, m.reconstruction, m.offset, m.stitcher))
        if on_frame is not None:
            self.followers.append(lambda m: on_frame(m.frame, m.stitcher))

    def read(self, rgb: np.ndarray) -> None:
        """A frame as it is read: its pixels kept until its layouts come (the recording's, the colours')."""
        if self.recording is not None:
            self.recording.keep(rgb)
        self.colours.keep(rgb)

    def take(self, stream: FrameStream, cfg: RunConfig) -> tuple[int, float]:
        """``stream``'s frames into the stages; returns the frame count and the last rack depth read."""
        source = stream.source
        bar = tqdm(total=source.frame_count(cfg.max_frames or None), desc=f"predict+stitch ({cfg.mode})",
                   unit="frame", disable=not cfg.progress, file=sys.stderr)  # fmt: skip
        whole = cfg.inference.whole_sequence  # the frames are all read before the first layouts: count reads

        def read(rgb: np.ndarray) -> None:
            self.read(rgb)
            if whole:
                bar.update(1)

        self.seconds = {"predict": 0.0, "stitch": 0.0, "rerun": 0.0}
        n, depth = 0, float("nan")
        ta = time.perf_counter()
        for frame in stream.frames(cfg.mode, cfg.max_frames or None, on_read=read):
            self.folder.write(frame.index, frame.layouts)
            tb = time.perf_counter()
            mapped = self.map(frame)
            tc = time.perf_counter()
            for follow in self.followers:
                follow(mapped)
            self.seconds["predict"] += tb - ta
            self.seconds["stitch"] += tc - tb
            self.seconds["rerun"] += time.perf_counter() - tc
            n, depth = frame.index + 1, frame.prediction.rack_depth
            if not whole:
                bar.update(1)
            ta = time.perf_counter()
        bar.close()
        if n == 0:
            raise InputError(f"{source.path}: no frames to process")
        if self.recording is None:
            del self.seconds["rerun"]
        return n, depth

    def map(self, frame: PredictedFrame) -> MappedFrame:
        """One frame's layouts pushed into the stitcher (with its front uprights) and its boxes' pixels to the
        colours."""
        ups = upright_columns(frame.prediction.maps.get("uprights"), self.stitcher.spec.size)
        rec, step = self.stitcher.push(frame.layouts, frame.index, uprights=ups)
        anchors = frame.prediction.anchors.float().cpu().numpy().reshape(-1)
        self.colours.add(rec, step.offset, anchors, self.intr, frame.distance, frame.angles)
        return MappedFrame(frame, rec, step.offset, self.stitcher)

    def finish(self, origin: Any, meta: dict[str, Any], frames: int, progress: bool) -> WarehouseMap:
        """The finished map (``meta`` kept in it, its boxes painted) written beside the layouts: warehouse.json,
        .glb and, with a recording, .rrd."""
        wmap = self.stitcher.map(origin, meta)
        self.colours.paint(wmap)
        stage = self.folder.root.parent
        steps = ["warehouse.json", "warehouse.glb"] + (["warehouse.rrd"] if self.recording is not None else [])
        with tqdm(total=len(steps), desc="export", unit="file", disable=not progress, file=sys.stderr) as bar:
            wmap.save(stage / "warehouse.json")
            bar.update(1)
            export_glb(wmap, stage / "warehouse.glb")
            bar.update(1)
            if self.recording is not None:
                self.recording.close(wmap, frames)
                self.recording = None
                bar.update(1)
        return wmap

    def abort(self) -> None:
        """A failed run: the recording stopped without finishing."""
        if self.recording is not None:
            self.recording.abort()


def upright_columns(logits: Any, size: int) -> np.ndarray | None:
    """A frame's front-upright columns for the stitcher: the upright head's front channel (logits ``(2, W)`` over
    canonical columns) from `network.heads.uprights.FRONT_THRESHOLD` on, brought to the ``size`` layout columns
    (both span the layouts' X extent about the camera); None without the head's output."""
    if logits is None:
        return None
    front = np.asarray(logits.float().cpu() if hasattr(logits, "cpu") else logits, np.float64)
    if front.ndim < 2 or front.shape[-2] != 2:
        raise InputError(f"upright head output must be (2, W) logits per frame, got shape {front.shape}")
    front = front.reshape(-1, 2, front.shape[-1])[0, 0]
    w = front.shape[0]
    cols = np.zeros(size, bool)
    for c in np.flatnonzero(front >= np.log(FRONT_THRESHOLD / (1.0 - FRONT_THRESHOLD))):
        lo = int(c * size // w)
        cols[lo : max(lo + 1, -(-(c + 1) * size // w))] = True
    return cols


def _map_meta(
    stream: FrameStream, cfg: RunConfig, n: int, loaded: tuple[Path, MVRackLay], depth: float
) -> dict[str, Any]:
    """The run's record kept in warehouse.json: input, model (``(checkpoint, model)``), settings and what was read
    from the frames."""
    (ckpt, model), source, pred, asked = loaded, stream.source, stream.predictor, cfg.inference
    roll, pitch, yaw = stream.median_angles()
    numbers = source.frame_numbers()
    return {
        "input": getattr(source, "url", None) or str(source.path),  # a live source's URL (without a password)
        "input_kind": source.kind,
        "frames": n,
        **({"every": cfg.every} if cfg.every != 1 else {}),  # every N-th input frame processed (live: or "auto")
        # a live stream's numbers of the frames mapped (of the steps kept): the others skipped or dropped
        **({"input_frames": numbers} if numbers is not None else {}),
        "checkpoint": str(ckpt),
        "mode": cfg.mode,
        "flip_average": asked.flip,
        "precision": trunk_precision(model),  # what ran: bf16 applies to the CPU's graphs only
        "depths_from": "the whole sequence" if asked.whole_sequence else "the frames so far",
        "fuse_frames": asked.fuse_tau,
        # the camera's rotation levelled before the network (`network.inference.roll`): the median over the frames
        "camera_roll_deg": roll,
        "camera_roll_source": _angle_source(pred.roll, asked.roll),
        "camera_pitch_deg": pitch,
        "camera_pitch_source": _angle_source(pred.pitch, asked.pitch),
        "camera_yaw_deg": yaw,
        "camera_yaw_source": _angle_source(pred.yaw, asked.yaw),
        # metres imposed on the top views (`layouts.rackdepth`; read: the last frame's reading), None = as decoded
        "rack_depth": depth if np.isfinite(depth) else None,
        "rack_depth_source": "given" if asked.rack_depth is not None else "read" if pred.reads_depth else "decoder",
        # each box's back: carried from the box-depth head's readings (`network.heads.boxdepth`) or as decoded
        "box_depth_source": "read" if pred.reads_box_depth else "decoder",
        "intrinsics": stream.intr.to_dict(),
        "spec": stream.spec.to_dict(),
    }


def _angle_source(used: float | str | None, asked: object) -> str:
    """How a camera angle was known: "read" (from the frames), "given" (asked for), "recorded" (a
    generated sequence's record) or "level" (taken as 0)."""
    if used == "auto":
        return "read"
    if not used:
        return "level"
    return "recorded" if asked is None else "given"

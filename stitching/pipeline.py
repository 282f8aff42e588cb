"""Detect -> lift -> shift -> merge over a sequence of layouts from any source.

>>> result = reconstruct(frames, spec)          # doctest: +SKIP
>>> result.map.save("warehouse.json")           # doctest: +SKIP

``frames`` yields `layouts.codecs.FrameLayouts` (or ``(top, front)`` / ``(top, front, visible)``
tuples); a `layouts.codecs.LayoutFolder` is stitched with `stitch_folder`. Frames are processed one
at a time and not kept (streaming); ``on_frame`` sees each frame's reconstruction and step.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from layouts.codecs import FrameLayouts, LayoutFolder
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from stitching.detect import DetectConfig, detect_frame
from stitching.lift import FrameReconstruction, LiftConfig, lift_frame
from stitching.merge import MapBuilder, MergeConfig
from stitching.path_record import StepStats
from stitching.shift import ShiftConfig
from stitching.warehouse_map import StepRecord, WarehouseMap


@dataclass(frozen=True)
class StitchConfig:
    """All stitching settings in one place."""

    detect: DetectConfig = field(default_factory=DetectConfig)
    lift: LiftConfig = field(default_factory=LiftConfig)
    shift: ShiftConfig = field(default_factory=ShiftConfig)
    merge: MergeConfig = field(default_factory=MergeConfig)

    def __post_init__(self) -> None:
        for name, kind in (
            ("detect", DetectConfig),
            ("lift", LiftConfig),
            ("shift", ShiftConfig),
            ("merge", MergeConfig),
        ):
            if not isinstance(getattr(self, name), kind):
                raise InputError(
                    f"StitchConfig.{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}"
                )

    @classmethod
    def noisy(cls, board_thickness: float = 0.06, keep_steps: int | None = None) -> StitchConfig:
        """Settings for network output, chosen on predicted layouts of a tuning set (never the
        held-out one): two 3x3 openings of the box masks and boxes under 0.03 m^2 dropped before
        labelling, and a merged box kept only when seen in >= 70 % of the frames that had it in view."""
        return cls(
            detect=DetectConfig(opening=2, min_box_area=0.03),
            lift=LiftConfig(board_thickness=board_thickness),
            merge=MergeConfig(min_support=0.7, keep_steps=keep_steps),
        )


@dataclass
class Reconstruction:
    map: WarehouseMap
    frames: int
    seconds: float = 0.0  #: time spent stitching (detect, lift, register, merge), not reading or ``on_frame``


FrameInput = FrameLayouts | tuple


def _as_frame(item: FrameInput, i: int) -> FrameLayouts:
    if isinstance(item, FrameLayouts):
        return item
    if isinstance(item, tuple) and len(item) in (2, 3):
        return FrameLayouts(*item)
    raise InputError(f"frame {i}: expected FrameLayouts or (top, front[, visible]), got {type(item).__name__}")


def _frame_index(index: object) -> int:
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise InputError(f"frame index must be an integer >= 0, got {index!r}")
    return int(index)


def folder_frames(folder: LayoutFolder, indices: Iterable[int] | None = None) -> Iterator[tuple[int, FrameLayouts]]:
    """``(index, FrameLayouts)`` for the frames of a layout folder, in index order."""
    for i in indices if indices is not None else folder.indices():
        yield i, folder.read(i)


class Stitcher:
    """Stateful, streaming: ``push`` one frame at a time, ``map()`` whenever needed.

    Memory is the map (proportional to the length of row covered) plus one `StepRecord` per frame
    for the camera path; ``StitchConfig(merge=MergeConfig(keep_steps=N))`` keeps only the last N
    records (running totals stay in `step_stats`).
    """

    def __init__(self, spec: LayoutSpec, config: StitchConfig | None = None):
        if not isinstance(spec, LayoutSpec):
            raise InputError(f"spec must be a LayoutSpec, got {type(spec).__name__}")
        self.spec = spec
        self.config = config or StitchConfig()
        self.builder = MapBuilder(spec, self.config.merge, self.config.shift, self.config.lift.board_thickness)
        self.count = 0

    def push(
        self,
        frame: FrameInput,
        index: int | None = None,
        motion: float | None = None,
        motion_conf: float | None = None,
        uprights: np.ndarray | None = None,
    ) -> tuple[FrameReconstruction, StepRecord]:
        """Detect, lift, register and merge one frame.

        ``motion``: optional camera step along the row since the previous pushed frame (metres,
        + = toward +X) from another source, e.g. the images (`network.model.motion`); the layouts still
        decide, the step fills in where they fail and, where both agree, is blended in by ``motion_conf``
        (its confidence in [0, 1], default 1; `stitching.merge.MapBuilder.register`). ``uprights``: the
        layout columns that show a front upright (bool, one per column), fused along X (`stitching.uprights`).
        """
        idx = self.count if index is None else _frame_index(index)
        fl = _as_frame(frame, idx)
        det = detect_frame(fl.top, fl.front, self.spec, fl.visible, self.config.detect, name=f"frame {idx}")
        rec = lift_frame(det, self.config.lift)
        top = fl.top
        if fl.visible is not None and not fl.visible.all():
            top = top * fl.visible[None, None, :].astype(np.uint8)  # unseen columns are guesses
        if uprights is not None:
            uprights = np.asarray(uprights)
            if uprights.shape != (self.spec.size,):
                raise InputError(f"frame {idx}: uprights must be one flag per layout column ({self.spec.size},)")
        step = self.builder.add(rec, top, frame=idx, motion=motion, motion_conf=motion_conf, uprights=uprights)
        self.count += 1
        return rec, step

    @property
    def step_stats(self) -> StepStats:
        """Totals over every frame's registration (frames, methods, path length, offsets, confidence)."""
        return self.builder.step_stats

    def map(self, origin_world: tuple[float, float, float] | None = None, meta: dict | None = None) -> WarehouseMap:
        """The map so far; ``origin_world`` (three finite metres) places it in a world frame."""
        if origin_world is not None:
            try:
                ow = tuple(float(v) for v in origin_world)
            except (TypeError, ValueError):
                ow = ()
            if len(ow) != 3 or not all(np.isfinite(ow)):
                raise InputError(f"origin_world must be three finite numbers (metres), got {origin_world!r}")
            origin_world = ow
        if meta is not None and not isinstance(meta, dict):
            raise InputError(f"meta must be a dict, got {type(meta).__name__}")
        return self.builder.build(origin_world, meta)


#: what `reconstruct` calls after each frame: its index, layouts, reconstruction, step and the stitcher so far
OnFrame = Callable[[int, FrameLayouts, FrameReconstruction, StepRecord, Stitcher], None]


def reconstruct(
    frames: Iterable[FrameInput] | Iterable[tuple[int, FrameLayouts]],
    spec: LayoutSpec,
    config: StitchConfig | None = None,
    on_frame: OnFrame | None = None,
    origin_world: tuple[float, float, float] | None = None,
    meta: dict | None = None,
    indexed: bool = False,
    uprights: Mapping[int, np.ndarray] | None = None,
) -> Reconstruction:
    """Stitch a sequence of layouts into a `WarehouseMap` (``indexed``: items are ``(index, frame)``);
    ``uprights``: by frame index, the layout columns showing a front upright (`Stitcher.push`)."""
    st = Stitcher(spec, config)
    seconds = 0.0
    for i, item in enumerate(frames):
        idx, fr = (item[0], item[1]) if indexed else (i, item)
        fl = _as_frame(fr, idx)
        t0 = time.perf_counter()
        rec, step = st.push(fl, idx, uprights=uprights.get(idx) if uprights else None)
        seconds += time.perf_counter() - t0
        if on_frame is not None:
            on_frame(idx, fl, rec, step, st)
    return Reconstruction(st.map(origin_world, meta), st.count, seconds)


def stitch_folder(
    folder: LayoutFolder,
    indices: Iterable[int] | None = None,
    config: StitchConfig | None = None,
    *,
    on_frame: OnFrame | None = None,
    origin_world: tuple[float, float, float] | None = None,
    meta: dict | None = None,
    uprights: Mapping[int, np.ndarray] | None = None,
) -> Reconstruction:
    """The layouts a folder holds (at ``indices``, default all, in that order) stitched into a map: `reconstruct`
    over `folder_frames`."""
    if not isinstance(folder, LayoutFolder):
        raise InputError(f"folder must be a LayoutFolder, got {type(folder).__name__}")
    frames = folder_frames(folder, indices)
    return reconstruct(frames, folder.spec, config, on_frame, origin_world, meta, indexed=True, uprights=uprights)


def frame_arrays(top: np.ndarray, front: np.ndarray, visible: np.ndarray | None = None) -> list[FrameLayouts]:
    """Split ``(N, R, D, D)`` top/front arrays (and ``(N, D)`` visible) into per-frame inputs."""
    top, front = np.asarray(top), np.asarray(front)
    if top.ndim != 4 or front.shape != top.shape:
        raise InputError(f"top/front must both be (N, R, D, D), got {top.shape} and {front.shape}")
    if visible is not None and np.asarray(visible).shape != (top.shape[0], top.shape[-1]):
        raise InputError(f"visible must be (N, D) = {(top.shape[0], top.shape[-1])}, got {np.asarray(visible).shape}")
    return [FrameLayouts(top[i], front[i], None if visible is None else visible[i]) for i in range(top.shape[0])]

"""Log a reconstruction to Rerun (0.41 API): layouts, per-frame cuboids, the growing map, camera path.

Entity tree (all 3D in the map frame, which is right/down/forward like Rerun's RDF):

* ``/`` — ``ViewCoordinates.RDF``, static; ``/layouts`` — the class `AnnotationContext`, static
* ``camera/rgb`` — the frame's RGB when given, as a JPEG ``EncodedImage`` (quality `JPEG_QUALITY`)
* ``layouts/top/slot_r``, ``layouts/front/slot_r`` — ``SegmentationImage`` per slot
* ``world/frame/boxes`` — this frame's lifted cuboids, placed at its estimated offset
* ``world/map/slot_r`` — the fused map's boxes of slot r, one ``Boxes3D`` batch per slot, each box
  labelled with its map id (``rack_01/shelf_00/box_002``: unique in the whole map)
* ``world/map/shelves`` — shelf volumes (board to next board), one batch
* ``world/camera/path`` — the estimated camera path so far; ``world/camera/position`` the current one

Time: ``rr.set_time("frame", sequence=i)``. Many boxes go out as one batch per shelf slot, never
one entity per box (the viewer slows down with thousands of entities).

The ``.rrd`` also holds a default blueprint (`blueprint`): the 3D view of ``/world`` (map, frame
cuboids, camera path and position) beside 2D views of the RGB and of each slot's top and front layout.
"""

from __future__ import annotations

import io
import math
import os
import sys

import numpy as np

from layouts.classes import BOX, CLASS_COLOURS, CLASS_NAMES, SHELF
from layouts.codecs import FrameLayouts
from stitching.geometry import Cuboid
from stitching.lift import FrameReconstruction
from stitching.warehouse_map import WarehouseMap

JPEG_QUALITY = 85
"""JPEG quality of the logged RGB: ~1/16 of the raw bytes at 640x480 (57 KB a frame), still sharp to the eye."""
DEFAULT_SLOTS = 3


#: Rerun's log filter while the SDK is first imported: a live run's file sink without a footer (`start`) warns
#: about it once per run otherwise
QUIET_FOOTER = "warn,re_log_encoding::rrd::file_sink=error"


def sdk():
    """The Rerun SDK, imported on first use with `QUIET_FOOTER` as its log filter (unless ``RUST_LOG`` is set;
    the environment left as it was)."""
    if "rerun" not in sys.modules and "RUST_LOG" not in os.environ:
        os.environ["RUST_LOG"] = QUIET_FOOTER
        try:
            import rerun  # noqa: F401 (its logging reads the filter once, here)
        finally:
            del os.environ["RUST_LOG"]
    import rerun as rr

    return rr


_rr = sdk


def start(
    app_id: str = "mvracklay",
    save: str | os.PathLike | None = None,
    spawn: bool = False,
    num_slots: int = DEFAULT_SLOTS,
    sinks: tuple = (),
    footer: bool = True,
):
    """A recording stream writing to ``save`` (an ``.rrd``, with `blueprint` as its default) or to a spawned viewer;
    ``sinks``: Rerun sinks it also streams to, live (``rr.GrpcSink`` to a viewer, ``rr.GrpcServerSink``);
    ``footer`` False: the file without its footer, a manifest of every chunk that Rerun keeps in memory until the
    file is closed (it grows with every frame logged: an endless stream's recording goes without; still a valid
    .rrd, read in order)."""
    rr = _rr()
    rec = rr.RecordingStream(app_id, recording_id=app_id)
    bp = blueprint(num_slots)
    if sinks or not footer:
        rec.set_sinks(*([_file_sink(str(save), footer)] if save is not None else []), *sinks, default_blueprint=bp)
    elif save is not None:
        rec.save(str(save), default_blueprint=bp)
    elif spawn:
        rec.spawn(default_blueprint=bp)
    log_static(rec)
    return rec


def _file_sink(path: str, footer: bool):
    """A file sink, without the footer when not ``footer`` (SDKs before footers have none: the plain sink)."""
    rr = _rr()
    if footer:
        return rr.FileSink(path)
    try:
        return rr.FileSink(path, write_footer=False)
    except TypeError:
        return rr.FileSink(path)


def blueprint(num_slots: int = DEFAULT_SLOTS):
    """The viewer's layout: the 3D map and camera large, the RGB and each slot's layouts (highest slot on top) beside."""
    import rerun.blueprint as rrb

    slots = range(num_slots - 1, -1, -1)
    layouts = rrb.Horizontal(
        *(
            rrb.Vertical(*(rrb.Spatial2DView(name=f"{v} slot {r}", origin=f"/layouts/{v}/slot_{r}") for r in slots))
            for v in ("top", "front")
        )
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="map", origin="/world"),
            rrb.Vertical(rrb.Spatial2DView(name="RGB", origin="/camera/rgb"), layouts, row_shares=[1, 2]),
            column_shares=[3, 2],
        )
    )


def log_static(rec) -> None:
    rr = _rr()
    rec.log("/", rr.ViewCoordinates.RDF, static=True)
    rec.log(
        "layouts",
        rr.AnnotationContext([(cid, CLASS_NAMES[cid], CLASS_COLOURS[cid]) for cid in sorted(CLASS_NAMES)]),
        static=True,
    )


def _boxes(cuboids: list[Cuboid], colour: tuple[int, int, int], labels: list[str] | None = None):
    rr = _rr()
    if not cuboids:
        return rr.Boxes3D(centers=np.zeros((0, 3)), half_sizes=np.zeros((0, 3)))
    centers = np.array([c.center for c in cuboids], np.float32)
    half = np.array([c.size for c in cuboids], np.float32) / 2
    # Map yaw turns the width axis from +X toward +Z: a rotation of -yaw about +Y.
    rot = [rr.RotationAxisAngle(axis=[0.0, 1.0, 0.0], radians=-float(c.yaw)) for c in cuboids]
    return rr.Boxes3D(
        centers=centers,
        half_sizes=half,
        rotation_axis_angles=rot,
        colors=np.tile(np.array(colour, np.uint8), (len(cuboids), 1)),
        labels=labels,
    )


def encode_rgb(rgb: np.ndarray, quality: int = JPEG_QUALITY):
    """``rgb`` (uint8, H x W x 3 or H x W) as a JPEG `EncodedImage` (raw frames make the .rrd over 10x larger)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, np.uint8)).save(buf, format="JPEG", quality=int(quality))
    return _rr().EncodedImage(contents=buf.getvalue(), media_type="image/jpeg")


def log_frame(
    rec,
    index: int,
    layouts: FrameLayouts | None,
    frame: FrameReconstruction | None,
    offset: float,
    rgb: np.ndarray | None = None,
    path: list[tuple[float, float, float]] | None = None,
) -> None:
    """Log one frame's inputs and per-frame cuboids (shifted to the map by ``offset``)."""
    rr = _rr()
    rec.set_time("frame", sequence=int(index))
    if rgb is not None:
        rec.log("camera/rgb", encode_rgb(rgb))
    if layouts is not None:
        for view, arr in (("top", layouts.top), ("front", layouts.front)):
            for r in range(arr.shape[0]):
                rec.log(f"layouts/{view}/slot_{r}", rr.SegmentationImage(arr[r]))
    if frame is not None:
        cubs = []
        for c in frame.cuboids():
            cubs.append(Cuboid((c.center[0] + offset, c.center[1], c.center[2]), c.size, c.yaw))
        rec.log("world/frame/boxes", _boxes(cubs, (255, 255, 255)))
    if path:
        pts = np.array(path, np.float32)
        rec.log("world/camera/path", rr.LineStrips3D([pts], colors=[(200, 60, 200)]))
        rec.log("world/camera/position", rr.Points3D(pts[-1:], colors=[(200, 60, 200)], radii=[0.05]))


def log_map(rec, wmap: WarehouseMap, index: int | None = None, num_slots: int | None = None) -> None:
    """Log the map's boxes (one batch per slot) and shelf volumes at frame ``index`` (or static)."""
    static = index is None
    if not static:
        rec.set_time("frame", sequence=int(index))
    slots = sorted({s.slot for s in wmap.shelves()} | set(range(num_slots or 0)))
    for r in slots:
        boxes = [b for s in wmap.shelves() if s.slot == r for b in s.boxes]
        rec.log(
            f"world/map/slot_{r}",
            _boxes([b.cuboid for b in boxes], CLASS_COLOURS[BOX], [b.id for b in boxes]),
            static=static,
        )
    shelves = wmap.shelves()
    labels = [f"{s.id} (partial: {s.partial})" if getattr(s, "partial", None) else s.id for s in shelves]
    rec.log(
        "world/map/shelves",
        _boxes([s.cuboid for s in shelves], CLASS_COLOURS[SHELF], labels),
        static=static,
    )


def camera_point(
    offset: float, height: float | None = None, distance: float | None = None
) -> tuple[float, float, float]:
    """Camera position in the map frame; unknown height/distance default to 0 and -3 m."""
    y = 0.0 if height is None or not math.isfinite(height) else height
    z = -3.0 if distance is None or not math.isfinite(distance) else distance
    return (offset, y, z)


def read_entities(path: str | os.PathLike) -> set[str]:
    """Entity paths stored in an ``.rrd`` (read back with the SDK's own `rerun.chunk.RrdReader`, in order: a live
    run's file has no footer)."""
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer")
        store = RrdReader(str(path)).stream().collect()
    return {c.entity_path for c in store.stream()}

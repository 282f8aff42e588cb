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

Files are written by us, not by Rerun's own file writer (`Recording`): on a full disk that writer stops, and
Rerun then either waits for it forever (a flush that never returns, deaf to SIGTERM) or finishes a truncated
file without a word. Rerun's file sink writes into a pipe instead, a thread of ours moves the bytes into the
file (`_Pump`), and the file is read back before it counts as written (`verify_rrd`); a failed write is an
`OSError` naming the file.
"""

from __future__ import annotations

import errno
import io
import math
import os
import shutil
import sys
import tempfile
import threading
import warnings
from pathlib import Path
from typing import Any

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
    bp = blueprint(num_slots)
    if save is not None:
        rec = recording(app_id, save, footer=footer, sinks=sinks, default_blueprint=bp)
    else:
        rr = _rr()
        rec = rr.RecordingStream(app_id, recording_id=app_id)
        if sinks:
            rec.set_sinks(*sinks, default_blueprint=bp)
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


#: seconds a recording's flush may take before it counts as failed (a sink that stopped taking data)
FLUSH_TIMEOUT = 600.0


def _write(fd: int, data: bytes) -> None:
    """All of ``data`` written to ``fd`` (``os.write`` may write part of it)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class _NoPipe(Exception):
    """No pipe could be made for `_Pump`: Rerun writes the file itself."""


class _Pump:
    """The bytes Rerun's file sink writes into a pipe, moved into ``path`` by a thread of ours: a failed write (a full
    disk, a quota) is kept as an `OSError` naming the file, and the pipe is drained to its end all the same, so
    Rerun's writer never stops and nothing waits on it. ``written``: the bytes in the file."""

    def __init__(self, path: Path) -> None:
        self.path, self.error, self.written = path, None, 0
        self._guard = threading.Lock()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)  # a file that cannot be made: said now
        self._dir = ""
        try:
            self._dir = tempfile.mkdtemp(prefix="mvracklay-rrd-")
            self.fifo = os.path.join(self._dir, "sink")
            os.mkfifo(self.fifo, 0o600)
            self._read = os.open(self.fifo, os.O_RDONLY | os.O_NONBLOCK)
            self._hold: int | None = os.open(self.fifo, os.O_WRONLY)  # no end of file before Rerun's end is open
            os.set_blocking(self._read, True)
        except (OSError, AttributeError, NotImplementedError) as e:  # no FIFOs here (or no room for one)
            os.close(fd)
            if self._dir:
                shutil.rmtree(self._dir, ignore_errors=True)
            raise _NoPipe from e
        self._thread = threading.Thread(target=self._run, args=(fd,), name="rrd-file", daemon=True)
        self._thread.start()

    def _release(self) -> None:
        """Our own end of the pipe closed (once Rerun's is open, or when it is done): its end of file ends the pump."""
        with self._guard:
            if self._hold is not None:
                os.close(self._hold)
                self._hold = None

    def _run(self, fd: int) -> None:
        try:
            while chunk := os.read(self._read, 1 << 20):
                self._release()
                if self.error is None:
                    try:
                        _write(fd, chunk)
                        self.written += len(chunk)
                    except OSError as e:
                        self.error = e
        except OSError as e:
            self.error = self.error or e
        finally:
            os.close(self._read)
            try:
                os.close(fd)
            except OSError as e:  # a write the filesystem reports only now (NFS, quotas)
                self.error = self.error or e

    def failure(self) -> OSError | None:
        """The failed write so far, as an `OSError` naming the file (None: every byte written)."""
        e = self.error
        if e is None:
            return None
        return OSError(e.errno or errno.EIO, e.strerror or str(e), str(self.path))

    def finish(self, timeout: float = FLUSH_TIMEOUT) -> None:
        """Wait for the last bytes (Rerun's end closed) and raise a failed write; the file's size checked."""
        self._release()
        self._thread.join(timeout)
        shutil.rmtree(self._dir, ignore_errors=True)
        if self._thread.is_alive():
            raise OSError(errno.EIO, "the recording's last bytes never came", str(self.path))
        failed = self.failure()
        if failed is not None:
            raise failed
        size = os.path.getsize(self.path)
        if size != self.written:
            raise OSError(errno.EIO, f"{size} bytes on disk of {self.written} written", str(self.path))


class Recording:
    """A Rerun recording stream saving an ``.rrd`` through `_Pump` (besides any other ``sinks``), used as the
    stream itself: `flush` bounded in time (`FLUSH_TIMEOUT`), `disconnect` waits for the file, reads it back
    (`verify_rrd`) and raises what failed as an `OSError` naming it, `check` raises a failed write at once (so a run
    on a full disk stops at the next frame), `abort` ends it without a word (a failed run)."""

    def __init__(self, rec: Any, path: Path, pump: _Pump | None, footer: bool) -> None:
        self._rec, self.path, self._pump, self._footer, self._closed = rec, path, pump, footer, False

    def __getattr__(self, name: str) -> Any:
        return getattr(self._rec, name)

    def to_native(self) -> Any:
        return self._rec.to_native()

    def check(self) -> None:
        failed = self._pump.failure() if self._pump is not None else None
        if failed is not None:
            raise failed

    def flush(self, *, timeout_sec: float = FLUSH_TIMEOUT) -> None:
        try:
            self._rec.flush(timeout_sec=timeout_sec)
        except RuntimeError as e:  # Rerun's sink gave up (e.g. "File-writer thread shut down prematurely")
            self.check()
            raise OSError(errno.EIO, f"the recording could not be written ({e})", str(self.path)) from None

    def disconnect(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.flush()
        except OSError:
            self.abort()
            raise
        self._rec.disconnect()
        if self._pump is not None:
            self._pump.finish()
        verify_rrd(self.path, self._footer)

    def abort(self) -> None:
        self._closed = True
        self._rec.disconnect()
        if self._pump is not None:
            try:
                self._pump.finish(timeout=5.0)
            except OSError:
                pass


def recording(
    app_id: str, path: str | os.PathLike, footer: bool = True, sinks: tuple = (), default_blueprint: Any = None
) -> Recording:
    """A recording stream ``app_id`` saving ``path`` (`Recording`); ``footer`` False: without Rerun's footer (an
    endless stream's), ``sinks``: other Rerun sinks it streams to as well. Where no pipe can be made (no FIFOs on
    this system), Rerun writes the file itself, still verified when it is closed."""
    rr = _rr()
    path = Path(path)
    rec = rr.RecordingStream(app_id, recording_id=app_id)
    try:
        pump: _Pump | None = _Pump(path)
    except _NoPipe:
        pump = None
    target = pump.fifo if pump is not None else str(path)
    try:
        rec.set_sinks(_file_sink(target, footer), *sinks, default_blueprint=default_blueprint)
    except BaseException:
        if pump is not None:
            pump._release()
            pump.finish(timeout=5.0)
        raise
    return Recording(rec, path, pump, footer)


def verify_rrd(path: str | os.PathLike, footer: bool = True) -> None:
    """Read ``path`` back to its end with Rerun's own reader: an ``.rrd`` cut short (a full disk, a killed writer) or,
    with ``footer``, missing its footer is an `OSError` naming it, never a file a viewer later refuses."""
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            for _ in RrdReader(str(path)).stream():
                pass
    except (RuntimeError, ValueError, OSError) as e:
        raise OSError(errno.EIO, f"not a whole Rerun recording ({str(e)[:160]})", str(path)) from None
    if footer and any("no footer" in str(w.message) for w in said):
        raise OSError(errno.EIO, "not a whole Rerun recording (its footer is missing)", str(path))


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

"""Live frame sources for `mvracklay run`: a camera device (``/dev/video0``, or its index ``0``) or a stream URL
FFmpeg opens through PyAV (``rtsp://``, ``rtmp://``, ``http(s)://``, ``udp://``, ``tcp://``, ``srt://``).

A reader thread decodes the stream into a bounded buffer (`LatestFrames`): when the consumer (the network) falls
behind, the oldest frame waiting is dropped and counted, so the frames mapped are always recent and memory and
latency stay bounded. A `LiveSource` is a `mvracklay.frames.FrameSource` (kind ``live``): the pipeline streams it
as it streams a file, frame by frame, until the stream ends, stays quiet for ``idle_timeout`` seconds, or
`LiveSource.stop` is called (Ctrl-C, SIGTERM). A connection lost mid-stream is reopened ``retries`` times, each
said in one line; a source that cannot be opened at all is one `InputError` line.

Spacing (``every="auto"``): frames are kept a few centimetres apart along the row (`Spacing`): the camera's
speed comes from the motion the network reads between the frames it mapped (`mvracklay.live.LiveRun.mapped`
feeds it back), and a frame arriving before the camera can have moved `AUTO_SPACING` is skipped.
"""

from __future__ import annotations

import re
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from layouts.errors import InputError
from mvracklay.frames import FrameSource

#: the URL schemes taken as live streams (FFmpeg's protocols through PyAV)
LIVE_SCHEMES = ("rtsp", "rtsps", "rtmp", "rtmps", "http", "https", "udp", "tcp", "srt")
#: metres between frames kept by ``every="auto"`` (the generator moves 6-16 cm a frame)
AUTO_SPACING = 0.06
#: with ``every="auto"``, a frame is kept at least this often (seconds), so a stopped camera's motion is read again
AUTO_MAX_GAP = 1.0
#: FFmpeg options: probe briefly (a live stream has no index to read); UDP into a ring of 50000 packets of 188 bytes
#: (9.4 MB: seconds of an HD stream; its pages are touched as the stream goes round it, so a larger ring shows as
#: memory growing for minutes), an overrun dropping packets rather than ending the stream
_OPTIONS = {"analyzeduration": "500000", "probesize": "500000", "fifo_size": "50000", "overrun_nonfatal": "1"}
_RTSP = {"rtsp_transport": "tcp"}


def is_live(text: str | Path) -> bool:
    """Whether INPUT names a live source: a URL of `LIVE_SCHEMES`, a ``/dev/video*`` device or a bare camera
    index (``0``) that is not a file or folder here."""
    s = str(text)
    m = re.match(r"^([a-zA-Z][a-zA-Z0-9+.-]*)://", s)
    if m:
        return m.group(1).lower() in LIVE_SCHEMES
    if re.fullmatch(r"/dev/video\d+", s):
        return True
    return s.isdigit() and not Path(s).exists()


#: query and fragment parameters whose values are secrets (their names compared lower-case, ``-`` read as ``_``;
#: a name ending in ``_`` and one of them, as ``client_secret`` or ``x_amz_signature``, is one too)
SECRET_PARAMS = frozenset(
    {"password", "pass", "pwd", "passwd", "token", "access_token", "key", "api_key", "apikey", "secret", "auth",
     "sig", "signature", "credential", "credentials"}
)  # fmt: skip
_PARAM = re.compile(r"(^|[&;?])([^&;?=]*)=([^&;?]*)")


def _secret_name(name: str) -> bool:
    from urllib.parse import unquote_plus

    n = unquote_plus(name).strip().lower().replace("-", "_")
    return n in SECRET_PARAMS or any(n.endswith(f"_{s}") for s in SECRET_PARAMS)


def shown(url: str) -> str:
    """``url`` as printed and recorded, every secret in it left out: a ``user:password@`` before the host, and the
    values of the query's and fragment's `SECRET_PARAMS` (``?password=...&fps=5`` -> ``?password=***&fps=5``; the
    other parameters kept as given). Every message and record that names a source shows it through here."""
    url = re.sub(r"^([a-zA-Z][a-zA-Z0-9+.-]*://)[^/?#]*@", r"\1", url)  # up to the authority's last @, as FFmpeg
    base, h, fragment = url.partition("#")
    head, q, query = base.partition("?")

    def hide(text: str) -> str:
        return _PARAM.sub(lambda m: f"{m[1]}{m[2]}=***" if _secret_name(m[2]) and m[3] else m[0], text)

    return f"{head}{q}{hide(query)}{h}{hide(fragment)}"


def _device(text: str) -> tuple[str, str | None]:
    """``(what av.open takes, its format)``: a camera index or device for the platform's capture API."""
    if text.isdigit():
        if sys.platform == "darwin":
            return text, "avfoundation"
        if sys.platform.startswith("win"):
            return f"video={text}", "dshow"
        text = f"/dev/video{text}"
    return (text, "v4l2") if text.startswith("/dev/") else (text, None)


def _open_container(url: str, open_timeout: float, read_timeout: float) -> Any:
    """The stream opened with PyAV (its first video stream checked); one `InputError` line when it cannot be."""
    import av

    target, fmt = _device(url)
    options = {**_OPTIONS, **(_RTSP if url.lower().startswith("rtsp") else {})}
    try:
        container = av.open(target, format=fmt, options=options, timeout=(open_timeout, read_timeout))
    except av.ExitError:  # FFmpeg's "Immediate exit requested": the open timeout passed with nothing received
        raise InputError(f"{shown(url)}: no frame within {open_timeout:g} s") from None
    except (av.FFmpegError, OSError, ValueError) as e:
        said = str(e).split(":")[0] if str(e) else type(e).__name__
        raise InputError(f"{shown(url)}: cannot open the live source ({type(e).__name__}: {said})") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{shown(url)}: holds no video stream")
    return container


#: a live map's bound: the camera steps its warehouse.json keeps (the last ones), and their input frame numbers
LIVE_KEEP_STEPS = 1000


@dataclass
class Arrival:
    """A frame as it came: its pixels, when it was received (``time.monotonic``), its stream time (seconds; None
    when the stream gives none) and its number in the stream (0 for the first decoded, before any was skipped)."""

    rgb: np.ndarray
    received: float
    stream_time: float | None
    number: int = 0


class LatestFrames:
    """A bounded FIFO of the newest frames: `put` drops the oldest waiting when full (counted in ``dropped``);
    `get` waits for one. ``most`` is the most frames ever held at once (never over ``capacity``)."""

    def __init__(self, capacity: int = 2) -> None:
        if not isinstance(capacity, int) or capacity < 1:
            raise InputError(f"--live-buffer must be an integer >= 1, got {capacity!r}")
        self.capacity = capacity
        self._items: deque[Arrival] = deque()
        self._cond = threading.Condition()
        self.dropped = self.received = self.most = 0
        self.closed = False

    def put(self, item: Arrival) -> None:
        with self._cond:
            self.received += 1
            if len(self._items) >= self.capacity:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.most = max(self.most, len(self._items))
            self._cond.notify()

    def close(self) -> None:
        """No more frames will come (those waiting are still given)."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        """Frames waiting."""
        return len(self._items)

    def get(self, timeout: float, stop: threading.Event) -> Arrival | None:
        """The oldest frame waiting; None once closed and empty, ``stop`` set, or ``timeout`` seconds quiet."""
        end = time.monotonic() + timeout
        with self._cond:
            while not self._items:
                left = end - time.monotonic()
                if self.closed or stop.is_set() or left <= 0:
                    return None
                self._cond.wait(min(left, 0.1))  # short waits: a signal handler's stop is seen soon
            return self._items.popleft()


class Spacing:
    """``every="auto"``: keep a frame once the camera can have moved ``spacing`` metres since the last kept one,
    at the speed the network's motion read gives (`moved`); every frame until a speed is known, and one at least
    every ``max_gap`` seconds."""

    def __init__(self, spacing: float = AUTO_SPACING, max_gap: float = AUTO_MAX_GAP) -> None:
        self.spacing, self.max_gap = spacing, max_gap
        self.speed: float | None = None  #: metres a second along the row (smoothed)
        self.last: float | None = None  #: the time of the last frame kept
        self.skipped = 0

    def keep(self, t: float) -> bool:
        if self.last is None or self.speed is None or t - self.last >= self.max_gap:
            ok = True
        else:
            ok = self.speed * (t - self.last) >= self.spacing - 1e-9
        if ok:
            self.last = t
        else:
            self.skipped += 1
        return ok

    def moved(self, step: float | None, seconds: float) -> None:
        """The camera moved ``step`` metres between two kept frames ``seconds`` apart (None: not read)."""
        if step is None or not np.isfinite(step) or seconds <= 0:
            return
        v = abs(step) / seconds
        self.speed = v if self.speed is None else 0.5 * self.speed + 0.5 * v


@dataclass
class LiveSource(FrameSource):
    """A live stream as a `FrameSource` (kind ``live``, `open_live`): the frames given out are the buffer's, in
    order; `arrival` says when each was received; `stats` what came, what was dropped; `stop` ends it."""

    url: str = ""  #: the source as printed and recorded (`shown`)
    target: str = field(default="", repr=False)  #: the source as opened
    idle_timeout: float = 5.0
    retries: int = 3
    every: int | str = 1
    buffer: LatestFrames = field(default_factory=LatestFrames, repr=False)
    spacing: Spacing | None = field(default=None, repr=False)
    #: frame index given out -> (when received, stream time) until the frame is mapped (`arrival`)
    arrivals: dict[int, tuple[float, float | None]] = field(default_factory=dict, repr=False)
    given: int = 0  #: frames given out
    #: the stream numbers of the last `LIVE_KEEP_STEPS` frames given out (`frame_numbers`)
    numbers: deque[int] = field(default_factory=lambda: deque(maxlen=LIVE_KEEP_STEPS), repr=False)
    ended: str = ""  #: why the stream ended ("" while it runs)
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)
    #: set while the reader reopens a lost connection (the idle timeout waits for it: the retries decide)
    _reconnecting: threading.Event = field(default_factory=threading.Event, repr=False)
    _thread: threading.Thread | None = field(default=None, repr=False)
    _container: Any = field(default=None, repr=False)
    _first: Arrival | None = field(default=None, repr=False)
    _decoded: int = 0
    _tries: int = 0  #: reconnections tried since the last frame decoded
    #: the reader ends a quiet stream itself (a read timeout) and flushes the decoder then (`_reader_waits_for_reader`)
    reader_times_out: ClassVar[bool] = True

    def stop(self, why: str = "stopped") -> None:
        """End the stream: the frames waiting are dropped, the pipeline finishes with what it mapped."""
        if not self.ended:
            self.ended = why
        self._stop.set()

    def close(self) -> None:
        """Stop the reader thread (waiting for it at most the read timeout)."""
        self._stop.set()
        self.buffer.close()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=self.idle_timeout + 1.0)

    def start(self) -> None:
        """Start decoding into the buffer (the first frame, read when opened, is the first given out)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._read, name="live-source", daemon=True)
            self._thread.start()

    def _raw_frames(self, max_frames: int | None) -> Iterator[np.ndarray]:
        self.start()
        n, waited = 0, False
        while not self._stop.is_set() and not (max_frames and n >= max_frames):
            item = self.buffer.get(self.idle_timeout, self._stop)
            if item is None and self._reconnecting.is_set() and not self.buffer.closed:
                continue
            if item is None and self._reader_waits_for_reader(waited):
                waited = True  # the reader's own read timeout ends a quiet stream, after the decoder's last frames
                continue
            waited = False
            if item is None:
                if not self._stop.is_set() and not self.buffer.closed:
                    self.ended = self.ended or f"quiet for {self.idle_timeout:g} s"
                break
            t = item.stream_time if item.stream_time is not None else item.received
            if self.spacing is not None and not self.spacing.keep(t):
                continue
            self.arrivals[self.given] = (item.received, item.stream_time)
            self.numbers.append(item.number)
            self.given += 1
            n += 1
            yield item.rgb
        self.ended = self.ended or ("max frames reached" if max_frames and n >= max_frames else "stream ended")
        self._stop.set()

    def _reader_waits_for_reader(self, waited: bool) -> bool:
        """Whether a quiet ``idle_timeout`` seen here waits once more for the reader: a stream's reader times out on
        its own read (then flushes the decoder's last frames into the buffer and closes it), and its clock may have
        started after ours, so frames flushed then would otherwise be received and never mapped."""
        alive = self._thread is not None and self._thread.is_alive()
        return self.reader_times_out and alive and not waited and not self.buffer.closed and not self._stop.is_set()

    def frame_numbers(self) -> list[int]:
        """The stream numbers of the frames given out (the last `LIVE_KEEP_STEPS`): which frames of the stream the
        map holds, the others skipped (``every``) or dropped (the network behind)."""
        return list(self.numbers)

    def arrival(self, index: int) -> tuple[float, float | None]:
        """When the frame given out as ``index`` was received and its stream time (forgotten once asked)."""
        return self.arrivals.pop(index)

    def _keep(self, frame: Any) -> bool:
        """Whether the reader buffers the decoded ``frame`` (every N-th with an integer ``every``)."""
        self._decoded += 1
        return not isinstance(self.every, int) or (self._decoded - 1) % self.every == 0

    def _arrival(self, frame: Any) -> Arrival:
        rgb = frame.to_ndarray(format="rgb24")
        t = float(frame.time) if frame.time is not None else None
        return Arrival(rgb, time.monotonic(), t, self._decoded - 1)

    def _read(self) -> None:
        """The reader thread: decode into the buffer, reconnecting a lost connection ``retries`` times."""
        import av

        if self._first is not None:
            self.buffer.put(self._first)
            self._first = None
        while not self._stop.is_set():
            container, failed = self._container, None
            try:
                stream = container.streams.video[0]
                for frame in container.decode(stream):
                    if self._stop.is_set():
                        break
                    self._tries = 0
                    if not self._keep(frame):
                        continue
                    item = self._arrival(frame)
                    if (item.rgb.shape[1], item.rgb.shape[0]) != (self.width, self.height):
                        self.stop(f"frame size changed to {item.rgb.shape[1]}x{item.rgb.shape[0]}")
                        break
                    self.buffer.put(item)
                else:
                    self.ended = self.ended or "stream ended"
                    break
            except av.ExitError:  # the read timeout passed: the stream went quiet
                self._flush(container)
                self.ended = self.ended or f"quiet for {self.idle_timeout:g} s"
                break
            except (av.FFmpegError, OSError, EOFError) as e:
                failed = type(e).__name__
            finally:
                _close_quietly(container)
                self._container = None
            if failed is None or self._stop.is_set():
                break
            if not self._reconnect(failed):
                break
        self.buffer.close()

    def _flush(self, container: Any) -> None:
        """Frames still inside the decoder once the stream went quiet (its last ones)."""
        try:
            for frame in container.streams.video[0].codec_context.decode(None):
                if self._keep(frame):
                    self.buffer.put(self._arrival(frame))
        except Exception:  # noqa: BLE001 (a decoder that cannot flush gives nothing more)
            pass

    def _reconnect(self, failed: str) -> bool:
        """Reopen after a lost connection (one line each try); False once ``retries`` tries failed."""
        self._reconnecting.set()
        try:
            return self._reopen(failed)
        finally:
            self._reconnecting.clear()

    def _reopen(self, failed: str) -> bool:
        while self._tries < self.retries and not self._stop.is_set():
            self._tries += 1
            said = f"connection lost ({failed}), reconnecting ({self._tries}/{self.retries})"
            print(f"{self.prog}: warning: {self.url}: {said}", file=sys.stderr, flush=True)
            time.sleep(min(0.5 * self._tries, 3.0))
            try:
                self._container = _open_container(self.target, self.idle_timeout, self.idle_timeout)
                return True
            except InputError:
                continue
        self.ended = self.ended or f"connection lost ({failed}), {self.retries} reconnections failed"
        return False

    def next_ready(self) -> bool:
        """Whether a frame waits in the buffer (else reading the next waits for the stream)."""
        return len(self.buffer) > 0

    def stats(self) -> dict[str, int]:
        """Frames received from the stream (after ``every``), dropped (the network behind), skipped (``every
        auto``: too close), mapped (given out), and the most held at once."""
        b = self.buffer
        skipped = self.spacing.skipped if self.spacing is not None else 0
        return {"received": b.received, "dropped": b.dropped, "skipped": skipped, "given": self.given,
                "buffer_most": b.most, "buffer_capacity": b.capacity}  # fmt: skip


def _close_quietly(container: Any) -> None:
    try:
        container.close()
    except Exception:  # noqa: BLE001 (closing a broken connection)
        pass


def open_live(
    url: str,
    *,
    idle_timeout: float = 5.0,
    retries: int = 3,
    buffer: int = 2,
    every: int | str = 1,
    open_timeout: float = 10.0,
    prog: str = "mvracklay run",
) -> LiveSource:
    """Open a live source and decode its first frame (its size); one `InputError` line when it cannot be opened or
    gives no frame within ``open_timeout`` seconds. The reader thread starts with the first frame asked for."""
    import av

    if not (isinstance(idle_timeout, (int, float)) and idle_timeout > 0):
        raise InputError(f"--idle-timeout must be > 0 seconds, got {idle_timeout!r}")
    if not isinstance(retries, int) or retries < 0:
        raise InputError(f"--retries must be an integer >= 0, got {retries!r}")
    auto = every == "auto"
    if not auto and (not isinstance(every, int) or isinstance(every, bool) or every < 1):
        raise InputError(f"--every must be an integer >= 1 or auto, got {every!r}")
    frames = LatestFrames(buffer)
    container = _open_container(url, open_timeout, idle_timeout)
    try:
        first = next(container.decode(container.streams.video[0]), None)
    except av.ExitError:  # the read timeout passed before the first frame
        _close_quietly(container)
        raise InputError(f"{shown(url)}: no frame within {idle_timeout:g} s of opening") from None
    except av.FFmpegError as e:
        _close_quietly(container)
        raise InputError(f"{shown(url)}: no frame decoded ({type(e).__name__})") from None
    if first is None:
        _close_quietly(container)
        raise InputError(f"{shown(url)}: the stream gave no frame")
    name = shown(url)
    src = LiveSource("live", Path(name), int(first.width), int(first.height), None, prog=prog, url=name, target=url,
                     idle_timeout=float(idle_timeout), retries=retries, every=every, buffer=frames,
                     spacing=Spacing() if auto else None)  # fmt: skip
    src._container = container
    src._decoded = 1
    src._first = src._arrival(first)
    return src


@dataclass
class _IteratorLive(LiveSource):
    """A live source fed by a Python iterator (frames as they arrive: a camera SDK's callback, a queue)."""

    frames_in: Iterator[Any] | None = field(default=None, repr=False)
    reader_times_out: ClassVar[bool] = False  #: an iterator has no read timeout: quiet is ``idle_timeout`` here

    def _read(self) -> None:
        from mvracklay.frames import _rgb_array

        if self._first is not None:
            self.buffer.put(self._first)
            self._first = None
        try:
            for a in self.frames_in or ():
                if self._stop.is_set():
                    break
                self._decoded += 1
                if isinstance(self.every, int) and (self._decoded - 1) % self.every:
                    continue
                try:
                    rgb = _rgb_array(a, self._decoded - 1, (self.width, self.height))
                except InputError as e:
                    self.stop(str(e))
                    break
                self.buffer.put(Arrival(rgb, time.monotonic(), None, self._decoded - 1))
            else:
                self.ended = self.ended or "stream ended"
        finally:
            self.buffer.close()


def iter_live(
    frames: Any, *, intrinsics: Any = None, idle_timeout: float = 5.0, buffer: int = 2, every: int | str = 1
) -> LiveSource:
    """A live source reading ``frames`` (an iterable of uint8 RGB ``(H, W, 3)`` arrays, yielded as they arrive) in a
    thread; its first frame is read here (the size)."""
    from mvracklay.frames import first_frame

    if not (isinstance(idle_timeout, (int, float)) and idle_timeout > 0):
        raise InputError(f"idle_timeout must be > 0 seconds, got {idle_timeout!r}")
    if every != "auto" and (not isinstance(every, int) or isinstance(every, bool) or every < 1):
        raise InputError(f"every must be an integer >= 1 or auto, got {every!r}")
    rgb, it, intrinsics = first_frame(frames, intrinsics)
    h, w = rgb.shape[:2]
    src = _IteratorLive("live", Path("<frames>"), w, h, None, intrinsics=intrinsics, prog="mvracklay.reconstruct_live",
                        url="<frames>", idle_timeout=float(idle_timeout), every=every, buffer=LatestFrames(buffer),
                        spacing=Spacing() if every == "auto" else None, frames_in=it)  # fmt: skip
    src._decoded = 1
    src._first = Arrival(rgb, time.monotonic(), None)
    return src

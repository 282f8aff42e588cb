"""Live sources for `mvracklay run`: a UDP stream mapped as it arrives, frames dropped when the network falls
behind (the buffer bounded, the drops counted), a bad URL in one line, SIGTERM and a quiet stream saving the map."""

from __future__ import annotations

import os
import signal
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from layouts.errors import InputError
from mvracklay.cli import main
from mvracklay.live_source import LatestFrames, Spacing, is_live, shown
from stitching.rerun_log import read_entities
from stitching.warehouse_map import WarehouseMap

#: the same camera for both runs: no distance or angle read from the frames (the stream and the folder alike)
FIXED = ["--distance", "2.6", "--roll", "0", "--pitch", "0", "--yaw", "0", "--threads", "1", "--quiet"]


@pytest.fixture(scope="module")
def seq20(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One generated sequence of 20 frames at 128x128 (a couple of seconds)."""
    from waresynth.generate import DatasetSettings, generate_dataset

    out = tmp_path_factory.mktemp("live") / "data"
    generate_dataset(out, DatasetSettings(num_sequences=1, frames=20, image_size=(128, 128), seed=11, progress=False))
    return out / "seq_00000"


def _frames(seq: Path) -> list[np.ndarray]:
    from waresynth.imageio import read_png

    return [read_png(p, np.uint8, 3) for p in sorted((seq / "rgb").glob("*.png"))]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _udp_bound(port: int) -> bool:
    """Whether a socket of this machine is bound to UDP ``port`` (Linux: /proc/net/udp, udp6)."""
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with open(table) as f:
            if any(line.split()[1].endswith(f":{port:04X}") for line in list(f)[1:]):
                return True
    return False


def _send_udp(frames: list[np.ndarray], url: str, fps: float, sent: list[int]) -> None:
    """Stream ``frames`` as MPEG-TS (intra-only MPEG-2 at a high rate: near lossless) in real time, once the
    receiver's socket is bound (nothing sent into the void); counts the frames sent in ``sent``."""
    import av

    port = int(url.rsplit(":", 1)[1])
    end = time.monotonic() + 60
    while not _udp_bound(port) and time.monotonic() < end:
        time.sleep(0.02)
    out = av.open(url + "?pkt_size=1316", "w", format="mpegts")
    stream = out.add_stream("mpeg2video", rate=int(fps))
    stream.width, stream.height, stream.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
    stream.bit_rate, stream.gop_size = 8_000_000, 1
    stream.codec_context.max_b_frames = 0
    t0 = time.monotonic()
    for i, rgb in enumerate(frames):
        frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
        frame.pts = i
        for packet in stream.encode(frame):
            out.mux(packet)
        sent.append(i)
        time.sleep(max(0.0, t0 + (i + 1) / fps - time.monotonic()))
    for packet in stream.encode():
        out.mux(packet)
    out.close()


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # a live run's .rrd: no footer, by design
def test_a_udp_stream_is_mapped_as_the_folder_is_and_ends_when_quiet(
    seq20, tiny_checkpoint, tmp_path, monkeypatch, capsys
):
    """The live map of a UDP stream is the map of a folder of exactly the frames it received and decoded (saved as
    they were mapped); every frame sent is received or lost, and the count says which."""
    import mvracklay.live_source as live_source
    from waresynth.imageio import write_png

    mapped: list[np.ndarray] = []
    given = live_source.LiveSource._raw_frames

    def keep(self, max_frames):  # the frames the live run maps, as decoded
        for rgb in given(self, max_frames):
            mapped.append(rgb.copy())
            yield rgb

    monkeypatch.setattr(live_source.LiveSource, "_raw_frames", keep)
    url, sent = f"udp://127.0.0.1:{_free_udp_port()}", []
    sender = threading.Thread(target=_send_udp, args=(_frames(seq20), url, 10.0, sent), daemon=True)
    sender.start()
    out = tmp_path / "live"
    with socket.socket() as s:  # a free TCP port for the recording's server
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = ["run", url, "--out", str(out), "--checkpoint", str(tiny_checkpoint), *FIXED, "--serve", str(port)]
    # a buffer holding the whole stream: nothing dropped however slow this machine, so every frame decoded is mapped
    assert main([*argv, "--idle-timeout", "2", "--live-buffer", "20"]) == 0
    sender.join(10)
    text = capsys.readouterr().out
    received, lost = len(mapped), len(sent) - len(mapped)
    assert len(sent) == 20 and received + lost == len(sent) and received > 0, f"sent {len(sent)}, lost {lost}"
    print(f"{len(sent)} frames sent: {received} received and decoded, {lost} lost")
    wmap = WarehouseMap.load(out / "warehouse.json")
    assert {p.name for p in out.iterdir()} >= {"warehouse.json", "warehouse.glb", "warehouse.rrd", "layouts"}
    assert wmap.meta["input"] == url and wmap.meta["input_kind"] == "live"
    assert wmap.meta["frames"] == received and f"{received} frames received, {received} mapped, 0 dropped" in text
    assert "ended: quiet for 2 s" in text and "latency, frame received -> map updated: p50" in text
    assert f"serving the recording: rerun --connect rerun+http://{socket.gethostname()}:{port}/proxy" in text
    from rerun.chunk import RrdReader

    reader = RrdReader(str(out / "warehouse.rrd"))  # the file written beside the server: whole, with the blueprint
    assert len(reader.blueprints()) == 1 and "/world/camera/path" in read_entities(out / "warehouse.rrd")

    folder = tmp_path / "decoded"
    folder.mkdir()
    for i, rgb in enumerate(mapped):
        write_png(folder / f"{i:06d}.png", rgb)
    ref = tmp_path / "ref"
    assert main(["run", str(folder), "--out", str(ref), "--checkpoint", str(tiny_checkpoint), *FIXED]) == 0
    ref_map = WarehouseMap.load(ref / "warehouse.json")
    assert ref_map.meta["frames"] == received
    assert wmap.boxes() == ref_map.boxes()


def test_a_source_faster_than_the_model_drops_frames_within_the_bound(tiny_checkpoint):
    import mvracklay

    frames = [np.full((96, 128, 3), 40 + i, np.uint8) for i in range(40)]
    produced = 0
    ahead = threading.Condition()

    def camera():  # yields as fast as it is read
        nonlocal produced
        for rgb in frames:
            with ahead:
                produced += 1
                ahead.notify_all()
            yield rgb

    def slow_network(update):  # the map is updated only once the camera is 6 frames further
        with ahead:
            ahead.wait_for(lambda: produced >= min(len(frames), update.index + 7), timeout=10)

    res = mvracklay.reconstruct_live(camera(), checkpoint=tiny_checkpoint, distance=2.6, roll=0.0, pitch=0.0,
                                     yaw=0.0, threads=1, buffer=2, on_update=slow_network)  # fmt: skip
    rep = res.report
    assert rep.buffer_capacity == 2 and rep.buffer_most <= 2
    assert rep.dropped > 0 and rep.received == 40 and rep.mapped + rep.dropped == rep.received
    assert res.run.frames == rep.mapped and 0 < rep.dropped_share < 1


def test_the_buffer_never_holds_more_than_its_bound():
    from mvracklay.live_source import Arrival

    buf = LatestFrames(3)
    for i in range(10):
        buf.put(Arrival(np.zeros((1, 1, 3), np.uint8), float(i), None))
    assert (buf.received, buf.dropped, buf.most) == (10, 7, 3)
    stop = threading.Event()
    assert len(buf) == 3
    assert [buf.get(0.01, stop).received for _ in range(3)] == [7.0, 8.0, 9.0]  # the newest kept, oldest first
    assert buf.get(0.01, stop) is None and len(buf) == 0  # nothing waits: the predictor does not read ahead
    with pytest.raises(InputError, match="--live-buffer"):
        LatestFrames(0)


def test_every_auto_keeps_frames_a_few_cm_apart():
    sp = Spacing(spacing=0.06, max_gap=1.0)
    assert sp.keep(0.0) and sp.keep(0.1)  # no speed read yet: every frame
    sp.moved(0.03, 0.1)  # 0.3 m/s: 6 cm take 0.2 s
    kept = [t for t in np.arange(0.2, 1.2, 0.1).round(2) if sp.keep(float(t))]
    assert kept == [0.3, 0.5, 0.7, 0.9, 1.1] and sp.skipped == 5
    sp.moved(0.0, 0.2)
    sp.moved(0.0, 0.2)  # the camera stopped: still a frame a second, so its motion is read again
    assert not sp.keep(1.5) and sp.keep(2.1)


def test_live_inputs_are_told_from_files(tmp_path):
    for live in ("rtsp://cam/1", "UDP://127.0.0.1:5000", "srt://h:1", "https://h/x.m3u8", "/dev/video0", "0"):
        assert is_live(live), live
    (tmp_path / "3").mkdir()
    for not_live in ("walk.mp4", "file:///x.mp4", "/dev/sda", "frames/", str(tmp_path / "3")):
        assert not is_live(not_live), not_live
    assert shown("rtsp://admin:secret@10.0.0.5/live") == "rtsp://10.0.0.5/live"


def _ts(values: list[int], start: int) -> bytes:
    """MPEG-TS bytes of flat 64x64 frames of ``values`` (pts from ``start``)."""
    import io

    import av

    buf = io.BytesIO()
    out = av.open(buf, "w", format="mpegts")
    stream = out.add_stream("mpeg2video", rate=10)
    stream.width = stream.height = 64
    stream.pix_fmt, stream.gop_size = "yuv420p", 1
    stream.codec_context.max_b_frames = 0
    for i, v in enumerate(values):
        frame = av.VideoFrame.from_ndarray(np.full((64, 64, 3), v, np.uint8), format="rgb24")
        frame.pts = start + i
        for packet in stream.encode(frame):
            out.mux(packet)
    for packet in stream.encode():
        out.mux(packet)
    out.close()
    return buf.getvalue()


def test_a_lost_connection_is_reopened_in_one_line(capsys):
    import struct

    from mvracklay.live_source import open_live

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(2)

    def serve():
        conn, _ = server.accept()
        conn.sendall(_ts([10, 20, 30, 40, 50], 0))
        time.sleep(0.8)
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        conn.close()  # a reset: the connection lost
        conn, _ = server.accept()
        data = _ts([100, 110, 120, 130, 140, 150], 5)
        for k in range(0, len(data), 1316):  # as a live stream sends
            conn.sendall(data[k : k + 1316])
            time.sleep(0.01)
        time.sleep(0.3)
        conn.close()  # the stream's end

    threading.Thread(target=serve, daemon=True).start()
    url = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    src = open_live(url, idle_timeout=3.0, retries=2)
    seen = [int(rgb[0, 0, 0]) for rgb in src.frames()]
    server.close()
    before, after = [v for v in seen if v < 90], [v for v in seen if v > 90]
    assert len(before) >= 3 and len(after) >= 5 and src.ended == "stream ended"
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"mvracklay run: warning: {url}: connection lost (ConnectionResetError), reconnecting (1/2)"]


def test_a_url_that_cannot_be_opened_is_one_line_and_status_2(tiny_checkpoint, tmp_path, capsys):
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"tcp://127.0.0.1:{port}"
    assert main(["run", url, "--out", str(tmp_path / "o"), "--checkpoint", str(tiny_checkpoint), *FIXED]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and url in err[0] and "cannot open the live source" in err[0]
    assert not (tmp_path / "o").exists()


def test_a_udp_source_that_never_sends_is_one_line_naming_the_wait():
    """A UDP port nobody sends to: one line, the source shown without its secret, the seconds waited."""
    from mvracklay.live_source import open_live

    port = _free_udp_port()
    with pytest.raises(InputError) as e:
        open_live(f"udp://127.0.0.1:{port}?token=abc", open_timeout=1.0, idle_timeout=1.0)
    assert str(e.value) == f"udp://127.0.0.1:{port}?token=***: no frame within 1 s"


def test_file_runs_refuse_the_live_options(seq20, tmp_path):
    base = ["run", str(seq20), "--out", str(tmp_path / "o"), "--quiet"]
    assert main([*base, "--serve"]) == 2
    assert main([*base, "--every", "auto"]) == 2


def _endless(frames: list[np.ndarray], stop: threading.Event, count: int | None = None):
    """A camera: the frames over and over, 20 a second (``count`` frames, then silent until ``stop``)."""
    for i in range(count or 10**6):
        if stop.is_set():
            return
        yield frames[i % len(frames)]
        time.sleep(0.05)
    stop.wait(30)


def test_sigterm_and_a_quiet_stream_save_the_map(seq20, tiny_checkpoint, tmp_path):
    import mvracklay

    frames, stop = _frames(seq20), threading.Event()
    kw = dict(checkpoint=tiny_checkpoint, distance=2.6, roll=0.0, pitch=0.0, yaw=0.0, threads=1)

    def term_at_4(update):
        if update.index == 3:
            os.kill(os.getpid(), signal.SIGTERM)  # handled: the stream ends, the map is saved

    before = signal.getsignal(signal.SIGTERM)
    try:
        res = mvracklay.reconstruct_live(_endless(frames, stop), out=tmp_path / "term", on_update=term_at_4, **kw)
        assert res.report.ended == "SIGTERM" and res.run.frames >= 4
        assert WarehouseMap.load(tmp_path / "term" / "warehouse.json").meta["frames"] == res.run.frames
        assert (tmp_path / "term" / "warehouse.glb").is_file() and (tmp_path / "term" / "warehouse.rrd").is_file()
        assert signal.getsignal(signal.SIGTERM) == before  # the handler put back

        updates = mvracklay.live_updates(
            _endless(frames, stop, count=6), out=tmp_path / "quiet", idle_timeout=0.5, **kw
        )
        seen = [u.index for u in updates]
        assert seen == list(range(len(seen))) and len(seen) == updates.result.run.frames
        assert updates.result.report.ended == "quiet for 0.5 s"
        assert WarehouseMap.load(tmp_path / "quiet" / "warehouse.json").meta["frames"] == len(seen)
    finally:
        stop.set()


def test_eval_reconstruction_scores_a_live_map_by_the_frames_it_mapped(seq20, tiny_checkpoint, tmp_path, capsys):
    """A live run's warehouse.json says which frames of the stream it mapped (every 2nd here, the buffer holding the
    whole stream: none dropped), and ``eval-reconstruction --map`` scores it against those frames' records."""
    import json

    import mvracklay
    from mvracklay.reconstruction_eval import open_sequences

    kw = dict(checkpoint=tiny_checkpoint, distance=2.6, roll=0.0, pitch=0.0, yaw=0.0, threads=1)
    res = mvracklay.reconstruct_live(iter(_frames(seq20)), out=tmp_path / "live", every=2, buffer=20, **kw)
    wmap = WarehouseMap.load(tmp_path / "live" / "warehouse.json")
    assert res.run.frames == 10 and wmap.meta["input_frames"] == list(range(0, 20, 2))
    capsys.readouterr()
    args = ["eval-reconstruction", str(seq20), "--map", str(tmp_path / "live" / "warehouse.json"), "--json", "--quiet"]
    assert main(args) == 0
    scored = json.loads(capsys.readouterr().out)["sequences"][seq20.name]
    seq = open_sequences(seq20)[0]
    walked = seq.frame(18)["camera_position"][0] - seq.frame(0)["camera_position"][0]
    assert scored["drift_end"] == pytest.approx(abs(wmap.steps[-1].offset - walked))  # its last frame: the 19th

    wmap.meta["input_frames"] = [25] * 10  # numbers the sequence does not have: one line
    wmap.save(tmp_path / "bad.json")
    assert main(["eval-reconstruction", str(seq20), "--map", str(tmp_path / "bad.json"), "--quiet"]) == 2
    assert "--map: its input_frames are not 10 frame numbers of a 20-frame sequence" in capsys.readouterr().err


def test_viewer_sinks_serve_and_spawn_without_a_gui(monkeypatch):
    import rerun as rr

    from mvracklay.live import viewer_sinks

    port = _free_udp_port()
    sinks, said = viewer_sinks(False, port)
    assert len(sinks) == 1 and isinstance(sinks[0], rr.GrpcServerSink) and f":{port}/proxy" in sinks[0].uri
    assert said == [f"serving the recording: rerun --connect rerun+http://{socket.gethostname()}:{port}/proxy"]
    del sinks
    spawned = []
    monkeypatch.setattr(rr, "spawn", lambda **kw: spawned.append(kw))
    sinks, said = viewer_sinks(True, None)
    assert spawned == [{"port": 9876, "connect": False}] and len(sinks) == 1 and not said
    assert isinstance(sinks[0], rr.GrpcSink)


def test_the_motion_read_sets_the_spacing_of_every_auto():
    from types import SimpleNamespace

    from mvracklay.live import LiveRun
    from mvracklay.live_source import iter_live

    src = iter_live(iter([np.zeros((8, 8, 3), np.uint8)]), every="auto")
    src.arrivals.update({0: (5.0, 0.0), 1: (5.1, 0.2)})  # received, stream time: 0.2 s apart in the stream
    run = LiveRun(src)
    for i, step in enumerate((0.0, 0.05)):
        run.mapped(SimpleNamespace(index=i, prediction=SimpleNamespace(camera_step=step)), None)
    assert src.spacing.speed == pytest.approx(0.25) and not src.arrivals  # 5 cm in 0.2 s; arrivals forgotten
    assert len(run.latencies) == 2


def test_the_live_options_in_a_config_file(seq20, tmp_path, capsys):
    import json

    cfg = tmp_path / "live.json"
    cfg.write_text(json.dumps({"idle-timeout": -1}))
    base = ["run", str(seq20), "--out", str(tmp_path / "o"), "--quiet", "--config", str(cfg)]
    assert main(base) == 2 and "idle-timeout" in capsys.readouterr().err
    cfg.write_text(json.dumps({"every": "auto", "idle-timeout": 2, "live-buffer": 4, "retries": 1}))
    assert main(base) == 2  # taken by the file, refused for a file run in one line
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--every auto keeps a live stream's frames a few cm apart" in err[0]


def test_leaving_the_updates_loop_early_stops_the_run(seq20, tiny_checkpoint, tmp_path):
    import mvracklay

    frames, stop = _frames(seq20), threading.Event()
    kw = dict(checkpoint=tiny_checkpoint, distance=2.6, roll=0.0, pitch=0.0, yaw=0.0, threads=1)
    try:
        for update in mvracklay.live_updates(_endless(frames, stop), out=tmp_path / "left", **kw):
            if update.index == 2:
                break
        (worker,) = [t for t in threading.enumerate() if t.name == "live-updates"] or [None]
        if worker is not None:
            worker.join(20)
        assert worker is None or not worker.is_alive()
        assert not (tmp_path / "left").exists()  # abandoned: nothing published
    finally:
        stop.set()


def test_a_long_live_walk_keeps_what_it_holds_bounded_by_the_map(seq20, tiny_checkpoint, tmp_path, monkeypatch):
    """A camera walking the row back and forth, fed from Python with the recording on: what a live run keeps per
    frame stays bounded by the map, not by the frames (the bounds set small, so they are reached here): box-colour
    samples (the newest per place), camera steps (the last ones; the totals over all), the recording's camera path
    (thinned) and the arrivals (forgotten once mapped)."""
    import mvracklay
    import mvracklay.live as live
    import mvracklay.pipeline as pipeline
    import mvracklay.recording as recording
    import stitching.box_colours as box_colours

    per_place, compact, points, steps = 2, 16, 8, 10
    monkeypatch.setattr(pipeline, "LIVE_KEEP_STEPS", steps)
    monkeypatch.setattr(pipeline, "LIVE_COLOUR_SAMPLES", per_place)
    monkeypatch.setattr(box_colours, "COMPACT_ROWS", compact)
    monkeypatch.setattr(recording, "PATH_POINTS", points)
    made: dict[str, object] = {}

    class Colours(box_colours.BoxColours):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made["colours"], self.taken = self, 0

        def add(self, *a, **k):
            got = super().add(*a, **k)
            self.taken += got
            return got

    class Recording(recording.RunRecording):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made["recording"] = self

    class Run(live.LiveRun):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made["source"] = self.source

    monkeypatch.setattr(pipeline, "BoxColours", Colours)
    monkeypatch.setattr(pipeline, "RunRecording", Recording)
    monkeypatch.setattr(live, "LiveRun", Run)
    walk = _frames(seq20)
    walk += walk[::-1]
    n, mapped, held, cond = 100, 0, [], threading.Condition()

    def camera():  # the next frame once the map has caught up: none dropped
        for i in range(n):
            with cond:
                cond.wait_for(lambda i=i: mapped >= i - 1, timeout=20)
            yield walk[i % len(walk)]

    def update(u):
        nonlocal mapped
        with cond:
            mapped += 1
            cond.notify_all()
        c = made["colours"]
        rows = c.samples()
        places = len({(r[0], np.floor((r[1] + r[2]) / 0.5), np.floor(r[3] / 0.25)) for r in rows})
        held.append((len(rows), places, len(made["recording"].path), len(u.map.steps), len(made["source"].arrivals)))

    kw = dict(checkpoint=tiny_checkpoint, distance=2.6, roll=0.0, pitch=0.0, yaw=0.0, threads=1, idle_timeout=20.0)
    res = mvracklay.reconstruct_live(camera(), out=tmp_path / "walk", on_update=update, **kw)
    assert res.report.mapped == n and res.report.dropped == 0 and len(held) == n
    for rows, places, path, kept, waiting in held:
        assert rows < per_place * places + compact and path <= 2 * points + 1 and kept <= steps and waiting <= 2
    colours = made["colours"]
    assert colours.taken > len(colours.samples())  # the bound reached: more samples taken than kept
    assert not made["source"].arrivals
    kept = res.run.map.steps
    assert [s.frame for s in kept] == list(range(n - steps, n)) and res.run.map.meta["step_summary"]["frames"] == n
    assert "/world/camera/path" in read_entities(tmp_path / "walk" / "warehouse.rrd")  # without its footer: whole


def test_frames_a_stream_s_reader_flushes_after_our_quiet_clock_are_still_mapped():
    """A stream's reader ends a quiet stream by its own read timeout and then flushes the decoder's last frames; its
    clock may start after ours, so those frames come after ``idle_timeout`` of quiet here: they are still given
    out (received = given), not counted received and never mapped. A reader that stays quiet longer still ends."""
    from mvracklay.live_source import Arrival, LiveSource

    def frame(i: int) -> Arrival:
        return Arrival(np.full((4, 4, 3), i, np.uint8), time.monotonic(), None)

    class Late(LiveSource):
        pause = 0.45  # longer than idle_timeout (0.3 s), shorter than twice it

        def _read(self) -> None:
            for i in range(3):
                self.buffer.put(frame(i))
            time.sleep(self.pause)  # the reader's read timeout runs out later than ours
            for i in range(3, 5):  # the decoder's last frames, flushed
                self.buffer.put(frame(i))
            self.ended = f"quiet for {self.idle_timeout:g} s"
            self.buffer.close()

    src = Late("live", Path("<late>"), 4, 4, None, idle_timeout=0.3, buffer=LatestFrames(8))
    got = [int(f[0, 0, 0]) for f in src._raw_frames(None)]
    assert got == [0, 1, 2, 3, 4] and src.buffer.received == src.given == 5 and src.ended == "quiet for 0.3 s"

    class Gone(Late):
        pause = 1.5  # quiet longer than both clocks: the stream ends with what came

    src = Gone("live", Path("<gone>"), 4, 4, None, idle_timeout=0.3, buffer=LatestFrames(8))
    t0 = time.monotonic()
    assert [int(f[0, 0, 0]) for f in src._raw_frames(None)] == [0, 1, 2] and time.monotonic() - t0 < 1.2
    src.close()

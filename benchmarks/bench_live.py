"""Live runs: latency (frame received -> map updated, p50 / p95), frames mapped a second and the share dropped, for
the shipped 128x128 and 256x256 models on a generated sequence streamed over UDP (MPEG-TS, real time, looped back
and forth), and the process's memory (RSS) over a longer stream: it should stay flat.

Each case runs `mvracklay.api.reconstruct_live` on ``udp://127.0.0.1:PORT`` (PyAV decoding in the reader thread,
the bounded buffer, the network, the stitcher, the recording written to a temporary .rrd) while a thread of this
process encodes and sends the frames, so the sender shares the cores with the run. The distance (2.6 m) and a
level mount are given, so no frames are read ahead (`--read-angles` reads the angles, the first ten frames ahead).

    .venv/bin/python benchmarks/bench_live.py                       # 128 and 256, 10 s each; memory over 0.5 min
    .venv/bin/python benchmarks/bench_live.py --sizes 128 --fps 30 --seconds 20 --minutes 10
    .venv/bin/python benchmarks/bench_live.py --sizes 128 --codec h264 --mbps 2 --compare --minutes 0
    .venv/bin/python benchmarks/bench_live.py --sizes 256 --fps 25 --step 0.024 0.064 --frames 150 \
        --codec h264 --mbps 4 --compare --minutes 0           # 25 fps: a walk's frames closer together

--compare streams each sequence once (its frames in order, not played back and forth) and maps the same frames
from memory with the same settings, as filmed and through the stream's codec: what the compression costs, and
what the live run's lost frames cost on top. --codec h264 / h265 streams as a phone or a robot does
(`waresynth.stream_codec`: low latency, --mbps for a 1080p stream spent at the same bits per pixel).
"""

from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

MODELS = {128: "mvracklay-disc-4", 256: "mvracklay-disc-4-256"}


def rss_mb() -> float:
    """The process's resident memory now (MB; Linux /proc, else the peak)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def frames_of(size: int, count: int, seed: int, tmp: Path, step: tuple[float, float] | None = None) -> list[np.ndarray]:
    """A generated sequence's frames, then the same reversed (a walk along the row and back); ``step``: the camera's
    step between frames (metres, drawn per sequence; default the config's)."""
    from waresynth.generate import DatasetSettings, generate_dataset
    from waresynth.imageio import read_png

    config = {"camera": {"step": list(step)}} if step else None
    generate_dataset(tmp / f"s{size}", DatasetSettings(num_sequences=1, frames=count, image_size=(size, size), seed=seed, config=config, progress=False))  # fmt: skip
    fwd = [read_png(p, np.uint8, 3) for p in sorted((tmp / f"s{size}" / "seq_00000" / "rgb").glob("*.png"))]
    return fwd + fwd[::-1]


def send(
    frames: list[np.ndarray],
    url: str,
    fps: float,
    seconds: float,
    go: threading.Event,
    codec: str = "mpeg2",
    mbps: float = 4.0,
    once: bool = False,
) -> None:
    """Stream ``frames`` in a loop (``once``: each once) as MPEG-TS over UDP in real time for ``seconds``, once ``go`` is set: MPEG-2 at
    8 Mbit/s (near lossless at these sizes) or H.264 / H.265 at a phone's ``mbps`` (`waresynth.stream_codec`)."""
    import av

    from waresynth.stream_codec import CODECS, KEY_INTERVAL, encoder_options, stream_bit_rate

    go.wait(60)
    time.sleep(0.3)
    out = av.open(url + "?pkt_size=1316", "w", format="mpegts")
    height, width = frames[0].shape[:2]
    if codec == "mpeg2":
        stream = out.add_stream("mpeg2video", rate=int(round(fps)))
        stream.bit_rate, stream.gop_size = 8_000_000, 12
    else:
        encoder = CODECS[f"{codec}_stream"][0]
        stream = out.add_stream(encoder, rate=int(round(fps)), options=encoder_options(encoder))
        stream.bit_rate, stream.gop_size = stream_bit_rate(mbps, width, height), KEY_INTERVAL
    stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
    stream.codec_context.max_b_frames = 0
    t0, i = time.monotonic(), 0
    while (i < len(frames)) if once else (time.monotonic() - t0 < seconds):
        frame = av.VideoFrame.from_ndarray(frames[i % len(frames)], format="rgb24")
        frame.pts = i
        for packet in stream.encode(frame):
            out.mux(packet)
        i += 1
        time.sleep(max(0.0, t0 + i / fps - time.monotonic()))
    for packet in stream.encode():
        out.mux(packet)
    out.close()


def run_case(
    size: int, frames: list[np.ndarray], args: argparse.Namespace, seconds: float, tmp: Path, once: bool = False
) -> dict:
    """One live run on a UDP stream of ``frames`` for ``seconds``; its report and RSS samples."""
    import mvracklay.live_source as live_source
    from mvracklay.api import reconstruct_live

    url, go = f"udp://127.0.0.1:{free_port()}", threading.Event()
    angles = {} if args.read_angles else {"roll": 0.0, "pitch": 0.0, "yaw": 0.0}
    opener = live_source._open_container

    def opened(*a):  # the sender starts once the receiver opens
        go.set()
        return opener(*a)

    live_source._open_container = opened
    sender = threading.Thread(
        target=send, args=(frames, url, args.fps, seconds, go, args.codec, args.mbps, once), daemon=True
    )
    sender.start()
    samples: list[tuple[float, float]] = []
    done = threading.Event()

    def sample() -> None:
        t0 = time.monotonic()
        while not done.wait(max(1.0, seconds / 20)):
            samples.append((time.monotonic() - t0, rss_mb()))

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    t0 = time.monotonic()
    try:
        res = reconstruct_live(url, out=tmp / f"out{size}_{int(seconds)}", checkpoint=args.checkpoint or MODELS[size],
                               distance=2.6, threads=args.threads, idle_timeout=2.0, buffer=args.buffer,
                               every=args.every, rrd=not args.no_rrd, **angles)  # fmt: skip
    finally:
        live_source._open_container = opener
        done.set()
    wall = time.monotonic() - t0
    sender.join(5)
    return {"report": res.report, "wall": wall, "rss": samples, "boxes": len(res.run.map.boxes())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--sizes", type=int, nargs="*", default=[128, 256], choices=sorted(MODELS), help="none: the memory run only"
    )
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--fps", type=float, default=10.0, help="the stream's frame rate")
    p.add_argument("--seconds", type=float, default=10.0, help="stream length per size for the latency")
    p.add_argument("--minutes", type=float, default=0.5, help="stream length of the memory run (128; 0: none)")
    p.add_argument("--buffer", type=int, default=2, help="--live-buffer")
    p.add_argument("--every", default=1, type=lambda s: s if s == "auto" else int(s), help="N or auto")
    p.add_argument("--no-rrd", action="store_true", help="no recording (what memory the .rrd's logging takes)")
    p.add_argument("--read-angles", action="store_true", help="read roll / pitch / yaw (default: a level mount given)")
    p.add_argument("--frames", type=int, default=40, help="frames of the generated sequence (played back and forth)")
    p.add_argument("--codec", choices=["mpeg2", "h264", "h265"], default="mpeg2", help="the stream's codec")
    p.add_argument("--mbps", type=float, default=4.0, help="h264 / h265: a 1080p stream's Mbit/s (phones 2-8)")
    p.add_argument("--compare", action="store_true", help="the live map's boxes against the same frames' from memory")
    p.add_argument("--seeds", type=int, nargs="+", default=[202], help="--compare: the sequences (generated seeds)")
    p.add_argument(
        "--step",
        type=float,
        nargs=2,
        default=None,
        metavar=("LO", "HI"),
        help="the camera's step between frames in metres (default the config's 0.06-0.16, a 10 fps walk; "
        "a 25 fps stream of the same walk: 0.024 0.064)",
    )
    p.add_argument("--checkpoint", default=None, help="the model (default: the shipped one of each size)")
    args = p.parse_args()
    if args.compare:
        return compare(args)
    with tempfile.TemporaryDirectory(prefix="bench-live-") as t:
        tmp = Path(t)
        print(
            f"stream: UDP MPEG-TS at {args.fps:g} fps; {args.threads} threads; buffer {args.buffer}; every {args.every}"
        )
        print("size  seconds  received  mapped  dropped  skipped  mapped/s  latency p50   p95 ms  boxes")
        for size in args.sizes:
            frames = frames_of(size, args.frames, 202, tmp, args.step)
            r = run_case(size, frames, args, args.seconds, tmp)
            rep = r["report"]
            print(
                f"{size:4d}  {args.seconds:7.0f}  {rep.received:8d}  {rep.mapped:6d}  {100 * rep.dropped_share:6.1f}%  "
                f"{rep.skipped:7d}  {rep.mapped / args.seconds:8.1f}  {1000 * rep.latency_p50:11.0f}  "
                f"{1000 * rep.latency_p95:7.0f}  {r['boxes']:5d}"
            )  # fmt: skip
        if args.minutes > 0:
            frames = frames_of(128, args.frames, 202, tmp, args.step)
            r = run_case(128, frames, args, 60 * args.minutes, tmp)
            rss = r["rss"]
            print(f"memory over {args.minutes:g} min (128, {r['report'].mapped} frames mapped): RSS MB at "
                  + ", ".join(f"{t:.0f}s {m:.0f}" for t, m in rss))  # fmt: skip
            if len(rss) >= 4:
                q = len(rss) // 4
                first, last = np.median([m for _, m in rss[q : 2 * q]]), np.median([m for _, m in rss[-q:]])
                print(f"RSS second quarter {first:.0f} MB -> last quarter {last:.0f} MB ({last - first:+.0f} MB)")


def compare(args: argparse.Namespace) -> None:
    """Per size and sequence, the boxes of three maps of the same frames: from memory as filmed, from memory
    through the stream's codec (each frame encoded and decoded in order, `waresynth.stream_codec`: the codec's cost
    alone) and live from the UDP stream (the codec's cost and the frames lost: a stream joined between key frames
    decodes nothing until the next one)."""
    from mvracklay.api import reconstruct
    from waresynth.stream_codec import VideoStream

    print(f"stream: UDP MPEG-TS {args.codec}" + (f" at {args.mbps:g} Mbit/s (1080p)" if args.codec != "mpeg2" else "")
          + f", {args.fps:g} fps, played once; {args.threads} threads; buffer {args.buffer}")  # fmt: skip
    print("size  seed  frames  live mapped  boxes: filmed  through the codec  live   codec / filmed  live / filmed")
    angles = {} if args.read_angles else {"roll": 0.0, "pitch": 0.0, "yaw": 0.0}
    with tempfile.TemporaryDirectory(prefix="bench-live-") as t:
        tmp = Path(t)
        for size in args.sizes:
            ckpt = args.checkpoint or MODELS[size]
            sums = np.zeros(3, int)
            for seed in args.seeds:
                frames = frames_of(size, args.frames, seed, tmp / str(seed), args.step)[: args.frames]
                r = run_case(size, frames, args, len(frames) / args.fps, tmp, once=True)
                filmed = len(reconstruct(frames, distance=2.6, checkpoint=ckpt, threads=args.threads, **angles).boxes())
                codec = filmed
                if args.codec != "mpeg2":
                    stream = VideoStream(f"{args.codec}_stream", size, size, args.mbps)
                    sent = [stream.send(f) for f in frames]
                    codec = len(
                        reconstruct(sent, distance=2.6, checkpoint=ckpt, threads=args.threads, **angles).boxes()
                    )
                n = np.array([filmed, codec, r["boxes"]])
                sums += n
                print(f"{size:4d}  {seed:4d}  {len(frames):6d}  {r['report'].mapped:11d}  {n[0]:13d}  {n[1]:17d}  "
                      f"{n[2]:4d}  {n[1] / max(n[0], 1):14.2f}  {n[2] / max(n[0], 1):13.2f}")  # fmt: skip
            print(f"{size:4d}   all  {'':6s}  {'':11s}  {sums[0]:13d}  {sums[1]:17d}  {sums[2]:4d}  "
                  f"{sums[1] / max(sums[0], 1):14.2f}  {sums[2] / max(sums[0], 1):13.2f}")  # fmt: skip


if __name__ == "__main__":
    main()

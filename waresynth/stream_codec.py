"""A sequence's frames through a real video codec as a phone or a robot streams them: H.264 (libx264) or H.265
(libx265) at a drawn bit rate, encoded frame after frame with motion compensation and decoded again (PyAV).

`VideoStream` keeps one encoder and one decoder for a sequence: each frame goes in as the camera sends it
and comes back as a viewer of the live stream sees it, at once (low-latency settings: no B-frames, no
look-ahead), so the artefacts are a stream's: blocks and smeared detail where the bits run short, worst
on moving edges and after a key frame. The bit rate is given for a 1920x1080 stream at `FPS` and spent at
the same bits per pixel on the frame's own size. One thread each way, so the same frames give the same
bytes.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from layouts.errors import InputError

#: the codec names of `waresynth.look`'s ``compression`` and PyAV's encoder and decoder for each
CODECS = {"h264_stream": ("libx264", "h264"), "h265_stream": ("libx265", "hevc")}
#: the frame rate a sequence streams at (the live maps' 10 fps) and its key-frame interval in frames
FPS = 10
KEY_INTERVAL = 20
#: the frame the bit rate is given for
REFERENCE_PIXELS = 1920 * 1080


def stream_bit_rate(mbps: float, width: int, height: int) -> int:
    """Bits per second for a ``width`` x ``height`` stream spending what ``mbps`` Mbit/s spends on 1080p."""
    return max(1000, int(round(mbps * 1e6 * width * height / REFERENCE_PIXELS)))


def encoder_options(encoder: str) -> dict[str, str]:
    """A phone's or a robot's low-latency settings of ``encoder`` (libx264 / libx265): no B-frames, no look-ahead,
    a key frame every `KEY_INTERVAL` frames, one thread."""
    gop = f"keyint={KEY_INTERVAL}:min-keyint={KEY_INTERVAL}:scenecut=0"
    if encoder == "libx264":
        return {"preset": "veryfast", "tune": "zerolatency", "x264-params": f"threads=1:{gop}"}
    params = f"log-level=none:pools=none:frame-threads=1:lookahead-threads=0:{gop}"
    return {"preset": "veryfast", "tune": "zerolatency", "x265-params": params}


class VideoStream:
    """One sequence's encoder and decoder; `send` passes a frame through both."""

    def __init__(self, kind: str, width: int, height: int, mbps: float) -> None:
        import av

        encoder, decoder = CODECS[kind]
        if encoder not in av.codecs_available:
            raise InputError(f"config: sensor.compression {kind}: this PyAV's FFmpeg has no {encoder} encoder")
        self.enc = av.CodecContext.create(encoder, "w")
        self.enc.width, self.enc.height, self.enc.pix_fmt = width, height, "yuv420p"
        self.enc.time_base, self.enc.framerate = Fraction(1, FPS), Fraction(FPS, 1)
        self.enc.bit_rate = stream_bit_rate(mbps, width, height)
        self.enc.gop_size = KEY_INTERVAL
        self.enc.thread_count = 1
        self.enc.options = encoder_options(encoder)
        self.dec = av.CodecContext.create(decoder, "r")
        self.dec.thread_count = 1
        self.n = 0

    def send(self, rgb: np.ndarray) -> np.ndarray:
        """``rgb`` (H, W, 3 uint8) as it comes out of the stream (the same shape and type)."""
        import av

        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24").reformat(format="yuv420p")
        frame.pts = self.n
        self.n += 1
        decoded = [f for packet in self.enc.encode(frame) for f in self.dec.decode(packet)]
        if len(decoded) != 1:  # the low-latency settings give one frame back per frame sent
            raise RuntimeError(f"{self.enc.name}: {len(decoded)} frames back for frame {self.n - 1}")
        return decoded[0].to_ndarray(format="rgb24")

"""What the stitcher records of its camera path beside the map: running totals over every step (`StepStats`),
and the frames whose place along the row was a guess (`UntrustedFrames`), both bounded in memory."""

from __future__ import annotations

from dataclasses import dataclass, field

from stitching.warehouse_map import StepRecord


@dataclass
class StepStats:
    """Running totals over every step record, kept whatever ``keep_steps`` is (a few numbers)."""

    frames: int = 0
    methods: dict[str, int] = field(default_factory=dict)  #: frames per registration method
    reversals: int = 0  #: direction changes between moving frames (+1 <-> -1)
    path_length: float = 0.0  #: sum of |shift|, metres
    offset_min: float = 0.0
    offset_max: float = 0.0
    confidence_min: float = 1.0
    confidence_mean: float = 0.0
    last_direction: int = 0

    def add(self, step: StepRecord) -> None:
        n = self.frames
        self.methods[step.method] = self.methods.get(step.method, 0) + 1
        if step.direction and self.last_direction and step.direction != self.last_direction:
            self.reversals += 1
        if step.direction:
            self.last_direction = step.direction
        self.path_length += abs(step.shift)
        self.offset_min = step.offset if n == 0 else min(self.offset_min, step.offset)
        self.offset_max = step.offset if n == 0 else max(self.offset_max, step.offset)
        self.confidence_min = min(self.confidence_min, step.confidence)
        self.confidence_mean = (self.confidence_mean * n + step.confidence) / (n + 1)
        self.frames = n + 1

    def to_dict(self) -> dict:
        return {
            "frames": self.frames,
            "methods": dict(sorted(self.methods.items())),
            "reversals": self.reversals,
            "path_length": round(self.path_length, 6),
            "offset_range": [round(self.offset_min, 6), round(self.offset_max, 6)],
            "confidence_min": round(self.confidence_min, 4),
            "confidence_mean": round(self.confidence_mean, 4),
        }


class UntrustedFrames:
    """The frames placed by a guess (`StepRecord.trusted` false): how many, the last ``keep`` of them (all
    when None), and the X intervals they saw, merged (bounded by the row, not by the frames)."""

    def __init__(self, keep: int | None = None) -> None:
        self.keep = keep
        self.count = 0
        self.frames: list[int] = []
        self.x: list[list[float]] = []

    def add(self, frame: int, lo: float, hi: float) -> None:
        self.count += 1
        self.frames.append(frame)
        if self.keep is not None and len(self.frames) > self.keep:
            del self.frames[: len(self.frames) - self.keep]
        for iv in self.x:
            if lo <= iv[1] and hi >= iv[0]:
                iv[0], iv[1] = min(iv[0], lo), max(iv[1], hi)
                return
        self.x.append([lo, hi])

    def share(self, x0: float, x1: float) -> float:
        """Fraction of ``[x0, x1]`` an untrusted frame saw (its place in the map is a guess)."""
        cover = sum(max(0.0, min(x1, b) - max(x0, a)) for a, b in self.x)
        return float(min(1.0, cover / max(x1 - x0, 1e-9)))

    def to_dict(self, shares: list[float]) -> dict:
        """The map's ``meta.registration``: the untrusted frames, the X they saw and, per rack, the share of it
        placed by them (its shelves' confidence is lowered by half that share)."""
        return {
            "trusted": not self.count,
            "untrusted_count": self.count,
            "untrusted_frames": list(self.frames),
            "untrusted_x": [[round(a, 6), round(b, 6)] for a, b in sorted(self.x)],
            "rack_untrusted_share": {f"rack_{k:02d}": round(v, 4) for k, v in enumerate(shares)},
        }

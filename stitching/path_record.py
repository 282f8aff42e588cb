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

    def to_dict(self, shares: list[float], left_out: int = 0) -> dict:
        """The map's ``meta.registration``: the untrusted frames, the X they saw and, per rack, the share of it
        placed by them (its shelves' confidence is lowered by half that share); ``left_out``: how many of them
        the map leaves out (no trusted frame followed them to place them by)."""
        return {
            "trusted": not self.count,
            "untrusted_count": self.count,
            "untrusted_left_out": left_out,
            "untrusted_frames": list(self.frames),
            "untrusted_x": [[round(a, 6), round(b, 6)] for a, b in sorted(self.x)],
            "rack_untrusted_share": {f"rack_{k:02d}": round(v, 4) for k, v in enumerate(shares)},
        }


def _frame_runs(frames: list[int]) -> str:
    """``[3, 4, 5, 9]`` -> ``"3-5, 9"`` (at most six runs, then how many more)."""
    runs: list[list[int]] = []
    for f in sorted(set(frames)):
        if runs and f == runs[-1][1] + 1:
            runs[-1][1] = f
        else:
            runs.append([f, f])
    text = [f"{a}-{b}" if b > a else f"{a}" for a, b in runs[:6]]
    if len(runs) > 6:
        text.append(f"and {len(runs) - 6} more stretches")
    return ", ".join(text)


def registration_warning(registration: dict | None, frames: int | None = None) -> str | None:
    """One line saying where the camera path is a guess (from a map's ``meta.registration``), else None: the
    frames, what became of their boxes and each rack's share seen only by them."""
    if not registration or not registration.get("untrusted_count"):
        return None
    n = int(registration["untrusted_count"])
    of = f" of {frames}" if frames else ""
    listed = registration.get("untrusted_frames") or []
    where = f" (frames {_frame_runs(listed)}{', the last ones kept' if len(listed) < n else ''})" if listed else ""
    left = int(registration.get("untrusted_left_out", 0))
    fate = (
        f"{left} of them left out of the map, the rest placed between the frames around them"
        if left
        else "their boxes placed between the frames around them"
    )
    shares = {k: v for k, v in (registration.get("rack_untrusted_share") or {}).items() if v >= 0.05}
    racks = "; " + ", ".join(f"{k} {v:.0%} seen only by them" for k, v in shares.items()) if shares else ""
    return (
        f"the camera's place along the row is a guess at {n}{of} frames{where}: no two estimates agreed; "
        f"{fate}{racks} (shelf confidences lowered; meta.registration in warehouse.json)"
    )

"""Levelling an askew camera: its roll (and pitch and yaw) carried over a sequence, given or read from the frames.

The network is trained on a level camera (the generator's camera never rolls), and a small roll
costs a lot: on the held-out 128x128 scenes, 2 degrees take 5.3 points of top rack mIoU and 7.2
of top box, 5 degrees 24 and 30 (docs/network.md, *A rotated camera*). Each frame's angles are read
by `network.inference.angle_reading` (`estimate_roll`; `estimate_tilt` for a pitch or a yaw, which
needs the intrinsics).

`CameraLeveller` carries the angles over a sequence: each frame is read after levelling it by the
angles so far (that levelling is the second reading's), and the readings are averaged with weights
decaying over ``tau`` frames, so a camera whose roll drifts slowly is followed and one frame with few
edges cannot tip it. A pitch or yaw is averaged over more frames than a roll, and read ahead over the
first frames (`CameraLeveller.prime`), since a yaw read wrong moves the levelled frame along the row.
`resolve_angles` picks each angle (given, recorded or read), `describe_angles` and `angle_warnings` say
what was read; `tilt_frame` and `turn_frame` turn a level frame for robustness checks.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

from layouts import Intrinsics
from layouts.canonical import FILL_RGB, MAX_ROLL_DEG, camera_rotation
from layouts.errors import InputError
from network.inference import angle_reading
from network.inference.angle_reading import MIN_STRUCTURE, SEARCH_DEG, TILT_SEARCH_DEG, perspective

#: a camera's rotation, in the order every (roll, pitch, yaw) triple takes
ANGLES = ("roll", "pitch", "yaw")
#: frames over which `CameraLeveller` averages its roll readings (weights exp(-frames ago / TAU))
TAU = 10.0
#: the same for pitch and yaw: a mount's, steadier than a roll and read less surely from one frame
TILT_TAU = 30.0
#: frames read before the first is levelled when a pitch or yaw is read (`CameraLeveller.prime`)
PRIME_FRAMES = 10
#: narrower frames read a pitch and a yaw unsurely (area-sampled held-out renders, level camera: the yaw
#: read 0.35 deg off on average at 128x128, a bias per scene, 0.07 at 256x256; docs/network.md)
SURE_READ_WIDTH = 256


def tilt_frame(rgb: np.ndarray, intr: Intrinsics, pitch_deg: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """``rgb`` (a level camera ``intr``'s) as the same camera tilted up ``pitch_deg`` / turned right ``yaw_deg`` shows it.

    A pure rotation, so one homography ``K R K^-1`` from the tilted camera's pixels to the level
    one's (``R = Ry(yaw) Rx(pitch)``, `layouts.canonical.camera_rotation`); the uncovered parts take the canonical fill colour. For
    robustness checks (`research/roll_robustness.py --axis`).
    """
    k = intr.matrix
    h = k @ camera_rotation(0.0, float(pitch_deg), float(yaw_deg)) @ np.linalg.inv(k)
    return np.asarray(perspective(Image.fromarray(np.ascontiguousarray(rgb)), h, FILL_RGB))


def turn_frame(rgb: np.ndarray, roll_deg: float, cx: float, cy: float) -> np.ndarray:
    """``rgb`` as a camera rolled ``roll_deg`` would show it: turned counter-clockwise about ``(cx, cy)``.

    The corners the turn uncovers take the canonical fill colour (a real camera would see more of
    the scene there). For robustness checks of the levelling (`research/roll_robustness.py`).
    """
    im = Image.fromarray(np.ascontiguousarray(rgb)).rotate(
        float(roll_deg), resample=Image.BILINEAR, center=(float(cx), float(cy)), fillcolor=FILL_RGB
    )
    return np.asarray(im)


def check_angle(angle: object, name: str = "roll") -> float | str | None:
    """A camera roll, pitch or yaw: None (the source's default, `resolve_angles`), ``"auto"`` (read from
    the frames) or a finite number of degrees within +-MAX_ROLL_DEG (as a float); else an InputError naming ``name``."""
    if angle is None or angle == "auto":
        return angle  # type: ignore[return-value]
    if isinstance(angle, str):
        try:
            angle = float(angle)
        except ValueError:
            raise InputError(f"{name} must be 'auto' or a number of degrees, got {angle!r}") from None
    if isinstance(angle, bool) or not isinstance(angle, (int, float, np.floating)):
        raise InputError(f"{name} must be 'auto' or a number of degrees, got {angle!r}")
    if not (math.isfinite(angle) and abs(angle) <= MAX_ROLL_DEG):
        raise InputError(f"{name} must be within +-{MAX_ROLL_DEG:g} degrees, got {angle!r}")
    return float(angle)


class CameraLeveller:
    """The camera's roll, pitch and yaw for each frame of a sequence, each known (degrees) or read (``"auto"``).

    ``angles(i, rgb, intr)`` returns frame ``i``'s (roll, pitch, yaw); each angle read from the
    frames is averaged over the readings so far with weights ``strength * exp(-frames ago / tau)``
    (``tilt_tau`` for pitch and yaw: a mount's angles, steadier than a roll and read less surely from
    one frame; each new frame read after levelling it by the angles so far). Asking again for the last frame
    returns its angles without reading it twice. A roll alone is read without the intrinsics
    (`estimate_roll`); a pitch or a yaw needs them (`estimate_tilt`). ``rolls`` / ``pitches`` /
    ``yaws`` list the angles given, frame by frame.
    """

    def __init__(
        self,
        roll: float | str = 0.0,
        pitch: float | str = 0.0,
        yaw: float | str = 0.0,
        tau: float = TAU,
        max_deg: float = SEARCH_DEG,
        tilt_tau: float = TILT_TAU,
    ) -> None:
        given = tuple(check_angle(a, n) for a, n in zip((roll, pitch, yaw), ANGLES))
        if None in given:
            raise InputError(f"(roll, pitch, yaw) must each be 'auto' or a number of degrees, got {given}")
        for name, t in (("tau", tau), ("tilt_tau", tilt_tau)):
            if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
                raise InputError(f"{name} must be a positive number of frames, got {t!r}")
        self.read = np.array([a == "auto" for a in given])  #: which of (roll, pitch, yaw) are read
        self.fixed = np.array([0.0 if a == "auto" else float(a) for a in given])
        self.decay = np.exp(-1.0 / np.array([tau, tilt_tau, tilt_tau], float))
        self.max_deg = max_deg
        self._sum = np.zeros(3)
        self._weight = np.zeros(3)
        self._last: tuple[int, tuple[float, float, float]] | None = None
        self.rolls: list[float] = []
        self.pitches: list[float] = []
        self.yaws: list[float] = []

    @property
    def current(self) -> np.ndarray:
        """(roll, pitch, yaw) so far (degrees; what is read is 0 before any reading)."""
        read = self.read & (self._weight > 0)
        return np.where(read, self._sum / np.where(read, self._weight, 1.0), self.fixed)

    def angles(self, i: int, rgb: np.ndarray, intr: Intrinsics | None = None) -> tuple[float, float, float]:
        if self._last is not None and self._last[0] == i:
            return self._last[1]
        if self.read.any():
            self._read(rgb, intr)
        r, p, y = (float(a) for a in self.current)
        self._last = (i, (r, p, y))
        self.rolls.append(r)
        self.pitches.append(p)
        self.yaws.append(y)
        return r, p, y

    def prime(self, frames: list[tuple[np.ndarray, Intrinsics | None]]) -> None:
        """Read the first frames ``[(rgb, intrinsics), ...]`` ahead, so the first is levelled by what they show.

        A yaw read wrong moves the levelled frame along the row, and a reading that changes from
        frame to frame moves it as a camera motion would; one frame's reading is the noisiest, so
        the start is read before it is levelled (on the held-out frames turned 3 degrees, ten frames
        ahead take the first five frames' yaw error from 0.98 to 0.43 degrees and halve the drift of
        the reading). The frames are read again when they come; nothing is recorded for them here.
        """
        for rgb, intr in frames:
            self._read(rgb, intr)
        self._last = None

    def _read(self, rgb: np.ndarray, intr: Intrinsics | None) -> None:
        """Fold one frame's reading into the running averages."""
        now = self.current
        if self.read[1:].any():
            if intr is None:
                raise InputError("reading a camera's pitch or yaw needs its intrinsics")
            reading, strength = angle_reading.estimate_tilt(rgb, intr, tuple(now), tuple(self.read), self.max_deg)
        else:
            roll, s = angle_reading.estimate_roll(rgb, self.max_deg, prior_deg=float(now[0]))
            s = s if s >= MIN_STRUCTURE else 0.0  # no structure, as `estimate_tilt` judges it: nothing read
            reading, strength = np.array([roll, 0.0, 0.0]), np.array([s, 0.0, 0.0])
        self._sum = np.where(self.read, self.decay * self._sum + strength * reading, 0.0)
        self._weight = np.where(self.read, self.decay * self._weight + strength, 0.0)

    def read_angles(self) -> dict[str, list[float]]:
        """The angles read from the frames, by name (``{"roll": [...]}``), frame by frame."""
        lists = (self.rolls, self.pitches, self.yaws)
        return {w: list(v) for w, v, r in zip(ANGLES, lists, self.read) if r}


def resolve_angles(
    roll: object, pitch: object, yaw: object, recorded: tuple[float, float, float] | None, prefix: str = "--"
) -> tuple[float | str, float | str, float | str]:
    """The (roll, pitch, yaw) to use: each as given, else the ``recorded`` one for a source whose camera
    rotation is known (a generated sequence's, `network.preprocess.sequence_angles`; 0 for a level camera), else
    ``"auto"`` (read from the frames). ``recorded`` None: footage, whose camera nothing records."""
    out = []
    for k, (name, angle) in enumerate(zip(ANGLES, (roll, pitch, yaw))):
        angle = check_angle(angle, prefix + name)
        out.append(angle if angle is not None else "auto" if recorded is None else float(recorded[k]))
    return out[0], out[1], out[2]


def describe_rolls(rolls: list[float], what: str = "roll") -> str:
    """One line on the angles (rolls by default) a `CameraLeveller` read, e.g. for a command's summary."""
    if not rolls:
        return f"camera {what}: no frames"
    r = np.asarray(rolls)
    return f"camera {what} read from the frames: {np.median(r):+.1f} deg (frames {r.min():+.1f} to {r.max():+.1f})"


def describe_angles(read: dict[str, list[float]]) -> list[str]:
    """One line per angle read from the frames (``{"roll": [...], ...}``, as `CameraLeveller.read_angles`)."""
    return [describe_rolls(v, w) for w, v in read.items()]


def roll_warning(rolls: list[float], max_deg: float = SEARCH_DEG, what: str = "roll") -> str:
    """A warning when the angles read reach the search's limit (the camera may be turned further); "" otherwise."""
    if rolls and max(abs(r) for r in rolls) >= max_deg - 0.05:
        return (
            f"the camera {what} read reaches the limit of the search (+-{max_deg:g} deg): the camera may be turned "
            f"further or the frames show few straight edges; pass --{what} DEG if you know it"
        )
    return ""


def angle_warnings(read: dict[str, list[float]], max_deg: float = SEARCH_DEG, width: int | None = None) -> list[str]:
    """`roll_warning` for each angle read (a pitch's and a yaw's limit is TILT_SEARCH_DEG), and, given the
    frames' ``width`` in pixels, a warning when a pitch or a yaw was read from frames under SURE_READ_WIDTH."""
    said = [roll_warning(v, max_deg if w == "roll" else TILT_SEARCH_DEG, w) for w, v in read.items()]
    tilt = [w for w in ("pitch", "yaw") if read.get(w)]
    if width is not None and width < SURE_READ_WIDTH and tilt:
        said.append(
            f"the camera {' and '.join(tilt)} were read from frames {width} px wide; under {SURE_READ_WIDTH} px "
            "such readings are unsure (128 px: ~0.35 deg of yaw, which moves the layouts along the row): "
            f"pass {' and '.join('--' + w + ' DEG' for w in tilt)} if the mount's angles are known"
        )
    return [w for w in said if w]

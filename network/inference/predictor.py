"""Inference: streaming (state carried frame to frame) and windowed (the paper's) modes.

Streaming runs the encoder once per frame and advances the ConvLSTM one step, so frame t sees
the whole prefix ``0..t``. Windowed mode reproduces training: frame t is predicted from the
window ``t-T+1..t`` (first frame repeated at the start) from a fresh ConvLSTM state. Encoder
features are cached across windows, so it also costs one encoder pass per frame; pass
``recompute=True`` for the naive form that re-encodes the whole window every frame.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from itertools import islice
from typing import Any

import numpy as np
import torch

from layouts import VIEWS, Intrinsics
from layouts.errors import InputError
from layouts.rackdepth import check_rack_depth
from network.heads.backedge import DepthReader
from network.heads.boxdepth import BoxDepthReader, ParallaxHistory, frame_head_inputs, front_reading, reading
from network.inference.decision import apply_box_offset
from network.inference.fusion import LayoutFusion, check_tau, fuse_sequence, seen_columns
from network.inference.overlap import always, overlapped
from network.inference.result import FramePrediction
from network.inference.roll import PRIME_FRAMES, CameraLeveller, check_angle
from network.model.decoders import board_peaks
from network.model.motion import StepReader, motion_signature
from network.model.net import MVRackLay, head_outputs
from network.preprocess import (
    DEFAULT_DISTANCE,
    canonical_image,
    frame_camera,
    image_intrinsics,
    sequence_angles,
    to_tensor,
)

MODES = ("stream", "window")
#: the per-frame maps the depth heads read, dropped from outputs held for ``whole_sequence``
HEAD_INPUTS = ("back", "uprights", "box_window", "box_parallax")
#: frame index -> (intrinsics or None for the default 60 deg camera, camera-to-rack distance in metres)
CameraFn = Callable[[int], tuple[Intrinsics | None, float]]
#: one frame's canonical image ``(1, 3, H, W)``, its shelf anchors ``(1, R)`` (None: the row head's), the camera's
#: step along the row since the frame before, ``(1,)`` metres, and the image's motion signature (None: the model
#: reads them where it needs them)
Inputs = tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None, torch.Tensor | None]


def fixed_camera(intrinsics: Intrinsics | None = None, distance: float = DEFAULT_DISTANCE) -> CameraFn:
    """The same camera and distance for every frame."""
    return lambda i: (intrinsics, distance)


class SequenceCamera:
    """A sequence's own intrinsics and per-frame distances (`network.preprocess.frame_camera`), called per
    frame like any `CameraFn`, and its recorded camera rotation ``angles`` (`network.preprocess.sequence_angles`),
    which a `Predictor` levels unless told otherwise."""

    def __init__(self, seq: Any, default_distance: float = DEFAULT_DISTANCE) -> None:
        self.seq = seq
        self.default_distance = default_distance
        self.angles = sequence_angles(seq)

    def __call__(self, i: int) -> tuple[Intrinsics | None, float]:
        return frame_camera(self.seq, i, self.default_distance)


def sequence_camera(seq: Any, default_distance: float = DEFAULT_DISTANCE) -> SequenceCamera:
    """A sequence's own intrinsics, per-frame distances and recorded rotation (`SequenceCamera`)."""
    return SequenceCamera(seq, default_distance)


class Predictor:
    """Wraps a model for frame-by-frame prediction from uint8 RGB images of any size and camera.

    Each frame is warped into the model's canonical view with ``camera(i)`` (intrinsics and the
    camera-to-rack distance), so layouts come out at their metric place for that camera.

    ``flip=True`` averages every frame's logits with those of the mirrored sequence (each
    canonical image flipped left-right, its own memory; the mirrored pass uses the direct pass's
    shelf anchors, so both fill the same slots), mirrored back: the test-time flip averaging of
    segmentation practice, at twice the compute. Averaging logits, not probabilities, keeps their
    scale, so the record's calibrated box offsets still apply (measured: the same offsets win).

    Rack depth: ``rack_depth`` (metres, known) is given to every frame; otherwise a model with a
    back-edge head reads it from the boards' back edges over the frames so far
    (`network.heads.backedge.DepthReader`), unless ``read_depth`` is False. Each output then carries
    ``"rack_depth"`` (metres, NaN while unknown), which `frame_layouts` imposes on the top view.

    Box depths: a model with a box-depth head reads each box's depth and carries what the frames
    have shown along the row (`network.heads.boxdepth.BoxDepthReader`, the camera's motion read from the
    images), unless ``read_depth`` is False. Each output then carries ``"box_back"`` ``(R, D)``
    (metres behind the rack front per model column, NaN where none is known), which `frame_layouts`
    imposes on every predicted box once the rack depth is known. A head that also reads parallax
    (`box_parallax` in the model config) gets each frame's plane-sweep maps, ``"box_parallax"`` in the
    output (`network.heads.boxdepth.ParallaxHistory`). (Fitting that head reads its inputs through
    `network.training.head_inputs.HeadInputPredictor`.)

    The camera's step along the row is read from the images once per frame (`network.model.motion.camera_motion`)
    and given to the memory, the parallax and the readers alike.

    ``whole_sequence``: the rack depth and the box depths come from every frame of the sequence, not
    only the frames so far: the frames are all read first, then each frame's outputs are given with
    the depth summed over the sequence and the box backs every frame showed (offline, for recorded
    footage: a frame also gains what later frames show; measured +0.2-1.4 top rack and +0.3-1.5 top
    box mIoU on the tuning and held-out sets, docs/network.md). The outputs are held until the
    sequence ends, without the intermediate maps the heads read (~0.3 MB per frame at D = 64).

    ``fuse_tau``: each frame's logits are averaged with its neighbours' (the frames so far; with
    ``whole_sequence`` the later ones too), shifted by the camera motion the images show and weighted by
    ``exp(-frames apart / fuse_tau)`` (`network.inference.fusion`); 0 (the default) leaves every frame alone. The depth heads
    read each frame's own outputs; the fused logits are what the frame's outputs then carry.

    ``roll``: the camera's roll about its optical axis (degrees, the image content turned
    counter-clockwise), levelled in the canonical warp: a number if known, ``"auto"`` to read it
    from the frames (`network.inference.roll.CameraLeveller`; ``self.leveller.rolls`` lists each frame's), None
    (the default) for the camera's recorded roll (a generated sequence's, `SequenceCamera`), else a
    level camera. ``pitch`` (optical axis tilted up > 0) and ``yaw`` (turned right > 0): the same;
    reading them (``"auto"``) needs the intrinsics.
    """

    def __init__(
        self,
        model: MVRackLay,
        camera: CameraFn | None = None,
        anchors: Callable[[int], np.ndarray] | None = None,
        flip: bool = False,
        rack_depth: float | None = None,
        read_depth: bool = True,
        whole_sequence: bool = False,
        fuse_tau: float = 0.0,
        roll: float | str | None = None,
        pitch: float | str | None = None,
        yaw: float | str | None = None,
    ) -> None:
        self.model = model.eval()
        self.cfg = model.cfg
        self.camera = camera or fixed_camera()
        self.anchors = anchors  #: frame index -> (R,) canonical board rows (NaN = no slot); None = the row head's
        self.flip = bool(flip)
        self.rack_depth = None if rack_depth is None else check_rack_depth(rack_depth, self.cfg.spec)
        #: the depth is read from the back edges (the model has the head, no depth is given, reading is on)
        self.reads_depth = (
            bool(read_depth) and rack_depth is None and (model.back is not None or model.uprights is not None)
        )
        self.reads_box_depth = bool(read_depth) and model.box_depth is not None
        #: each frame's parallax maps for the box-depth head are made (it reads them)
        self.box_parallax = self.reads_box_depth and self.cfg.box_parallax
        #: the frames before these skip the head's parallax maps, and the network (`stream` only): 0 here, set
        #: by `network.training.head_inputs.HeadInputPredictor`
        self.box_inputs_from = self.trunk_from = 0
        self.fuse_tau = check_tau(fuse_tau)
        self._tracks_motion = self.reads_box_depth or self.box_parallax or self.fuse_tau > 0
        memory = model.memory
        #: the model reads the camera's step (its aligned memory): streaming gives it `_inputs`' own
        self._model_motion = memory is not None and memory.view is not None
        self.whole_sequence = bool(whole_sequence)
        # an angle not given is the camera's recorded one (a generated sequence's, `SequenceCamera`), else 0
        recorded = getattr(self.camera, "angles", (0.0, 0.0, 0.0))
        roll, pitch, yaw = ((a if a is not None else r or None) for a, r in zip((roll, pitch, yaw), recorded))
        self.roll = check_angle(roll, "roll")  #: degrees, "auto" or None (level)
        self.pitch = check_angle(pitch, "pitch")  #: degrees the optical axis is tilted up, "auto" or None (level)
        self.yaw = check_angle(yaw, "yaw")  #: degrees the camera is turned right, "auto" or None (level)
        #: the camera's rotation, known or read from the frames (None: the camera is taken as level)
        turned = (self.roll or 0.0, self.pitch or 0.0, self.yaw or 0.0)
        self.leveller = CameraLeveller(*turned) if any(a != 0 for a in turned) else None
        #: the direct pass's camera steps (metres), motion signatures, canonical images and step confidences not yet used
        self._motion: deque[tuple[float, torch.Tensor, torch.Tensor, float]] = deque()
        self.device = next(model.parameters()).device  # frames go where the weights are (CPU or a GPU)
        #: whether the next frame is at hand (a live source sets its buffer's): a frame's readers then run beside the
        #: next frame's network pass (`network.inference.overlap`; never with one CPU thread)
        self.next_ready: Callable[[], bool] = always

    def _decide(self, res: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """One frame's outputs with the model's box-logit offsets applied (an empty one, a frame the
        network skipped, as it is)."""
        if not res:
            return res
        res = dict(res)
        for v in VIEWS:
            res[v] = apply_box_offset(res[v], self.model.box_logit_offset.get(v, 0.0))
        return res

    def _anchors(self, i: int) -> torch.Tensor | None:
        if self.anchors is None:
            return None
        return torch.as_tensor(np.asarray(self.anchors(i), np.float32), device=self.device)[None]

    def preprocess(self, rgb: np.ndarray, i: int = 0) -> torch.Tensor:
        intr, dist = self.camera(i)
        rgb = np.asarray(rgb)
        if self.leveller is None:
            img = canonical_image(rgb, self.cfg.view, intr, dist)
        else:
            angles = self.leveller.angles(i, rgb, image_intrinsics(intr, rgb.shape[1], rgb.shape[0]))
            img = canonical_image(rgb, self.cfg.view, intr, dist, *angles)
        return to_tensor(img)[None].to(self.device)

    def _primed(self, frames: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
        """``frames`` as they come; when a pitch or yaw is read, the leveller first reads the first few
        (`network.inference.roll.CameraLeveller.prime`), so the first frames are not levelled by a guess."""
        lev = self.leveller
        if lev is None or not lev.read[1:].any():
            yield from frames
            return
        it = iter(frames)
        head = [np.asarray(rgb) for rgb in islice(it, PRIME_FRAMES)]
        lev.prime(
            [(rgb, image_intrinsics(self.camera(i)[0], rgb.shape[1], rgb.shape[0])) for i, rgb in enumerate(head)]
        )
        yield from head
        yield from it

    def _inputs(self, frames: Iterable[np.ndarray], streaming: bool) -> Iterator[Inputs]:
        """Each frame's inputs (canonical image, anchors, the camera's step, the image's motion signature); the step
        and signature read once where the readers need them or, ``streaming``, the model."""
        steps = StepReader(self.cfg.view)
        for i, rgb in enumerate(self._primed(frames)):
            x = self.preprocess(rgb, i)
            step = sig = None
            if self._tracks_motion or (streaming and self._model_motion):
                sig = motion_signature(x)
                step, conf = steps(sig)
                if self._tracks_motion:
                    self._motion.append((float(step[0]), sig, x, float(conf[0])))
            yield x, self._anchors(i), step, sig

    def stream(self, frames: Iterable[np.ndarray]) -> Iterator[FramePrediction]:
        """Each frame's `FramePrediction` (logits with the box offset applied, slots, depths), carrying the memory;
        None for a frame the network skipped (``trunk_from``, `network.training.head_inputs.HeadInputPredictor`)."""
        return _typed(self._depths(self._decided(frames, self._stream, streaming=True)))

    def window(self, frames: Iterable[np.ndarray], recompute: bool = False) -> Iterator[FramePrediction]:
        """Each frame's `FramePrediction` from the window of ``seq_len`` frames ending there (fresh memory each)."""
        if self.trunk_from:
            raise InputError("trunk_from skips frames of a stream; the windowed mode runs every frame")
        return _typed(
            self._depths(self._decided(frames, lambda inputs: self._window(inputs, recompute), streaming=False))
        )

    def run(self, frames: Iterable[np.ndarray], mode: str = "stream") -> Iterator[FramePrediction]:
        """Each frame's `FramePrediction`, streaming or windowed (``mode``)."""
        if mode == "stream":
            return self.stream(frames)
        if mode == "window":
            return self.window(frames)
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")

    #: the same as `run` (what a caller of the model reads)
    predict = run

    def _depths(self, outs: Iterator[dict[str, torch.Tensor]]) -> Iterator[dict[str, torch.Tensor]]:
        """Each frame's outputs with ``"rack_depth"`` (0-d tensor, metres; NaN: none known or read yet) and,
        with the box-depth head, ``"box_back"``: from the frames so far, or (``whole_sequence``) from all;
        the logits fused with the neighbouring frames' (``fuse_tau``) once the heads have read them."""
        reader = (
            DepthReader(self.cfg.view, self.cfg.spec.z_extent, self.model.rack_depth_offset)
            if self.reads_depth
            else None
        )
        x_extent = self.cfg.spec.x_extent
        fusion = LayoutFusion(self.fuse_tau, x_extent) if self.fuse_tau > 0 and not self.whole_sequence else None
        steps: list[float] = []  # whole_sequence with fusion: each frame's camera step and columns seen
        seen: list[torch.Tensor] = []
        boxes = BoxDepthReader(self.cfg.spec) if self.reads_box_depth else None
        history = ParallaxHistory(self.cfg.view) if self.box_parallax else None
        self._motion.clear()
        held: list[tuple[dict[str, torch.Tensor], float, np.ndarray]] = []  # whole_sequence: (out, camera X, slots)

        def post(i: int, out: dict[str, torch.Tensor]) -> dict[str, torch.Tensor] | None:
            """Frame ``i``'s readers on its network outputs (on `overlapped`'s worker thread, beside frame i+1)."""
            depth = self.rack_depth
            if reader is not None:
                back, ups = out.get("back"), out.get("uprights")
                depth = reader.add(
                    None if back is None else torch.sigmoid(back.float()).cpu().numpy(),
                    board_peaks(torch.sigmoid(out["rows"].float()), self.cfg.view),
                    self.camera(i)[1],
                    None if ups is None else torch.sigmoid(ups.float()).cpu().numpy(),
                )
            if out:  # not a frame the network skipped (`trunk_from`)
                out["rack_depth"] = _depth_tensor(depth)
            if self._tracks_motion:
                step, sig, x, conf = self._motion.popleft()
                if out:  # the camera's step as the images read it, for a stitcher (`stitching.merge.MapBuilder`)
                    out["camera_step"] = torch.tensor(step, dtype=torch.float64)
                    out["camera_step_confidence"] = torch.tensor(conf, dtype=torch.float64)
                if history is not None and i < self.box_inputs_from:
                    history.keep(x, step)
                elif history is not None:
                    maps = history.add(x, step)
                    out["box_parallax"] = self.model.slots.window(maps.to(x.dtype), out["anchors"][None])[0]
                if boxes is not None:
                    self._read_boxes(out, boxes, i, step)
                if self.fuse_tau > 0:
                    cols = seen_columns(sig, out["top"].shape[-1]).to(out["top"].device)
                    if fusion is not None:
                        out.update(fusion.add({v: out[v] for v in VIEWS}, step, cols))
                    else:
                        steps.append(step)
                        seen.append(cols)
            if not self.whole_sequence:
                return out
            kept = {k: v for k, v in out.items() if k not in HEAD_INPUTS}
            held.append((kept, 0.0 if boxes is None else boxes.camera_x, torch.isfinite(out["anchors"]).cpu().numpy()))
            return None

        ahead = self.next_ready if torch.get_num_threads() > 1 else None
        for done in overlapped(post, enumerate(outs), ahead):
            if done is not None:
                yield done
        depth = self.rack_depth if reader is None else reader.depth
        if self.fuse_tau > 0 and held:
            fused = fuse_sequence([{v: o[v] for v in VIEWS} for o, _, _ in held], steps, seen, self.fuse_tau, x_extent)
            for (out, _, _), f in zip(held, fused):
                out.update(f)
        for out, camera_x, valid in held:
            out["rack_depth"] = _depth_tensor(depth)
            if boxes is not None:
                _put_box_depths(out, boxes, camera_x, valid)
            yield out

    @torch.no_grad()
    def _box_logits(self, out: dict[str, torch.Tensor], i: int) -> torch.Tensor:
        """The box-depth head's ``(R, K+1, D)`` logits on one frame's outputs (`network.heads.boxdepth`), run on the
        slots with an anchor only (about a third of the frames show fewer shelves than the slots): the rows of the
        others are zero, which no reader reads (`BoxDepthReader.add` takes the slots with an anchor)."""
        win, extra = frame_head_inputs(out, self.cfg.view, self.camera(i)[1])
        keep = torch.isfinite(out["anchors"]).nonzero()[:, 0].to(win.device)
        if len(keep) == len(win):
            return self.model.box_logits(win.to(self.device), extra.to(self.device))
        assert self.model.box_depth is not None
        logits = win.new_zeros((len(win), self.model.box_depth.out.out_channels, extra.shape[-1]))
        if len(keep):
            logits[keep] = self.model.box_logits(win[keep].to(self.device), extra[keep].to(self.device)).to(win.device)
        return logits

    def _read_boxes(self, out: dict[str, torch.Tensor], boxes: BoxDepthReader, i: int, step: float) -> None:
        """One frame's head reading added to ``boxes``, and its carried box depths put in ``out``."""
        logits = self._box_logits(out, i)
        valid = torch.isfinite(out["anchors"]).cpu().numpy()
        boxes.add(*reading(logits), valid, step, front_reading(logits))
        _put_box_depths(out, boxes, boxes.camera_x, valid)

    @torch.no_grad()
    def _decided(
        self,
        frames: Iterable[np.ndarray],
        raw: Callable[[Iterable[Inputs]], Iterator[dict[str, torch.Tensor]]],
        streaming: bool,
    ) -> Iterator[dict[str, torch.Tensor]]:
        """``raw`` (a mode's pass over (image, anchors) inputs) per frame, flip-averaged if asked, decided."""
        if not self.flip:
            for out in raw(self._inputs(frames, streaming)):
                yield self._decide(out)
            return
        mirrored: deque[Inputs] = deque()  # the mirrored pass's next input, queued once the direct pass is done

        def direct() -> Iterator[Inputs]:
            for x, a, step, sig in self._inputs(frames, streaming):
                mirrored.append((x.flip(-1), a, None, None))  # the mirrored pass reads its own motion
                yield x, a, step, sig

        def mirror() -> Iterator[Inputs]:
            while True:  # a pass takes one input per output: the queue never runs dry
                yield mirrored.popleft()

        passes = raw(mirror())
        for out in raw(direct()):
            x, a, _, _ = mirrored[-1]
            if a is None:  # the row head's: the direct pass's slots, so both passes fill the same shelves
                mirrored[-1] = (x, out["anchors"][None], None, None)
            back = next(passes)
            yield self._decide(
                {**out, **{v: 0.5 * (out[v] + back[v].flip(-1)) for v in VIEWS}}  # logits averaged, mirrored back
            )

    def _stream(self, inputs: Iterable[Inputs]) -> Iterator[dict[str, torch.Tensor]]:
        state = None
        for i, (x, a, step, sig) in enumerate(inputs):
            if i < self.trunk_from:
                yield {}
                continue
            out, state = self.model.step(x, state, a, None if state is None else step, signature=sig)
            yield {k: o[0] for k, o in out.items()}

    def _window(self, inputs: Iterable[Inputs], recompute: bool = False) -> Iterator[dict[str, torch.Tensor]]:
        m, t_len = self.model, self.cfg.seq_len
        images: deque[torch.Tensor] = deque(maxlen=t_len)
        anchors: deque[torch.Tensor | None] = deque(maxlen=t_len)
        cached: deque = deque(maxlen=t_len)
        for x, a, _, _ in inputs:  # each window's fresh memory reads its own steps
            if recompute:  # the naive form: the whole window through the model again
                if not images:
                    images.extend([x] * t_len)
                    anchors.extend([a] * t_len)
                images.append(x)
                anchors.append(a)
                given = None if a is None else torch.stack(list(anchors), 1)
                out = m(torch.stack(list(images), 1), given)
                yield {k: o[0, -1] for k, o in out.items()}
                continue
            feats, rows, anc = m.frame_features(x, a)  # per-frame work, shared by the windows it is in
            if not cached:
                cached.extend([feats] * t_len)
            cached.append(feats)
            out = m.decode_window(list(cached))[-1]
            out["rows"], out["anchors"] = rows, anc
            out.update(head_outputs(feats))
            yield {k: o[0] for k, o in out.items()}


def _typed(outs: Iterator[dict[str, torch.Tensor]]) -> Iterator[FramePrediction]:
    """Each frame's raw outputs as a `FramePrediction` (None for a frame the network skipped)."""
    for out in outs:
        yield FramePrediction.from_outputs(out) if out else None  # type: ignore[misc]


def rack_depth_source(model: MVRackLay) -> str:
    """How ``model`` reads the rack depth, in words (records and tables)."""
    cues = [name for name, head in (("uprights", model.uprights), ("back edges", model.back)) if head is not None]
    if not cues:
        return "as decoded"
    offset = f", {100 * model.rack_depth_offset:+.1f} cm calibrated" if model.rack_depth_offset else ""
    return "read from " + " and ".join(cues) + offset


def _depth_tensor(depth: float | None) -> torch.Tensor:
    """A rack depth as the outputs carry it: a 0-d float64 tensor, NaN while unknown."""
    return torch.tensor(float("nan") if depth is None else depth, dtype=torch.float64)


def _put_box_depths(out: dict[str, torch.Tensor], boxes: BoxDepthReader, camera_x: float, valid: np.ndarray) -> None:
    """``out["box_back"]`` ``(R, D)`` from the maps of ``boxes`` with the camera at ``camera_x`` and, for a head
    that reads fronts, ``out["box_front"]``."""
    out["box_back"] = torch.from_numpy(boxes.backs(camera_x, valid))
    fronts = boxes.fronts(camera_x, valid)
    if fronts is not None:
        out["box_front"] = torch.from_numpy(fronts)


def warm_up(model: MVRackLay, frames: int = 2) -> None:
    """Build what a stream of ``model`` builds on its first frames (`network.model.frozen`'s graphs of the trunk, the
    slot maps, the memory and the heads: ~0.8 s on 2 CPU threads at either size) from ``frames`` frames of noise
    through a throw-away `Predictor`, so a live stream's first frame does not wait on them while the frames behind
    it are dropped."""
    rng = np.random.default_rng(0)
    noise = [rng.integers(0, 256, (model.cfg.input_height, model.cfg.input_width, 3), np.uint8) for _ in range(frames)]
    with torch.no_grad():
        for _ in Predictor(model).stream(noise):
            pass


def predict_layouts(
    model: MVRackLay,
    frames: Iterable[np.ndarray],
    mode: str = "stream",
    size: int | None = None,
    camera: CameraFn | None = None,
    flip: bool = False,
) -> Iterator[dict[str, np.ndarray]]:
    """``{"top", "front"}`` uint8 ``(R, size, size)`` class ids per frame of uint8 RGB images (any size)."""
    spec = model.cfg.spec if size is None else replace(model.cfg.spec, size=size)
    for out in Predictor(model, camera, flip=flip).run(frames, mode):
        yield out.layouts(spec)

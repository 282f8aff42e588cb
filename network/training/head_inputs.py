"""A `Predictor` that gives the box-depth head's inputs to the fit (`network.training.fit_box_depth`).

Inference reads box depths with a fitted head; the fit needs the same per-frame inputs from a model whose head
is not fitted yet (so it does not read), and can skip work on the frames whose slots it does not keep. These
options belong to the fit, not to a user running a model, so they live here.
"""

from __future__ import annotations

from typing import Any

from layouts.errors import InputError
from network.inference.predictor import CameraFn, Predictor
from network.model.net import MVRackLay


class HeadInputPredictor(Predictor):
    """`Predictor` whose outputs carry the box-depth head's inputs whether or not the head reads (with
    ``box_parallax`` in the model config, each frame's plane-sweep maps, ``"box_parallax"``).

    ``box_inputs_from``: the maps of the frames before it are skipped (they still enter the parallax history):
    a fit that keeps none of their slots need not pay for their plane sweeps. ``trunk_from`` (streaming, not
    reading) goes further: the frames before it are not run through the network at all (their outputs are
    None), they only enter the motion estimate and the parallax history, and the memory starts at
    that frame. Other arguments: `Predictor`'s.
    """

    def __init__(
        self,
        model: MVRackLay,
        camera: CameraFn | None = None,
        *,
        box_inputs_from: int = 0,
        trunk_from: int = 0,
        **options: Any,
    ) -> None:
        super().__init__(model, camera, **options)
        self.box_parallax = self.cfg.box_parallax
        if not isinstance(box_inputs_from, int) or isinstance(box_inputs_from, bool) or box_inputs_from < 0:
            raise InputError(f"box_inputs_from must be a frame index >= 0, got {box_inputs_from!r}")
        if box_inputs_from and self.reads_box_depth:
            raise InputError(
                "box_inputs_from is for fitting the box-depth head: a reading head needs every frame's maps"
            )
        if not isinstance(trunk_from, int) or isinstance(trunk_from, bool) or not 0 <= trunk_from <= box_inputs_from:
            raise InputError(f"trunk_from must be a frame index from 0 to box_inputs_from, got {trunk_from!r}")
        if trunk_from and (self.flip or self.whole_sequence or self.fuse_tau or self.reads_depth):
            raise InputError(
                "trunk_from is for fitting the box-depth head: not with flip, whole_sequence, fuse_tau or a depth read"
            )
        self.box_inputs_from, self.trunk_from = box_inputs_from, trunk_from
        self._tracks_motion = self._tracks_motion or self.box_parallax

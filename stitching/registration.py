"""Registration: where a new frame sits along the row, estimated against the map built so far.

`Registration` is the half of `stitching.merge.MapBuilder` that places a frame (it changes nothing in the
map): the box edges and rack ends of the frame and of the map near the camera (`stitching.shift.Edges`), the
edge vote, the motion prior and what may overrule it (a second estimator reading the same step, strong votes
lining up on a new speed), and the fallbacks (the given motion, the layouts' correlation, the prior's step).
It reads the builder's state: ``spec``, ``dx``, ``shift_cfg``, ``prior``, ``frames``, ``ends``, the box and
rack-end indexes and the previous frame's offset, velocity and top layout.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from stitching.lift import FrameReconstruction
from stitching.shift import Edges, correlate_shift, vote_offset
from stitching.warehouse_map import StepRecord

RACK_SLOT = 1000  # slot code offset for rack-end edges, so they only pair with rack ends


class Registration:
    """Placing a frame along the row (a base of `stitching.merge.MapBuilder`, which holds the state it reads)."""

    def _frame_edges(self, rec: FrameReconstruction) -> Edges:
        rows = []
        for b in rec.boxes:
            w = math.nan if (b.cut_left or b.cut_right) else b.x1 - b.x0
            zc, d = (b.z0 + b.z1) / 2, b.z1 - b.z0
            if not b.cut_left:
                rows.append((b.slot, 0, b.x0, w, d, zc, b.height))
            if not b.cut_right:
                rows.append((b.slot, 1, b.x1, w, d, zc, b.height))
            if b.yaw != 0.0 and not (b.cut_left or b.cut_right):
                # A turned box's fitted centre is sub-pixel accurate (its slanted sides cross many columns).
                rows.append((b.slot, 2, b.cx, w, d, zc, b.height))
        return Edges.from_rows(rows)

    def _map_edges(self, lo: float, hi: float) -> Edges:
        rows = []
        for r in range(len(self.boxes)):
            for m in self._boxes_near(r, lo, hi):
                if m.x1 < lo or m.x0 > hi:
                    continue
                w = m.width if (m.nl and m.nr) else math.nan
                zc = (m.z0 + m.z1) / 2
                if m.nl:
                    rows.append((m.slot, 0, m.x0, w, m.depth, zc, m.h, m.nl))
                if m.nr:
                    rows.append((m.slot, 1, m.x1, w, m.depth, zc, m.h, m.nr))
                if m.n_full and abs(math.atan2(m.s4, m.c4)) > 1e-3:
                    rows.append((m.slot, 2, m.cx, w, m.depth, zc, m.h, m.n_full))
        return Edges.from_rows(rows)

    def _frame_rack_edges(self, rec: FrameReconstruction) -> Edges:
        rows = []
        for sh in rec.shelves:
            for x0, x1, cut_l, cut_r in sh.segments:
                if not cut_l:
                    rows.append((sh.slot + RACK_SLOT, 0, x0, math.nan, 0.0, 0.0, 0.0))
                if not cut_r:
                    rows.append((sh.slot + RACK_SLOT, 1, x1, math.nan, 0.0, 0.0, 0.0))
        return Edges.from_rows(rows)

    def _map_rack_edges(self, lo: float, hi: float) -> Edges:
        """Fused rack ends (shelf-run ends) between ``lo`` and ``hi``."""
        rows = []
        for i in self._end_index.query(lo, hi):
            slot, side, x, n = self.ends[i]
            if lo <= x <= hi:
                rows.append((slot + RACK_SLOT, side, x, math.nan, 0.0, 0.0, 0.0, n))
        return Edges.from_rows(rows)

    def register(
        self, rec: FrameReconstruction, top: np.ndarray | None, motion: float | None = None, motion_conf: float = 1.0
    ) -> StepRecord:
        """Estimate this frame's camera offset in the map (does not change the map).

        The box-edge vote is centred on the robust velocity of `MotionPrior` (median of the recent
        trusted steps). A vote outside the prior's gate is believed only when ``motion`` agrees with it
        or when ``relock`` strong votes in a row (``override_support`` edges, twice those of the best
        vote inside the gate) line up on a new speed (`MotionPrior.propose`);
        otherwise the gated vote, the correlation or ``motion`` stands, and with none of them the step
        is the prior's and marked untrusted. ``motion`` (metres, + = the camera moved to +X) is an
        independent estimate of the step (wheel odometry, or the images via `network.model.motion`):
        it replaces the correlation and velocity fallbacks (the layouts' edges are the better
        measurement wherever they agree, see docs/stitching.md), arbitrates a vote that breaks the
        prior, and lowers the confidence of a step it disagrees with. Where the two agree the offset is their
        blend, weighted by ``motion_conf`` (the images' confidence, [0, 1]) against the vote's and scaled by
        ``ShiftConfig.motion_gain``: the images' step is precise from frame to frame but biased over a row
        (parallax), the vote is noisier but placed against the map, so the blend follows the images' step
        while the map keeps it from drifting (method ``edges+motion``).
        """
        idx = self.frames
        if idx == 0:
            return StepRecord(0, 0.0, 0.0, 0, 1.0, "first", 0)
        cfg, prior = self.shift_cfg, self.prior
        pred = self._offset
        vel = prior.predict(idx, pred, self._velocity)
        half = self.spec.x_extent / 2 + cfg.max_step
        # Box edges and rack ends vote together (each kind only pairs with its own kind).
        fe = Edges.concat(self._frame_edges(rec), self._frame_rack_edges(rec))
        me = Edges.concat(self._map_edges(pred - half, pred + half), self._map_rack_edges(pred - half, pred + half))
        off, support, conf = vote_offset(fe, me, pred, cfg, self.dx, pred + vel)
        method, trusted, gate = "edges", True, prior.gate()
        mtol = max(gate, 2 * cfg.prior_gate)  # how far a given step may be from a vote and still agree
        outside = support >= cfg.min_support and not prior.agrees(off - pred)
        done = False
        if outside and prior.plausible(off - pred) and self._corroborated(off - pred, top, motion, mtol):
            # a second estimator (the layouts' own frame-to-frame correlation, or the given motion) reads the
            # same step: the camera stopped, sped up, slowed down or stepped back; the prior starts again here
            conf *= 0.75
            prior.restart(idx - 1, pred)
            outside, done = False, True
        if (outside or support < cfg.min_support) and prior.rejected and prior.rejected[-1][0] == idx - 1:
            # the last step broke the prior: does this one go on at its speed (the camera changed speed)?
            p_off, p_support, p_conf = vote_offset(fe, me, pred, cfg, self.dx, pred + self._velocity)
            vetoed = motion is not None and abs(motion - (p_off - pred)) > mtol
            if p_support >= cfg.min_support and abs(p_off - pred - self._velocity) <= gate and not vetoed:
                trusted = prior.propose(idx, p_off)
                off, support, conf, done = p_off, p_support, p_conf * (0.5 if trusted else 0.25), True
        if outside and not done:
            g_off, g_support, g_conf = vote_offset(
                fe, me, pred, replace(cfg, max_speed_change=gate), self.dx, pred + vel
            )
            if motion is not None and prior.agrees(motion):
                # the image motion sides with the prior: the vote inside the gate, else the motion itself
                off, conf, support = (g_off, g_conf, g_support) if g_support >= cfg.min_support else (off, 0.0, 0)
            elif motion is not None and abs(motion - (off - pred)) <= mtol:
                conf *= 0.5  # the image motion confirms a change of speed: believed, not as well as a fit
                prior.restart(idx - 1, pred)
            elif support >= max(cfg.override_support, 2 * g_support):
                # strong, but one frame cannot tell a change of speed from a wrong consensus: taken,
                # untrusted, until `relock` frames in a row go on at its speed
                trusted = prior.propose(idx, off)
                conf *= 0.5 if trusted else 0.25
            elif g_support >= cfg.min_support:
                off, conf = g_off, g_conf * g_support / (g_support + support)
                support = g_support
            else:
                support = 0  # the vote broke the prior with nothing to back it: as if no edges agreed
            done = support >= cfg.min_support
        if support < cfg.min_support:
            method, conf, off, trusted = self._fallback(top, motion, vel, motion_conf)
        elif not done or trusted:
            conf *= prior.agreement(off - pred) ** 0.5
        if motion is not None and method != "motion":
            gap = motion - (off - pred)
            if not abs(gap) <= mtol:
                conf *= 0.5  # the two estimators disagree: the layouts' step stands, less confidently
            elif method == "edges" and cfg.motion_gain > 0 and motion_conf > 0:
                w = cfg.motion_gain * motion_conf / (motion_conf + max(conf, 1e-3))
                off += w * gap
                conf *= 1.0 - 0.5 * abs(gap) / max(mtol, 1e-9)  # the wider the gap, the less sure the blend
                method = "edges+motion"
        shift = off - self._offset
        direction = 0 if abs(shift) < 0.25 * self.dx else int(math.copysign(1, shift))
        return StepRecord(idx, off, shift, direction, float(conf), method, int(support), bool(trusted))

    def _corroborated(self, step: float, top: np.ndarray | None, motion: float | None, mtol: float) -> bool:
        """Whether an estimator other than the box vote reads ``step`` too: the given ``motion`` (when given it
        decides), else the correlation of this frame's top layouts with the previous frame's, confident and
        within two layout columns of it."""
        if motion is not None:  # it decides; one that sides with the prior says the camera kept its speed
            return abs(motion - step) <= mtol and not self.prior.agrees(motion)
        if top is None or self._prev_top is None:
            return False
        cfg = self.shift_cfg
        s, c = correlate_shift(self._prev_top, top, self.spec, cfg.max_step)
        return c >= cfg.min_corr_conf and abs(s - step) <= 2 * cfg.tol_px * self.dx

    def _fallback(
        self, top: np.ndarray | None, motion: float | None, vel: float, motion_conf: float = 1.0
    ) -> tuple[str, float, float, bool]:
        """(method, confidence, offset, trusted) where too few edges agree: the given ``motion``, else the
        profile correlation, else the prior's velocity ``vel`` (untrusted); a step the prior rejects is untrusted."""
        cfg, prior = self.shift_cfg, self.prior
        if motion is not None:
            ok = prior.agrees(motion)
            return "motion", 0.5 * motion_conf * prior.agreement(motion), self._offset + motion, ok
        if top is not None and self._prev_top is not None:
            s, c = correlate_shift(self._prev_top, top, self.spec, cfg.max_step)
            fits = prior.agrees(s) if prior.ready else cfg.allows(s, self._velocity)
            if c >= cfg.min_corr_conf and fits:
                return "correlation", c * 0.5 * prior.agreement(s), self._offset + s, True
        return "prediction", 0.0, self._offset + vel, False

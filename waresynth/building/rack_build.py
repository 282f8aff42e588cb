"""How a face's racks are built: apart (free-standing racks with gaps between them, `bay_gap`), as continuous
runs of pallet racking (neighbouring bays share one upright frame, no gap) or as shelving units standing side by
side (touching, each with its own uprights: two back to back at the joint).

The building config's ``rack_build`` gives the shares of faces built each way (one kind per face, drawn from a
stream of its own so that a building without it draws what it always drew) and ``run_bays`` how many bays one
run or one line of units holds before a gap (``bay_gap``) starts the next; the bays of one run share one width
(its beams' length), as racking is bought. A bay's span (its location column) covers its own uprights whole
and half of a shared one: runs and lines of units are cut into bays at the shared frame's centre line or at the
joint of two units' uprights.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from waresynth.draws import integer, uniform

KINDS = ("apart", "run", "units")  #: the ways a face's racks are built
DEFAULT_RUN_BAYS = (3, 8)  #: ``run_bays`` when a building config sets ``rack_build`` alone


def face_kind(bcfg: dict[str, Any], seed: int, k: int) -> tuple[str, np.random.Generator | None]:
    """Face ``k``'s kind and the stream its runs are drawn from (None for a face built apart); ``apart``
    without drawing anything when the config has no ``rack_build``."""
    shares = bcfg.get("rack_build")
    if not shares:
        return "apart", None
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xB11D, k]))
    weights = np.array([float(shares.get(kind, 0.0)) for kind in KINDS], np.float64)
    kind = KINDS[int(rng.choice(len(KINDS), p=weights / weights.sum()))]
    return kind, (None if kind == "apart" else rng)


def lay_bays(rng: np.random.Generator, bcfg: dict[str, Any], kind: str, runs: np.random.Generator | None
             ) -> tuple[list[tuple[float, float]], list[bool]]:  # fmt: skip
    """A face's bays along building X from ``cross_aisle`` (widths and gaps from the face's ``rng``, drawn
    as for racks apart whatever the kind) and, per joint between bay b and b + 1, whether they touch (in one
    run or line of units: no gap; a run's bays one width, drawn from ``runs``)."""
    x, bays, touch = float(bcfg["cross_aisle"]), [], []
    left, width = 0, 0.0
    lo, hi = bcfg.get("run_bays") or DEFAULT_RUN_BAYS
    for _ in range(integer(rng, bcfg["bays"])):
        w = uniform(rng, bcfg["bay_width"])
        if runs is not None:
            if left == 0:
                left, width = integer(runs, [lo, hi]), uniform(runs, bcfg["bay_width"])
            w, left = width, left - 1
        bays.append((x, x + w))
        gap = uniform(rng, bcfg["bay_gap"])
        touch.append(runs is not None and left > 0)
        x += w + (0.0 if touch[-1] else gap)
    return bays, touch[:-1]


def rack_ends(kind: str, touch: list[bool], bay: int, flip: bool) -> tuple[bool, bool]:
    """`waresynth.row_plan.RackPlan.shared` of bay ``bay`` (from 1) of a face of this kind: the ends it shares
    an upright frame with a neighbour (a run's joints), in the row frame (``flip``: an L face's runs the other way)."""
    if kind != "run":
        return False, False
    low = bay > 1 and touch[bay - 2]
    high = bay <= len(touch) and touch[bay - 1]
    return (high, low) if flip else (low, high)

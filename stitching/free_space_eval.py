"""Where `free-space --box` offers a box, checked against a generated building's ground truth
(``ground_truth/building.json``, `waresynth.building_truth`).

An offered placement (`stitching.building_free.LocationFit`: a location and ranges of building X for the box's
centre) *fits* when its location is one of the ground truth's and, for every centre in its ranges, the box's
extent along X (``along_x``, without the margin) lies on that location's level within the bay's usable board
(the ground truth's positions, between the uprights) and overlaps no ground-truth stack of that level of that
bay. A placement at a code the ground truth lacks is *invented*; one whose box reaches past the board is *into
an upright*; one that overlaps a stack is *onto a box*. ``worst`` is the deepest such reach (metres).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from layouts.errors import InputError
from stitching.building_eval import truth_stacks
from stitching.building_free import LocationFit

EPS = 1e-6  #: metres of overlap below which a box still fits (rounding of the ground truth's numbers)


@dataclass
class FitEval:
    offered: int  #: placements offered (one per location and turn)
    fit: int  #: of them, fitting at every offered centre
    invented: int  #: at a code the ground truth lacks
    into_upright: int  #: reaching past the usable board
    onto_box: int  #: overlapping a ground-truth stack
    worst: float = 0.0  #: the deepest reach past the board or into a stack (metres)
    wrong: list[dict[str, Any]] = field(default_factory=list)  #: the first placements that do not fit

    @property
    def share(self) -> float:
        return self.fit / self.offered if self.offered else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "share": self.share}


def truth_levels(truth: dict[str, Any]) -> dict[str, tuple[tuple[float, float], list[tuple[float, float]]]]:
    """Location code -> (its bay's usable board along building X, the X extents of the stacks on its level)."""
    stacks = truth_stacks(truth)
    out: dict[str, tuple[tuple[float, float], list[tuple[float, float]]]] = {}
    try:
        for rack in truth["racks"]:
            for level in rack["levels"]:
                pos = level["positions"]
                board = (min(float(p["x_min"]) for p in pos), max(float(p["x_max"]) for p in pos))
                key = (int(rack["aisle"]), str(rack["side"]), int(level["level"]))
                mine = {str(p["location"]) for p in pos}
                spans = [c.x_range() for code, c in stacks.get(key, []) if code in mine]
                for code in mine:
                    out[code] = (board, spans)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"ground truth building.json: malformed ({type(e).__name__}: {e})") from None
    return out


def evaluate_fits(found: list[LocationFit], truth: dict[str, Any]) -> FitEval:
    """The share of ``found`` (`building_fits`' placements) that fit the ground-truth building (module docstring)."""
    levels = truth_levels(truth)
    ev = FitEval(len(found), 0, 0, 0, 0)
    for f in found:
        if f.location not in levels:
            ev.invented += 1
            if len(ev.wrong) < 20:
                ev.wrong.append({"location": f.location, "why": "no such location"})
            continue
        (b0, b1), spans = levels[f.location]
        past = box = 0.0
        for c0, c1 in f.centres:
            lo, hi = c0 - f.along_x / 2, c1 + f.along_x / 2  # every centre's box lies within [lo, hi]
            past = max(past, b0 - lo, hi - b1)
            for a, b in spans:
                box = max(box, min(hi, b) - max(lo, a))
        ev.into_upright += past > EPS
        ev.onto_box += box > EPS
        if past <= EPS and box <= EPS:
            ev.fit += 1
        else:
            ev.worst = max(ev.worst, past, box)
            if len(ev.wrong) < 20:
                ev.wrong.append({"location": f.location, "past_board": round(past, 4), "onto_box": round(box, 4)})
    return ev

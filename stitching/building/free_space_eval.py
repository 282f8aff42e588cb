"""Where `free-space --box` offers a box, checked against a generated building's ground truth
(``ground_truth/building.json``, `waresynth.building.truth`).

An offered placement (`stitching.building.free.LocationFit`: a location and ranges of building X for the box's
centre) *fits* when its location is one of the ground truth's and, for every centre in its ranges, the box's
extent along X (``along_x``, without the margin) lies on that location's level between the inner faces of its
bay's two upright frames (the ground truth's ``uprights``; where a ground truth lacks them, the usable board:
its positions) and overlaps no ground-truth stack of that level of that bay. A placement at a code the ground
truth lacks is *invented*; one whose box reaches into an upright frame is *into an upright*; one that overlaps a
stack is *onto a box*; ``worst`` is the deepest such reach (metres). ``past_board`` counts the fitting ones that
reach past the usable board into the clearance the generator leaves beside an upright (3 cm).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from layouts.errors import InputError
from stitching.building.eval import truth_stacks
from stitching.building.free import LocationFit

EPS = 1e-6  #: metres of overlap below which a box still fits (rounding of the ground truth's numbers)


@dataclass
class FitEval:
    offered: int  #: placements offered (one per location and turn)
    fit: int  #: of them, fitting at every offered centre
    invented: int  #: at a code the ground truth lacks
    into_upright: int  #: reaching into an upright frame
    onto_box: int  #: overlapping a ground-truth stack
    past_board: int = 0  #: fitting, but reaching past the usable board (into the clearance beside an upright)
    worst: float = 0.0  #: the deepest reach past the board or into a stack (metres)
    wrong: list[dict[str, Any]] = field(default_factory=list)  #: the first placements that do not fit

    @property
    def share(self) -> float:
        return self.fit / self.offered if self.offered else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "share": self.share}


Span = tuple[float, float]


def truth_levels(truth: dict[str, Any]) -> dict[str, tuple[Span, Span, list[Span]]]:
    """Location code -> (the clear span between its bay's upright frames, its usable board, the X extents of the
    stacks on its level), along building X."""
    stacks = truth_stacks(truth)
    out: dict[str, tuple[Span, Span, list[Span]]] = {}
    try:
        for rack in truth["racks"]:
            for level in rack["levels"]:
                pos = level["positions"]
                board = (min(float(p["x_min"]) for p in pos), max(float(p["x_max"]) for p in pos))
                frames = sorted(rack.get("uprights") or [])
                clear = (float(frames[0][1]), float(frames[-1][0])) if len(frames) == 2 else board
                key = (int(rack["aisle"]), str(rack["side"]), int(level["level"]))
                mine = {str(p["location"]) for p in pos}
                spans = [c.x_range() for code, c in stacks.get(key, []) if code in mine]
                for code in mine:
                    out[code] = (clear, board, spans)
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
        (u0, u1), (b0, b1), spans = levels[f.location]
        past = box = board = 0.0
        for c0, c1 in f.centres:
            lo, hi = c0 - f.along_x / 2, c1 + f.along_x / 2  # every centre's box lies within [lo, hi]
            past = max(past, u0 - lo, hi - u1)
            board = max(board, b0 - lo, hi - b1)
            for a, b in spans:
                box = max(box, min(hi, b) - max(lo, a))
        ev.into_upright += past > EPS
        ev.onto_box += box > EPS
        if past <= EPS and box <= EPS:
            ev.fit += 1
            ev.past_board += board > EPS
        else:
            ev.worst = max(ev.worst, past, box)
            if len(ev.wrong) < 20:
                ev.wrong.append({"location": f.location, "into_upright": round(past, 4), "onto_box": round(box, 4)})
    return ev

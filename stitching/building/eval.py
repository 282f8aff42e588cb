"""A building map against a generated building's ground truth (``ground_truth/building.json`` and
``inventory.csv``, `waresynth.building.truth`).

* **Locations**: those some pass's layouts held (the ground truth's ``pass`` column not empty) are counted;
  one is *exact* when the map has its code, scanned, with the same number of boxes (stacks). A map location
  whose code the ground truth lacks is *invented*; a counted one the map lacks or calls ``not scanned`` is
  *missed*.
* **Boxes**: per face and level, the map's boxes and the ground truth's stacks (a stack's boxes as one
  cuboid) in the building frame, matched one to one by 3D IoU (Hungarian); a match at IoU >= 0.5 is a true
  positive. Stacks in counted locations count; a map box matched to none is a false positive unless it lies in
  a location no pass saw.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from layouts.errors import InputError
from layouts.locations import NOT_SCANNED
from stitching.building.map import BuildingMap
from stitching.building.schema import check_change_rows, check_inventory, check_truth
from stitching.geometry import Cuboid, iou_matrix


@dataclass
class BuildingEval:
    locations: int  #: counted: some pass's layouts held them
    exact: int  #: code and box count right
    missed: int  #: counted, but absent from the map or not scanned there
    invented: int  #: codes the ground truth lacks
    tp: int
    fp: int
    fn: int
    mean_iou: float
    wrong: list[dict[str, Any]] = field(default_factory=list)  #: every counted location whose count differs
    flagged: int = 0  #: counted and scanned locations whose row says ``recount``
    unflagged: int = 0  #: counted and scanned locations whose row does not
    unflagged_exact: int = 0  #: of those, the ones with the exact count

    @property
    def exact_share(self) -> float:
        return self.exact / self.locations if self.locations else 1.0

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else 1.0

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else 1.0

    @property
    def flagged_share(self) -> float:
        """The share of scanned counted rows flagged ``recount``."""
        n = self.flagged + self.unflagged
        return self.flagged / n if n else 0.0

    @property
    def unflagged_exact_share(self) -> float:
        """How often a row without ``recount`` has the exact count."""
        return self.unflagged_exact / self.unflagged if self.unflagged else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "exact_share": self.exact_share, "precision": self.precision, "recall": self.recall,
                "flagged_share": self.flagged_share, "unflagged_exact_share": self.unflagged_exact_share}  # fmt: skip


def truth_stacks(
    truth: dict[str, Any], source: str = "ground_truth/building.json"
) -> dict[tuple[int, str, int], list[tuple[str, Cuboid]]]:
    """(aisle, side, level) -> [(location code, stack cuboid in the building frame)] from ``building.json``
    (read from ``source``: refused in one line when it breaks its schema, `check_truth`)."""
    check_truth(truth, source)
    out: dict[tuple[int, str, int], list[tuple[str, Cuboid]]] = {}
    try:
        for rack in truth["racks"]:
            for level in rack["levels"]:
                key = (int(rack["aisle"]), str(rack["side"]), int(level["level"]))
                for pos in level["positions"]:
                    stacks: dict[int, list[dict]] = {}
                    for b in pos["boxes"]:
                        stacks.setdefault(int(b["stack"]), []).append(b)
                    for _, bs in sorted(stacks.items()):
                        y0 = min(b["center"][1] - b["size"][1] / 2 for b in bs)
                        y1 = max(b["center"][1] + b["size"][1] / 2 for b in bs)
                        b0 = bs[0]
                        c = Cuboid((b0["center"][0], (y0 + y1) / 2, b0["center"][2]), (b0["size"][0], y1 - y0, b0["size"][2]),
                                   float(b0["yaw"]))  # fmt: skip
                        out.setdefault(key, []).append((str(pos["location"]), c))
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise InputError(f"ground truth building.json: malformed ({type(e).__name__}: {e})") from None
    return out


def evaluate_building(
    bmap: BuildingMap,
    truth: dict[str, Any],
    truth_rows: list[dict[str, str]],
    iou_threshold: float = 0.5,
    source: str = "ground_truth/inventory.csv",
) -> BuildingEval:
    """Locations and boxes of ``bmap`` against a building's ground truth (its JSON and inventory rows, read from
    ``source``: refused in one line when they break the inventory's schema)."""
    check_inventory(truth_rows, source)
    counted = {r["location"]: r for r in truth_rows if r.get("pass")}
    all_codes = {r["location"] for r in truth_rows}
    rows = {r["location"]: r for r in bmap.inventory()}
    exact, missed, wrong = 0, 0, []
    flags = {True: [0, 0], False: [0, 0]}  # recount -> [rows, exact]
    for code, t in counted.items():
        m = rows.get(code)
        if m is None or m["boxes"] == NOT_SCANNED:
            missed += 1
            continue
        right = int(m["boxes"]) == int(t["boxes"])
        tally = flags[m.get("recount") == "true"]
        tally[0] += 1
        tally[1] += right
        if right:
            exact += 1
        else:
            wrong.append({"location": code, "map": m["boxes"], "truth": int(t["boxes"])})
    invented = sum(1 for code in rows if code not in all_codes)
    stacks = truth_stacks(truth)
    mine: dict[tuple[int, str, int], list[tuple[str, Cuboid]]] = {}
    for f, shelf, loc in bmap.locations():
        for b in shelf.boxes:
            mine.setdefault((loc.aisle, loc.side, loc.level), []).append((loc.code, f.to_building(b.cuboid)))
    tp = fp = fn = 0
    ious = []
    for key in sorted(set(stacks) | set(mine)):
        gt = stacks.get(key, [])
        pr = mine.get(key, [])
        matched_gt, matched_pr = set(), set()
        if gt and pr:
            m = iou_matrix([c for _, c in pr], [c for _, c in gt])
            rr, cc = linear_sum_assignment(-m)
            for i, j in zip(rr, cc):
                if m[i, j] >= iou_threshold:
                    matched_pr.add(i)
                    matched_gt.add(j)
                    if gt[j][0] in counted:
                        tp += 1
                        ious.append(float(m[i, j]))
        fn += sum(1 for j, (code, _) in enumerate(gt) if j not in matched_gt and code in counted)
        fp += sum(
            1 for i, (code, _) in enumerate(pr) if i not in matched_pr and (code in counted or code not in all_codes)
        )
    mean_iou = float(np.mean(ious)) if ious else 0.0
    return BuildingEval(
        len(counted), exact, missed, invented, tp, fp, fn, mean_iou, wrong, flags[True][0], *flags[False]
    )


def evaluate_changes(
    found: list[dict[str, Any]], truth: list[dict[str, str]], source: str = "--truth"
) -> dict[str, dict[str, float]]:
    """Precision and recall per change category of diff rows against a rescan's ``changes.csv`` rows (read from
    ``source``: refused in one line when they break the changes' schema): a change is right where the truth has
    the same category at the same location (for a move, from the same location too), each truth row matched at
    most once."""
    check_change_rows(truth, source)
    from collections import Counter

    def key(r: dict) -> tuple[str, str, str]:
        return (
            str(r["change"]),
            str(r["location"]),
            str(r.get("other_location") or "") if r["change"] == "moved" else "",
        )

    got, want = Counter(map(key, found)), Counter(map(key, truth))
    out = {}
    for cat in ("added", "removed", "moved", "shifted"):
        g = {k: v for k, v in got.items() if k[0] == cat}
        w = {k: v for k, v in want.items() if k[0] == cat}
        tp = sum(min(v, w.get(k, 0)) for k, v in g.items())
        ng, nw = sum(g.values()), sum(w.values())
        out[cat] = {"tp": tp, "found": ng, "truth": nw, "precision": tp / ng if ng else 1.0,
                    "recall": tp / nw if nw else 1.0}  # fmt: skip
    return out

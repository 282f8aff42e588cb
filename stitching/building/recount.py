"""The recount flag of an inventory row: ``true`` where the row's count is uncertain, so that the rows without
it can be taken as counted.

A row's evidence (`RowEvidence`) is what the map knows of how its count was made: the row's confidence, its
least sure box (confidence and the frames that saw it), whether part of its length was never in view, whether the
passes that held all of it in view counted different numbers of boxes, whether a bay boundary of it is uncertain.
`needs_recount` flags it where any of these falls short of `RecountRule`. From ground-truth layouts the rows
without the flag are exact; from the network's layouts they are right more often than the flagged ones but not
yet 98 % of the time (docs/buildings.md, "The inventory", with the figures).
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from layouts.locations import INVENTORY_COLUMNS
from stitching.warehouse_map import MapRack, MapShelf

SAME_CUT = 0.05  #: metres: a bay ends at a cut this close to it
RECOUNT = "recount"  #: the inventory's column: ``true``, ``false``, or empty where the location was not scanned
#: a building map's inventory columns: a generated building's ground truth has no recount
MAP_INVENTORY_COLUMNS = (*INVENTORY_COLUMNS, RECOUNT)


@dataclass(frozen=True)
class RowEvidence:
    """How one location's count was made."""

    confidence: float  #: the row's confidence (its shelf's and boxes' times the share of it seen)
    box_confidence: float = 1.0  #: its least sure box's confidence (1 without boxes)
    support: int = 1_000_000  #: the frames that saw its least seen box (no boxes: unbounded)
    partial: bool = False  #: some of its length never in view
    disagree: bool = False  #: the passes that held all of it in view counted differently
    uncertain_boundary: bool = False  #: a bay boundary of it is uncertain


@dataclass(frozen=True)
class RecountRule:
    min_confidence: float = 0.8  #: a row less confident than this is recounted
    min_box_confidence: float = 0.6  #: a row with a box less confident than this is recounted
    min_support: int = 3  #: a row with a box seen in fewer frames than this is recounted
    #: a bay whose width lies outside this share of its face's median bay width has an uncertain boundary (two
    #: bays run together, or one cut in two): racking repeats its bay widths along a face
    bay_width: tuple[float, float] = (0.75, 1.33)


RULE = RecountRule()


def needs_recount(e: RowEvidence, rule: RecountRule = RULE) -> bool:
    """Whether the row ``e`` describes must be counted again by a person."""
    return (
        e.partial
        or e.disagree
        or e.uncertain_boundary
        or e.confidence < rule.min_confidence
        or e.box_confidence < rule.min_box_confidence
        or e.support < rule.min_support
    )


def uncertain_bays(racks: list[MapRack], rule: RecountRule = RULE, cuts: Iterable[tuple[float, bool]] = ()) -> set[str]:
    """The ids of a face's racks (bays) whose width lies outside ``rule.bay_width`` of the face's median, and
    those with an end at an uncertain one of ``cuts``, the face's bay boundaries found at uprights as
    ``(x, certain)`` (`stitching.uprights.bay_cuts`, face frame)."""
    widths = {r.id: r.x_range[1] - r.x_range[0] for r in racks}
    odd = {r.id for x, ok in cuts if not ok for r in racks if min(abs(e - x) for e in r.x_range) <= SAME_CUT}
    if len(widths) < 3:
        return odd
    med = statistics.median(widths.values())
    lo, hi = rule.bay_width
    return odd | {k for k, w in widths.items() if not lo * med <= w <= hi * med}


def shelf_evidence(shelf: MapShelf, confidence: float, partial: bool, **more: Any) -> RowEvidence:
    """The evidence of a scanned location from its shelf (its boxes' confidences and observations), the row's
    ``confidence`` and ``partial``; ``more``: `RowEvidence`'s other fields where the map knows them."""
    boxes = shelf.boxes
    return RowEvidence(
        confidence=confidence,
        box_confidence=min((b.confidence for b in boxes), default=1.0),
        support=min((b.observations for b in boxes), default=RowEvidence.support),
        partial=partial,
        **more,
    )


def recount_cell(e: RowEvidence | None, rule: RecountRule = RULE) -> str:
    """The inventory's ``recount`` cell: ``true`` / ``false``, empty for a location not scanned (None)."""
    return "" if e is None else ("true" if needs_recount(e, rule) else "false")

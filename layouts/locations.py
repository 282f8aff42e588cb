"""Storage locations, shared by the building generator's ground truth and the building map: the code of a
slot, and the inventory's columns (one row per location, as a warehouse management system takes a cycle count).

A location is one position of one level of one bay of one rack face. Its code comes from a format string with
the fields ``aisle``, ``side`` (``L`` / ``R``), ``bay`` (from 1 along +X), ``level`` (from 1 at the floor) and
``position`` (from 1 along +X within the level); the default `DEFAULT_CODE` gives e.g. ``01-L-03-02``.
A stack of boxes one on another counts as one in ``boxes``: seen from the aisle, a stack shows its outline, not
the seams between its boxes.
"""

from __future__ import annotations

import csv
import io
from typing import Any

from layouts.errors import InputError

DEFAULT_CODE = "{aisle:02d}-{side}-{bay:02d}-{level:02d}"
NOT_SCANNED = "not scanned"  #: ``boxes`` of a location no pass saw (never 0: unseen is not empty)
INVENTORY_COLUMNS = (
    "location", "aisle", "side", "bay", "level", "position", "boxes", "occupancy", "free_length_m", "free_area_m2",
    "free_volume_m3", "partial", "confidence", "last_seen", "pass",
)  # fmt: skip


def location_code(code: str, aisle: int, side: str, bay: int, level: int, position: int = 1) -> str:
    """A location's code from the format ``code``."""
    try:
        return code.format(aisle=aisle, side=side, bay=bay, level=level, position=position)
    except (KeyError, IndexError, ValueError, AttributeError) as e:
        raise InputError(f"location code format {code!r}: {e} (fields: aisle, side, bay, level, position)") from None


def check_code_format(code: str, positions: int = 1) -> str:
    """``code`` when it tells every location apart (with ``{position}`` where levels have several positions)."""
    if not isinstance(code, str):
        raise InputError(f"location code format must be a string, got {code!r}")
    location_code(code, 1, "L", 1, 1, 1)
    keys = ("aisle", "side", "bay", "level") + (("position",) if positions > 1 else ())
    missing = [k for k in keys if "{" + k not in code]
    if missing:
        raise InputError(f"location code format {code!r} lacks {', '.join(missing)}: two locations would share a code")
    return code


def covered_length(intervals: list[tuple[float, float]], lo: float, hi: float) -> float:
    """Length of ``[lo, hi]`` under the union of ``intervals`` (a location's occupied or seen length)."""
    total, end = 0.0, lo
    for a, b in sorted((max(a, lo), min(b, hi)) for a, b in intervals):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def rows_csv(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> str:
    """Rows as CSV text: the ``columns`` header, then one line per row."""
    out = io.StringIO()
    w = csv.DictWriter(out, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return out.getvalue()


def inventory_csv(rows: list[dict[str, Any]]) -> str:
    """Inventory rows as CSV text: the `INVENTORY_COLUMNS` header, then one row per location."""
    return rows_csv(rows, INVENTORY_COLUMNS)


def read_rows(text: str, needs: tuple[str, ...], source: str) -> list[dict[str, str]]:
    """Rows of a CSV whose header holds ``needs`` (one line naming ``source`` otherwise)."""
    rows = list(csv.DictReader(io.StringIO(text)))
    if not text.strip() or (rows and set(needs) - set(rows[0])):
        raise InputError(f"{source}: its header must hold {', '.join(needs)}")
    return rows


def read_inventory(text: str, source: str = "inventory") -> list[dict[str, str]]:
    """Rows of an inventory CSV (its header must hold `INVENTORY_COLUMNS`)."""
    return read_rows(text, INVENTORY_COLUMNS, f"{source}: not an inventory")

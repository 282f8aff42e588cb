"""The location list: a warehouse's location master as a warehouse management system exports it (CSV), the codes
and geometry of its storage locations, no contents.

Columns ``code,aisle,side,bay,level,start_m,end_m`` and optionally ``position``: a location's code, its face
(aisle from 1, side ``L`` / ``R``), bay, level (from 1 at the floor), position within the level (from 1, default
1), and the span it takes along its face in metres of building X (the floor plan's coordinate, as a route's
``x_min`` / ``x_max``: X along the aisles), ``start_m`` below ``end_m``. `mvracklay generate --building` writes
one (``locations.csv``); ``mvracklay map --locations`` takes its codes from one.
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from layouts.errors import ContractError, InputError
from layouts.fileio import atomic_write_text, finite_float

COLUMNS = ("code", "aisle", "side", "bay", "level", "start_m", "end_m")
OPTIONAL = ("position",)
MAX_BYTES = 64 * 1024 * 1024  #: a location master this large is not one
CODE = re.compile(r"^\S(.*\S)?$")


def _whole(lo: int, hi: int) -> Callable[[str], int]:
    def read(v: str) -> int:
        if not re.fullmatch(r"[+]?\d{1,6}", v):
            raise ValueError(f"must be a whole number, got {v[:20]!r}")
        n = int(v)
        if not lo <= n <= hi:
            raise ValueError(f"must lie in [{lo}, {hi}], got {n}")
        return n

    return read


def _metres(v: str) -> float:
    try:
        x = finite_float(v)
    except ValueError:
        raise ValueError(f"must be a finite number of metres, got {v[:20]!r}") from None
    if not -1e5 <= x <= 1e5:
        raise ValueError(f"must lie within 100 km, got {x}")
    return x


def _code(v: str) -> str:
    if not 1 <= len(v) <= 64 or not CODE.match(v):
        raise ValueError(f"must be 1-64 characters, not blank at either end, got {v[:20]!r}")
    return v


def _side(v: str) -> str:
    if v not in ("L", "R"):
        raise ValueError(f"must be L or R, got {v[:20]!r}")
    return v


#: the declared schema: each column's reader (a ValueError says what is wrong), checked on load and before writing
SCHEMA: dict[str, Callable[[str], Any]] = {
    "code": _code, "aisle": _whole(1, 9999), "side": _side, "bay": _whole(1, 9999), "level": _whole(1, 99),
    "start_m": _metres, "end_m": _metres, "position": _whole(1, 999),
}  # fmt: skip


@dataclass(frozen=True)
class ListedLocation:
    """One location of the list: code, face, bay, level, position and its span along building X (metres)."""

    code: str
    aisle: int
    side: str
    bay: int
    level: int
    start_m: float
    end_m: float
    position: int = 1

    @property
    def face(self) -> tuple[int, str]:
        return (self.aisle, self.side)

    @property
    def length(self) -> float:
        return self.end_m - self.start_m


def _entry(row: dict[str, Any]) -> ListedLocation:
    """One row through `SCHEMA` (a ValueError ``column: what``)."""
    got: dict[str, Any] = {"position": 1}
    for col, read in SCHEMA.items():
        v = row.get(col)
        if v is None or (col in OPTIONAL and str(v).strip() == ""):
            if col in OPTIONAL:
                continue
            raise ValueError(f"{col}: missing")
        try:
            got[col] = read(str(v).strip())
        except ValueError as e:
            raise ValueError(f"{col}: {e}") from None
    if not got["start_m"] < got["end_m"]:
        raise ValueError(f"start_m, end_m: start_m {got['start_m']} must lie below end_m {got['end_m']}")
    return ListedLocation(**got)


def check_entries(entries: list[dict[str, Any]], source: str, built: bool = False) -> list[ListedLocation]:
    """Entries (one dict per row, as CSV gives them) checked against the schema: one line naming ``source``, the
    row (from 1, as a spreadsheet counts data rows after the header: ``row 3``) and the column. ``built``: the
    entries are ours (about to be written), so a problem is a `ContractError`."""
    fail = ContractError if built else InputError
    out, codes, places = [], {}, {}
    for k, raw in enumerate(entries, start=1):
        try:
            e = _entry(raw)
        except ValueError as err:
            raise fail(f"{source}: row {k}: {err}") from None
        if e.code in codes:
            raise fail(f"{source}: row {k}: code: {e.code!r} is listed twice (rows {codes[e.code]} and {k})")
        place = (e.aisle, e.side, e.bay, e.level, e.position)
        if place in places:
            raise fail(
                f"{source}: row {k}: bay, level, position: face {e.aisle:02d}-{e.side} bay {e.bay} level {e.level} "
                f"position {e.position} is listed twice (rows {places[place]} and {k})"
            )
        codes[e.code], places[place] = k, k
        out.append(e)
    if not out:
        raise fail(f"{source}: lists no location")
    return out


def parse_location_list(text: str, source: str = "location list") -> list[ListedLocation]:
    """A location list from its CSV text (`check_entries`); its header must hold `COLUMNS`."""
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise InputError(f"{source}: header lacks {', '.join(missing)} (a location list has {','.join(COLUMNS)})")
    reader.fieldnames = header
    rows = []
    for k, r in enumerate(reader, start=1):
        if None in r or any(v is None for v in r.values()):
            more = "more" if None in r else "fewer"
            raise InputError(f"{source}: row {k}: holds {more} fields than the header ({','.join(header)})")
        rows.append({c: v.strip() for c, v in r.items()})
    return check_entries(rows, source)


def read_location_list(path: str | os.PathLike) -> list[ListedLocation]:
    """Read and check a location list file; a missing, unreadable or malformed one: one line naming it."""
    p = Path(path)
    try:
        if p.is_dir():
            raise InputError(f"{p}: a folder, not a location list (CSV)")
        if p.stat().st_size > MAX_BYTES:
            raise InputError(f"{p}: larger than {MAX_BYTES // 2**20} MB: not a location list")
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a location list (not UTF-8 text)") from None
    except OSError as e:
        raise InputError(f"{p}: cannot read ({e.strerror})") from None
    try:
        return parse_location_list(text, str(p))
    except csv.Error as e:
        raise InputError(f"{p}: not a location list (CSV: {e})") from None


def location_list_csv(entries: list[ListedLocation]) -> str:
    """The list as CSV text (`COLUMNS` then ``position``), one line per entry in the order given."""
    out = io.StringIO()
    w = csv.DictWriter(out, fieldnames=COLUMNS + OPTIONAL, lineterminator="\n")
    w.writeheader()
    for e in entries:
        d = asdict(e)
        d["start_m"], d["end_m"] = round(e.start_m, 6) + 0.0, round(e.end_m, 6) + 0.0
        w.writerow(d)
    return out.getvalue()


def write_location_list(entries: list[ListedLocation], path: str | os.PathLike) -> None:
    """Write a location list (atomic), checked against its schema first (a list that breaks it: `ContractError`)."""
    text = location_list_csv(list(entries))
    check_entries(list(csv.DictReader(io.StringIO(text))), str(path), built=True)
    atomic_write_text(path, text)

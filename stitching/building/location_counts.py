"""Per-location counts compared: a diff's location changes scored against a rescan's ground truth, and a scan
against the counts a warehouse management system expects (``mvracklay diff MAP --expected WMS_CSV``).

The WMS's file is CSV with a header: ``location`` (or ``code``) and ``expected`` (box stacks), one row per
location (`ExpectedRow`, refused in one line naming the file, the row and the column). The exceptions
(`EXCEPTION_COLUMNS`), one row per location a person must look at:

* ``count differs``: scanned, its count not the expected one;
* ``not scanned``: listed and in the map, but no pass saw it;
* ``missing from the map``: listed, the map has no such location;
* ``not in the WMS``: a location of the map the list lacks (its count, where scanned).

Each carries the map row's confidence and ``recount``.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, StrictStr, ValidationError

from layouts.errors import InputError, first_problem
from layouts.location_changes import LOCATION_CHANGES
from layouts.locations import NOT_SCANNED
from stitching.building.map import BuildingMap
from stitching.building.schema import _refuse

EXCEPTIONS = ("count differs", "not scanned", "missing from the map", "not in the WMS")
EXCEPTION_COLUMNS = ("location", "exception", "expected", "counted", "confidence", "recount")
EXCEPTION_FILES = ("exceptions.csv",)


class ExpectedRow(BaseModel):
    """One row of the WMS's expected counts."""

    model_config = ConfigDict(extra="ignore")
    location: StrictStr = Field(min_length=1)
    expected: int = Field(ge=0, le=1_000_000)


class ExceptionRow(BaseModel):
    """One row of ``exceptions.csv``."""

    model_config = ConfigDict(extra="forbid")
    location: StrictStr = Field(min_length=1)
    exception: StrictStr = Field(pattern="^(" + "|".join(EXCEPTIONS) + ")$")
    expected: int | StrictStr
    counted: int | StrictStr
    confidence: float = Field(ge=0, le=1, allow_inf_nan=False)
    recount: StrictStr = Field(pattern="^(true|false|)$")


def read_expected(path: str | Path, what: str = "--expected") -> dict[str, int]:
    """location -> expected count from the WMS's CSV at ``path``; one line naming it and what is wrong else."""
    path = Path(path)
    src = f"{what} {path}"
    if not path.is_file():
        raise InputError(f"{src}: file not found")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{src}: cannot be read as UTF-8 text ({type(e).__name__})") from None
    reader = csv.DictReader(io.StringIO(text))
    head = [h.strip() for h in (reader.fieldnames or [])]
    key = "location" if "location" in head else "code" if "code" in head else None
    if key is None or "expected" not in head:
        raise InputError(
            f"{src}: its header must hold location (or code) and expected, got {', '.join(head) or 'none'}"
        )
    out: dict[str, int] = {}
    for k, raw in enumerate(reader, start=2):
        r = {str(a).strip(): (b.strip() if isinstance(b, str) else b) for a, b in raw.items() if a is not None}
        try:
            row = ExpectedRow.model_validate({"location": r.get(key), "expected": r.get("expected")})
        except ValidationError as e:
            raise InputError(f"{src}: line {k}: {first_problem(e.errors())}") from None
        if row.location in out:
            raise InputError(f"{src}: line {k}: location {row.location!r} is listed twice")
        out[row.location] = row.expected
    if not out:
        raise InputError(f"{src}: no location listed")
    return out


def expected_exceptions(bmap: BuildingMap, expected: dict[str, int]) -> list[dict[str, Any]]:
    """The exceptions between the map's inventory and the expected counts (`EXCEPTIONS`), building order then the
    list's order for the locations the map lacks."""
    out = []
    rows = {r["location"]: r for r in bmap.inventory()}
    for code, r in rows.items():
        conf, flag = float(r["confidence"]), str(r.get("recount", ""))
        scanned = r["boxes"] != NOT_SCANNED
        if code not in expected:
            out.append(_exc(code, "not in the WMS", "", r["boxes"] if scanned else "", conf, flag))
        elif not scanned:
            out.append(_exc(code, "not scanned", expected[code], "", conf, flag))
        elif int(r["boxes"]) != expected[code]:
            out.append(_exc(code, "count differs", expected[code], int(r["boxes"]), conf, flag))
    out += [_exc(c, "missing from the map", n, "", 0.0, "") for c, n in expected.items() if c not in rows]
    return out


def _exc(code: str, kind: str, expected: Any, counted: Any, conf: float, recount: str) -> dict[str, Any]:
    return {"location": code, "exception": kind, "expected": expected, "counted": counted,
            "confidence": round(conf, 4), "recount": recount}  # fmt: skip


def check_exceptions(rows: list[dict[str, Any]], source: str) -> None:
    """Hold exceptions about to be written to `ExceptionRow` (a defect raised before anything is written)."""
    for k, r in enumerate(rows, start=1):
        try:
            ExceptionRow.model_validate(r)
        except ValidationError as e:
            _refuse(f"row {k}: {first_problem(e.errors())}", source, "exceptions", True)


def format_exceptions(rows: list[dict[str, Any]], listed: int, limit: int = 40) -> str:
    """The exceptions, one line each (the first ``limit``), then their counts by kind."""
    lines = [
        f"{r['location']:<14} {r['exception']:<21} expected {str(r['expected']):>4} counted {str(r['counted']):>4}"
        f"  conf {r['confidence']:.2f}{'  recount' if r['recount'] == 'true' else ''}"
        for r in rows[:limit]
    ]
    if len(rows) > limit:
        lines.append(f"... and {len(rows) - limit} more (exceptions.csv lists all)")
    kinds = ", ".join(f"{sum(1 for r in rows if r['exception'] == k)} {k}" for k in EXCEPTIONS)
    return "\n".join([*lines, f"{len(rows)} exceptions of {listed} listed locations: {kinds}"])


def write_exceptions(rows: list[dict[str, Any]], out: str | Path) -> None:
    """``exceptions.csv`` (`EXCEPTION_COLUMNS`) in ``out``, atomically, held to `ExceptionRow` first."""
    from layouts.fileio import atomic_write_text
    from layouts.locations import rows_csv

    path = Path(out) / "exceptions.csv"
    check_exceptions(rows, str(path))
    atomic_write_text(path, rows_csv(rows, EXCEPTION_COLUMNS))


def evaluate_location_changes(found: list[dict[str, Any]], truth: list[dict[str, str]]) -> dict[str, dict[str, Any]]:
    """Precision and recall per location category (emptied, filled, count changed) of a diff's location rows
    against a rescan's ``location_changes.csv``: a location is right where both give it the same category. Only
    locations both scans saw are scored (``change`` set); ``unscored`` counts the truth's elsewhere."""
    compared = {r["location"] for r in found if r["change"]}
    got = {r["location"]: r["change"] for r in found if r["change"] in LOCATION_CHANGES}
    want = {r["location"]: r["change"] for r in truth if r["location"] in compared}
    out = {}
    for cat in LOCATION_CHANGES:
        g = {c for c, k in got.items() if k == cat}
        w = {c for c, k in want.items() if k == cat}
        tp = len(g & w)
        out[cat] = {"tp": tp, "found": len(g), "truth": len(w), "precision": tp / len(g) if g else 1.0,
                    "recall": tp / len(w) if w else 1.0}  # fmt: skip
    out["unscored"] = {"truth": sum(1 for r in truth if r["location"] not in compared)}
    return out


def read_location_truth(path: Path, what: str = "--truth") -> list[dict[str, str]]:
    """A rescan's ``location_changes.csv`` rows (location, before, after, change), one line when malformed."""
    from layouts.location_changes import TRUTH_COLUMNS, count_change
    from layouts.locations import read_rows

    rows = read_rows(path.read_text(encoding="utf-8"), TRUTH_COLUMNS, f"{what} {path}")
    for k, r in enumerate(rows, start=2):
        try:
            ok = count_change(int(r["before"]), int(r["after"])) == r["change"] and r["change"] in LOCATION_CHANGES
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(f"{what} {path}: line {k}: before, after and change disagree ({r})")
    return rows


def score_locations(found: list[dict[str, Any]], path: Path) -> dict[str, dict[str, Any]]:
    """`evaluate_location_changes` of a diff's location rows against the truth at ``path``, each category printed."""
    scores = evaluate_location_changes(found, read_location_truth(path))
    for cat in LOCATION_CHANGES:
        s = scores[cat]
        print(f"{cat:<14} (locations) precision {s['precision']:.3f} recall {s['recall']:.3f} ({s['tp']} of "
              f"{s['found']} found, {s['truth']} true)")  # fmt: skip
    return scores

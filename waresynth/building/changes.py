"""What changed in a building between two scans: a seeded change set applied to a planned building's stacks.

`apply_changes` takes a planned `Building` (its faces' racks and stacks) and returns a changed copy and the
list of `Change` records; `changes_rows` / `changes_csv` turn them into ``ground_truth/changes.csv``
(docs/waresynth.md, "Rescans"), `location_change_rows` / `location_changes_csv` the per-location counts before and
after into ``ground_truth/location_changes.csv`` (`layouts.location_changes`). Rates (`waresynth.building.schema.CHANGE_DEFAULTS`) are shares of the
building's stacks before the changes: ``round(rate x stacks)`` stacks are removed, moved, shifted and replaced
(each stack at most once), and ``round(added x stacks)`` new stacks added. A change that finds no room (a move with no location to take it, a shift with no
free length along its position) is left out, so the counts are at most the rates'. Everything is drawn from
one generator seeded by ``seed``: the same building, rates and seed give the same changes.

Stacks never overlap: a placed stack's footprint keeps `GAP` from the others' along X and stays on the
board's usable span, its boxes within the level's clear height less the config's ``head_room`` and its depth on
the board. A shift moves a stack along its level by at least `MIN_SHIFT` and keeps it in its location; a
replacement's box differs from the old one by at least `MIN_RESIZE` in width, height or depth and stands in
the same location (it is reported as ``removed`` and ``added`` there, both noted ``replaced``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from layouts.errors import InputError
from layouts.location_changes import TRUTH_COLUMNS, UNCHANGED, count_change
from layouts.locations import rows_csv
from waresynth.building.plan import Building, Face
from waresynth.building.schema import CHANGE_DEFAULTS, change_rates
from waresynth.building.truth import board_positions, box_id, ground_truth, location_code, position_of
from waresynth.draws import choice, colour, uniform
from waresynth.row_plan import RackPlan, StackPlan, clear_heights
from waresynth.scene import PATTERNS, Material

MIN_SHIFT = 0.15  #: m a shifted stack's centre moves along X at least
MIN_RESIZE = 0.10  #: m a replacement's box differs from the old one by at least, in width, height or depth
GAP = 0.02  #: m kept between a placed stack's footprint and its neighbours'
TRIES = 24  #: boards (an added stack) or boxes (a replacement) tried before a change is left out
CHANGES_COLUMNS = (
    "location", "change", "other_location", "boxes", "size", "box_ids", "old_box_ids", "x", "old_x", "note",
)  # fmt: skip


@dataclass(frozen=True)
class Board:
    """One level of one bay of one face: ``faces[face]``, rack ``rack_BB`` (BB = bay), level from 0."""

    face: int
    bay: int
    level: int


@dataclass
class Change:
    """One changed stack: what happened, where it stands now (``removed``: where it stood) and, for a stack of
    the building before the changes, its board and index there (``removed``, ``moved``, ``shifted``)."""

    change: str  #: added | removed | moved | shifted
    board: Board
    stack: StackPlan  #: as it stands now (``removed``: as it stood)
    old_board: Board | None = None
    old_index: int | None = None  #: its index in its board's stacks before the changes
    note: str = ""  #: "replaced" for both records of a replacement


def _rack(building: Building, b: Board) -> RackPlan:
    return next(r for r in building.faces[b.face].row.racks if r.id == f"rack_{b.bay:02d}")


def _boards(building: Building) -> list[Board]:
    """Every board in building order: face, bay, level."""
    return [
        Board(k, bay, lv)
        for k, face in enumerate(building.faces)
        for bay in range(1, len(face.bays) + 1)
        for lv in range(len(face.row.levels))
    ]


def _half_x(st: StackPlan) -> float:
    w, _, d = st.size
    return 0.5 * (abs(math.cos(st.yaw)) * w + abs(math.sin(st.yaw)) * d)


def _half_z(yaw: float, w: float, d: float) -> float:
    return 0.5 * (abs(math.sin(yaw)) * w + abs(math.cos(yaw)) * d)


def _limit(face: Face, level: int, cfg: dict[str, Any]) -> float:
    """The height a stack may take on this level: its clear height less the head room."""
    return clear_heights(face.row.levels, face.row.thickness, face.row.top)[level] - cfg["boxes"]["head_room"]


def _window(building: Building, b: Board, j: int | None) -> tuple[float, float]:
    """Row-frame X range a stack's centre may take on board ``b``: its usable span, or position ``j``'s part."""
    face, rack = building.faces[b.face], _rack(building, b)
    if j is None:
        return rack.board_span(face.row.upright_width)
    b0, cut = board_positions(face, rack, building.config["positions"])
    lo, hi = sorted((face.sign * (b0 + j * cut), face.sign * (b0 + (j + 1) * cut)))
    return lo + 1e-6, hi - 1e-6  # the centre strictly inside, whichever way the face runs


def _position(building: Building, b: Board, x: float) -> int:
    """The position (from 0) of a stack centred at row-frame X ``x`` on board ``b``."""
    face = building.faces[b.face]
    n = building.config["positions"]
    b0, cut = board_positions(face, _rack(building, b), n)
    return position_of(b0, cut, n, face.sign * x)


def _centres(building: Building, b: Board, hx: float, window: tuple[float, float], avoid: float | None = None
             ) -> list[tuple[float, float]]:  # fmt: skip
    """Row-frame X segments where a footprint of half width ``hx`` may be centred on board ``b``: on the usable
    span, `GAP` from every stack there, the centre in ``window`` and (``avoid``) at least `MIN_SHIFT` from it."""
    face, rack = building.faces[b.face], _rack(building, b)
    lo, hi = rack.board_span(face.row.upright_width)
    free = [(lo, hi)]
    for st in rack.stacks[b.level]:
        a, c = st.x - _half_x(st) - GAP, st.x + _half_x(st) + GAP
        free = [seg for f0, f1 in free for seg in ((f0, min(f1, a)), (max(f0, c), f1)) if seg[1] > seg[0]]
    cuts = [(window[0], window[1])]
    if avoid is not None:
        cuts = [(window[0], min(window[1], avoid - MIN_SHIFT)), (max(window[0], avoid + MIN_SHIFT), window[1])]
    out = []
    for f0, f1 in free:
        for w0, w1 in cuts:
            s0, s1 = max(f0 + hx, w0), min(f1 - hx, w1)
            if s1 - s0 > 1e-6:
                out.append((s0, s1))
    return out


def _draw_x(rng: np.random.Generator, segments: list[tuple[float, float]]) -> float | None:
    """A point drawn uniformly along the segments (None when there are none)."""
    if not segments:
        return None
    lengths = np.array([b - a for a, b in segments])
    t = float(rng.uniform(0.0, float(lengths.sum())))
    for (a, _), n in zip(segments, lengths):
        if t <= n:
            return a + t
        t -= n
    return segments[-1][1]


def _fits(building: Building, b: Board, st: StackPlan, cfg: dict[str, Any]) -> bool:
    """The stack's boxes within the level's clear height and its footprint's depth on the board."""
    face = building.faces[b.face]
    _, h, d = st.size
    return st.count * h <= _limit(face, b.level, cfg) + 1e-9 and st.z + _half_z(st.yaw, st.size[0], d) <= (
        face.row.depth - 0.02 + 1e-9
    )


def _draw_stack(rng: np.random.Generator, building: Building, b: Board, cfg: dict[str, Any]) -> StackPlan | None:
    """A new stack for board ``b`` as the sampler draws one (size, yaw, setback, count, look), x unset (0), or
    None when it does not fit the level."""
    bc, face = cfg["boxes"], building.faces[b.face]
    w, d, h = uniform(rng, bc["width"]), uniform(rng, bc["depth"]), uniform(rng, bc["height"])
    yaw = math.radians(uniform(rng, [-bc["yaw_deg"], bc["yaw_deg"]])) if rng.random() < bc["yaw_probability"] else 0.0
    setback = uniform(rng, bc["setback"])
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    max_hz = (face.row.depth - setback - 0.02) / 2
    if 0.5 * (s * w + c * d) > max_hz:
        d = max((2 * max_hz - s * w) / max(c, 1e-6), 0.0)
    count = 1
    while count < bc["max_stack"] and rng.random() < face.row.preset["stack_probability"]:
        count += 1
    limit = _limit(face, b.level, cfg)
    h = min(h, limit)
    count = max(1, min(count, int(limit // h))) if h > 0 else 0
    rgb = colour(rng, bc["colours"], bc["colour_jitter"])
    pattern = PATTERNS[choice(rng, bc["textures"])]
    refl = uniform(rng, bc["reflectance"])
    if d < 0.05 or h < 0.05 or count < 1:
        return None
    return StackPlan(0.0, setback + _half_z(yaw, w, d), (w, h, d), yaw, count, Material(rgb, pattern, refl, w))


def apply_changes(
    building: Building, rates: dict[str, float] | None, seed: int, cfg: dict[str, Any] | None = None
) -> tuple[Building, list[Change]]:
    """``(changed copy of building, changes)``: ``rates`` (`waresynth.building.schema.change_rates`) applied by a generator seeded by
    ``seed``; ``cfg`` the generator config the building was planned with (None: the default), for the sizes,
    looks and head room of new boxes. ``building`` is left as it was; the passes are copied unchanged."""
    from waresynth.config import load_config

    if not isinstance(building, Building):
        raise InputError(
            f"building must be a planned Building (waresynth.building.plan_building), got {type(building).__name__}"
        )
    rates = change_rates(rates)
    cfg = load_config(cfg)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    out = copy.deepcopy(building)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xC4A6]))
    boards = _boards(out)
    stacks = [(b, i, st) for b in boards for i, st in enumerate(_rack(out, b).stacks[b.level])]
    n = {k: math.floor(rates[k] * len(stacks) + 0.5) for k in CHANGE_DEFAULTS}
    order = [int(i) for i in rng.permutation(len(stacks))]
    picked: dict[str, list[tuple[Board, int, StackPlan]]] = {}
    at = 0
    for kind in ("removed", "moved", "shifted", "replaced"):
        picked[kind] = [stacks[i] for i in sorted(order[at : at + n[kind]])]
        at += n[kind]
    changes: list[Change] = []

    def take(b: Board, st: StackPlan) -> None:
        lst = _rack(out, b).stacks[b.level]
        del lst[next(i for i, s in enumerate(lst) if s is st)]

    def put(b: Board, st: StackPlan) -> None:
        lst = _rack(out, b).stacks[b.level]
        lst.append(st)
        lst.sort(key=lambda s: s.x)

    for b, i, st in picked["removed"]:
        take(b, st)
        changes.append(Change("removed", b, st, b, i))
    for b, i, st in picked["replaced"]:
        take(b, st)
        window = _window(out, b, _position(out, b, st.x))
        for _ in range(TRIES):
            new = _draw_stack(rng, out, b, cfg)
            if new is None or max(abs(p - q) for p, q in zip(new.size, st.size)) < MIN_RESIZE:
                continue
            x = _draw_x(rng, _centres(out, b, _half_x(new), window))
            if x is not None:
                new = replace(new, x=x)
                put(b, new)
                changes += [Change("removed", b, st, b, i, "replaced"), Change("added", b, new, note="replaced")]
                break
        else:
            put(b, st)
    for b, i, st in picked["shifted"]:
        take(b, st)
        window = _window(out, b, _position(out, b, st.x))
        x = _draw_x(rng, _centres(out, b, _half_x(st), window, avoid=st.x))
        new = st if x is None else replace(st, x=x)
        put(b, new)
        if x is not None:
            changes.append(Change("shifted", b, new, b, i))
    n_pos = out.config["positions"]
    places = [(b, j) for b in boards for j in range(n_pos)]
    for b, i, st in picked["moved"]:
        take(b, st)
        here = (b, _position(out, b, st.x))
        for t in rng.permutation(len(places)):
            dest, j = places[int(t)]
            if (dest, j) == here or not _fits(out, dest, st, cfg):
                continue
            x = _draw_x(rng, _centres(out, dest, _half_x(st), _window(out, dest, j)))
            if x is not None:
                new = replace(st, x=x)
                put(dest, new)
                changes.append(Change("moved", dest, new, b, i))
                break
        else:
            put(b, st)
    for _ in range(n["added"]):
        for _ in range(TRIES):
            b = boards[int(rng.integers(len(boards)))]
            new = _draw_stack(rng, out, b, cfg)
            x = None if new is None else _draw_x(rng, _centres(out, b, _half_x(new), _window(out, b, None)))
            if new is not None and x is not None:
                new = replace(new, x=x)
                put(b, new)
                changes.append(Change("added", b, new))
                break
    return out, changes


def _where(building: Building, b: Board, index: int, st: StackPlan) -> tuple[str, list[str], float]:
    """(location code, box ids, building X) of the stack at ``index`` on board ``b``."""
    face = building.faces[b.face]
    j = _position(building, b, st.x)
    code = location_code(building.config["code"], face.aisle, face.side, b.bay, b.level + 1, j + 1)
    return code, [box_id(code, index, k) for k in range(st.count)], face.sign * st.x + 0.0


def changes_rows(before: Building, after: Building, changes: list[Change]) -> list[dict[str, Any]]:
    """``changes.csv``'s rows (`CHANGES_COLUMNS`), sorted by location and change: ``location`` where the stack
    stands in ``after`` (``removed``: where it stood in ``before``), ``other_location`` the location a move left,
    ``box_ids`` its boxes' ids in ``after``'s ground truth, ``old_box_ids`` in ``before``'s."""
    rows = []
    for c in changes:
        w, h, d = c.stack.size
        row = {"change": c.change, "other_location": "", "boxes": c.stack.count, "size": f"{w:.3f}x{h:.3f}x{d:.3f}",
               "box_ids": "", "old_box_ids": "", "x": "", "old_x": "", "note": c.note}  # fmt: skip
        if c.old_board is not None and c.old_index is not None:
            old = _rack(before, c.old_board).stacks[c.old_board.level][c.old_index]
            code, ids, x = _where(before, c.old_board, c.old_index, old)
            row.update(location=code, old_box_ids=";".join(ids), old_x=round(x, 4))
        if c.change != "removed":
            lst = _rack(after, c.board).stacks[c.board.level]
            index = next(i for i, s in enumerate(lst) if s is c.stack)
            code, ids, x = _where(after, c.board, index, c.stack)
            if c.change == "moved":
                row["other_location"] = row["location"]
            row.update(location=code, box_ids=";".join(ids), x=round(x, 4))
        rows.append(row)
    rows.sort(key=lambda r: (r["location"], r["change"], str(r["x"]), str(r["old_x"])))
    return rows


def changes_csv(rows: list[dict[str, Any]]) -> str:
    """``changes.csv`` as text: a header (`CHANGES_COLUMNS`), then one row per changed stack."""
    return rows_csv([{k: r[k] for k in CHANGES_COLUMNS} for r in rows], CHANGES_COLUMNS)


def location_change_rows(before: Building, after: Building) -> list[dict[str, Any]]:
    """``location_changes.csv``'s rows (`layouts.location_changes.TRUTH_COLUMNS`), building order: each location
    whose stack count differs between ``before`` and ``after``, with both counts and its category."""
    counts = {r["location"]: int(r["boxes"]) for r in ground_truth(before)[1]}
    rows = []
    for r in ground_truth(after)[1]:
        old, new = counts.get(r["location"], 0), int(r["boxes"])
        if (kind := count_change(old, new)) != UNCHANGED:
            rows.append({"location": r["location"], "before": old, "after": new, "change": kind})
    return rows


def location_changes_csv(rows: list[dict[str, Any]]) -> str:
    """``location_changes.csv`` as text: a header (`TRUTH_COLUMNS`), then one row per location whose count changed."""
    return rows_csv(rows, TRUTH_COLUMNS)

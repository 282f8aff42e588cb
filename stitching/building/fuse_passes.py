"""Fuse the placed passes of a building into one `BuildingMap`: one rack per bay, one shelf per location, each
box once.

Per face (its frame, `stitching.building.map`):

* **Racks**: a rack one pass saw where another saw two bays with a gap between is cut at that gap; then
  two passes' racks whose X ranges overlap by half the shorter are one bay; its ends are where the
  passes that saw them whole put them (median), so a rack cut at one pass's end is joined with the next pass's
  view of it, and stays ``partial`` only where no pass saw that end. Bays are numbered from 1 along building +X.
* **Levels**: a bay's levels are those of the floor plan (else those some pass saw); a level no pass's view held
  is kept with no boxes and ``not scanned``.
* **Boxes**: per level, the boxes of every pass, best seen first (observations, then confidence); a box of
  another pass whose X extent overlaps an kept one's by half the narrower is the same box seen again.
* **Locations**: a level cut along X into ``positions`` equal parts, each a shelf whose id is its code; the
  passes whose view held part of it, and the share held, decide whether it was scanned.
* **With a location list** (`layouts.location_list`, ``listed``): codes, bays, levels and spans come from the
  list, never from what the passes found: each listed location is a shelf over its listed span (a face's bay
  the union of its locations), the fused boxes of its level go to the listed location holding their centre,
  and a box that no listed location holds is kept aside (`BuildingMap.outside`), never given a code. Every
  listed location gets a record (``not scanned`` where no pass's view held it), on faces no pass saw too.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

from layouts.errors import InputError
from layouts.location_list import ListedLocation
from layouts.locations import DEFAULT_CODE, check_code_format, covered_length, location_code
from stitching.building.config import FuseConfig
from stitching.building.map import BuildingMap, FaceMap, Location, PassPlacement, listed_code_format
from stitching.building.place import PlacedBox, PlacedPass, PlacedRack, PlacedShelf
from stitching.building.route import FacePlan, Route
from stitching.uprights import Upright, bay_cuts, fuse_uprights
from stitching.warehouse_map import MapBox, MapRack, MapShelf, WarehouseMap, partial_side

Seen = tuple[PlacedPass, PlacedRack]  #: a rack as one pass saw it
Bay = list[Seen]  #: the racks of the passes that are one bay
Fused = tuple[PlacedBox, float, list[str]]  #: a box once: its best view, its face X, the passes that saw it


def _clusters(items: list[Seen], cfg: FuseConfig) -> list[Bay]:
    """Racks of the face grouped into bays (union-find on overlap), ordered by face X."""
    n = len(items)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    spans = [(r.lo + p.offset, r.hi + p.offset) for p, r in items]
    for i in range(n):
        for j in range(i + 1, n):
            if items[i][0] is items[j][0]:
                continue
            (a0, a1), (b0, b1) = spans[i], spans[j]
            shorter = min(a1 - a0, b1 - b0)
            if shorter > 0 and min(a1, b1) - max(a0, b0) >= cfg.same_rack * shorter:
                parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    out = [[items[i] for i in g] for g in groups.values()]
    return sorted(out, key=lambda g: statistics.median((r.lo + r.hi) / 2 + p.offset for p, r in g))


def _split_joined(items: list[Seen], cfg: FuseConfig) -> list[Seen]:
    """A rack one pass saw as one where another pass saw two (a narrow gap between bays lost in its layouts) is
    cut at the other pass's gap: its shelves go to both parts, its boxes by their centre."""
    gaps = []  # (gap start, gap end, pass) between two whole-seen neighbouring racks of a pass
    for p in {id(p): p for p, _ in items}.values():
        rs = sorted(p.racks, key=lambda r: r.lo)
        for a, b in zip(rs, rs[1:]):
            if not a.cut_hi and not b.cut_lo and 0 <= b.lo - a.hi < 1.0:
                gaps.append((a.hi + p.offset, b.lo + p.offset, p))
    out = []
    for p, r in items:
        parts = [r]
        for g0, g1, other in sorted(gaps, key=lambda g: g[0]):
            if other is p:
                continue
            last = parts[-1]
            lo, hi = last.lo + p.offset, last.hi + p.offset
            if lo + cfg.split_margin < g0 and g1 < hi - cfg.split_margin:
                cut0, cut1 = g0 - p.offset, g1 - p.offset
                left = PlacedRack(
                    last.lo, cut0, last.cut_lo, False, last.shelves, [b for b in last.boxes if b.x < (cut0 + cut1) / 2]
                )
                right = PlacedRack(
                    cut1, last.hi, False, last.cut_hi, last.shelves, [b for b in last.boxes if b.x >= (cut0 + cut1) / 2]
                )
                parts[-1:] = [left, right]
        out += [(p, part) for part in parts]
    return out


def _split_long(groups: list[Bay], cfg: FuseConfig) -> list[Bay]:
    """A bay ``long_bay`` times longer than the face's typical bay is bays whose gap no pass saw: cut into as many
    typical bays, each cut in the box-free X nearest its even share (boxes never straddle two bays)."""
    lengths = [hi - lo for lo, hi, _, _ in map(_ends, groups)]
    whole = sorted(n for n, g in zip(lengths, groups) if not any(r.cut_lo or r.cut_hi for _, r in g))
    if len(whole) < 3:
        return groups
    typical = whole[len(whole) // 2]
    out = []
    for n, g in zip(lengths, groups):
        k = round(n / typical)
        if n < cfg.long_bay * typical or k < 2:
            out.append(g)
            continue
        lo, hi, _, _ = _ends(g)
        spans = [(b.x + p.offset - b.size[0] / 2, b.x + p.offset + b.size[0] / 2) for p, r in g for b in r.boxes]
        cuts = []
        for j in range(1, k):
            aim = lo + j * n / k
            free = [
                x
                for x in (aim + 0.02 * i for i in range(-30, 31))
                if not any(a - 0.05 < x < b + 0.05 for a, b in spans)
            ]
            cuts.append(min(free, key=lambda x: abs(x - aim)) if free else aim)
        out += _cut_group(g, cuts)
    return out


def _cut_group(g: Bay, cuts: list[float]) -> list[Bay]:
    """A bay group cut at face X ``cuts`` (ascending): each pass's rack clipped to each part, boxes by centre."""
    lo, hi = _ends(g)[:2]
    edges = [lo - 1.0, *cuts, hi + 1.0]
    out = []
    for a, b in zip(edges, edges[1:]):
        part = []
        for p, r in g:
            r0, r1 = max(r.lo + p.offset, a), min(r.hi + p.offset, b)
            if r1 - r0 > 0.2:
                mine = [bx for bx in r.boxes if a <= bx.x + p.offset < b]
                part.append((p, PlacedRack(r0 - p.offset, r1 - p.offset, r.cut_lo and r0 == r.lo + p.offset,
                                           r.cut_hi and r1 == r.hi + p.offset, r.shelves, mine)))  # fmt: skip
        if part:
            out.append(part)
    return out


def _split_at_uprights(groups: list[Bay], passes: list[PlacedPass]) -> tuple[list[Bay], list[float]]:
    """Bays run together (touching, or a gap no pass saw) cut at the upright frames the passes found, fused over
    the face (`stitching.uprights`); the face's typical bay width (the median of the bays so cut) drops a cut
    that would leave two half bays. Also the face X of the cuts `bay_cuts` calls uncertain (for the recount)."""
    ups = fuse_uprights([[Upright(u.x + p.offset, u.support) for u in p.uprights] for p in passes])
    if not ups:
        return groups, []
    spans = [_ends(g)[:2] for g in groups]
    first = [[x for x, _ in bay_cuts(lo, hi, ups, None)] for lo, hi in spans]
    widths = [b - a for (lo, hi), cuts in zip(spans, first) for a, b in zip([lo, *cuts], [*cuts, hi])]
    typical = statistics.median(widths) if widths else None
    out, uncertain = [], []
    for g, (lo, hi) in zip(groups, spans):
        found = bay_cuts(lo, hi, ups, typical)
        cuts = [x for x, _ in found]
        uncertain += [x for x, certain in found if not certain]
        out += _cut_group(g, cuts) if cuts else [g]
    return out, uncertain


def _ends(group: Bay) -> tuple[float, float, bool, bool]:
    whole_lo = [r.lo + p.offset for p, r in group if not r.cut_lo]
    whole_hi = [r.hi + p.offset for p, r in group if not r.cut_hi]
    lo = statistics.median(whole_lo) if whole_lo else min(r.lo + p.offset for p, r in group)
    hi = statistics.median(whole_hi) if whole_hi else max(r.hi + p.offset for p, r in group)
    return lo, hi, not whole_lo, not whole_hi


def _board_heights(face: FacePlan, passes: Sequence[PlacedPass]) -> dict[int, float]:
    """Level -> board height above the floor: the plan's, else the passes' (lowest slot's board on the floor)."""
    if face.levels_m:
        return {k + 1: h for k, h in enumerate(face.levels_m)}
    seen: dict[int, list[float]] = {}
    for p in passes:
        for r in p.racks:
            for s in r.shelves:
                seen.setdefault(s.level, []).append(s.board)
    base = min(seen) if seen else 1
    return {lv: statistics.median(v) for lv, v in seen.items()} | ({base: 0.0} if seen else {})


def _fuse_boxes(candidates: list[tuple[PlacedPass, PlacedBox]], cfg: FuseConfig) -> list[Fused]:
    """Each box once: (box, face-frame X, passes that saw it)."""
    order = sorted(candidates, key=lambda c: (-c[1].observations, -c[1].confidence, c[1].x + c[0].offset))
    kept: list[tuple[PlacedBox, float, list[str], PlacedPass]] = []
    for p, b in order:
        x = b.x + p.offset
        for k, (kb, kx, names, kp) in enumerate(kept):
            overlap = min(x + b.size[0] / 2, kx + kb.size[0] / 2) - max(x - b.size[0] / 2, kx - kb.size[0] / 2)
            narrower = min(b.size[0], kb.size[0])
            if kp is not p and overlap >= cfg.same_box * narrower:
                kept[k] = (kb, kx, names + [p.pose.sequence], kp)
                break
            if overlap >= cfg.ghost * narrower:  # boxes stand side by side: one this far into a better seen is none
                break
        else:
            kept.append((b, x, [p.pose.sequence], p))
    return sorted(((b, x, names) for b, x, names, _ in kept), key=lambda t: t[1])


def _pass_counts(
    boxes: Sequence[Fused], saw: list[str], views: dict[str, list], a: float, b: float, cfg: FuseConfig
) -> dict[str, int]:
    """The boxes of a location on face X ``[a, b]`` (`_fuse_boxes`' triples) each pass of ``saw`` counted that
    held all of it in view, where two or more did (else empty): passes that disagree make the count uncertain."""
    whole = [n for n in saw if covered_length(views[n], a, b) >= cfg.whole_view * (b - a)]
    return {n: sum(n in names for _, _, names in boxes) for n in whole} if len(whole) > 1 else {}


def _fuse_face(
    face: FacePlan, passes: list[PlacedPass], code: str, positions: int, order: dict[str, int], cfg: FuseConfig
) -> FaceMap:
    items = _split_joined([(p, r) for p in passes for r in p.racks], cfg)
    views = {p.pose.sequence: [(a + p.offset, b + p.offset) for a, b in p.seen] or [p.seen_range()] for p in passes}
    groups, uncertain = _split_at_uprights(_clusters(items, cfg), passes)
    spans = _unseen_bays(face, [(*_ends(g)[:2], g) for g in _split_long(groups, cfg)], views)
    if face.sign < 0:
        spans = spans[::-1]  # bays count along building +X, face X runs the other way on an L face
    heights = _board_heights(face, passes)
    thickness = statistics.median(p.board_thickness for p in passes) if passes else 0.06
    racks, locations, bays = [], {}, {}
    for bay, (lo, hi, group) in enumerate(spans, start=1):
        cut_lo, cut_hi = _ends(group)[2:] if group else (False, False)
        rack_id = f"{face.aisle:02d}-{face.side}-{bay:02d}"
        partial = partial_side(cut_lo, cut_hi)
        levels = sorted(set(heights) | {s.level for _, r in group for s in r.shelves})
        shelves = []
        for lv in levels:
            seen_shelves: list[tuple[PlacedPass, PlacedShelf]] = [
                (p, s) for p, r in group for s in r.shelves if s.level == lv
            ]
            board = heights.get(lv)
            if board is None:  # a level the plan does not list: where the passes put it above a known one
                board = statistics.median(
                    heights.get(min(p.levels), 0.0) + s.board - _lowest_board(p) for p, s in seen_shelves
                )
            above = [h for k, h in heights.items() if k > lv]
            if above:
                clear = min(above) - board - thickness
            elif seen_shelves:
                clear = statistics.median(s.clear for _, s in seen_shelves)
            else:
                clear = cfg.default_clear
            z_range = (
                tuple(statistics.median(s.z_range[k] for _, s in seen_shelves) for k in (0, 1))
                if seen_shelves
                else _face_depth(group)
            )
            conf = max((s.confidence for _, s in seen_shelves), default=0.0)
            boxes = _fuse_boxes([(p, b) for p, r in group for b in r.boxes if b.level == lv], cfg)
            cut = (hi - lo) / positions
            for j in range(positions):
                # position 1 at the lowest building X: the low face-X end on an R face, the high one on an L face
                a = lo + j * cut if face.sign > 0 else hi - (j + 1) * cut
                b = a + cut
                pos_code = location_code(code, face.aisle, face.side, bay, lv, j + 1)
                mine = [t for t in boxes if a <= t[1] < b or (t[1] == b and b == hi)]
                map_boxes = [
                    _map_box(f"{pos_code}/box_{k:02d}", bx, x, board, clear) for k, (bx, x, _) in enumerate(mine)
                ]
                pcut_lo = cut_lo and abs(a - lo) < 1e-9
                pcut_hi = cut_hi and abs(b - hi) < 1e-9
                shelves.append(
                    MapShelf(
                        pos_code,
                        lv - 1,
                        board,
                        max(clear, 0.05),
                        (a, b),
                        z_range,
                        conf,
                        map_boxes,
                        partial_side(pcut_lo, pcut_hi),
                    )  # fmt: skip
                )
                saw = sorted(
                    {
                        p.pose.sequence
                        for p in passes
                        if group and lv in p.levels and covered_length(views[p.pose.sequence], a, b) > 1e-6
                    },  # a bay no pass found (`_unseen_bays`) is not scanned
                    key=order.__getitem__,
                )
                seen = covered_length([iv for name in saw for iv in views[name]], a, b) / (b - a) if b > a else 0.0
                counts = _pass_counts(mine, saw, views, a, b, cfg)
                locations[pos_code] = Location(
                    pos_code, face.aisle, face.side, bay, lv, j + 1, saw, min(seen, 1.0), counts
                )
        racks.append(MapRack(rack_id, (lo, hi), shelves, partial))
        bays[rack_id] = bay
    seen_x = sorted(iv for v in views.values() for iv in v)
    wmap = WarehouseMap(racks, [], thickness, None, {"face": f"{face.aisle:02d}-{face.side}"}, seen_x)
    return FaceMap(face.aisle, face.side, face.front_z, wmap, locations, bays, tuple(uncertain))


def _map_box(ident: str, bx: PlacedBox, x: float, board: float, clear: float) -> MapBox:
    """The map's box ``ident`` of fused box ``bx`` at face X ``x``, standing on its board (`_standing`)."""
    rel, size = _standing(bx, clear)
    return MapBox(ident, (x, -(board + rel), bx.z), size, bx.yaw, bx.confidence, bx.observations, bx.colour)


def _standing(bx: PlacedBox, clear: float) -> tuple[float, tuple[float, float, float]]:
    """(centre height above the board, size) of a box on a level of ``clear`` height: no taller than the level,
    standing on its board (a pass that measured its level higher than the plan's saw it taller)."""
    clear = max(clear, 0.05)
    h = min(bx.size[1], clear)
    return min(max(bx.rel, h / 2), clear - h / 2), (bx.size[0], h, bx.size[2])


def _unseen_bays(
    face: FacePlan, spans: list[tuple[float, float, list]], views: dict[str, list[tuple[float, float]]]
) -> list[tuple[float, float, list]]:
    """The face's bays (face-frame ends, the racks of each) with every stretch of the floor plan's face that no
    pass's view held and no bay fills cut into bays of the face's typical length, with no racks: a bay never seen
    is a bay, `not scanned`, never absent."""
    if face.x_min is None or face.x_max is None or not spans:
        return spans
    typical = statistics.median(hi - lo for lo, hi, _ in spans)
    start, end = sorted((face.sign * face.x_min, face.sign * face.x_max))
    seen = [iv for v in views.values() for iv in v]
    out, edge = [], start
    for lo, hi, g in [*sorted(spans, key=lambda t: t[0]), (end, end, None)]:
        gap = lo - edge
        k = round(gap / typical) if typical > 0 else 0
        if k >= 1 and gap >= 0.8 * typical:
            cuts = [(edge + j * gap / k, edge + (j + 1) * gap / k) for j in range(k)]
            out += [(a, b, []) for a, b in cuts if covered_length(seen, a, b) < 0.5 * (b - a)]
        if g is not None:
            out.append((lo, hi, g))
        edge = max(edge, hi)
    return out


def _shelf_facts(
    lv: int, a: float, b: float, heights: dict[int, float], thickness: float, passes: list[PlacedPass], clear0: float
) -> tuple[float, float, tuple[float, float], float]:
    """(board, clear height, Z range, confidence) of level ``lv`` over face X ``[a, b]``: the plan's heights,
    else what the passes whose racks overlap it saw (``clear0``: the clear height of a level nobody saw)."""
    seen = [
        (p, s)
        for p in passes
        for r in p.racks
        if min(r.hi + p.offset, b) > max(r.lo + p.offset, a)
        for s in r.shelves
        if s.level == lv
    ]
    board = heights.get(lv)
    if board is None:
        board = (
            statistics.median(heights.get(min(p.levels), 0.0) + s.board - _lowest_board(p) for p, s in seen)
            if seen
            else max(heights.values(), default=0.0) + clear0 * (lv - max(heights, default=0))
        )
    above = [h for k, h in heights.items() if k > lv]
    clear = min(above) - board - thickness if above else (
        statistics.median(s.clear for _, s in seen) if seen else clear0
    )  # fmt: skip
    zs = [s.z_range for _, s in seen] or [s.z_range for p in passes for r in p.racks for s in r.shelves]
    z = (statistics.median(v[0] for v in zs), statistics.median(v[1] for v in zs)) if zs else (0.0, 1.0)
    return board, max(clear, 0.05), z, max((s.confidence for _, s in seen), default=0.0)


def _fuse_listed(
    face: FacePlan, passes: list[PlacedPass], listed: list[ListedLocation], order: dict[str, int], cfg: FuseConfig
) -> tuple[FaceMap, list[dict[str, Any]]]:
    """A face whose locations the list gives (see the module docstring); returns it and the boxes outside every
    listed location of it (building frame)."""
    heights = _board_heights(face, passes)
    thickness = statistics.median(p.board_thickness for p in passes) if passes else 0.06
    views = {p.pose.sequence: [(a + p.offset, b + p.offset) for a, b in p.seen] or [p.seen_range()] for p in passes}
    span = {e.code: tuple(sorted((face.sign * e.start_m, face.sign * e.end_m))) for e in listed}
    kept: dict[str, list[Fused]] = {e.code: [] for e in listed}
    outside = []
    for lv in sorted({b.level for p in passes for r in p.racks for b in r.boxes}):
        mine = [e for e in listed if e.level == lv]
        for bx, x, names in _fuse_boxes(
            [(p, b) for p in passes for r in p.racks for b in r.boxes if b.level == lv], cfg
        ):
            home = [e for e in mine if span[e.code][0] <= x < span[e.code][1]]
            if home:
                kept[home[0].code].append((bx, x, names))
                continue
            board = heights.get(lv, 0.0)
            outside.append({
                "face": f"{face.aisle:02d}-{face.side}", "level": lv, "x": round(face.sign * x, 4) + 0.0,
                "center": [round(face.sign * x, 4) + 0.0, round(-(board + bx.rel), 4),
                           round(face.front_z + face.sign * bx.z, 4)],
                "size": [round(v, 4) for v in bx.size], "confidence": round(bx.confidence, 4), "passes": names,
            })  # fmt: skip
    racks, locations, bays = [], {}, {}
    for bay in sorted({e.bay for e in listed}):
        entries = sorted((e for e in listed if e.bay == bay), key=lambda e: (e.level, span[e.code]))
        lo, hi = min(span[e.code][0] for e in entries), max(span[e.code][1] for e in entries)
        shelves = []
        for e in entries:
            a, b = span[e.code]
            board, clear, z_range, conf = _shelf_facts(e.level, a, b, heights, thickness, passes, cfg.default_clear)
            boxes = [
                _map_box(f"{e.code}/box_{k:02d}", bx, x, board, clear) for k, (bx, x, _) in enumerate(kept[e.code])
            ]
            shelves.append(MapShelf(e.code, e.level - 1, board, clear, (a, b), z_range, conf, boxes, None))
            saw = sorted(
                (n for n, p in ((p.pose.sequence, p) for p in passes) if e.level in p.levels
                 and covered_length(views[n], a, b) > 1e-6),
                key=order.__getitem__,
            )  # fmt: skip
            seen = covered_length([iv for n in saw for iv in views[n]], a, b) / (b - a)
            counts = _pass_counts(kept[e.code], saw, views, a, b, cfg)
            locations[e.code] = Location(
                e.code, e.aisle, e.side, e.bay, e.level, e.position, saw, min(seen, 1.0), counts
            )
        rack_id = f"{face.aisle:02d}-{face.side}-{bay:02d}"
        racks.append(MapRack(rack_id, (lo, hi), shelves, None))
        bays[rack_id] = bay
    racks.sort(key=lambda r: r.x_range)
    seen_x = sorted(iv for v in views.values() for iv in v)
    wmap = WarehouseMap(racks, [], thickness, None, {"face": f"{face.aisle:02d}-{face.side}"}, seen_x)
    return FaceMap(face.aisle, face.side, face.front_z, wmap, locations, bays), outside


def _lowest_board(p: PlacedPass) -> float:
    return min((s.board for r in p.racks for s in r.shelves), default=0.0)


def _face_depth(group: Bay) -> tuple[float, float]:
    zs = [s.z_range for _, r in group for s in r.shelves]
    if not zs:
        return (0.0, 1.0)
    return (statistics.median(z[0] for z in zs), statistics.median(z[1] for z in zs))


def check_listed(listed: Sequence[ListedLocation], route: Route, source: str) -> None:
    """Refuse, in one line naming ``source``, a location list with a location on a face the floor plan lacks."""
    lacking = [e for e in listed if e.face not in route.faces]
    if lacking:
        e = lacking[0]
        raise InputError(f"{source}: location {e.code!r} is on face {e.aisle:02d}-{e.side}, which the route's "
                         f"floor plan ({route.source}) does not list")  # fmt: skip


def fuse_building(
    route: Route,
    placed: list[PlacedPass],
    code: str = DEFAULT_CODE,
    positions: int = 1,
    meta: dict | None = None,
    listed: Sequence[ListedLocation] | None = None,
    listed_source: str = "location list",
    cfg: FuseConfig | None = None,
) -> BuildingMap:
    """Fuse the passes, placed and registered (`stitching.building.place.place_passes`), into one building map
    (faces in plan order); with ``listed`` (a location list, read from ``listed_source``) its codes and spans
    (see the module docstring)."""
    cfg = cfg or FuseConfig()
    if listed is not None:
        positions = max(e.position for e in listed)
        code = listed_code_format(positions)
        check_listed(listed, route, listed_source)
    check_code_format(code, positions)
    order = {p.pose.sequence: k for k, p in enumerate(placed)}
    faces, outside = [], []
    for key, plan in sorted(route.faces.items()):
        mine = [p for p in placed if p.pose.key == key]
        if listed is not None:
            face_list = [e for e in listed if e.face == key]
            if face_list or mine:  # a face the list lacks: every box its passes saw lies outside
                face, out = _fuse_listed(plan, mine, face_list, order, cfg)
                faces.append(face)
                outside += out
        elif mine:
            faces.append(_fuse_face(plan, mine, code, positions, order, cfg))
    placements = [
        PassPlacement(
            p.pose.sequence,
            p.pose.aisle,
            p.pose.side,
            p.x0,
            p.shift,
            p.levels,
            p.edges,
            sum(len(r.boxes) for r in p.racks),
            p.trusted,
        )  # fmt: skip
        for p in placed
    ]
    plan = tuple(f for _, f in sorted(route.faces.items()))
    bmap = BuildingMap(faces, placements, code, positions, dict(meta or {}), plan)
    if listed is not None:
        bmap.location_list, bmap.outside = listed_source, outside
    return bmap

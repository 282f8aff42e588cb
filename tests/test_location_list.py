"""The location list (`layouts.location_list`): round trip, the generated building's list, each malformed file
refused in one line naming the file, the row and the column."""

from __future__ import annotations

import pytest

from layouts.errors import ContractError, InputError
from layouts.location_list import ListedLocation, read_location_list, write_location_list
from layouts.locations import read_inventory

HEADER = "code,aisle,side,bay,level,start_m,end_m"
GOOD = [
    "01-L-01-01,1,L,1,1,3.0,5.7",
    "01-L-01-02,1,L,1,2,3.0,5.7",
    "01-R-02-01,1,R,2,1,5.7,8.4",
]


def _write(tmp_path, lines: list[str], header: str = HEADER):
    p = tmp_path / "locations.csv"
    p.write_text("\n".join([header, *lines]) + "\n", encoding="utf-8")
    return p


def test_round_trip(tmp_path):
    entries = [
        ListedLocation("A1", 1, "L", 1, 1, 3.0, 4.35, 1),
        ListedLocation("A2", 1, "L", 1, 1, 4.35, 5.7, 2),
        ListedLocation("B1", 2, "R", 4, 3, -2.5, 0.125, 1),
    ]
    p = tmp_path / "out" / "locations.csv"
    p.parent.mkdir()
    write_location_list(entries, p)
    assert read_location_list(p) == entries
    first = p.read_bytes()
    write_location_list(entries, p)
    assert p.read_bytes() == first
    assert first.decode().splitlines()[0] == HEADER + ",position"


def test_position_optional(tmp_path):
    got = read_location_list(_write(tmp_path, GOOD))
    assert [e.code for e in got] == ["01-L-01-01", "01-L-01-02", "01-R-02-01"]
    assert all(e.position == 1 for e in got)
    assert got[2].face == (1, "R") and got[2].start_m == 5.7 and got[2].length == pytest.approx(2.7)


@pytest.mark.parametrize(
    ("lines", "header", "needle"),
    [
        (GOOD + ["01-L-01-01,1,L,3,1,9,10"], HEADER, "row 4: code: '01-L-01-01' is listed twice"),
        (GOOD + ["X,1,L,1,1,9,10"], HEADER, "row 4: bay, level, position"),
        (["A,1,L,1,1,5.7,3.0"], HEADER, "row 1: start_m, end_m: start_m 5.7 must lie below end_m 3.0"),
        (["A,1,L,1,1,3.0,3.0"], HEADER, "row 1: start_m, end_m"),
        (["A,1,L,1,0,3.0,4.0"], HEADER, "row 1: level:"),
        (["A,1,L,1,1.5,3.0,4.0"], HEADER, "row 1: level: must be a whole number"),
        (["A,1,L,1,100,3.0,4.0"], HEADER, "row 1: level: must lie in [1, 99]"),
        (["A,1,L,1,1,3.0,nan"], HEADER, "row 1: end_m:"),
        (["A,1,L,1,1,3.0,1e400"], HEADER, "row 1: end_m:"),
        (["A,1,X,1,1,3.0,4.0"], HEADER, "row 1: side:"),
        (["A,one,L,1,1,3.0,4.0"], HEADER, "row 1: aisle:"),
        (["A,1,L,1,1,3.0,4.0,0"], HEADER + ",position", "row 1: position:"),
        ([",1,L,1,1,3.0,4.0"], HEADER, "row 1: code:"),
        (["A,1,L,1,1,3.0"], HEADER, "row 1: holds fewer fields"),
        (["A,1,L,1,1,3.0,4.0,7"], HEADER, "row 1: holds more fields"),
        (["A,1,L,1,1,3.0"], "code,aisle,side,bay,level,start_m", "header lacks end_m"),
        ([], HEADER, "lists no location"),
    ],
)
def test_malformed_one_line(tmp_path, lines, header, needle):
    p = _write(tmp_path, lines, header)
    with pytest.raises(InputError) as e:
        read_location_list(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)) and needle in msg, msg


def test_unreadable_files(tmp_path):
    for p, needle in ((tmp_path / "none.csv", "file not found"), (tmp_path, "a folder")):
        with pytest.raises(InputError, match=needle):
            read_location_list(p)
    bad = tmp_path / "bin.csv"
    bad.write_bytes(b"\xff\xfe\x00code")
    with pytest.raises(InputError, match="not UTF-8"):
        read_location_list(bad)


def test_write_checks_first(tmp_path):
    p = tmp_path / "locations.csv"
    with pytest.raises(ContractError, match="row 2: code"):
        write_location_list([ListedLocation("A", 1, "L", 1, 1, 0, 1), ListedLocation("A", 1, "L", 2, 1, 1, 2)], p)
    assert not p.exists()


def test_generated_building_list(tiny_building):
    """`generate --building` writes the list of every ground-truth location, spans along building X."""
    listed = read_location_list(tiny_building / "locations.csv")
    truth = read_inventory((tiny_building / "ground_truth" / "inventory.csv").read_text())
    assert [e.code for e in listed] == [r["location"] for r in truth]
    assert [(e.aisle, e.side, e.bay, e.level) for e in listed] == [
        (int(r["aisle"]), r["side"], int(r["bay"]), int(r["level"])) for r in truth
    ]
    by_face: dict = {}
    for e in listed:
        by_face.setdefault((e.face, e.level), []).append((e.start_m, e.end_m))
    for spans in by_face.values():  # bays along a face do not overlap
        spans.sort()
        assert all(a[1] <= b[0] + 1e-6 for a, b in zip(spans, spans[1:]))

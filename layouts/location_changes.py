"""A location's change between two counts, as a warehouse acts on it: shared by a generated rescan's ground truth
(``ground_truth/location_changes.csv``) and ``mvracklay diff`` (``location_changes.csv``).

A location's count is its box stacks (as in the inventory). Between an earlier and a later count it was
``emptied`` (some -> none), ``filled`` (none -> some), its ``count changed`` (some -> another number) or is
``unchanged``: the categories a person acts on (put away, pick, recount), whatever moved inside it.
"""

from __future__ import annotations

EMPTIED, FILLED, COUNT_CHANGED, UNCHANGED = "emptied", "filled", "count changed", "unchanged"
#: the categories a location's change is reported in (`UNCHANGED` is not a change)
LOCATION_CHANGES = (EMPTIED, FILLED, COUNT_CHANGED)
#: a generated rescan's ``ground_truth/location_changes.csv``: one row per location whose count changed
TRUTH_COLUMNS = ("location", "before", "after", "change")


def count_change(before: int, after: int) -> str:
    """The category of a location counted ``before`` and then ``after`` box stacks."""
    if before == after:
        return UNCHANGED
    if after == 0:
        return EMPTIED
    if before == 0:
        return FILLED
    return COUNT_CHANGED

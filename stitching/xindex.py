"""`XIndex`: integer ids bucketed by an X coordinate, for range queries along a long rack row.

The map of a long aisle holds thousands of boxes and rack ends, but each frame only touches the
few metres in view. Scanning every map item per frame makes stitching time grow with the length
already mapped (quadratic over a sequence); bucketing by X keeps the per-frame cost proportional
to what is nearby. Queries return ids in ascending order (insertion order), so callers see items
in the same order as a full scan would give them and results do not depend on the index.
"""

from __future__ import annotations

import math


class XIndex:
    """Ids keyed by X (metres) in buckets of ``bucket`` metres; ``query`` returns a sorted superset."""

    def __init__(self, bucket: float = 1.0):
        if not (isinstance(bucket, (int, float)) and math.isfinite(bucket) and bucket > 0):
            raise ValueError(f"XIndex bucket must be a positive finite number, got {bucket!r}")
        self.bucket = float(bucket)
        self._buckets: dict[int, set[int]] = {}
        self._where: dict[int, int] = {}

    def _key(self, x: float) -> int:
        return math.floor(x / self.bucket)

    def __len__(self) -> int:
        return len(self._where)

    def add(self, ident: int, x: float) -> None:
        """Index ``ident`` at ``x`` (an id already present is moved)."""
        k = self._key(x)
        old = self._where.get(ident)
        if old == k:
            return
        if old is not None:
            self._buckets[old].discard(ident)
        self._buckets.setdefault(k, set()).add(ident)
        self._where[ident] = k

    move = add

    def query(self, lo: float, hi: float) -> list[int]:
        """Ids whose X may lie in ``[lo, hi]`` (whole buckets: callers apply the exact test), ascending."""
        if hi < lo:
            return []
        k0, k1 = self._key(lo), self._key(hi)
        if k1 - k0 + 1 > len(self._buckets):
            found = [i for k, ids in self._buckets.items() if k0 <= k <= k1 for i in ids]
        else:
            found = [i for k in range(k0, k1 + 1) for i in self._buckets.get(k, ())]
        found.sort()
        return found

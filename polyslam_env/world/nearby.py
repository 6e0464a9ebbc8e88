"""The static wall index: a uniform grid listing the wall segments that touch each cell.

Walls never move, so one index per layout serves every episode on it. The compiled kernels
(:mod:`~polyslam_env.world.kernels`) ask it for the segments that may meet an axis-aligned box
— the bounding box of a beam, of a camera's line of sight, of a robot's path grown by its
radius — and test only those instead of every wall of the map.

A cell lists every segment whose bounding box, grown by ``MARGIN``, overlaps the cell, so a
segment that meets a box meets it in a cell the box overlaps (boxes are grown by the same
margin in the kernels), and that cell lists it: tests over the candidates give the same answers
as tests over all segments. A segment may be listed by several cells of a box and be tested
more than once; the kernels keep minima and "any", which repeats do not change.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from polyslam_env.world.layout import Layout

__all__ = ["MARGIN", "IndexArrays", "WallIndex", "wall_index"]

#: The index as the kernels take it: segments, origin, cell, rows, cols, starts, items.
IndexArrays = tuple[np.ndarray, np.ndarray, float, int, int, np.ndarray, np.ndarray]

#: Growth of segment and query boxes, m: far above any round-off of the coordinates.
MARGIN = 1e-6
#: Default cell side, m: a 2 m beam's box spans a few cells, a robot's guard box one to four.
CELL = 0.5


@dataclass(frozen=True, eq=False)
class WallIndex:
    """Segments (S, 4) and, per grid cell, the ids of those that may touch it (CSR layout).

    Cell ``(row, col)`` covers ``[ox + col·cell, ox + (col+1)·cell) × [oy + row·cell, …)``;
    the segments of cell ``c = row · cols + col`` are ``items[starts[c]:starts[c + 1]]``.
    """

    segments: np.ndarray  # (S, 4) x0, y0, x1, y1
    origin: np.ndarray  # (2,) lower-left corner of cell (0, 0)
    cell: float  # cell side, m
    rows: int
    cols: int
    starts: np.ndarray  # (rows · cols + 1,) int64
    items: np.ndarray  # (K,) int64 segment ids

    @classmethod
    def build(cls, segments: np.ndarray, cell: float = CELL) -> WallIndex:
        """The index of ``segments`` (S, 4) with square cells of side ``cell``."""
        if not (math.isfinite(cell) and cell > 0):
            raise ValueError(f"cell: must be a finite number > 0, got {cell!r}")
        segs = np.ascontiguousarray(np.asarray(segments, dtype=float).reshape(-1, 4))
        if len(segs) == 0:
            empty = np.zeros(1, dtype=np.int64)
            return cls(segs, np.zeros(2), float(cell), 0, 0, empty, np.zeros(0, dtype=np.int64))
        lo = np.minimum(segs[:, 0:2], segs[:, 2:4]) - MARGIN  # (S, 2)
        hi = np.maximum(segs[:, 0:2], segs[:, 2:4]) + MARGIN
        origin = lo.min(axis=0) - cell  # one empty cell of border on every side
        cols, rows = (int(v) + 2 for v in np.floor((hi.max(axis=0) - origin) / cell))
        first = np.floor((lo - origin) / cell).astype(np.int64)  # (S, 2) col, row
        last = np.floor((hi - origin) / cell).astype(np.int64)
        cells: list[np.ndarray] = []
        owners: list[np.ndarray] = []
        for s in range(len(segs)):
            c = np.arange(first[s, 0], last[s, 0] + 1)
            r = np.arange(first[s, 1], last[s, 1] + 1)
            flat = (r[:, None] * cols + c[None, :]).reshape(-1)
            cells.append(flat)
            owners.append(np.full(len(flat), s, dtype=np.int64))
        flat_all, owner_all = np.concatenate(cells), np.concatenate(owners)
        order = np.lexsort((owner_all, flat_all))  # by cell, then segment id
        counts = np.bincount(flat_all, minlength=rows * cols)
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return cls(segs, origin, float(cell), rows, cols, starts, owner_all[order])

    @property
    def arrays(self) -> IndexArrays:
        """The index's fields in the kernels' argument order."""
        return (
            self.segments,
            self.origin,
            self.cell,
            self.rows,
            self.cols,
            self.starts,
            self.items,
        )

    def candidates(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:  # (k,) sorted ids
        """Ids of the segments listed by the cells that the box ``lo``–``hi`` (2,) overlaps
        (grown by ``MARGIN``): a superset of those that meet the box."""
        if self.rows == 0:
            return np.zeros(0, dtype=np.int64)
        c0, r0 = np.floor((np.asarray(lo) - MARGIN - self.origin) / self.cell).astype(np.int64)
        c1, r1 = np.floor((np.asarray(hi) + MARGIN - self.origin) / self.cell).astype(np.int64)
        c0, r0 = max(c0, 0), max(r0, 0)
        c1, r1 = min(c1, self.cols - 1), min(r1, self.rows - 1)
        found = [
            self.items[self.starts[r * self.cols + c] : self.starts[r * self.cols + c + 1]]
            for r in range(r0, r1 + 1)
            for c in range(c0, c1 + 1)
        ]
        return np.unique(np.concatenate(found)) if found else np.zeros(0, dtype=np.int64)


_INDEXES: weakref.WeakKeyDictionary[Layout, WallIndex] = weakref.WeakKeyDictionary()


def wall_index(layout: Layout) -> WallIndex:
    """The :class:`WallIndex` of a layout's segments, built once per layout (a world is rebuilt
    at every reset; the layout usually is not)."""
    index = _INDEXES.get(layout)
    if index is None:
        index = _INDEXES[layout] = WallIndex.build(layout.segments)
    return index

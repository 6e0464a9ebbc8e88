"""Which wall segments can be near a point: a uniform grid of candidate lists (numpy only).

The physics guard asks, every control step, whether a robot is within a few decimetres of any
wall segment or crossed one. On a map of a few hundred segments nearly all are far away, so
testing all of them costs several times more than testing the few a grid cell lists. The
answer does not change: every segment within ``reach`` of a point is among the candidates of
the point's cell (see :class:`SegmentGrid`), so "is any segment within ``reach``" and "the
nearest one, if within ``reach``" come out the same over the candidates as over all.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from polyslam_env.world.layout import Layout

__all__ = ["SegmentGrid", "segment_grid"]

#: Slack added to the candidate radius of a cell, m: far above any round-off of the distances.
_MARGIN = 1e-3


class SegmentGrid:
    """Candidate segments near points, exact for distances up to ``reach``.

    A grid of square cells (side ``cell``) covers the segments' bounding box grown by
    ``reach``; each cell lists (at least) the segments within ``reach`` + half its diagonal of
    its centre, which by the triangle inequality includes every segment within ``reach`` of
    any point of the cell. Points outside the grid are farther than ``reach`` from every segment.
    """

    def __init__(self, segments: np.ndarray, reach: float, cell: float) -> None:
        if not (reach >= 0 and cell > 0):
            raise ValueError(f"need reach >= 0 and cell > 0, got {reach}, {cell}")
        self.segments = np.asarray(segments, dtype=float).reshape(-1, 4)  # (S, 4)
        self.reach = float(reach)
        self.cell = float(cell)
        if len(self.segments) == 0:
            self.origin = np.zeros(2)
            self.shape = (0, 0)
            self._near = np.zeros((0, 0), dtype=bool)
            return
        xy = self.segments.reshape(-1, 2)  # (2S, 2) every end point
        self.origin = xy.min(axis=0) - reach - _MARGIN  # (2,) lower-left corner of the grid
        extent = xy.max(axis=0) + reach + _MARGIN - self.origin
        cols, rows = (max(math.ceil(e / cell), 1) for e in extent)
        self.shape = (rows, cols)
        # A cell must list every segment within ``radius`` of its centre (reach plus half the
        # cell's diagonal). Marked from samples every cell/2 along each segment: a centre within
        # ``radius`` of a segment is within ``radius + spacing/2`` of one of its samples.
        spacing = cell / 2
        radius = reach + cell * math.sqrt(0.5) + spacing / 2 + _MARGIN
        pts, seg_id = _samples(self.segments, spacing)  # (K, 2), (K,)
        home = np.floor((pts - self.origin) / cell).astype(np.intp)  # (K, 2): col, row
        w = math.ceil(radius / cell + 0.5)  # cells within radius lie within w of the home cell
        off = np.arange(-w, w + 1)
        col = home[:, 0, None, None] + off[None, None, :]  # (K, 1, 2w+1)
        row = home[:, 1, None, None] + off[None, :, None]  # (K, 2w+1, 1)
        dx = self.origin[0] + cell * (col + 0.5) - pts[:, 0, None, None]
        dy = self.origin[1] + cell * (row + 0.5) - pts[:, 1, None, None]
        keep = (dx * dx + dy * dy <= radius * radius) & (col >= 0) & (col < cols)
        keep &= (row >= 0) & (row < rows)  # (K, 2w+1, 2w+1)
        flat = np.broadcast_to(row * cols + col, keep.shape)[keep]
        self._near = np.zeros((rows * cols, len(self.segments)), dtype=bool)  # (cells, S)
        self._near[flat, np.broadcast_to(seg_id[:, None, None], keep.shape)[keep]] = True

    def candidates(self, points: np.ndarray) -> np.ndarray:  # (k,) segment indices, sorted
        """Indices of the segments that may lie within ``reach`` of any of ``points`` (M, 2)."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        rows, cols = self.shape
        ij = np.floor((p - self.origin) / self.cell).astype(np.intp)  # (M, 2): col, row
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < cols) & (ij[:, 1] >= 0) & (ij[:, 1] < rows)
        if not inside.any():
            return np.zeros(0, dtype=np.intp)
        flat = ij[inside, 1] * cols + ij[inside, 0]
        return np.flatnonzero(self._near[flat].any(axis=0))


def _samples(segments: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (K, 2) at most ``spacing`` apart along each segment (S, 4), both ends included,
    and the segment of each (K,)."""
    length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    pieces = np.maximum(np.ceil(length / spacing).astype(np.intp), 1)  # (S,)
    seg_id = np.repeat(np.arange(len(segments)), pieces + 1)  # (K,)
    first = np.repeat(np.cumsum(pieces + 1) - (pieces + 1), pieces + 1)
    frac = (np.arange(len(seg_id)) - first) / pieces[seg_id]  # (K,) in [0, 1]
    a, b = segments[seg_id, 0:2], segments[seg_id, 2:4]
    return a + frac[:, None] * (b - a), seg_id


_GRIDS: weakref.WeakKeyDictionary[Layout, dict[tuple[float, float], SegmentGrid]] = (
    weakref.WeakKeyDictionary()
)


def segment_grid(layout: Layout, reach: float, cell: float) -> SegmentGrid:
    """The :class:`SegmentGrid` of a layout's segments, built once per layout and parameters
    (a world is rebuilt at every reset; the layout usually is not)."""
    per_layout = _GRIDS.setdefault(layout, {})
    key = (float(reach), float(cell))
    if key not in per_layout:
        per_layout[key] = SegmentGrid(layout.segments, reach, cell)
    return per_layout[key]

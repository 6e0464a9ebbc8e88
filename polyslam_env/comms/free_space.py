"""Where a robot's own beams have passed: the negative evidence that vetoes wrong alignments.

Corners and pillars repeat: the shelf rows of a warehouse, the rooms of an office floor. An
alignment shifted by one period of such a building matches as many features as the true one,
so no feature count tells them apart. What does is **free space**: moved by the wrong transform,
the sender's walls land where the receiver's beams have travelled and found nothing.

:class:`FreeSpace` marks, in the robot's own frame (placed with its pose estimates, like its
map), the cells of a grid that its beams crossed, stopping ``margin`` short of each return (the
last stretch before a hit is where the robot's own walls, and anything aligned onto them with a
few centimetres of error, lie). A received wall point in a free cell contradicts the receiver's
observations, unless it lies within ``margin`` of one of the receiver's own walls: a beam that
grazes a wall crosses cells the wall runs through long before its return, so cells along the
robot's own walls are marked free too. :meth:`FreeSpace.conflict` is the fraction of a received
map's length that contradicts.

The test runs both ways: the receiver's walls moved into the sender's frame must not lie in the
*sender's* free space either. Two robots whose maps share little (an office floor's repeating
rooms, each robot having seen its own few) can agree on a shift by one period, and the
receiver's own free space holds too little of the shifted map to refuse it; the sender's does.
So a robot sends its free space with its walls: the cells its beams crossed whose centres lie
further than ``margin`` from every wall of its current map (:meth:`FreeSpace.clear_of`; it
knows its whole map, including walls it received from that receiver and never sends back).
That set changes both ways as the map grows, so a message carries only the cells that changed
since what the receiver holds (:meth:`FreeSpace.changes`, a bitmap of their bounding box), and
the receiver flips them in its copy (:meth:`FreeSpace.toggle`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from polyslam_env.core.geometry import beam_endpoints

__all__ = ["FreeCells", "FreeSpace"]

#: A block of cells: the lattice index (col, row) of its lower-left cell, and the cells
#: (rows, cols) bool.
FreeCells = tuple[tuple[int, int], np.ndarray]


class FreeSpace:
    """A growing boolean grid of the cells a robot's beams crossed (see the module docstring)."""

    def __init__(self, resolution: float, margin: float, max_range: float) -> None:
        if not (resolution > 0 and margin >= 0 and max_range > 0):
            raise ValueError(
                f"resolution and max_range must be > 0 and margin >= 0, got {resolution!r},"
                f" {max_range!r}, {margin!r}"
            )
        self.resolution = float(resolution)
        self.margin = float(margin)
        self.max_range = float(max_range)
        self.origin = np.zeros(2)  # (x, y) of cell [0, 0]'s corner, a multiple of resolution
        self.cells = np.zeros((0, 0), dtype=bool)  # [row (y), col (x)]

    def add(self, pose: np.ndarray, ranges: np.ndarray, beam_angles: np.ndarray) -> None:
        """One scan from the pose estimate ``pose`` (3,): ``ranges`` (B,) (inf: no return)
        along ``beam_angles`` (B,) relative to the heading."""
        p = np.asarray(pose, dtype=float).reshape(3)
        r = np.asarray(ranges, dtype=float).ravel()
        length = np.where(np.isfinite(r), r - self.margin, self.max_range)
        length = np.clip(length, 0.0, self.max_range)
        if not np.any(length > 0):
            return
        t = np.arange(0.0, float(length.max()), self.resolution)  # (T,)
        keep = t[None, :] < length[:, None]  # (B, T)
        phi = p[2] + np.asarray(beam_angles, dtype=float).ravel()
        points = beam_endpoints(p[:2], phi[:, None], t[None, :])[keep]  # (S, 2)
        self._grow(points.min(axis=0), points.max(axis=0))
        rows, cols = self._index(points)
        self.cells[rows, cols] = True

    def clear_of(self, walls: np.ndarray) -> FreeCells:
        """The crossed cells whose centres lie further than ``margin`` from every point of
        ``walls`` (P, 2) (samples of the robot's map, spaced well below ``margin``), over the
        whole grid: (lattice index (col, row) of cell [0, 0], bool (rows, cols)). Lattice:
        cells of ``resolution`` with a corner at (0, 0)."""
        clear = self.cells.copy()
        rows, cols = np.nonzero(clear)
        pts = np.asarray(walls, dtype=float).reshape(-1, 2)
        if len(rows) and len(pts):
            centres = self.origin + (np.column_stack([cols, rows]) + 0.5) * self.resolution
            dist, _ = cKDTree(pts).query(centres, distance_upper_bound=self.margin)
            clear[rows[np.isfinite(dist)], cols[np.isfinite(dist)]] = False
        return self._lattice_corner(), clear

    def changes(self, current: FreeCells) -> FreeCells:
        """The cells where ``current`` (a block as :meth:`clear_of` gives it; cells outside it
        are not free) and this grid differ, over their bounding box: what :meth:`toggle`
        needs to turn this grid into ``current``; an empty block for none."""
        blocks = [current, (self._lattice_corner(), self.cells)]
        blocks = [(corner, cells) for corner, cells in blocks if cells.size]
        if not blocks:
            return (0, 0), np.zeros((0, 0), dtype=bool)
        lo = np.min([corner for corner, _ in blocks], axis=0)  # (col, row)
        hi = np.max([np.add(corner, cells.shape[::-1]) for corner, cells in blocks], axis=0)
        diff = np.zeros((int(hi[1] - lo[1]), int(hi[0] - lo[0])), dtype=bool)
        for (col, row), cells in blocks:
            r0, c0 = row - int(lo[1]), col - int(lo[0])
            diff[r0 : r0 + cells.shape[0], c0 : c0 + cells.shape[1]] ^= cells
        rows, cols = np.nonzero(diff)
        if len(rows) == 0:
            return (0, 0), np.zeros((0, 0), dtype=bool)
        r_lo, c_lo = int(rows.min()), int(cols.min())
        block = diff[r_lo : int(rows.max()) + 1, c_lo : int(cols.max()) + 1]
        return (int(lo[0]) + c_lo, int(lo[1]) + r_lo), block

    def toggle(self, corner: tuple[int, int], block: np.ndarray) -> None:
        """Flip the cells of ``block`` (rows, cols) bool whose lower-left cell has lattice
        index ``corner`` (col, row), as :meth:`changes` gives them."""
        block = np.asarray(block, dtype=bool)
        if not block.any():
            return
        res = self.resolution
        lo = np.asarray(corner, dtype=float) * res
        hi = lo + res * (np.array(block.shape[::-1], dtype=float) - 1)
        self._grow(lo + 0.5 * res, hi + 0.5 * res)
        col, row = self._lattice_corner()
        r0, c0 = corner[1] - row, corner[0] - col
        window = self.cells[r0 : r0 + block.shape[0], c0 : c0 + block.shape[1]]
        window ^= block

    def _lattice_corner(self) -> tuple[int, int]:
        """Lattice index (col, row) of cell [0, 0]."""
        col, row = np.rint(self.origin / self.resolution).astype(np.int64)
        return int(col), int(row)

    def conflict(self, points: np.ndarray, own_walls: cKDTree | None) -> float:
        """Fraction of ``points`` (P, 2) (samples of the received walls, equally spaced along
        them, in this robot's frame) that lie in cells its beams crossed and further than
        ``margin`` from every point of ``own_walls`` (a tree of samples of its own walls,
        spaced well below ``margin``; None: no walls); 0 for no points."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(pts) == 0 or self.cells.size == 0:
            return 0.0
        rows, cols = self._index(pts)
        rows_n, cols_n = self.cells.shape
        inside = (rows >= 0) & (rows < rows_n) & (cols >= 0) & (cols < cols_n)
        free = np.zeros(len(pts), dtype=bool)
        free[inside] = self.cells[rows[inside], cols[inside]]
        if free.any() and own_walls is not None:
            dist, _ = own_walls.query(pts[free], distance_upper_bound=self.margin)
            free[np.flatnonzero(free)[np.isfinite(dist)]] = False
        return float(free.mean())

    def _index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx = np.floor((points - self.origin) / self.resolution).astype(np.int64)
        return idx[:, 1], idx[:, 0]

    def _grow(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Enlarge the grid (by at least 4 m on a side that grows) to hold [lo, hi]."""
        res = self.resolution
        if self.cells.size == 0:
            self.origin = np.floor(lo / res) * res
            shape = np.floor((hi - self.origin) / res).astype(np.int64) + 1
            self.cells = np.zeros((int(shape[1]), int(shape[0])), dtype=bool)
            return
        top = self.origin + res * np.array(self.cells.shape[::-1])  # (x, y) beyond the last
        pad = int(np.ceil(4.0 / res))
        below = np.where(lo < self.origin, np.ceil((self.origin - lo) / res).astype(int) + pad, 0)
        above = np.where(hi >= top, np.ceil((hi - top) / res).astype(int) + 1 + pad, 0)
        if not (below.any() or above.any()):
            return
        self.cells = np.pad(self.cells, ((below[1], above[1]), (below[0], above[0])))
        self.origin = self.origin - res * below

"""Area coverage: the team's coverage grid and time-to-fraction."""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core import raster
from polyslam_env.metrics.boundary import _frozen


# -- coverage -------------------------------------------------------------------------------
class CoverageGrid:
    """Which free cells any range beam has swept, for the team and per robot.

    Grid convention: ``free[i, j]`` is the cell x ∈ [ox + j·res, ox + (j+1)·res),
    y ∈ [oy + i·res, oy + (i+1)·res) with ``origin = (ox, oy)`` its lower-left corner (row
    index grows with y). Beams are sampled every res/2 (both ends included), so a cell that a
    beam crosses over at least res/2 is always marked and a barely clipped corner may not be.
    """

    def __init__(self, free: np.ndarray, origin: tuple[float, float], resolution: float) -> None:
        mask = np.asarray(free)
        if mask.ndim != 2 or mask.dtype != bool:
            raise ValueError(f"free must be a boolean (H, W) mask, got {mask.dtype} {mask.shape}")
        if not resolution > 0:
            raise ValueError(f"resolution must be > 0, got {resolution}")
        self.free = _frozen(mask.copy())  # (H, W)
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.n_free = int(mask.sum())
        self.swept = np.zeros_like(mask)  # (H, W): swept by any beam (free or not)
        self.robot_swept: dict[int, np.ndarray] = {}  # robot -> (H, W)
        self.gain = 0  # new free cells of the team in the last sweep
        self._n_swept_free = 0
        self._linspaces: dict[tuple[int, int], np.ndarray] = {}

    def cells_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows, columns (N,) of points (N, 2) and whether each lies inside the grid."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        col = np.floor((p[:, 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((p[:, 1] - self.origin[1]) / self.resolution).astype(np.int64)
        h, w = self.free.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        return row, col, inside

    def _fractions(self, n: int, width: int) -> np.ndarray:  # (width,)
        """``linspace(0, 1, n)`` padded with 1.0 to ``width`` (a beam's end sampled again, which
        adds no cell), cached: only a few ``n`` occur and linspace is slow."""
        out = self._linspaces.get((n, width))
        if out is None:
            out = np.ones(width)
            out[:n] = np.linspace(0.0, 1.0, n)
            self._linspaces[n, width] = _frozen(out)
        return out

    def beam_cells(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> np.ndarray:  # (M,) flat cell ids, repeats kept
        """Flat ids (row · W + col) of the grid cells under the samples of each beam.

        Arguments as in :meth:`sweep`; ``origins`` may also be one (2,) origin for all beams.
        Beams are sampled every ≤ res/2, both ends included. Nothing is marked:
        :meth:`new_free_cells` and :meth:`mark` take the result.
        """
        a = np.asarray(angles, dtype=float).reshape(1, -1)
        o = np.asarray(origins, dtype=float).reshape(1, -1, 2)
        r = np.asarray(ranges, dtype=float).reshape(1, -1)
        return self.scan_cells(o, a, r, max_range)[0]

    def scan_cells(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> list[np.ndarray]:  # K × (M_k,) flat cell ids, repeats kept
        """:meth:`beam_cells` of K scans in one numpy pass (a robot's beams are few, so numpy
        call overhead is most of the cost): ``origins`` (K, 2) or (K, R, 2), ``angles`` and
        ``ranges`` (K, R). Each scan is sampled as if alone (its own sample count)."""
        if not max_range > 0:
            raise ValueError(f"max_range must be > 0, got {max_range}")
        a = np.asarray(angles, dtype=float)
        r = np.asarray(ranges, dtype=float)
        o = np.asarray(origins, dtype=float)
        o = o[:, None, :] if o.ndim == 2 else o  # (K, R or 1, 2)
        if not (a.ndim == 2 and a.shape == r.shape and o.shape[0] == len(a)) or (
            o.shape[1] not in (1, a.shape[1])
        ):
            raise ValueError(f"origins {o.shape}, angles {a.shape}, ranges {r.shape} disagree")
        if (r < 0).any():
            raise ValueError("ranges must be >= 0 (use inf or nan for no return)")
        if len(a) == 0:
            return []
        length = np.fmin(r, max_range)  # (K, R): fmin maps nan (and inf) to max_range
        spacing = 0.5 * self.resolution
        counts = [math.ceil(max(m, 0.0) / spacing) + 1 for m in length.max(axis=1, initial=0.0)]
        width = max(counts)
        frac = np.array([self._fractions(n, width) for n in counts])  # (K, width)
        t = length[:, :, None] * frac[:, None, :]  # (K, R, width), spacing ≤ res/2
        flat, inside = raster.beam_cells(
            o[..., 0:1], o[..., 1:2], a, t, self.origin, self.resolution, self.free.shape
        )  # (K, R, width)
        return [flat[k][inside[k]] for k in range(len(flat))]

    def new_free_cells(self, cells: np.ndarray) -> int:
        """How many distinct free cells among ``cells`` (flat ids, repeats allowed) nobody has
        swept yet."""
        free, swept = self.free.reshape(-1), self.swept.reshape(-1)  # (H·W,) views
        fresh = cells[free[cells] & ~swept[cells]]  # few, usually none
        return _count_distinct(fresh)

    def mark(self, cells: np.ndarray, robot: int | None = None) -> int:
        """Mark ``cells`` (flat ids from :meth:`beam_cells`) swept, and ``robot``'s own mask.

        Returns (and stores as ``gain``) the number of newly swept free cells of the team.
        """
        self.gain = self.new_free_cells(cells)
        self._n_swept_free += self.gain
        self.swept.reshape(-1)[cells] = True
        if robot is not None:
            mine = self.robot_swept.setdefault(int(robot), np.zeros_like(self.swept))
            mine.reshape(-1)[cells] = True
        return self.gain

    def sweep(
        self,
        origins: np.ndarray,
        angles: np.ndarray,
        ranges: np.ndarray,
        max_range: float,
        robot: int | None = None,
    ) -> int:
        """Mark the cells along each beam up to its hit (or ``max_range`` for no return).

        ``origins`` (R, 2), absolute ``angles`` (R,), ``ranges`` (R,) with inf/nan meaning no
        return; ranges beyond ``max_range`` are cut there. ``robot`` also marks that robot's own
        mask. Returns (and stores as ``gain``) the number of newly swept free cells of the team.
        """
        return self.mark(self.beam_cells(origins, angles, ranges, max_range), robot)

    @property
    def coverage(self) -> float:
        """Swept free cells / free cells (0.0 for a grid without free cells)."""
        if self.n_free == 0:
            return 0.0
        return self._n_swept_free / self.n_free

    def robot_coverage(self, robot: int) -> float:
        """Free cells swept by ``robot`` / free cells."""
        mine = self.robot_swept.get(int(robot))
        if mine is None or self.n_free == 0:
            return 0.0
        return int(np.count_nonzero(mine & self.free)) / self.n_free

    def overlap(self) -> float:
        """Free cells swept by ≥ 2 robots / free cells swept by any (0.0 if none swept).

        Sweeps without a ``robot`` count in the denominator only.
        """
        swept = self._n_swept_free
        if swept == 0 or not self.robot_swept:
            return 0.0
        counts = np.sum([m & self.free for m in self.robot_swept.values()], axis=0)
        return int(np.count_nonzero(counts >= 2)) / swept


def _count_distinct(values: np.ndarray) -> int:
    """Number of distinct values in a 1-D integer array (cheaper than ``len(np.unique(…))``)."""
    if len(values) < 2:
        return len(values)
    v = np.sort(values)
    return 1 + int(np.count_nonzero(v[1:] != v[:-1]))


def time_to_fraction(series: np.ndarray, fraction: float) -> int | None:
    """First index where ``series`` (K,) reaches ``fraction``; None if it never does."""
    s = np.asarray(series, dtype=float).reshape(-1)
    hits = np.flatnonzero(s >= fraction)
    return int(hits[0]) if len(hits) else None

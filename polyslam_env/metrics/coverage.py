"""Area coverage: the team's coverage grid and time-to-fraction."""

from __future__ import annotations

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
    The sampling, counting and marking are compiled kernels of :mod:`polyslam_env.core.raster`.
    """

    def __init__(self, free: np.ndarray, origin: tuple[float, float], resolution: float) -> None:
        mask = np.asarray(free)
        if mask.ndim != 2 or mask.dtype != bool:
            raise ValueError(f"free must be a boolean (H, W) mask, got {mask.dtype} {mask.shape}")
        if not resolution > 0:
            raise ValueError(f"resolution must be > 0, got {resolution}")
        self.free = _frozen(np.ascontiguousarray(mask).copy())  # (H, W)
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.n_free = int(mask.sum())
        self.swept = np.zeros_like(self.free)  # (H, W): swept by any beam (free or not)
        self._masks = np.zeros((0, *mask.shape), dtype=bool)  # (R, H, W): per swept robot
        self._rows: dict[int, int] = {}  # robot -> its row of _masks, in order of first sweep
        # sweep_team's rows (N,) int64 for its last active flags (N,): a robot's row never moves
        self._team_flags: list[bool] = []
        self._team_rows = np.zeros(0, dtype=np.int64)
        self.gain = 0  # new free cells of the team in the last sweep
        self._n_swept_free = 0

    @property
    def robot_swept(self) -> dict[int, np.ndarray]:  # robot -> (H, W) view
        """Per robot that swept anything, the cells its beams swept."""
        return {robot: self._masks[row] for robot, row in self._rows.items()}

    def _row(self, robot: int) -> int:
        """Robot ``robot``'s row of ``_masks``, made (empty) at its first sweep."""
        row = self._rows.get(robot)
        if row is None:
            row = self._rows[robot] = len(self._masks)
            self._masks = np.concatenate([self._masks, np.zeros((1, *self.free.shape), bool)])
        return row

    def cells_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows, columns (N,) of points (N, 2) and whether each lies inside the grid."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        col = np.floor((p[:, 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((p[:, 1] - self.origin[1]) / self.resolution).astype(np.int64)
        h, w = self.free.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        return row, col, inside

    def beam_cells(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> np.ndarray:  # (M,) flat cell ids
        """Flat ids (row · W + col) of the grid cells under the samples of each beam.

        Arguments as in :meth:`sweep`; ``origins`` may also be one (2,) origin for all beams.
        Beams are sampled every ≤ res/2, both ends included. Nothing is marked:
        :meth:`new_free_cells` and :meth:`mark` take the result.
        """
        a = np.asarray(angles, dtype=float).reshape(1, -1)
        o = np.asarray(origins, dtype=float).reshape(1, -1, 2)
        r = np.asarray(ranges, dtype=float).reshape(1, -1)
        return self.scan_cells(o, a, r, max_range)[0]

    def _scan_ids(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> np.ndarray:  # (K, R, width) int64, −1 for none
        """Checked arguments of :meth:`scan_cells` → the cell ids of every sample."""
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
        ox, oy = o[..., 0], o[..., 1]
        if o.shape[1] != a.shape[1]:  # one origin per scan
            ox, oy = np.repeat(ox, a.shape[1], axis=1), np.repeat(oy, a.shape[1], axis=1)
        return raster.even_beam_cells(
            np.ascontiguousarray(ox), np.ascontiguousarray(oy), np.ascontiguousarray(a),
            np.ascontiguousarray(r), max_range, self.origin, self.resolution, self.free.shape,
        )  # fmt: skip

    def scan_cells(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> list[np.ndarray]:  # K × (M_k,) flat cell ids, repeats kept
        """:meth:`beam_cells` of K scans: ``origins`` (K, 2) or (K, R, 2), ``angles`` and
        ``ranges`` (K, R). Each scan is sampled as if alone (its own sample count)."""
        ids = self._scan_ids(origins, angles, ranges, max_range)
        return [k[k >= 0] for k in ids.reshape(len(ids), ids[0].size if len(ids) else 0)]

    def new_free_cells(self, cells: np.ndarray) -> int:
        """How many distinct free cells among ``cells`` (flat ids, repeats allowed) nobody has
        swept yet."""
        return raster.count_new(cells, self.free, self.swept)

    def mark(self, cells: np.ndarray, robot: int | None = None) -> int:
        """Mark ``cells`` (flat ids from :meth:`beam_cells`) swept, and ``robot``'s own mask.

        Returns (and stores as ``gain``) the number of newly swept free cells of the team.
        """
        row = None if robot is None else self._row(int(robot))  # before _masks may grow
        mine = None if row is None else self._masks[row]
        self.gain = raster.mark_cells(cells, self.free, self.swept, mine)
        self._n_swept_free += self.gain
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

    def sweep_team(
        self,
        poses: np.ndarray,
        angles: np.ndarray,
        ranges: np.ndarray,
        max_range: float,
        active: np.ndarray,
    ) -> np.ndarray:  # (N,) int
        """Sweep the scans of a team's active robots at once (one kernel call): robot i at
        ``poses[i]`` (N, 3) with beams at ``angles`` (B,) relative to its heading and
        ``ranges`` (N, B), if ``active[i]`` (N,). Returns each robot's new free cells counted
        against the grid as it was before this call (a cell first swept by two robots at once
        counts for both; 0 for inactive robots); the team's coverage counts it once."""
        if not max_range > 0:
            raise ValueError(f"max_range must be > 0, got {max_range}")
        act = np.asarray(active, dtype=bool)
        flags = act.tolist()
        if flags != self._team_flags:
            rows = [self._row(i) if a else -1 for i, a in enumerate(flags)]
            self._team_rows = np.array(rows, dtype=np.int64)
            self._team_flags = flags
        gains, total, last = raster.sweep_team(
            np.ascontiguousarray(poses, dtype=float), np.ascontiguousarray(angles, dtype=float),
            np.ascontiguousarray(ranges, dtype=float), act, max_range, self.origin,
            self.resolution, self.free, self.swept, self._masks, self._team_rows,
        )  # fmt: skip
        if True in flags:
            self.gain = last
        self._n_swept_free += total
        return gains

    @property
    def coverage(self) -> float:
        """Swept free cells / free cells (0.0 for a grid without free cells)."""
        if self.n_free == 0:
            return 0.0
        return self._n_swept_free / self.n_free

    def robot_coverage(self, robot: int) -> float:
        """Free cells swept by ``robot`` / free cells."""
        row = self._rows.get(int(robot))
        if row is None or self.n_free == 0:
            return 0.0
        return int(np.count_nonzero(self._masks[row] & self.free)) / self.n_free

    def overlap(self) -> float:
        """Free cells swept by ≥ 2 robots / free cells swept by any (0.0 if none swept).

        Sweeps without a ``robot`` count in the denominator only.
        """
        swept = self._n_swept_free
        if swept == 0 or not self._rows:
            return 0.0
        counts = np.sum(self._masks & self.free, axis=0)
        return int(np.count_nonzero(counts >= 2)) / swept


def time_to_fraction(series: np.ndarray, fraction: float) -> int | None:
    """First index where ``series`` (K,) reaches ``fraction``; None if it never does."""
    s = np.asarray(series, dtype=float).reshape(-1)
    hits = np.flatnonzero(s >= fraction)
    return int(hits[0]) if len(hits) else None

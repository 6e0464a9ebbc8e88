"""What a robot could send instead of polynomials: raw beam points or an occupancy grid.

These exist to measure the paper's claim that polynomials are a cheap way to share a map
(SPEC §4, last point). A :class:`ScanLog` keeps one robot's beams in its own start frame, as
placed with its pose estimate of the step (the same data its SLAM saw); from it come

* the **points** payload: the beam hit points recorded since some log position, and
* the **grid** payload (:func:`occupancy_grid`): a 2-bit occupancy raster of the robot's own
  map — every swept beam marks its cells free, every map polynomial marks its cells occupied
  (occupied wins) — over the bounding box of that data.

numpy only; the receiving side of these payloads just counts bytes (see ``exchange.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from polyslam_env.comms.messages import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from polyslam_env.core.geometry import beam_endpoints
from polyslam_env.slam.polynomial import Polynomial


class ScanLog:
    """One robot's beams, step by step, in its own start frame."""

    def __init__(self, max_range: float) -> None:
        if not (np.isfinite(max_range) and max_range > 0):
            raise ValueError(f"max_range must be > 0, got {max_range!r}")
        self.max_range = float(max_range)
        self._starts: list[np.ndarray] = []  # per record (B, 2): beam origins
        self._ends: list[np.ndarray] = []  # per record (B, 2): hit, or max-range end
        self._hit: list[np.ndarray] = []  # per record (B,) bool: beam had a return

    def __len__(self) -> int:
        return len(self._starts)

    def record(self, pose: np.ndarray, ranges: np.ndarray, beam_angles: np.ndarray) -> None:
        """Add one scan taken at pose estimate ``pose`` (3,) with ``ranges`` (B,)."""
        p = np.asarray(pose, dtype=float).reshape(3)
        r = np.asarray(ranges, dtype=float).ravel()
        angles = np.asarray(beam_angles, dtype=float).ravel()
        if r.shape != angles.shape:
            raise ValueError(f"ranges {r.shape} and beam_angles {angles.shape} disagree")
        hit = np.isfinite(r)
        length = np.where(hit, r, self.max_range)  # (B,)
        phi = p[2] + angles
        ends = beam_endpoints(p[:2], phi, length)
        self._starts.append(np.broadcast_to(p[:2], ends.shape).copy())
        self._ends.append(ends)
        self._hit.append(hit)

    def hits_since(self, position: int) -> np.ndarray:
        """Hit points (H, 2) of the records from log position ``position`` on."""
        ends, hit = self._ends[position:], self._hit[position:]
        if not ends:
            return np.zeros((0, 2))
        return np.concatenate(ends)[np.concatenate(hit)]

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """All beams so far: origins (M, 2) and ends (M, 2)."""
        if not self._starts:
            return np.zeros((0, 2)), np.zeros((0, 2))
        return np.concatenate(self._starts), np.concatenate(self._ends)


def _cells_of(points: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    """(row, col) integer indices (P, 2) of the cells holding ``points`` (P, 2)."""
    idx = np.floor((points - origin) / resolution).astype(np.int64)  # (P, 2): col, row
    return np.maximum(idx[:, ::-1], 0)  # rounding may put the lowest point at −1


def _ray_samples(starts: np.ndarray, ends: np.ndarray, step: float) -> np.ndarray:
    """Points (S, 2) every ``step`` along each segment start→end, ends excluded."""
    if len(starts) == 0:
        return np.zeros((0, 2))
    length = np.linalg.norm(ends - starts, axis=1)  # (M,)
    n_max = int(np.ceil(length.max() / step)) if length.max() > 0 else 0
    t = np.arange(n_max) * step  # (T,)
    keep = t[None, :] < length[:, None]  # (M, T)
    unit = (ends - starts) / np.maximum(length, 1e-12)[:, None]
    pts = starts[:, None, :] + t[None, :, None] * unit[:, None, :]  # (M, T, 2)
    return pts[keep]


def occupancy_grid(
    polynomials: Sequence[Polynomial],
    ray_starts: np.ndarray,
    ray_ends: np.ndarray,
    resolution: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """``(origin (2,), cells (rows, cols) uint8)`` of a robot's own map.

    Cells swept by a beam are free, cells a polynomial passes through are occupied, the rest
    unknown. Cell ``[r, c]`` covers ``origin + resolution · ([c, c+1] × [r, r+1])`` (the
    layout of :class:`~polyslam_env.comms.messages.GridMessage`); the grid spans the bounding
    box of the rays and polynomials, so an empty map gives a 0 × 0 grid.
    """
    if not (np.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be > 0, got {resolution!r}")
    step = 0.5 * resolution  # half a cell: every cell a segment crosses gets a sample
    free = _ray_samples(np.asarray(ray_starts, float), np.asarray(ray_ends, float), step)
    occupied_parts = [p.sample_arclength(step) for p in polynomials]
    occupied = np.concatenate(occupied_parts) if occupied_parts else np.zeros((0, 2))
    everything = np.concatenate([free, occupied, np.asarray(ray_ends, float).reshape(-1, 2)])
    if len(everything) == 0:
        return np.zeros(2), np.zeros((0, 0), dtype=np.uint8)
    origin = np.floor(everything.min(axis=0) / resolution) * resolution  # (2,)
    top = _cells_of(everything, origin, resolution).max(axis=0) + 1  # (2,): rows, cols
    cells = np.full((int(top[0]), int(top[1])), CELL_UNKNOWN, dtype=np.uint8)
    rc = _cells_of(free, origin, resolution)
    cells[rc[:, 0], rc[:, 1]] = CELL_FREE
    rc = _cells_of(occupied, origin, resolution)
    cells[rc[:, 0], rc[:, 1]] = CELL_OCCUPIED
    return origin, cells

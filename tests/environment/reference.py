"""Readable numpy versions of the observation kernels (``polyslam_env/environment/kernels.py``):
the oracles of the kernel tests (same float operations in the same order: identical cells)."""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import rotation
from polyslam_env.environment.observations import BeliefGrid
from tests.core.reference import point_cells


def local_cells(
    pose: np.ndarray,
    map_points: np.ndarray,
    belief: BeliefGrid,
    cell_centres: np.ndarray,
    g: int,
    res: float,
    use_hits: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Occupied and free cells (G²,) of the egocentric grid (``ObservationEncoder.local_cells``)."""
    rot = rotation(pose[2])  # ego → own frame; (own − xy) @ rot = ego
    occ = np.zeros(g * g, dtype=bool)  # (G²,)
    if len(map_points):
        ego = (map_points - pose[:2]) @ rot  # (M, 2)
        idx = np.floor(ego / res + (g // 2 + 0.5)).astype(np.intp)  # (M, 2)
        u = idx.view(np.uintp)  # negatives wrap to huge values
        ok = (u[:, 0] < g) & (u[:, 1] < g)
        occ[idx[ok, 1] * g + idx[ok, 0]] = True
    centres = cell_centres @ rot.T + pose[:2]
    flat, inside = point_cells(centres[:, 0], centres[:, 1], *belief._grid)
    flat = np.where(inside, flat, 0)
    free = belief.free.reshape(-1)[flat] & inside
    hit = belief.hit.reshape(-1)[flat] & inside
    if use_hits:
        occ |= hit
    free &= ~occ
    return occ, free

"""Compiled kernels of the observations: the egocentric local map's occupied and free cells.

Plain loops compiled by :func:`polyslam_env.core.jit.njit`, with the same float operations in
the same order as the numpy version they replaced (the oracle in
``tests/environment/reference.py``), so the cells are identical. The two small matrix products
that place points (``points @ R``) stay in numpy, which may compute them with fused
multiply-adds; the kernel takes their results.
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import njit
from polyslam_env.core.raster import cell_id


@njit
def local_cells(
    centres: np.ndarray,
    ego_points: np.ndarray,
    g: int,
    cell: float,
    belief_free: np.ndarray,
    belief_hit: np.ndarray,
    origin: float,
    resolution: float,
    n: int,
    use_hits: bool,
    occ: np.ndarray,
    free: np.ndarray,
) -> None:
    """Occupied ``occ`` and free ``free`` (G²,) cells of a G × G egocentric grid of side
    ``cell``: occupied where an ego point (M, 2) falls (and, with ``use_hits``, where the belief
    grid saw a hit), free where the belief grid (flat, n × n, lower-left corner (origin,
    origin), cell side ``resolution``) is free at the cell's centre ``centres`` (G², 2, in the
    belief grid's frame) and not occupied."""
    half = g // 2 + 0.5
    for i in range(g * g):
        occ[i] = False
    for m in range(ego_points.shape[0]):
        col = math.floor(ego_points[m, 0] / cell + half)
        row = math.floor(ego_points[m, 1] / cell + half)
        if 0 <= col < g and 0 <= row < g:
            occ[row * g + col] = True
    for i in range(g * g):
        c = cell_id(centres[i, 0], centres[i, 1], origin, origin, resolution, n, n)
        if c >= 0 and use_hits and belief_hit[c]:
            occ[i] = True
        free[i] = c >= 0 and belief_free[c] and not occ[i]


@njit
def _clip(v: float, lo: float, hi: float) -> float:
    """``min(max(v, lo), hi)`` with Python's builtins' semantics (the first argument wins ties
    and NaN comparisons)."""
    v = lo if lo > v else v
    return hi if hi < v else v


@njit
def vector_head(
    ranges: np.ndarray,
    max_range: float,
    pose: np.ndarray,
    scale: float,
    std: np.ndarray,
    caps: np.ndarray,
    occ: np.ndarray,
    free: np.ndarray,
    codes: np.ndarray,
    out: np.ndarray,
) -> None:
    """The vector observation's first parts in ``out`` (float32): ranges / max_range (no
    return → 1), a no-return flag per beam, the pose (x/scale, y/scale clipped to ±1, cos θ,
    sin θ), the pose standard deviations / caps clipped to 0…1, then, when ``occ`` is not
    empty, the local map coded ``codes`` = (free, unknown, occupied) per cell."""
    nb = ranges.shape[0]
    for b in range(nb):
        v = ranges[b] / max_range
        out[b] = v if v < 1.0 else 1.0  # fmin: inf and nan → 1
        out[nb + b] = 0.0 if math.isfinite(ranges[b]) else 1.0
    p = 2 * nb
    out[p] = _clip(pose[0] / scale, -1.0, 1.0)
    out[p + 1] = _clip(pose[1] / scale, -1.0, 1.0)
    out[p + 2] = math.cos(pose[2])
    out[p + 3] = math.sin(pose[2])
    for j in range(3):
        out[p + 4 + j] = _clip(std[j] / caps[j], 0.0, 1.0)
    m = p + 7
    for i in range(occ.shape[0]):
        out[m + i] = codes[0] if free[i] else (codes[2] if occ[i] else codes[1])

"""Range beams rasterised on square-celled grids: the cells their samples fall in.

Grid convention shared by every grid that beams are swept into (the coverage grid of the
metrics, the robots' belief grids, the frontier policy's own map): cell ``(row, col)`` covers
``x ∈ [ox + col·res, ox + (col+1)·res)``, ``y ∈ [oy + row·res, oy + (row+1)·res)`` with
``origin = (ox, oy)`` the grid's lower-left corner, and its flat id is ``row · W + col`` for a
grid of ``shape = (H, W)``. A beam is sampled at distances along it; callers choose the
distances (every ≤ res/2, so a cell a beam crosses over at least res/2 is always hit).

numpy only, and nothing of the package but ``core``; the slow per-beam oracle is in
``tests/core/test_raster.py``.
"""

from __future__ import annotations

import math

import numpy as np


def point_cells(
    x: np.ndarray,
    y: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Flat ids and whether each point lies inside the grid, for coordinates ``x``, ``y``
    (same shape). Ids of points outside are meaningless: mask them with the second result."""
    col = np.floor((x - origin[0]) / resolution).astype(np.intp)
    row = np.floor((y - origin[1]) / resolution).astype(np.intp)
    h, w = shape
    # Negative indices wrap to huge unsigned values, so one comparison per axis suffices.
    inside = (row.view(np.uintp) < h) & (col.view(np.uintp) < w)
    return row * w + col, inside


def beam_cells(
    x0: np.ndarray,
    y0: np.ndarray,
    angles: np.ndarray,
    distances: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`point_cells` of the samples ``distances`` (…, R, S) along beams of absolute
    ``angles`` (…, R) from origins ``x0``, ``y0`` (broadcast against (…, R, 1))."""
    x = x0 + distances * np.cos(angles)[..., None]
    y = y0 + distances * np.sin(angles)[..., None]
    return point_cells(x, y, origin, resolution, shape)


def beam_fractions(max_range: float, resolution: float) -> np.ndarray:  # (S,)
    """Sample positions 0…1 along a beam of at most ``max_range``, ≤ res/2 apart."""
    return np.linspace(0.0, 1.0, math.ceil(max_range / (0.5 * resolution)) + 1)


def scan_cells(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    fractions: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cells of K scans from ``poses`` (K, 3), beams at ``angles`` (B,) relative to the
    heading, ``ranges`` (K, B) (inf or nan: no return; beyond ``max_range``: cut there).

    Free: each beam sampled at ``fractions`` (S,) (:func:`beam_fractions`) of its length, which
    stops half a cell short of a hit (so the hit cell is not cleared) or runs to ``max_range``
    without a return. Hit: the cell of the end point of each beam with a return.
    Returns free ids and inside mask (K, B, S), hit ids (K, B) and hit mask (K, B).
    """
    finite = np.isfinite(ranges)  # (K, B)
    r = np.fmin(ranges, max_range)  # (K, B); no return (inf, nan) → max_range
    length = np.where(finite, np.maximum(r - 0.5 * resolution, 0.0), r)
    phi = poses[:, 2:3] + angles  # (K, B)
    # Each beam's S free samples and its end point (used only for hits) in one array.
    t = np.empty((*r.shape, fractions.size + 1))  # (K, B, S + 1)
    np.multiply(length[..., None], fractions, out=t[..., :-1])
    t[..., -1] = r
    x0, y0 = poses[:, 0, None, None], poses[:, 1, None, None]
    flat, inside = beam_cells(x0, y0, phi, t, origin, resolution, shape)  # (K, B, S + 1)
    return flat[..., :-1], inside[..., :-1], flat[..., -1], inside[..., -1] & finite

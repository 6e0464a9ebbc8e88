"""Readable numpy versions of the raster kernels of ``polyslam_env/core/raster.py`` and of
``wrap_angle`` and ``between`` of ``polyslam_env/core/geometry.py``: the oracles of the kernel
tests (they were the production code before the kernels; same float operations in the same
order, so the cells and poses are identical)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np


def point_cells(
    x: np.ndarray,
    y: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Flat ids and whether each point lies inside the grid (ids outside meaningless)."""
    col = np.floor((x - origin[0]) / resolution).astype(np.intp)
    row = np.floor((y - origin[1]) / resolution).astype(np.intp)
    h, w = shape
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
    """:func:`point_cells` of the samples ``distances`` (…, R, S) along beams ``angles`` (…, R)."""
    x = x0 + distances * np.cos(angles)[..., None]
    y = y0 + distances * np.sin(angles)[..., None]
    return point_cells(x, y, origin, resolution, shape)


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
    """Free ids and inside mask (K, B, S), hit ids and hit mask (K, B) of K scans."""
    finite = np.isfinite(ranges)  # (K, B)
    r = np.fmin(ranges, max_range)  # (K, B); no return (inf, nan) → max_range
    length = np.where(finite, np.maximum(r - 0.5 * resolution, 0.0), r)
    phi = poses[:, 2:3] + angles  # (K, B)
    t = np.empty((*r.shape, fractions.size + 1))  # (K, B, S + 1)
    np.multiply(length[..., None], fractions, out=t[..., :-1])
    t[..., -1] = r
    x0, y0 = poses[:, 0, None, None], poses[:, 1, None, None]
    flat, inside = beam_cells(x0, y0, phi, t, origin, resolution, shape)  # (K, B, S + 1)
    return flat[..., :-1], inside[..., :-1], flat[..., -1], inside[..., -1] & finite


def even_scan_cells(
    origins: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> list[np.ndarray]:  # K × (M_k,) flat ids, repeats kept
    """The coverage grid's cells of K scans (``origins`` (K, 2) or (K, R, 2), absolute
    ``angles`` and ``ranges`` (K, R)): each scan's beams sampled ``linspace(0, 1, n)`` of their
    length with ``n`` from its longest beam, padded with the end point to a common width."""
    a = np.asarray(angles, dtype=float)
    r = np.asarray(ranges, dtype=float)
    o = np.asarray(origins, dtype=float)
    o = o[:, None, :] if o.ndim == 2 else o
    length = np.fmin(r, max_range)
    spacing = 0.5 * resolution
    counts = [math.ceil(max(m, 0.0) / spacing) + 1 for m in length.max(axis=1, initial=0.0)]
    width = max(counts)
    frac = np.ones((len(counts), width))
    for k, n in enumerate(counts):
        frac[k, :n] = np.linspace(0.0, 1.0, n)
    t = length[:, :, None] * frac[:, None, :]
    flat, inside = beam_cells(o[..., 0:1], o[..., 1:2], a, t, origin, resolution, shape)
    return [flat[k][inside[k]] for k in range(len(flat))]


def count_distinct_new(cells: np.ndarray, mask: np.ndarray, marked: np.ndarray) -> int:
    """Distinct ids among ``cells`` in ``mask`` and not ``marked`` (flat views)."""
    m, s = mask.reshape(-1), marked.reshape(-1)
    return len(np.unique(cells[m[cells] & ~s[cells]]))


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles (any shape) wrapped to (−π, π] by numpy's mod."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi))


def between(
    a: np.ndarray, b: np.ndarray, wrap: Callable[[Any], Any] = wrap_angle
) -> np.ndarray:  # (…, 3)
    """``a⁻¹ ⊕ b`` in numpy, broadcast: ``R(θ_a)ᵀ (b_xy − a_xy)`` and ``wrap(θ_b − θ_a)``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[..., 2] - a[..., 2])], axis=-1)

"""The true boundary of a layout: dense samples and the distance of points to it."""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from polyslam_env.metrics.kernels import buckets, wall_distances
from polyslam_env.world.layout import Layout
from polyslam_env.world.nearby import wall_index

# -- the true boundary ----------------------------------------------------------------------
_BoundaryCache = dict[tuple[Any, ...], tuple[Any, ...]]
_CACHE: weakref.WeakKeyDictionary[Layout, _BoundaryCache] = weakref.WeakKeyDictionary()


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _segment_samples(
    segs: np.ndarray, step: float, midpoints: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (M, 2), weights (M,) and segment ids (M,) spaced ≤ ``step`` along each segment.

    ``midpoints``: the centres of n = ⌈L/step⌉ equal pieces, each weighing L/n (for length
    fractions); otherwise n + 1 points including both ends (so corners are exact).
    """
    lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])  # (S,)
    pieces = np.maximum(np.ceil(lengths / step).astype(int), 1)
    counts = pieces if midpoints else pieces + 1
    seg_id = np.repeat(np.arange(len(segs)), counts)  # (M,)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    k = np.arange(len(seg_id)) - first
    frac = (k + 0.5) / pieces[seg_id] if midpoints else k / pieces[seg_id]
    a, b = segs[seg_id, 0:2], segs[seg_id, 2:4]
    pts = a + frac[:, None] * (b - a)
    return pts, lengths[seg_id] / pieces[seg_id], seg_id


def _pillar_samples(pillars: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) and weights (M,) at the centres of equal arcs ≤ ``step`` on each pillar."""
    if len(pillars) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    circ = 2.0 * np.pi * pillars[:, 2]
    pieces = np.maximum(np.ceil(circ / step).astype(int), 3)
    pid = np.repeat(np.arange(len(pillars)), pieces)
    k = np.arange(len(pid)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    ang = 2.0 * np.pi * (k + 0.5) / pieces[pid]
    p = pillars[pid]
    pts = np.column_stack([p[:, 0] + p[:, 2] * np.cos(ang), p[:, 1] + p[:, 2] * np.sin(ang)])
    return pts, circ[pid] / pieces[pid]


def boundary_samples(layout: Layout, step: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The true boundary (wall segments and pillar circles) sampled every ≤ ``step`` metres.

    Returns points (M, 2) at the centres of equal pieces and the length each stands for (M,),
    so weighted sums give boundary lengths. Cached per layout; the arrays are read-only.
    """
    if step <= 0:
        raise ValueError(f"step must be > 0, got {step}")
    per_layout = _CACHE.setdefault(layout, {})
    key = ("samples", float(step))
    if key not in per_layout:
        wp, ww, _ = _segment_samples(layout.segments, step, midpoints=True)
        pp, pw = _pillar_samples(np.asarray(layout.pillars, dtype=float), step)
        per_layout[key] = (_frozen(np.vstack([wp, pp])), _frozen(np.concatenate([ww, pw])))
    pts, weights = per_layout[key]
    return pts, weights


#: :func:`~polyslam_env.metrics.kernels.buckets`' answer: x0, y0, side, ncols, nrows, order, starts.
Buckets = tuple[float, float, float, int, int, np.ndarray, np.ndarray]


def boundary_buckets(layout: Layout, step: float, tol: float) -> Buckets:
    """:func:`~polyslam_env.metrics.kernels.buckets` of :func:`boundary_samples` (``step``)
    for queries within ``tol`` (what :func:`~polyslam_env.metrics.kernels.covered_by` takes
    after the samples), cached per layout; the layout must have boundary samples."""
    per_layout = _CACHE.setdefault(layout, {})
    key = ("buckets", float(step), float(tol))
    if key not in per_layout:
        bpts = boundary_samples(layout, step)[0]
        per_layout[key] = tuple(buckets(bpts, float(tol)))
    found: Buckets = per_layout[key]
    return found


def boundary_points(layout: Layout, step: float = 0.01) -> np.ndarray:  # (M, 2)
    """The true boundary sampled every ≤ ``step`` metres (see :func:`boundary_samples`)."""
    return boundary_samples(layout, step)[0]


def distance_to_boundary(points: np.ndarray, layout: Layout) -> np.ndarray:  # (N,)
    """Distance from each point (N, 2) to the nearest true boundary point (walls, pillars),
    exact: walls by :func:`~polyslam_env.metrics.kernels.wall_distances` over the layout's
    static wall index, pillars as |‖q−c‖ − r|."""
    q = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))
    if len(layout.segments) == 0 and len(layout.pillars) == 0:
        raise ValueError(f"layout {layout.name!r} has no walls and no pillars")
    dist = wall_distances(q, *wall_index(layout).arrays)
    if len(layout.pillars):
        p = np.asarray(layout.pillars, dtype=float)
        dp = np.abs(np.hypot(q[:, None, 0] - p[:, 0], q[:, None, 1] - p[:, 1]) - p[:, 2])
        dist = np.minimum(dist, dp.min(axis=1))
    return dist

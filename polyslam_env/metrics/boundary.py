"""The true boundary of a layout: dense samples and the distance of points to it."""

from __future__ import annotations

import weakref

import numpy as np
from scipy.spatial import cKDTree

from polyslam_env.world.layout import Layout

# Spacing of the dense boundary samples behind the distance tree: the nearest sample is at most
# half of it away from the true nearest boundary point, so distances err by ≤ 1 mm at worst
# (and are exact whenever the nearest segment is among the K_REFINE nearest samples' segments).
_TREE_SPACING = 0.002
_K_REFINE = 4


# -- the true boundary ----------------------------------------------------------------------
_BoundaryCache = dict[tuple[str, float], tuple[np.ndarray, ...]]
_CACHE: weakref.WeakKeyDictionary[Layout, _BoundaryCache] = weakref.WeakKeyDictionary()
_TREES: weakref.WeakKeyDictionary[Layout, tuple[cKDTree | None, np.ndarray]] = (
    weakref.WeakKeyDictionary()
)


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


def boundary_points(layout: Layout, step: float = 0.01) -> np.ndarray:  # (M, 2)
    """The true boundary sampled every ≤ ``step`` metres (see :func:`boundary_samples`)."""
    return boundary_samples(layout, step)[0]


def _wall_tree(layout: Layout) -> tuple[cKDTree | None, np.ndarray]:
    """KD-tree over dense wall samples (with ends) and each sample's segment id; cached."""
    if layout not in _TREES:
        if len(layout.segments) == 0:
            _TREES[layout] = (None, np.zeros(0, dtype=int))
        else:
            pts, _, seg_id = _segment_samples(layout.segments, _TREE_SPACING, midpoints=False)
            _TREES[layout] = (cKDTree(pts), seg_id)
    return _TREES[layout]


def _paired_segment_distance(points: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Distance from points (…, 2) to the segment (…, 4) paired with each: shape (…)."""
    a, b = segs[..., 0:2], segs[..., 2:4]
    ab = b - a
    denom = np.maximum(np.einsum("...i,...i->...", ab, ab), 1e-300)
    t = np.clip(np.einsum("...i,...i->...", points - a, ab) / denom, 0.0, 1.0)
    return np.asarray(np.linalg.norm(points - (a + t[..., None] * ab), axis=-1))


def distance_to_boundary(points: np.ndarray, layout: Layout) -> np.ndarray:  # (N,)
    """Distance from each point (N, 2) to the nearest true boundary point (walls, pillars).

    Walls: a KD-tree over samples every 2 mm gives the K nearest samples; the exact
    point-to-segment distance to their segments refines it. The result lies between the exact
    distance and the exact distance + 1 mm, and is exact in practice. Pillars: exact |‖q−c‖ − r|.
    """
    q = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(layout.segments) == 0 and len(layout.pillars) == 0:
        raise ValueError(f"layout {layout.name!r} has no walls and no pillars")
    dist = np.full(len(q), np.inf)
    tree, seg_id = _wall_tree(layout)
    if tree is not None and len(q):
        k = min(_K_REFINE, tree.n)
        d_s, idx = tree.query(q, k=k)
        d_s, idx = d_s.reshape(len(q), k), idx.reshape(len(q), k)
        cand = layout.segments[seg_id[idx]]  # (N, k, 4)
        exact = _paired_segment_distance(q[:, None, :], cand).min(axis=1)
        dist = np.minimum(exact, d_s[:, 0])
    if len(layout.pillars):
        p = np.asarray(layout.pillars, dtype=float)
        dp = np.abs(np.hypot(q[:, None, 0] - p[:, 0], q[:, None, 1] - p[:, 1]) - p[:, 2])
        dist = np.minimum(dist, dp.min(axis=1))
    return dist

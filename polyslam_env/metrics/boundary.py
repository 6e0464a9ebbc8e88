"""The true boundary of a layout: dense samples and the distance of points to it."""

from __future__ import annotations

import math
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


def _pillar_samples(pillars: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (M, 2), weights (M,) and pillar ids (M,) at the centres of equal arcs ≤ ``step``
    on each pillar."""
    if len(pillars) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
    circ = 2.0 * np.pi * pillars[:, 2]
    pieces = np.maximum(np.ceil(circ / step).astype(int), 3)
    pid = np.repeat(np.arange(len(pillars)), pieces)
    k = np.arange(len(pid)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    ang = 2.0 * np.pi * (k + 0.5) / pieces[pid]
    p = pillars[pid]
    pts = np.column_stack([p[:, 0] + p[:, 2] * np.cos(ang), p[:, 1] + p[:, 2] * np.sin(ang)])
    return pts, circ[pid] / pieces[pid], pid


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
        pp, pw, _ = _pillar_samples(np.asarray(layout.pillars, dtype=float), step)
        per_layout[key] = (_frozen(np.vstack([wp, pp])), _frozen(np.concatenate([ww, pw])))
    pts, weights = per_layout[key]
    return pts, weights


#: Degrees: where a wall polyline turns by this much or more, one face of the boundary ends
#: and the next begins (:func:`boundary_faces`). A beam sweeping a face reaches the face's
#: next piece across a vertex that turns it by a few degrees (a traced wall's jogs, a curved
#: wall's polygon), but not across a corner: past a convex corner the next face looks away
#: from the robot, and past a concave one it is a wall of its own. Half a right angle.
FACE_TURN_DEG = 45.0


def segment_faces(layout: Layout) -> np.ndarray:
    """A face id per segment of ``layout.segments`` (S,): consecutive segments of one wall
    polyline share a face while it turns by less than :data:`FACE_TURN_DEG` at their common
    vertex (a closed polyline's last segment joins its first by the same rule); face ids
    count from 0 in segment order."""
    limit = math.cos(math.radians(FACE_TURN_DEG))
    faces: list[int] = []
    next_face = 0
    for wall in layout.walls:
        d = np.diff(np.asarray(wall, dtype=float), axis=0)
        length = np.hypot(d[:, 0], d[:, 1])
        d = d[length > 0] / length[length > 0, None]  # the kept segments' unit directions
        if not len(d):
            continue
        # a new face where the turn's cosine falls to cos(FACE_TURN_DEG) or below
        new = np.concatenate([[True], np.einsum("ij,ij->i", d[:-1], d[1:]) <= limit])
        ids = next_face + np.cumsum(new) - 1
        closed = len(wall) > 2 and np.array_equal(wall[0], wall[-1])
        if closed and len(d) > 1 and ids[-1] != ids[0] and float(d[-1] @ d[0]) > limit:
            ids[ids == ids[-1]] = ids[0]  # the last face goes on into the first
        faces.extend(ids.tolist())
        next_face = int(ids.max()) + 1
    out = np.asarray(faces, dtype=np.int64)
    assert out.size == len(layout.segments)
    return out


def boundary_faces(layout: Layout, step: float = 0.01) -> np.ndarray:  # (M,) int64
    """The face of each of :func:`boundary_samples`' samples (same order): its segment's
    (:func:`segment_faces`), and one face per pillar after the walls'. Cached per layout;
    read-only."""
    per_layout = _CACHE.setdefault(layout, {})
    key = ("faces", float(step))
    if key not in per_layout:
        seg_id = _segment_samples(layout.segments, step, midpoints=True)[2]
        seg_faces = segment_faces(layout)
        first_pillar = int(seg_faces.max()) + 1 if seg_faces.size else 0
        pillar_id = _pillar_samples(np.asarray(layout.pillars, dtype=float), step)[2]
        per_layout[key] = (_frozen(np.concatenate([seg_faces[seg_id], first_pillar + pillar_id])),)
    faces: np.ndarray = per_layout[key][0]
    return faces


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

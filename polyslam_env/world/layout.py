"""Layouts: walls (polylines), pillars and start poses, plus their geometry helpers.

A :class:`Layout` is plain immutable data; the physics, the sensors, the generators and the
metrics all read it. Coordinates are metres, angles radians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


@dataclass(frozen=True, eq=False)
class Layout:
    """A map: wall polylines, circular pillars and one start pose per robot."""

    name: str
    walls: tuple[np.ndarray, ...]  # each (k, 2), k >= 2; closed when first == last
    pillars: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (p, 3): x, y, r
    start_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (n, 3): x, y, θ

    @cached_property
    def segments(self) -> np.ndarray:  # (S, 4): x0, y0, x1, y1
        """Every wall polyline split into its straight segments (zero-length ones dropped)."""
        parts = [np.hstack([w[:-1], w[1:]]) for w in self.walls]
        segs = np.vstack(parts) if parts else np.zeros((0, 4))
        keep = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0
        return np.ascontiguousarray(segs[keep], dtype=float)

    @cached_property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of all walls and pillars."""
        pts = [w for w in self.walls]
        if len(self.pillars):
            p = self.pillars
            pts.append(np.column_stack([p[:, 0] - p[:, 2], p[:, 1] - p[:, 2]]))
            pts.append(np.column_stack([p[:, 0] + p[:, 2], p[:, 1] + p[:, 2]]))
        allp = np.vstack(pts)
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    @cached_property
    def outer_boundary(self) -> np.ndarray | None:
        """The closed wall polyline enclosing the largest area, or None if no wall is closed."""
        closed = [w for w in self.walls if len(w) >= 4 and np.array_equal(w[0], w[-1])]
        if not closed:
            return None
        return max(closed, key=lambda w: abs(polygon_area(w)))

    @property
    def num_start_poses(self) -> int:
        return len(self.start_poses)

    def boundary_length(self) -> float:
        """Total length of all walls plus pillar circumferences."""
        s = self.segments
        walls = float(np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]).sum())
        return walls + float(2 * np.pi * self.pillars[:, 2].sum()) if len(self.pillars) else walls

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether each point (…, 2) lies inside the outer boundary (bounding box if none)."""
        pts = np.asarray(points, dtype=float)
        outer = self.outer_boundary
        if outer is None:
            x0, y0, x1, y1 = self.bounds
            return (pts[..., 0] > x0) & (pts[..., 0] < x1) & (pts[..., 1] > y0) & (pts[..., 1] < y1)
        return points_in_polygon(pts, outer)

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point (…, 2) to the nearest wall or pillar surface."""
        pts = np.asarray(points, dtype=float)
        d = point_segment_distance(pts, self.segments).min(axis=-1)
        if len(self.pillars):
            p = self.pillars
            dp = np.hypot(pts[..., None, 0] - p[:, 0], pts[..., None, 1] - p[:, 1]) - p[:, 2]
            d = np.minimum(d, dp.min(axis=-1))
        return d


def polygon_area(poly: np.ndarray) -> float:
    """Signed area (shoelace) of a closed polyline (first == last)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon test for points (…, 2) against a closed polyline."""
    px, py = points[..., 0, None], points[..., 1, None]
    x0, y0, x1, y1 = poly[:-1, 0], poly[:-1, 1], poly[1:, 0], poly[1:, 1]
    crosses = (y0 > py) != (y1 > py)
    # a (nearly) horizontal edge gives ±inf or nan here; it crosses no point's row, so unused
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x_at = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
    inside = np.count_nonzero(crosses & (px < x_at), axis=-1) % 2 == 1
    return np.asarray(inside)


def point_segment_distance(points: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Distance from each point (…, 2) to each segment (S, 4): shape (…, S)."""
    p = np.asarray(points, dtype=float)[..., None, :]
    a, b = segs[:, 0:2], segs[:, 2:4]
    ab = b - a
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    t = np.clip(np.einsum("...ij,ij->...i", p - a, ab) / denom, 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.asarray(np.linalg.norm(p - closest, axis=-1))

"""Shared drawing pieces of the generators: curved blobs, snapped draws, boxes, walls with gaps.

Rectilinear floors (rooms, offices, warehouses, loops, pillar halls) put every coordinate on
multiples of :data:`SNAP` (5 cm); curved walls are finely sampled closed polylines.
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.config import check_range
from polyslam_env.world.generators.base import Walls

#: Snapped coordinates (wall positions, doors, widths) are multiples of this (m).
SNAP = 0.05


def blob(rng: np.random.Generator, harmonics: int, roughness: float) -> np.ndarray:
    """A densely sampled star-shaped closed curve around the origin, mean radius 1: (K+1, 2)."""
    phi = np.linspace(0.0, 2 * np.pi, 1025)  # (K+1,), last == first angle
    k = np.arange(2, harmonics + 2)  # (h,)
    raw = rng.uniform(0.2, 1.0, size=harmonics) / k
    amp = roughness * raw / raw.sum()
    phase = rng.uniform(0.0, 2 * np.pi, size=harmonics)
    rho = 1.0 + (amp * np.cos(np.outer(phi, k) + phase)).sum(axis=1)
    pts = np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])
    pts[-1] = pts[0]
    return pts


def resample_closed(poly: np.ndarray, spacing: float) -> np.ndarray:
    """A closed polyline (first == last) resampled at equal arc length ≤ ``spacing``."""
    seg = np.hypot(*np.diff(poly, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])  # (k,)
    n = max(8, math.ceil(s[-1] / spacing))
    t = np.linspace(0.0, s[-1], n + 1)
    out = np.column_stack([np.interp(t, s, poly[:, 0]), np.interp(t, s, poly[:, 1])])
    out[-1] = out[0]
    return out


# -- snapped floor plans ------------------------------------------------------------------
Range = tuple[float, float]  # (low, high), both inclusive


def check_span(name: str, span: Range, low: float, high: float) -> None:
    """``span`` = (a, b) with low <= a <= b <= high, else a ConfigError naming ``name``."""
    a, b = span
    check_range(f"{name}[0]", a, low, high)
    check_range(f"{name}[1]", b, a, high)


def snap_units(value: float) -> int:
    """``value`` (m) in snap units, rounded."""
    return round(value / SNAP)


def draw_snapped(rng: np.random.Generator, span: Range) -> float:
    """A multiple of the snap uniformly in ``span`` (m), or its lower end if none lies inside."""
    lo, hi = math.ceil(round(span[0] / SNAP, 6)), math.floor(round(span[1] / SNAP, 6))
    return round((float(rng.integers(lo, hi + 1)) if hi >= lo else span[0] / SNAP) * SNAP, 9)


def partition(
    rng: np.random.Generator, length: float, count: int | None, span: Range
) -> list[float] | None:
    """Widths (m, snapped) of ``count`` pieces (None: a feasible count drawn at random) that
    sum to ``length``, each within ``span``; None if no count fits. Every piece starts at the
    smallest width and the rest is dealt out one snap unit at a time to random pieces below
    the largest width."""
    total, lo, hi = snap_units(length), math.ceil(round(span[0] / SNAP, 6)), snap_units(span[1])
    n_min, n_max = max(1, math.ceil(total / hi)), total // lo if lo > 0 else 0
    if count is not None:
        n_min = n_max = count
    if n_max < n_min or not n_min * lo <= total <= n_min * hi:
        return None
    n = int(rng.integers(n_min, n_max + 1))
    widths = np.full(n, lo)
    for _ in range(total - n * lo):
        open_ = np.flatnonzero(widths < hi)
        widths[open_[int(rng.integers(len(open_)))]] += 1
    return [round(float(w) * SNAP, 9) for w in widths]


def tiles(length: float, span: Range) -> bool:
    """Whether some number of pieces with widths in ``span`` (snapped) sums to ``length``."""
    total, lo, hi = snap_units(length), math.ceil(round(span[0] / SNAP, 6)), snap_units(span[1])
    return lo > 0 and any(n * lo <= total <= n * hi for n in range(1, total // lo + 1))


def rectangle(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """A closed axis-aligned rectangle (5, 2): a solid block when inside the outline."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]], dtype=float)


def line_with_gaps(
    fixed: float, lo: float, hi: float, gaps: list[tuple[float, float]], vertical: bool
) -> Walls:
    """The wall ``x = fixed`` (vertical) or ``y = fixed`` from ``lo`` to ``hi`` without the
    ``gaps`` (doors, openings), as 2-point polylines."""
    out: Walls = []
    start = lo
    for a, b in [*sorted(gaps), (hi, hi)]:
        if a - start > 1e-9:
            pts = [[fixed, start], [fixed, a]] if vertical else [[start, fixed], [a, fixed]]
            out.append(np.array(pts, dtype=float))
        start = max(start, b)
    return out


def cuts(lo: float, widths: list[float]) -> list[float]:
    """Boundaries lo, lo + w0, … of consecutive pieces (snapped sums)."""
    return [round(lo + float(c), 9) for c in np.concatenate([[0.0], np.cumsum(widths)])]


def outline(width: float, height: float) -> np.ndarray:
    return rectangle(0.0, 0.0, width, height)


def spanning_tree(points: np.ndarray) -> list[tuple[int, int]]:
    """Edges (i, j) of the Euclidean minimum spanning tree of ``points`` (n, 2) (Prim's, in
    the order they join the tree; ties to the lowest index)."""
    n = len(points)
    if n < 2:
        return []
    dist = np.hypot(*(points[:, None, :] - points[None, :, :]).transpose(2, 0, 1))  # (n, n)
    in_tree = np.zeros(n, dtype=bool)
    in_tree[0] = True
    best = dist[0].copy()  # (n,) distance to the tree
    parent = np.zeros(n, dtype=int)
    edges = []
    for _ in range(n - 1):
        j = int(np.argmin(np.where(in_tree, np.inf, best)))
        edges.append((int(parent[j]), j))
        in_tree[j] = True
        closer = dist[j] < best
        best = np.where(closer, dist[j], best)
        parent = np.where(closer, j, parent)
    return edges

"""Boundary tracing (world/contours.py) against brute force: every sample's side of the traced
rings, the rings' count against the free space's components, the simplification's distance
from the traced rings, and corners of straight walls put back."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from polyslam_env.world.contours import (
    main_region,
    ring_area,
    rings_touching,
    sharpen_corners,
    simplify_ring,
    simplify_rings,
    trace_rings,
)
from polyslam_env.world.layout import point_segment_distance, points_in_polygon

EIGHT = np.ones((3, 3), dtype=bool)


def _random_grid(rng: np.random.Generator) -> np.ndarray:
    """A binary grid (1 free) with an occupied border, of a random size and density."""
    h, w = rng.integers(3, 36, size=2)
    grid = (rng.random((h, w)) < rng.uniform(0.3, 0.85)).astype(float)
    grid[0] = grid[-1] = 0.0
    grid[:, 0] = grid[:, -1] = 0.0
    return grid


def _parity(rings: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """Even-odd count of the rings around each point (…, 2), brute force over all rings."""
    count = np.zeros(points.shape[:-1], dtype=int)
    for ring in rings:
        count += points_in_polygon(points, ring)
    return count % 2 == 1


def _samples(shape: tuple[int, ...], origin: tuple[float, float], res: float) -> np.ndarray:
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    return np.stack([origin[0] + cols * res, origin[1] + rows * res], axis=-1)


@pytest.mark.parametrize("seed", range(40))
def test_trace_rings__binary_grid_inside_exactly_the_free_samples(seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = _random_grid(rng)
    origin, res = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5))), 0.05
    rings = trace_rings(grid, 0.5, origin, res)
    assert np.array_equal(_parity(rings, _samples(grid.shape, origin, res)), grid > 0.5)
    # Free space 4-connected: one counter-clockwise ring per 4-component of free samples, one
    # clockwise ring per 8-component of occupied samples that does not touch the border.
    outer = sum(ring_area(r) > 0 for r in rings)
    holes = sum(ring_area(r) < 0 for r in rings)
    assert outer == ndimage.label(grid > 0.5)[1]
    assert holes == ndimage.label(grid < 0.5, structure=EIGHT)[1] - 1
    assert not rings_touching(rings)


@pytest.mark.parametrize("seed", range(10))
def test_trace_rings__field_crossings_interpolate_to_the_level(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    h, w = 30, 40
    rows, cols = np.mgrid[0:h, 0:w]
    field = -np.ones((h, w))
    for _ in range(6):  # bumps: free where their sum exceeds the level
        cy, cx, s = rng.uniform(3, h - 3), rng.uniform(3, w - 3), rng.uniform(2, 5)
        field += 2 * np.exp(-((rows - cy) ** 2 + (cols - cx) ** 2) / (2 * s * s))
    field[0] = field[-1] = field[:, 0] = field[:, -1] = -1.0
    level = 0.2
    rings = trace_rings(field, level, (0.0, 0.0), 1.0)
    assert np.array_equal(_parity(rings, _samples(field.shape, (0.0, 0.0), 1.0)), field > level)
    for ring in rings:
        for x, y in ring:
            if x == int(x):  # on a vertical grid edge: interpolate along y
                r, c = math.floor(y), int(x)
                t = y - r
                v = (1 - t) * field[r, c] + t * field[r + 1, c]
            else:
                r, c = int(y), math.floor(x)
                t = x - c
                v = (1 - t) * field[r, c] + t * field[r, c + 1]
            assert v == pytest.approx(level, abs=1e-12)


def test_trace_rings__border_above_level_is_refused() -> None:
    with pytest.raises(ValueError, match="border"):
        trace_rings(np.ones((4, 4)), 0.5, (0.0, 0.0), 1.0)


def test_main_region__largest_region_with_its_islands_only() -> None:
    grid = np.zeros((20, 30))
    grid[2:18, 2:20] = 1.0  # the big room
    grid[6:14, 6:14] = 0.0  # an island in it ...
    grid[9:11, 9:11] = 1.0  # ... with a pocket of free space inside
    grid[3:5, 16:18] = 0.0  # a second, small island
    grid[4:8, 23:27] = 1.0  # a separate small room
    rings = trace_rings(grid, 0.5, (0.0, 0.0), 1.0)
    outer, holes = main_region(rings)
    # the traced boundary runs half a cell outside the free samples, corners cut by ⅛ cell²
    assert ring_area(outer) == pytest.approx(16 * 18 - 0.5)
    assert sorted(-ring_area(h) for h in holes) == pytest.approx([4 - 0.5, 64 - 0.5])
    _, big = main_region(rings, min_hole_area=5.0)
    assert [-ring_area(h) for h in big] == pytest.approx([64 - 0.5])


@pytest.mark.parametrize("seed", range(20))
def test_simplify_ring__every_traced_point_within_tolerance(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    rings = trace_rings(_random_grid(rng), 0.5, (0.0, 0.0), 0.05)
    tol = float(rng.uniform(0.01, 0.1))
    for ring in rings:
        simple = simplify_ring(ring, tol)
        assert np.array_equal(simple[0], simple[-1]) and len(simple) >= 4
        segs = np.hstack([simple[:-1], simple[1:]])
        assert point_segment_distance(ring, segs).min(axis=1).max() <= tol + 1e-12
        # the kept points are traced points, in order
        idx = [int(np.flatnonzero((ring == p).all(axis=1))[0]) for p in simple[:-1]]
        assert idx == sorted(idx)


@pytest.mark.parametrize("seed", range(20))
def test_simplify_rings__never_makes_rings_touch(seed: int) -> None:
    """Thin walls of one cell between free cells: a coarse tolerance would make the rings
    on both sides cross; the result must not (and still follow its traced ring)."""
    rng = np.random.default_rng(300 + seed)
    grid = _random_grid(rng)
    rings = trace_rings(grid, 0.5, (0.0, 0.0), 1.0)
    simple = simplify_rings(rings, 2.0)
    assert not rings_touching(simple)
    for ring, s in zip(rings, simple, strict=True):
        segs = np.hstack([s[:-1], s[1:]])
        assert point_segment_distance(ring, segs).min(axis=1).max() <= 2.0 + 1e-12


def test_rings_touching__finds_crossing_and_touching_rings() -> None:
    a = np.array([[0, 0], [2, 0], [2, 2], [0, 2], [0, 0]], dtype=float)
    b = a + np.array([1.0, 1.0])  # crosses a
    c = a + np.array([2.0, 0.0])  # shares a's right side
    d = a + np.array([5.0, 0.0])  # apart
    bow = np.array([[0, 0], [2, 2], [2, 0], [0, 2], [0, 0]], dtype=float) + np.array([10.0, 0.0])
    assert rings_touching([a, b, d]) == {0, 1}
    assert rings_touching([a, c]) == {0, 1}
    assert rings_touching([a, d]) == set()
    assert rings_touching([bow]) == {0}


@pytest.mark.parametrize("angle", [0.0, 0.3, 1.1, 2.0])
def test_sharpen_corners__traced_turned_square_gets_its_corners_back(angle: float) -> None:
    """A square of side 6 turned by ``angle`` as a signed-distance field on a grid of 0.1:
    tracing cuts its corners; simplified and sharpened they are exact again."""
    h = 0.1
    ys, xs = np.mgrid[-50:51, -50:51] * h
    c, s = math.cos(angle), math.sin(angle)
    u, v = xs * c + ys * s, -xs * s + ys * c
    field = np.minimum(3.0 - np.abs(u), 3.0 - np.abs(v))
    ring = simplify_rings(trace_rings(field, 0.0, (-5.0, -5.0), h), 1e-6)[0]
    sharp = sharpen_corners(ring, 1.5 * h)
    corners = np.array([[su * 3, sv * 3] for su, sv in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
    true = np.column_stack([corners[:, 0] * c - corners[:, 1] * s,
                            corners[:, 0] * s + corners[:, 1] * c])  # fmt: skip
    assert len(sharp) == 5
    for corner in true:
        assert np.hypot(*(sharp[:-1] - corner).T).min() < 1e-9

"""Beam rasterisation: the compiled kernels against the numpy oracles (``reference.py``, exact)
and a slow per-beam, per-sample oracle, and the sampling guarantee."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.core import raster
from polyslam_env.core.raster import beam_fractions, even_beam_cells, point_cells, scan_cells
from tests.core import reference


def _oracle_cells(
    pose: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    origin: tuple[float, float],
    res: float,
    shape: tuple[int, int],
) -> tuple[set[int], set[int]]:
    """Free and hit flat ids of one scan, one beam and one sample at a time (the spec).

    The same float operations as the vectorised kernel (a sample at ``length · fraction``, the
    point ``pose + t·(cos φ, sin φ)``, the cell ``⌊(p − origin) / res⌋``), so the sets are
    equal, not merely close.
    """
    h, w = shape
    fractions = np.linspace(0.0, 1.0, math.ceil(max_range / (0.5 * res)) + 1).tolist()
    free: set[int] = set()
    hit: set[int] = set()

    def cell(t: float, phi: float) -> int | None:
        x = pose[0] + t * np.cos(phi)
        y = pose[1] + t * np.sin(phi)
        col, row = math.floor((x - origin[0]) / res), math.floor((y - origin[1]) / res)
        return row * w + col if 0 <= row < h and 0 <= col < w else None

    for angle, r_raw in zip(angles.tolist(), ranges.tolist(), strict=True):
        phi = pose[2] + angle
        returned = math.isfinite(r_raw)
        r = min(r_raw, max_range) if returned else max_range
        length = max(r - 0.5 * res, 0.0) if returned else r
        free |= {c for f in fractions if (c := cell(length * f, phi)) is not None}
        if returned and (c := cell(r, phi)) is not None:
            hit.add(c)
    return free, hit


@pytest.mark.parametrize("res", [0.05, 0.1, 0.13])
def test_scan_cells__match_the_per_sample_oracle(res: float) -> None:
    rng = np.random.default_rng(7)
    shape = (37, 52)
    origin = (-1.3, -0.7)
    max_range = 2.5
    fractions = beam_fractions(max_range, res)
    for _ in range(40):
        k, b = 3, 5
        poses = np.column_stack([rng.uniform(-2.0, 5.0, (k, 2)), rng.uniform(-7, 7, k)])
        angles = rng.uniform(-np.pi, np.pi, b)
        ranges = rng.uniform(0.0, 4.0, (k, b))  # some beyond max_range
        ranges[rng.random((k, b)) < 0.2] = np.inf
        ranges[rng.random((k, b)) < 0.1] = np.nan
        ranges[0, 0] = 0.0
        free, free_in, hit, hit_in = scan_cells(
            poses, angles, ranges, max_range, fractions, origin, res, shape
        )
        assert free.shape == (k, b, len(fractions)) and hit.shape == (k, b)
        for j in range(k):
            want_free, want_hit = _oracle_cells(
                poses[j], angles, ranges[j], max_range, origin, res, shape
            )
            assert set(free[j][free_in[j]].tolist()) == want_free
            assert set(hit[j][hit_in[j]].tolist()) == want_hit


def test_even_beam_cells__samples_res_half_apart_hit_every_cell_crossed_over_half_a_cell() -> None:
    rng = np.random.default_rng(8)
    res, shape, origin = 0.1, (60, 60), (0.0, 0.0)
    for _ in range(200):
        x0, y0 = rng.uniform(1.0, 5.0, 2)
        angle, length = rng.uniform(-np.pi, np.pi), rng.uniform(0.0, 0.9)
        ids = even_beam_cells(
            np.array([[x0]]), np.array([[y0]]), np.array([[angle]]), np.array([[length]]), 1.0,
            origin, res, shape,
        )  # fmt: skip
        got = set(ids[ids >= 0].tolist())
        # dense reference: how far the beam runs inside each cell
        step = res / 500
        t = np.arange(0.0, length, step)
        dense, ok = point_cells(x0 + t * np.cos(angle), y0 + t * np.sin(angle), origin, res, shape)
        ids_, counts = np.unique(dense[ok], return_counts=True)
        crossed = {int(c) for c, m in zip(ids_, counts, strict=True) if (m - 2) * step > 0.5 * res}
        assert crossed <= got


def test_point_cells__equal_the_oracle() -> None:
    rng = np.random.default_rng(9)
    x, y = rng.uniform(-3, 8, 5000), rng.uniform(-3, 8, 5000)
    x[:20] = np.round(x[:20], 1)  # on cell borders
    for res, shape, origin in [(0.1, (50, 40), (0.0, 0.0)), (0.13, (7, 90), (-1.3, 2.2))]:
        flat, inside = point_cells(x, y, origin, res, shape)
        want, want_in = reference.point_cells(x, y, origin, res, shape)
        np.testing.assert_array_equal(inside, want_in)
        np.testing.assert_array_equal(flat[inside], want[want_in])
        assert (flat[~inside] == -1).all()


@pytest.mark.parametrize("res", [0.05, 0.13])
def test_scan_cells_and_mark_scans__equal_the_oracle(res: float) -> None:
    rng = np.random.default_rng(10)
    shape, origin, max_range = (37, 52), (-1.3, -0.7), 2.5
    fractions = beam_fractions(max_range, res)
    for _ in range(40):
        poses = np.column_stack([rng.uniform(-2.0, 5.0, (3, 2)), rng.uniform(-7, 7, 3)])
        angles = rng.uniform(-np.pi, np.pi, 5)
        ranges = rng.uniform(0.0, 4.0, (3, 5))
        ranges[rng.random((3, 5)) < 0.2] = np.inf
        ranges[rng.random((3, 5)) < 0.1] = np.nan
        got = scan_cells(poses, angles, ranges, max_range, fractions, origin, res, shape)
        want = reference.scan_cells(poses, angles, ranges, max_range, fractions, origin, res, shape)
        for ids, inside, want_ids, want_in in [(got[0], got[1], *want[:2]), (*got[2:], *want[2:])]:
            np.testing.assert_array_equal(inside, want_in)
            np.testing.assert_array_equal(ids[inside], want_ids[want_in])
        free, hit = np.zeros((4, *shape), dtype=bool), np.zeros((4, *shape), dtype=bool)
        rows = np.array([3, 0, 2])  # scan k into grid rows[k]; grid 1 stays empty
        raster.mark_scans(poses, angles, ranges, max_range, fractions, origin, res, free, hit, rows)
        for k in range(3):
            assert set(np.flatnonzero(free[rows[k]])) == set(want[0][k][want[1][k]].tolist())
            assert set(np.flatnonzero(hit[rows[k]])) == set(want[2][k][want[3][k]].tolist())
        assert not free[1].any() and not hit[1].any()


def test_even_beam_cells__equal_the_oracle() -> None:
    rng = np.random.default_rng(11)
    shape, origin, res, max_range = (40, 50), (-0.5, -0.2), 0.1, 1.7
    for _ in range(60):
        k, b = 4, 6
        o = rng.uniform(-1.0, 5.0, (k, b, 2))
        phi = rng.uniform(-7, 7, (k, b))
        ranges = rng.uniform(0.0, 2.5, (k, b))
        ranges[rng.random((k, b)) < 0.2] = np.inf
        ranges[rng.random((k, b)) < 0.1] = np.nan
        ids = even_beam_cells(o[..., 0].copy(), o[..., 1].copy(), phi, ranges, max_range, origin,
                              res, shape)  # fmt: skip
        want = reference.even_scan_cells(o, phi, ranges, max_range, origin, res, shape)
        for j in range(k):
            assert set(ids[j][ids[j] >= 0].tolist()) == set(want[j].tolist())


def test_linspace_fraction__equals_numpy_linspace() -> None:
    for n in range(1, 700):
        got = [raster._linspace_fraction(i, n) for i in range(n)]
        assert got == np.linspace(0.0, 1.0, n).tolist()


def test_count_new_and_mark_cells__equal_the_oracle() -> None:
    rng = np.random.default_rng(12)
    mask = rng.random((20, 30)) < 0.7
    marked = rng.random((20, 30)) < 0.3
    for _ in range(50):
        cells = rng.integers(0, 600, int(rng.integers(0, 80)))
        want = reference.count_distinct_new(cells, mask, marked)
        before = marked.copy()
        assert raster.count_new(cells, mask, marked) == want
        np.testing.assert_array_equal(marked, before)  # not changed
        mine = np.zeros_like(marked)
        assert raster.mark_cells(np.concatenate([cells, [-1]]), mask, marked, mine) == want
        assert marked[np.unravel_index(cells, mask.shape)].all() and mine.sum() == len(set(cells))


def test_point_cells__half_open_cells_and_outside_mask() -> None:
    res, shape, origin = 0.5, (2, 3), (1.0, -1.0)
    x = np.array([1.0, 1.49, 1.5, 2.49, 2.5, 0.99, 1.2])
    y = np.array([-1.0, -1.0, -0.5, -0.01, -1.0, -1.0, 0.0])
    flat, inside = point_cells(x, y, origin, res, shape)
    np.testing.assert_array_equal(inside, [True, True, True, True, False, False, False])
    np.testing.assert_array_equal(flat[inside], [0, 0, 4, 5])
    assert (flat[~inside] == -1).all()

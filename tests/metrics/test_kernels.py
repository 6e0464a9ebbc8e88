"""The mapping metrics' kernels against brute force: exact wall distances (the ring search
over the wall index stops only when no unvisited segment can be nearer) and the covered
samples of the completeness."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.metrics.boundary import distance_to_boundary
from polyslam_env.metrics.kernels import (
    buckets,
    covered,
    covered_by,
    parallel_neighbours,
    record_rows,
    sample_rows,
    wall_distances,
)
from polyslam_env.slam.landmarks import PackedPolynomials
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.generators import make_generator
from polyslam_env.world.layout import Layout
from polyslam_env.world.nearby import WallIndex


def _brute_distances(points: np.ndarray, segments: np.ndarray) -> np.ndarray:  # (N,)
    """The oracle: min over every segment of the closed-form point–segment distance."""
    a, b = segments[None, :, 0:2], segments[None, :, 2:4]  # (1, S, 2)
    ab = b - a
    p = points[:, None, :]  # (N, 1, 2)
    t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    d = p - (a + t[..., None] * ab)
    return np.sqrt((d * d).sum(-1)).min(axis=1)


@pytest.mark.parametrize(("generator", "seed"), [("office_floor", 0), ("warehouse", 3)])
@pytest.mark.parametrize("cell", [0.5, 0.13, 3.0])
def test_wall_distances__equal_brute_force_inside_and_far_outside(
    generator: str, seed: int, cell: float
) -> None:
    layout = make_generator(generator)(np.random.default_rng(seed))
    x0, y0, x1, y1 = layout.bounds
    rng = np.random.default_rng(seed)
    inside = rng.uniform([x0, y0], [x1, y1], size=(400, 2))
    # points on the walls, near corners, and far outside the index's grid
    on = layout.segments[rng.integers(len(layout.segments), size=50)]
    on_walls = on[:, 0:2] + rng.uniform(0, 1, (50, 1)) * (on[:, 2:4] - on[:, 0:2])
    far = rng.uniform([x0 - 30, y0 - 30], [x1 + 30, y1 + 30], size=(100, 2))
    corners = layout.segments[:40, 0:2] + rng.normal(0, 1e-3, (min(40, len(layout.segments)), 2))
    points = np.ascontiguousarray(np.vstack([inside, on_walls, far, corners]))
    index = WallIndex.build(layout.segments, cell=cell)
    got = wall_distances(points, *index.arrays)
    # the same closed form, only the minimum's search differs: equal to round-off of the
    # coordinates (1e-12 of metres)
    np.testing.assert_allclose(got, _brute_distances(points, layout.segments), rtol=0, atol=1e-12)


def test_wall_distances__no_walls_is_inf() -> None:
    index = WallIndex.build(np.zeros((0, 4)))
    assert np.all(np.isinf(wall_distances(np.zeros((3, 2)), *index.arrays)))


def test_distance_to_boundary__pillars_and_walls() -> None:
    box = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0], [0.0, 0.0]])
    layout = Layout("box", (box,), pillars=((2.0, 1.5, 0.25),))
    q = np.array([[2.0, 1.0], [0.5, 1.5], [2.0, 2.9]])
    np.testing.assert_allclose(distance_to_boundary(q, layout), [0.25, 0.5, 0.1], atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("tol", [0.05, 0.3])
def test_covered__equals_brute_force(seed: int, tol: float) -> None:
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 5, size=(int(rng.integers(1, 300)), 2))
    if seed == 3:  # spread far: the bucket side grows past tol
        points = np.vstack([points, [[400.0, -250.0]]])
    samples = rng.uniform(-1, 6, size=(2000, 2))
    d2 = ((samples[:, None, :] - points[None, :, :]) ** 2).sum(-1)  # (M, N)
    expected = (d2 < tol * tol).any(axis=1)
    assert np.array_equal(covered(samples, np.ascontiguousarray(points), tol), expected)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("tol", [0.05, 0.3])
def test_covered_by__equals_brute_force_and_covered(seed: int, tol: float) -> None:
    """The samples bucketed once, each point marking its neighbours: the same booleans as
    the brute force and as ``covered`` (points far outside the samples' grid included)."""
    rng = np.random.default_rng(seed)
    samples = rng.uniform(-1, 6, size=(2000, 2))
    if seed == 3:  # spread far: the bucket side grows past tol
        samples = np.vstack([samples, [[400.0, -250.0]]])
    found = buckets(samples, tol)
    for n in (0, 1, int(rng.integers(2, 300))):
        points = rng.uniform(-3, 8, size=(n, 2))
        if seed == 2 and n:
            points[0] = (-900.0, 700.0)  # far outside the grid
        d2 = ((samples[:, None, :] - points[None, :, :]) ** 2).sum(-1)  # (M, N)
        expected = (d2 < tol * tol).any(axis=1)
        got = covered_by(samples, *found, np.ascontiguousarray(points), tol)
        assert np.array_equal(got, expected)
        assert np.array_equal(got, covered(samples, np.ascontiguousarray(points), tol))


def test_covered_by__non_finite_points_mark_nothing() -> None:
    rng = np.random.default_rng(5)
    samples = rng.uniform(-1, 6, size=(1500, 2))
    found = buckets(samples, 0.2)
    points = rng.uniform(-1, 6, size=(120, 2))
    points[::7, 0] = np.nan
    points[3::11, 1] = np.inf
    points[5::13] = -np.inf
    finite = np.ascontiguousarray(points[np.isfinite(points).all(axis=1)])
    got = covered_by(samples, *found, points, 0.2)
    assert np.array_equal(got, covered_by(samples, *found, finite, 0.2))
    assert np.array_equal(got, covered(samples, finite, 0.2))


def test_covered__empty_inputs_and_zero_tolerance() -> None:
    samples = np.ones((4, 2))
    assert not covered(samples, np.zeros((0, 2)), 0.1).any()
    assert not covered(samples, samples.copy(), 0.0).any()
    assert covered(np.zeros((0, 2)), samples, 0.1).shape == (0,)


def _random_polynomials(rng: np.random.Generator, n: int) -> list[Polynomial]:
    """Lines to cubics of either variate, extents from 0 (a point) to 8 m, steep and flat."""
    polys = []
    for k in range(n):
        order = int(rng.integers(1, 4))
        coeffs = rng.normal(0.0, [1.0, 2.0, 0.5, 0.2][: order + 1])
        lo = float(rng.uniform(-4.0, 4.0))
        width = [0.0, 1e-3, float(rng.uniform(0.01, 8.0))][min(k % 7, 2)]
        polys.append(Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + width))
    return polys


@pytest.mark.parametrize("step", [0.01, 0.05, 0.1, 3.0])
def test_sample_rows__equals_sample_arclength_bit_for_bit(step: float) -> None:
    """The oracle is ``Polynomial.sample_arclength`` (numpy's linspace, polyval, norm, cumsum
    and interp), one polynomial at a time; the kernel samples all rows, zero-padded to the
    widest order, in one call."""
    polys = _random_polynomials(np.random.default_rng(int(step * 100)), 40)
    packed = PackedPolynomials.from_polynomials(polys)
    coeffs = packed.shape.copy()
    coeffs[:, 0] = [p.c0 for p in polys]
    rows = np.arange(len(polys))[::-1].copy()  # any order of rows
    points, starts = sample_rows(packed.variate, coeffs, packed.lo, packed.hi, rows, step, 512)
    assert starts[0] == 0 and starts[-1] == len(points)
    for q, r in enumerate(rows.tolist()):
        want = polys[r].sample_arclength(step)
        np.testing.assert_array_equal(points[starts[q] : starts[q + 1]], want)


def _parallel_neighbours_by_kd_tree(
    points: np.ndarray, owner: np.ndarray, tangent: np.ndarray, has_dir: np.ndarray, tol: float,
    max_sine: float,
) -> np.ndarray:  # fmt: skip
    """The oracle: the duplicates metric as it was written with scipy's KD-tree pairs."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray")  # (P, 2), i < j
    pairs = pairs[(owner[pairs[:, 0]] != owner[pairs[:, 1]]) & has_dir[pairs].all(axis=1)]
    ta, tb = tangent[pairs[:, 0]], tangent[pairs[:, 1]]
    pairs = pairs[np.abs(ta[:, 0] * tb[:, 1] - ta[:, 1] * tb[:, 0]) <= max_sine]
    marked = np.zeros(len(points), dtype=bool)
    marked[pairs.ravel()] = True
    return marked


@pytest.mark.parametrize("seed", range(4))
def test_parallel_neighbours__equal_the_kd_tree_pairs(seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = int(rng.integers(2, 3000))
    points = rng.uniform(0, 4, size=(m, 2))
    if seed == 1:  # points on a 5 cm lattice: many pairs exactly at the tolerance
        points = np.round(points / 0.05) * 0.05
    if seed == 3:  # spread far: the bucket side grows past tol
        points[-1] = [500.0, -300.0]
    owner = rng.integers(0, 12, size=m)
    angle = rng.uniform(0, 2 * np.pi, size=m)
    tangent = np.column_stack([np.cos(angle), np.sin(angle)])
    has_dir = rng.random(m) > 0.1
    max_sine = float(np.sin(np.deg2rad(30.0)))
    for tol in (0.05, 0.1, 0.0):
        expected = _parallel_neighbours_by_kd_tree(points, owner, tangent, has_dir, tol, max_sine)
        got = parallel_neighbours(points, owner, tangent, has_dir, tol, max_sine)
        assert np.array_equal(got, expected)
        assert tol == 0.0 or 0 < got.sum() < m  # both kinds present: a real comparison


def test_covered__equals_the_kd_tree_query_within_its_bound() -> None:
    """``covered`` replaced ``cKDTree.query(…, distance_upper_bound=tol)`` in the seen
    boundary: the same samples, ties at exactly ``tol`` included (both strict)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    points = np.round(rng.uniform(0, 3, size=(500, 2)) / 0.05) * 0.05
    samples = np.round(rng.uniform(-0.5, 3.5, size=(4000, 2)) / 0.05) * 0.05
    for tol in (0.05, 0.15):
        d, _ = cKDTree(points).query(samples, k=1, distance_upper_bound=tol)
        assert np.array_equal(covered(samples, points, tol), np.isfinite(d))


def _record_rows_numpy(
    slots: np.ndarray, true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray,
    slam_times: np.ndarray, ranges: np.ndarray, collided: np.ndarray, diverging: np.ndarray,
    h: dict[str, np.ndarray],
) -> None:  # fmt: skip
    """The oracle: ``TeamHistory.record``'s numpy form before the kernel (fancy indexing)."""
    rows = h["lengths"][slots]
    last = h["true"][rows - 1, slots]
    step = np.hypot(true_poses[:, 0] - last[:, 0], true_poses[:, 1] - last[:, 1])
    h["path_length"][slots] += step
    h["true"][rows, slots] = true_poses
    h["est"][rows, slots] = est_poses
    h["cov"][rows, slots] = est_covs
    h["times"][rows, slots] = slam_times
    h["beams"][rows, slots] = ranges
    h["collisions"][slots] += collided
    first = diverging & ~h["diverged"][slots]
    h["diverged_at"][slots[first]] = rows[first]
    h["diverged"][slots] |= diverging
    h["lengths"][slots] = rows + 1


def test_record_rows__equals_the_numpy_record_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    j, capacity = 5, 40
    start = rng.normal(size=(j, 3)) * 20.0
    fresh = {
        "lengths": np.ones(j, dtype=np.int64),
        "true": np.zeros((capacity, j, 3)),
        "est": np.zeros((capacity, j, 3)),
        "cov": np.zeros((capacity, j, 3, 3)),
        "times": np.full((capacity, j), np.nan),
        "beams": np.full((capacity, j, 4), np.inf),
        "path_length": np.zeros(j),
        "collisions": np.zeros(j, dtype=np.int64),
        "diverged": np.zeros(j, dtype=bool),
        "diverged_at": np.full(j, -1, dtype=np.int64),
    }
    fresh["true"][0] = start
    ours = {name: a.copy() for name, a in fresh.items()}
    oracle = {name: a.copy() for name, a in fresh.items()}
    for _ in range(30):  # steps recording a random ascending subset of slots
        slots = np.flatnonzero(rng.random(j) < 0.7)
        k = len(slots)
        args = (
            slots, rng.normal(size=(k, 3)) * 20.0, rng.normal(size=(k, 3)),
            rng.normal(size=(k, 3, 3)), np.where(rng.random(k) < 0.3, np.nan, rng.random(k)),
            np.where(rng.random((k, 4)) < 0.3, np.inf, rng.random((k, 4)) * 5.0),
            rng.random(k) < 0.3, rng.random(k) < 0.1,
        )  # fmt: skip
        record_rows(*args, *ours.values())
        _record_rows_numpy(*args, oracle)
    for name in fresh:
        np.testing.assert_array_equal(ours[name], oracle[name], err_msg=name, strict=True)
    assert ours["diverged"].any() and ours["collisions"].any()  # the flags were exercised

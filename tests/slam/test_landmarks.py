"""Fast-path helpers of the SLAM step: the landmark table, bounding boxes, and the
faster variants (in-place prediction, candidate ray casting, packed association) against the
pure or brute-force versions they replace."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.slam import map_kernels
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import predict, predict_inplace, spectral_norm_sym
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.landmarks import LandmarkTable, PackedPolynomials, _own_order, shape_range
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from tests.slam.reference import (
    approximation_error,
    expected_ranges_and_jacobian,
    ray_intersections,
)

BEAMS = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])


def random_polys(rng: np.random.Generator, n: int, spread: float = 3.0) -> list[Polynomial]:
    """n short cubics (some straight lines) of both variates scattered over ±spread m."""
    polys = []
    for i in range(n):
        coeffs = np.array([rng.uniform(-spread, spread), *rng.normal(0.0, [0.5, 0.3, 0.2])])
        if i % 3 == 0:
            coeffs[2:] = 0.0  # a straight wall
        lo = rng.uniform(-spread, spread)
        polys.append(Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + rng.uniform(0.1, 1.5)))
    return polys


def arrays_of(polys: list[Polynomial]) -> LandmarkTable:
    arrays = LandmarkTable()
    for i, p in enumerate(polys):
        arrays.append(
            p, pivot=0.5 * (p.lo + p.hi), xi_var=0.01 * i, model_var=0.001 * i, fit_half=0.2
        )
    return arrays


def assert_packed_equal(a: PackedPolynomials, b: PackedPolynomials) -> None:
    np.testing.assert_array_equal(a.variate, b.variate)
    np.testing.assert_array_equal(a.shape, b.shape)
    np.testing.assert_array_equal(a.lo, b.lo)
    np.testing.assert_array_equal(a.hi, b.hi)


# -- LandmarkTable -------------------------------------------------------------------------------
# Seeded random maps (``random_polys``): the seed is the only input, so these are plain
# parametrised seeds rather than Hypothesis draws, which could not shrink a seed.
@pytest.mark.parametrize("seed", range(40))
def test_shape_range__bounds_the_curve_on_its_extent(seed: int) -> None:
    rng = np.random.default_rng(seed)
    polys = random_polys(rng, 4)
    arrays = arrays_of(polys)
    for p, (low, high) in zip(polys, arrays.eta_range, strict=True):
        values = p.with_c0(0.0).value(np.linspace(p.lo, p.hi, 2001))
        assert values.min() >= low and values.max() <= high  # exact: the bound is conservative


def test_shape_range__is_tight_for_a_straight_line() -> None:
    shape = np.array([[0.0, 2.0, 0.0, 0.0]])  # B(ξ) = 2ξ
    low, high = shape_range(shape, np.array([1.0]), np.array([3.0]))[0]
    # only the 1e-9 relative pad separates the bound from the true range [2, 6]
    assert abs(low - 2.0) < 1e-7 and abs(high - 6.0) < 1e-7


def test_landmark_table__tracks_appends_removals_and_extents() -> None:
    rng = np.random.default_rng(3)
    polys = random_polys(rng, 6)
    polys[1] = Polynomial(1, np.array([0.5, 0.1]), -1.0, 1.0)  # lower order: zero-padded
    arrays = arrays_of(polys)
    assert_packed_equal(arrays.packed(), PackedPolynomials.from_polynomials(polys))
    arrays.remove(2)
    arrays.set_extent(0, polys[0].lo - 0.5, polys[0].hi)
    expected = [Polynomial(polys[0].variate, polys[0].coeffs, polys[0].lo - 0.5, polys[0].hi)]
    expected += polys[1:2] + polys[3:]
    assert_packed_equal(arrays.packed(), PackedPolynomials.from_polynomials(expected))
    np.testing.assert_array_equal(arrays.xi_var, [0.0, 0.01, 0.03, 0.04, 0.05])
    np.testing.assert_array_equal(arrays.eta_range, arrays_of(expected).eta_range)
    assert arrays.ids == [0, 1, 3, 4, 5] and len(arrays) == 5
    for got, want in zip(arrays.polys, expected, strict=True):  # the polynomials follow
        assert (got.variate, got.lo, got.hi) == (want.variate, want.lo, want.hi)
        np.testing.assert_array_equal(got.coeffs, want.coeffs)


def test_landmark_table__ids_stay_stable_through_removals() -> None:
    polys = random_polys(np.random.default_rng(5), 3)
    table = LandmarkTable()
    a, b, c = (table.append(p, 0.0, 0.0, 0.0, 1.0, step=k) for k, p in enumerate(polys))
    assert [table.state_index(x) for x in (a, b, c)] == [3, 4, 5]
    assert table.remove(table.index_of(a)) == a
    assert table.ids == [b, c] and table.state_index(c) == 4 and a not in table
    assert table.changed_at.tolist() == [1, 2]
    d = table.append(polys[0], 0.0, 0.0, 0.0, 1.0, step=7)
    assert d not in (a, b, c) and table.index_of(d) == 2
    assert dict(table.shapes) == {b: polys[1], c: polys[2], d: polys[0]}
    before = table.shapes[b]
    table.set_extent(0, before.lo - 1.0, before.hi)
    assert table.shapes[b] is not before and table.shapes[b].lo == before.lo - 1.0


def test_landmark_table__polynomials_are_new_objects_only_when_a_row_changes() -> None:
    polys = random_polys(np.random.default_rng(6), 3)
    table = arrays_of(polys)
    first = [table.polys[i] for i in range(3)]
    assert all(table.polys[i] is first[i] for i in range(3))  # unchanged: the same objects
    table.extend_to_hit(1, polys[1].hi + 0.5)
    assert table.polys[0] is first[0] and table.polys[2] is first[2]
    assert table.polys[1] is not first[1] and table.polys[1].hi == polys[1].hi + 0.5
    np.testing.assert_array_equal(table.polys[1].coeffs, polys[1].coeffs)
    table.remove(0)
    assert table.polys[1] is first[2]  # removal moves the rows, not the objects


def test_landmark_table__grows_past_its_capacity_and_wider_shapes() -> None:
    rng = np.random.default_rng(9)
    polys = random_polys(rng, 40)
    polys[30] = Polynomial(1, np.array([0.5, 0.1, 0.0, 0.0, 0.0, 0.02]), -1.0, 1.0)  # order 5
    table = LandmarkTable(capacity=2)
    for p in polys:
        table.append(p, 0.0, 0.0, 0.0, 1.0)
    assert len(table) == 40 and table.shape.shape == (40, 6)
    assert_packed_equal(table.packed(), PackedPolynomials.from_polynomials(polys))
    np.testing.assert_array_equal(table.eta_range, arrays_of(polys).eta_range)


def test_landmark_table__packed_views_stay_valid_after_changes() -> None:
    polys = random_polys(np.random.default_rng(4), 3)
    arrays = arrays_of(polys)
    before = arrays.packed()
    arrays.set_extent(1, -10.0, 10.0)
    assert before.lo[1] == polys[1].lo  # not written in place
    assert arrays.packed().lo[1] == -10.0


@pytest.mark.parametrize("seed", range(30))
def test_near__keeps_every_landmark_with_a_curve_point_within_the_distance(seed: int) -> None:
    rng = np.random.default_rng(seed)
    distance = rng.uniform(0.05, 3.0)
    polys = random_polys(rng, 12)
    arrays = arrays_of(polys)
    c0s = rng.uniform(-2.0, 2.0, len(polys))
    point = rng.uniform(-3.0, 3.0, 2)
    near = set(arrays.near(np.repeat(point, 2), c0s, distance).tolist())
    for i, p in enumerate(polys):
        curve = p.with_c0(c0s[i]).equally_spaced(500)
        if np.min(np.linalg.norm(curve - point, axis=1)) <= distance:
            assert i in near


# -- fast variants against the pure ones -----------------------------------------------------------
@pytest.mark.parametrize("seed", range(30))
def test_expected_ranges__candidates_give_the_same_result_as_all(seed: int) -> None:
    rng = np.random.default_rng(seed)
    polys = random_polys(rng, 15)
    arrays = arrays_of(polys)
    mean = np.concatenate([rng.uniform(-2, 2, 2), rng.uniform(-np.pi, np.pi, 1)])
    mean = np.concatenate([mean, rng.uniform(-2.0, 2.0, len(polys))])
    reach = arrays.near(np.repeat(mean[:2], 2), mean[3:], 2.0 + 1e-3)
    full = expected_ranges_and_jacobian(mean, polys, BEAMS, 2.0)
    fast = expected_ranges_and_jacobian(mean, arrays.packed(), BEAMS, 2.0, candidates=reach)
    for a, b in zip(full, fast, strict=True):
        np.testing.assert_array_equal(a, b)  # same rows solved the same way: bit-identical


def test_ray_intersections__padding_lines_to_cubics_changes_nothing() -> None:
    rng = np.random.default_rng(5)
    lines = [Polynomial(1 + i % 2, np.array([rng.uniform(-1, 1), 0.3]), -2, 2) for i in range(4)]
    padded = PackedPolynomials(
        np.array([p.variate for p in lines]),
        np.array([[0.0, 0.3, 0.0, 0.0]] * 4),
        np.full(4, -2.0),
        np.full(4, 2.0),
    )
    pose = np.array([0.1, -0.2, 0.4])
    c0s = np.array([p.c0 for p in lines])
    a = ray_intersections(pose, BEAMS, lines, c0s, 2.0)
    b = ray_intersections(pose, BEAMS, padded, c0s, 2.0)
    np.testing.assert_array_equal(a.ranges, b.ranges)
    np.testing.assert_array_equal(a.index, b.index)


def test_approximation_error__packed_matches_list() -> None:
    rng = np.random.default_rng(6)
    polys = random_polys(rng, 8)
    points = rng.uniform(-3, 3, (7, 2))
    c0s = rng.uniform(-1, 1, 8)
    a = approximation_error(points, polys, c0s)
    b = approximation_error(points, PackedPolynomials.from_polynomials(polys), c0s)
    np.testing.assert_array_equal(a, b)


def test_predict_inplace__matches_pure_predict() -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(8, 8))
    cov = a @ a.T
    mean = rng.normal(size=8)
    odometry, W = np.array([0.1, 0.02, 0.05]), np.diag([1e-4, 1e-4, 1e-6])
    want_mean, want_cov = predict(mean, cov, odometry, W)
    predict_inplace(mean, cov, odometry, W)
    np.testing.assert_array_equal(mean, want_mean)
    np.testing.assert_array_equal(cov, want_cov)


def test_spectral_norm_sym__matches_svd_norm() -> None:
    rng = np.random.default_rng(8)
    for _ in range(20):
        a = rng.normal(size=(3, 3))
        a = a + a.T  # indefinite: the norm may come from the most negative eigenvalue
        # eigvalsh and the SVD round differently: a few ulps of the norm
        assert abs(spectral_norm_sym(a) - np.linalg.norm(a, 2)) <= 1e-13 * np.linalg.norm(a, 2)


# -- PolySlam helpers ----------------------------------------------------------------------------
def _slam_with_walls() -> PolySlam:
    slam = PolySlam(SlamConfig(), BEAMS, 2.0)
    for wall in (
        Polynomial(1, np.array([0.5, 0.0]), -1.5, 0.9),
        Polynomial(1, np.array([-0.5, 0.0]), -1.5, 0.9),
        Polynomial(2, np.array([1.0, 0.0]), -0.45, 0.45),
    ):
        gx = np.zeros((1, slam.mean.size))
        gx[0, 1 if wall.variate == 1 else 0] = 1.0
        fit = Fit(wall, wall.c0, gx, np.ones((1, 1)), np.array([[4e-4]]), 0.02, 1)
        slam.insert_landmark(fit, merge=False)
    return slam


def test_profile_hook__records_stages_without_changing_the_estimate() -> None:
    plain, profiled = _slam_with_walls(), _slam_with_walls()
    profiled.profile = {}
    rng = np.random.default_rng(10)
    walls = plain.polynomials()
    c0s = np.array([w.c0 for w in walls])
    pose = np.zeros(3)
    for _ in range(5):
        pose = pose + np.array([0.01, 0.0, 0.0])
        ranges = ray_intersections(pose, BEAMS, walls, c0s, 2.0).ranges
        ranges = ranges + rng.normal(0.0, 0.02, BEAMS.size)
        odometry = np.array([0.01, 0.0, 0.0])
        assert plain.step(odometry, ranges).beams_used > 0
        profiled.step(odometry, ranges)
    np.testing.assert_array_equal(plain.mean, profiled.mean)
    np.testing.assert_array_equal(plain.cov, profiled.cov)
    assert set(profiled.profile) == {"predict", "association", "map", "update"}
    assert all(len(t) == 5 for t in profiled.profile.values())


def test_landmark_table__append_writes_every_column_of_the_row() -> None:
    """A new row (one compiled write, ``map_kernels.write_row``) holds the polynomial's shape
    zero-padded to the table's width, its extent and η range (``map_kernels.eta_range`` of
    that row), evidence, scalars and flags; its own order is the last nonzero coefficient's
    (a zero tail, −0.0 included, does not count; at least 1)."""
    rng = np.random.default_rng(8)
    table = LandmarkTable()
    for k in range(40):
        coeffs = rng.normal(0.0, 1.0, int(rng.integers(2, 5)))
        cut = int(rng.integers(1, coeffs.size + 1))  # the zero tail starts here
        coeffs[cut:] = [0.0, -0.0][k % 2]
        poly = Polynomial(int(rng.integers(1, 3)), coeffs, -1.0 - k, 2.0 + k)
        values = rng.normal(size=5).tolist()
        lid = table.append(poly, *values[:4], step=k, side=k % 3 - 1, evidence=(-50.0, 50.0),
                           received=bool(k % 2), shift_slope=values[4])  # fmt: skip
        i = table.index_of(lid)
        row = table.shape[i]
        assert row[0] == 0.0 and np.array_equal(row[1 : coeffs.size], coeffs[1:])
        assert not row[coeffs.size :].any()
        assert (table.lo[i], table.hi[i]) == (poly.lo, poly.hi)
        assert tuple(table.eta_range[i]) == map_kernels.eta_range(row.copy(), poly.lo, poly.hi)
        assert tuple(table.evidence[i]) == (-50.0, 50.0)
        assert [table.pivot[i], table.xi_var[i], table.model_var[i], table.fit_half[i]] == values[
            :4
        ]
        assert table.shift_slope[i] == values[4]
        assert int(table.order[i]) == max(cut - 1, 1)  # normal draws are nonzero
        assert (int(table.variate[i]), int(table.side[i]), int(table.changed_at[i])) == (
            poly.variate, k % 3 - 1, k,
        )  # fmt: skip
        assert (int(table.received[i]), int(table.stamp[i])) == (k % 2, 0)


@pytest.mark.parametrize(
    ("row", "order"),
    [
        ([0.0, 0.5, 0.0, 0.0], 1),
        ([0.0, 0.0, 0.0, 0.0], 1),  # a flat line is still a line
        ([0.0, 1.0, 2.0, -0.0], 2),  # −0.0 is zero
        ([0.0, 0.0, 3.0, 0.0], 2),
        ([0.0, 0.0, 0.0, np.nan], 3),  # a NaN is not zero (as np.flatnonzero says)
    ],
)
def test_own_order__the_last_nonzero_coefficient_at_least_linear(row: list, order: int) -> None:
    """A shape row's own order (``map_kernels.own_order``) and the row cut to it
    (``landmarks._own_order``)."""
    shape = np.array(row)
    assert map_kernels.own_order(shape) == order
    got = _own_order(shape)
    assert len(got) == order + 1
    np.testing.assert_array_equal(got, shape[: order + 1])

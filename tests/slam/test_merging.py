"""Tests of map merging: overlap, γ test, and the merged fit's Jacobians."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.slam import map_kernels
from polyslam_env.slam.fitting import PointSet, centroid_xi, fit_polynomial, turn_gradient
from polyslam_env.slam.landmarks import LandmarkTable, boxes_near
from polyslam_env.slam.merging import (
    JOIN_GAP,
    MERGE_ANGLE_DEG,
    THIN_WALL,
    choose_merge,
    face_normal,
    find_merge,
    join_gamma,
    merge_angle,
    merge_fit,
    merge_gammas,
    near_merge_gammas,
    table_candidates,
    unit_tangent,
)
from polyslam_env.slam.polynomial import Polynomial
from tests.slam import reference_merging
from tests.slam.finite_differences import FD_ATOL, FD_RTOL, fd_jacobian
from tests.slam.reference_merging import join_gamma as reference_join_gamma
from tests.slam.reference_merging import max_slope, merge_gamma, merge_points, overlap_interval

GAMMA_M = 0.35  # paper value


def wall_value(x: np.ndarray) -> np.ndarray:
    """The true wall x² = w(x¹), gently curved."""
    return 0.8 + 0.2 * x - 0.05 * x**2


def fitted_piece(lo: float, hi: float, rng: np.random.Generator, variate: int = 1) -> Polynomial:
    """A cubic fitted to noisy points of the wall over x¹ ∈ [lo, hi]."""
    x = np.linspace(lo, hi, 30)
    xy = np.column_stack([x, wall_value(x) + rng.normal(0, 0.005, 30)])
    ps = PointSet(xy, np.zeros((30, 2, 3)), np.zeros((30, 2, 0)), np.zeros((0, 0)), np.ones(30))
    return fit_polynomial(ps, 3, variate).poly


def line(variate: int, c0: float, slope: float, lo: float, hi: float) -> Polynomial:
    return Polynomial(variate, np.array([c0, slope, 0.0, 0.0]), lo, hi)


def test_merge__overlapping_pieces_of_one_wall_merge_close_to_it() -> None:
    rng = np.random.default_rng(0)
    old = fitted_piece(0.0, 1.2, rng)
    new = fitted_piece(0.8, 2.0, rng)
    far = line(1, 3.0, 0.0, 0.0, 2.0)  # a wall 2 m away: overlapping in x¹, not mergeable
    idx = find_merge(new, new.c0, [far, old], [far.c0, old.c0], GAMMA_M)
    assert idx == 1
    pts = merge_points(new, 4, 1e-4, old, 5, 2e-4, 5, n_state=6)
    merged = fit_polynomial(pts, 3)
    assert (merged.poly.lo, merged.poly.hi) == pytest.approx((0.0, 2.0), abs=0.02)  # fit noise
    x = np.linspace(0.0, 2.0, 50)
    # each piece is within ~5 mm (its noise); their blend stays within 1 cm of the wall
    assert np.max(np.abs(merged.poly.value(x) - wall_value(x))) < 0.01


@pytest.mark.parametrize("variates", [(1, 1), (2, 2), (1, 2)])
def test_merge_points__jacobians_on_both_c0s_match_finite_differences(
    variates: tuple[int, int],
) -> None:
    # a diagonal wall described as x¹- or x²-variate polynomials
    a = Polynomial(variates[0], np.array([0.3, 0.9, 0.05, -0.01]), 0.0, 1.5)
    b_coeffs = (
        np.array([0.35, 0.95, 0.02, 0.0])
        if variates[1] == variates[0]
        else np.array([-0.3, 1.1, 0.0, 0.0])
    )
    b = Polynomial(variates[1], b_coeffs, 1.0, 2.5)
    state = np.array([0.1, 0.2, 0.3, 9.0, a.c0, b.c0])
    i_a, i_b = 4, 5

    def merged_c0(x: np.ndarray, variate: int) -> float:
        pts = merge_points(a.with_c0(x[i_a]), i_a, 1e-4, b.with_c0(x[i_b]), i_b, 3e-4, 5, 6)
        return fit_polynomial(pts, 3, variate).c0

    fit = fit_polynomial(merge_points(a, i_a, 1e-4, b, i_b, 3e-4, 5, 6), 3)
    fd = fd_jacobian(lambda x: merged_c0(x, fit.poly.variate), state)
    np.testing.assert_allclose(fit.Gx[0], fd, rtol=FD_RTOL, atol=FD_ATOL)
    # both c0s enter (b's share of the intercept at ξ = 0 is small: its points are far from 0
    # and weigh 1/3 of a's; measured ≥ 0.004)
    assert abs(fit.Gx[0, i_a]) > 1e-3 and abs(fit.Gx[0, i_b]) > 1e-3
    np.testing.assert_array_equal(fit.Gx[0, :4], 0.0)
    assert fit.Gy.shape == (1, 0)


@pytest.mark.parametrize("rotation", [False, True])
def test_merge_fit__is_the_points_then_fit_polynomial_bit_for_bit(rotation: bool) -> None:
    """A merge's points and fit in one compiled call (``merging.merge_fit``) equal
    ``merge_points`` then ``fit_polynomial`` (shape fixed, the map's settings): the points,
    their Jacobians and weights, and the fit's variate, coefficients, extent, order, RMS,
    G_x, G_y and R, on random pairs of curves of either variate, with and without turns, auto
    order on and off; and the same error for a non-positive variance."""
    rng = np.random.default_rng(17)
    for trial in range(120):
        polys = []
        for _ in range(2):
            coeffs = rng.normal(0.0, [1.0, 0.6, 0.1, 0.02])
            coeffs[int(rng.integers(2, 5)) :] = 0.0
            lo = float(rng.uniform(-2.0, 2.0))
            polys.append(Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + rng.uniform(0.1, 3)))
        n_state = int(rng.integers(7, 20))
        turns = (6, float(rng.uniform(-1, 1))), (5, float(rng.uniform(-1, 1)))
        turn_a, turn_b = turns if rotation else (None, None)
        var_a, var_b = rng.uniform(1e-5, 1e-2, 2).tolist()
        settings = (3, bool(trial % 2), 0.02**2, bool(trial % 3))
        pts, fit = merge_fit(polys[0], 3, var_a, polys[1], 4, var_b, 5, n_state, turn_a, turn_b,
                             settings)  # fmt: skip
        want_pts = merge_points(polys[0], 3, var_a, polys[1], 4, var_b, 5, n_state, turn_a, turn_b)
        want = fit_polynomial(
            want_pts, 3, None, shape_fixed=True, auto_order=settings[1],
            min_noise_var=settings[2], curvature_test=settings[3],
        )  # fmt: skip
        for name in ("xy", "d_state", "d_noise", "noise_cov", "weights"):
            assert np.array_equal(getattr(pts, name), getattr(want_pts, name)), name
        assert (fit.poly.variate, fit.poly.lo, fit.poly.hi, fit.c0, fit.rms, fit.order) == (
            want.poly.variate, want.poly.lo, want.poly.hi, want.c0, want.rms, want.order,
        )  # fmt: skip
        assert np.array_equal(fit.poly.coeffs, want.poly.coeffs)
        assert np.array_equal(fit.Gx, want.Gx) and np.array_equal(fit.Gy, want.Gy)
        assert fit.r_factor is not None and want.r_factor is not None
        assert np.array_equal(fit.r_factor, want.r_factor) and fit.scale == want.scale
    for bad in (0.0, -1e-4, math.nan):
        with pytest.raises(ValueError, match="c0_var must be > 0"):
            merge_fit(polys[0], 3, bad, polys[1], 4, 1e-4, 5, 8, None, None, (3, True, 0.0, False))


def test_find_merge__gamma_threshold_is_respected() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    p2 = line(1, 1.3, 0.0, 0.2, 1.2)  # parallel, 0.3 m apart: γ = 0.3
    assert find_merge(p, p.c0, [p2], [p2.c0], gamma_max=0.35) == 0
    assert find_merge(p, p.c0, [p2], [p2.c0], gamma_max=0.25) is None
    # the c0 from the state counts, not the polynomial's own
    assert find_merge(p, p.c0, [p2], [1.05], gamma_max=0.1) == 0


def test_find_merge__far_or_disjoint_or_barely_touching_are_not_merged() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    far = line(1, 2.0, 0.0, 0.0, 1.0)  # 1 m away
    disjoint = line(1, 1.0, 0.0, 1.5, 2.5)  # same line, no overlap
    touching = line(1, 1.0, 0.0, 0.95, 2.0)  # overlap 5 cm < 10 cm, neither includes the other
    for other in (far, disjoint, touching):
        assert find_merge(p, p.c0, [other], [other.c0], GAMMA_M) is None
    assert find_merge(p, p.c0, [touching], [touching.c0], GAMMA_M, min_overlap=0.04) == 0


def test_find_merge__short_included_piece_is_merged() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    short = line(1, 1.02, 0.0, 0.4, 0.45)  # 5 cm, inside p's extent
    assert find_merge(p, p.c0, [short], [short.c0], GAMMA_M) == 0


def test_find_merge__perpendicular_walls_at_a_corner_are_not_merged() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)  # x² = 1
    wall = line(2, 0.9, 0.0, 1.0, 1.3)  # x¹ = 0.9 for x² ∈ [1, 1.3]: meets p at a corner
    assert overlap_interval(p, wall) is not None  # it projects inside p's extent…
    assert find_merge(p, p.c0, [wall], [wall.c0], GAMMA_M) is None  # …but is not the same wall


def test_find_merge__different_variates_compare_geometrically() -> None:
    # the diagonal x² = x¹ as x¹-variate on [0, 1] and as x²-variate on [0.5, 1.5]
    p = line(1, 0.0, 1.0, 0.0, 1.0)
    p2 = line(2, 0.05, 1.0, 0.5, 1.5)  # x¹ = x² + 0.05: 5 cm from p along x¹
    a, b, included = overlap_interval(p, p2) or (0.0, 0.0, True)
    assert (a, b) == pytest.approx((0.55, 1.0)) and not included  # projected on p's x¹ axis
    assert find_merge(p, p.c0, [p2], [p2.c0], 0.1) == 0
    assert find_merge(p, p.c0, [p2], [p2.c0], 0.051) == 0
    assert find_merge(p, p.c0, [p2], [p2.c0], 0.049) is None  # γ = 0.05 (horizontal distance)


def test_find_merge__picks_the_best_and_skips_excluded() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    near, nearer = line(1, 1.2, 0.0, 0.0, 1.0), line(1, 1.05, 0.0, 0.0, 1.0)
    polys = [near, p, nearer]
    c0s = [q.c0 for q in polys]
    assert find_merge(p, p.c0, polys, c0s, GAMMA_M, exclude=1) == 2
    assert find_merge(p, p.c0, polys, c0s, GAMMA_M) == 1  # itself, γ = 0
    assert find_merge(p, p.c0, [near], [near.c0], GAMMA_M) == 0


# -- joins and faces (issue 14) -----------------------------------------------------------------
def test_find_merge__pieces_of_one_wall_end_to_end_are_joined_not_across_a_door() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    next_piece = line(1, 1.01, 0.0, 1.06, 2.0)  # 6 cm gap < JOIN_GAP, 1 cm offset
    across_door = line(1, 1.0, 0.0, 1.6, 2.5)  # 0.6 m doorway
    offset = line(1, 1.08, 0.0, 1.02, 2.0)  # 8 cm off: another wall's face, not a continuation
    assert find_merge(p, p.c0, [next_piece], [next_piece.c0], GAMMA_M) is None  # paper rule
    assert find_merge(p, p.c0, [next_piece], [next_piece.c0], GAMMA_M, join_gap=JOIN_GAP) == 0
    for other in (across_door, offset):
        assert find_merge(p, p.c0, [other], [other.c0], GAMMA_M, join_gap=JOIN_GAP) is None


def test_find_merge__corner_pieces_meeting_end_to_end_are_not_joined() -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    wall = line(2, 1.02, 0.0, 0.0, 0.98)  # x = 1.02 for y ∈ [0, 0.98]: ends 2 cm apart
    assert find_merge(p, p.c0, [wall], [wall.c0], GAMMA_M, join_gap=JOIN_GAP) is None


@pytest.mark.parametrize(
    ("offset", "sides", "merged"),
    [
        (0.10, (1, 1), True),  # a duplicate of one face 10 cm off (within γ_M): merge
        (0.05, (1, 1), True),
        (0.10, (1, -1), False),  # the two faces of a 10 cm thick wall: keep both
        (1.20, (1, -1), False),  # the two walls of a corridor
        (0.02, (1, -1), True),  # a wall thinner than THIN_WALL is one curve
        (0.10, (0, -1), True),  # a face of unknown side (received): the paper's rule
    ],
)
def test_find_merge__faces_seen_from_opposite_sides_merge_only_when_thin(
    offset: float, sides: tuple[int, int], merged: bool
) -> None:
    p = line(1, 1.0, 0.0, 0.0, 1.0)
    other = line(1, 1.0 + offset, 0.0, 0.2, 1.2)
    gamma = 1.3 if offset > 1 else GAMMA_M  # let γ_M admit the corridor, to test the faces
    found = find_merge(p, p.c0, [other], [other.c0], gamma, new_side=sides[0], sides=[sides[1]])
    assert (found == 0) is merged
    assert offset > THIN_WALL or merged  # the table's cases are on the stated rule's sides


def test_face_normal__points_to_the_observed_side_for_both_variates() -> None:
    horizontal = line(1, 1.0, 0.0, 0.0, 1.0)  # y = 1
    vertical = line(2, 2.0, 0.0, 0.0, 1.0)  # x = 2
    np.testing.assert_allclose(face_normal(horizontal, 0.5, 1), [0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(face_normal(vertical, 0.5, 1), [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(face_normal(vertical, 0.5, -1), [-1.0, 0.0], atol=1e-12)


def test_merge_points__merged_c0_variance_does_not_double_count_shared_information() -> None:
    """Two landmarks with the very same information (fully correlated c0s, variance s²):
    the merged c0's variance G_x P G_xᵀ is s², not the s²/2 two independent ones would give.
    """
    a = line(1, 1.0, 0.0, 0.0, 1.0)
    b = line(1, 1.0, 0.0, 0.5, 1.5)
    s2 = 1e-4
    cov = np.zeros((5, 5))
    cov[3:, 3:] = s2  # c0_a ≡ c0_b
    fit = fit_polynomial(merge_points(a, 3, s2, b, 4, s2, 5, 5), 3, shape_fixed=True)
    merged_var = float((fit.Gx @ cov @ fit.Gx.T)[0, 0])
    assert merged_var == pytest.approx(s2, rel=1e-9)
    independent = np.diag([0.0, 0.0, 0.0, s2, s2])
    assert float((fit.Gx @ independent @ fit.Gx.T)[0, 0]) == pytest.approx(s2 / 2, rel=1e-9)


def test_max_slope__exact_against_dense_sampling() -> None:
    """The steepest |dη/dξ| on the extent (ends, or where the slope turns) against the
    maximum over 20,001 samples: equal up to the sampling step's effect. The ends are
    samples, and at an interior maximum the slope is flat, so the sampled maximum is within
    ½ max|η‴| (h/2)² of the true one (h ≤ 1e-4 m: below 1e-5 here; 1e-3 leaves room)."""
    rng = np.random.default_rng(5)
    for k in range(300):
        order = 3 + k % 3  # cubics and the orders 4 and 5 the config allows
        coeffs = rng.normal(0.0, [1.0, 1.0, 2.0, 3.0, 3.0, 3.0][: order + 1])
        lo = float(rng.uniform(-2.0, 1.0))
        poly = Polynomial(1, coeffs, lo, lo + float(rng.uniform(0.1, 2.0)))
        dense = np.abs(poly.slope(np.linspace(poly.lo, poly.hi, 20001))).max()
        assert poly.max_slope() == pytest.approx(dense, abs=1e-3)
        assert poly.max_slope() >= dense - 1e-12


def test_max_slope__bit_identical_to_numpys_polynomial_functions() -> None:
    """Lines, parabolas, cubics (a turn inside the extent, outside, none: b₃ = 0, and
    b₂ = 0) and the orders 4 and 5 give the same float as polyder, polytrim and polyroots."""
    rng = np.random.default_rng(6)
    for k in range(400):
        order = 1 + k % 5
        coeffs = rng.normal(0.0, 2.0, order + 1)
        if k % 7 == 0 and order >= 3:
            coeffs[3] = 0.0
        if k % 11 == 0 and order >= 2:
            coeffs[2] = 0.0
        lo = float(rng.uniform(-2.0, 1.0))
        poly = Polynomial(1 + k % 2, coeffs, lo, lo + float(rng.uniform(0.01, 3.0)))
        assert poly.max_slope() == max_slope(poly)


def test_unit_tangent__same_floats_as_numpys_norm() -> None:
    """The tangent divided by its length as ``np.linalg.norm`` computes it, bit for bit."""
    rng = np.random.default_rng(8)
    for k in range(200):
        poly = Polynomial(1 + k % 2, rng.normal(0.0, 2.0, 4), -1.0, 1.0)
        xi = float(rng.uniform(-1.0, 1.0))
        slope = float(poly.slope(xi))
        t = np.array([1.0, slope]) if poly.variate == 1 else np.array([slope, 1.0])
        assert unit_tangent(poly, xi).tobytes() == (t / np.linalg.norm(t)).tobytes()


def test_fit__a_shape_curving_away_between_its_points_is_refused() -> None:
    """Two tight groups of points (5 mm) 0.34 m apart on a steep parabola η = 100 (ξ − 0.17)² (the
    merge traced on a pillar hall: its curve ran 9 m across the hall between them): the fit
    reproduces it exactly (rms 0), but its slope at the ends is 34 > tan 75°, so PolySlam
    refuses it; the same groups on a gentle parabola (slope 0.34) are accepted."""
    from polyslam_env.slam.config import SlamConfig
    from polyslam_env.slam.fitting import MAX_SLOPE
    from polyslam_env.slam.robot import PolySlam

    slam = PolySlam(SlamConfig(), np.radians([0.0]), 2.0)
    xi = np.concatenate([np.linspace(0.0, 0.005, 5), np.linspace(0.335, 0.34, 5)])
    for curvature, accepted in ((100.0, False), (1.0, True)):
        xy = np.column_stack([xi, curvature * (xi - 0.17) ** 2])
        n = len(xy)
        ps = PointSet(xy, np.zeros((n, 2, 3)), np.zeros((n, 2, 0)), np.zeros((0, 0)), np.ones(n))
        fit = slam.maintenance.fit(ps)
        assert (fit is not None) == accepted, curvature
        steep = fit_polynomial(ps, 3, 1).poly.max_slope()
        assert (steep <= MAX_SLOPE) == accepted


@pytest.mark.parametrize(("variate", "order"), [(1, 1), (2, 1), (1, 3), (2, 2)])
def test_turn_gradient__merged_turn_matches_finite_differences(variate: int, order: int) -> None:
    """∂α/∂X of the merged shape's turn about its pivot, α = atan of its direction there
    (counter-clockwise in (x¹, x²)), against central differences over both pieces' c0s and
    turns: each piece's points are its shape with that c0, turned rigidly about its pivot
    point, and the fit is made again."""
    coeffs_a = np.array([0.3, 0.4, 0.05, -0.01])[: order + 1]
    coeffs_b = np.array([0.35, 0.42, 0.04, -0.01])[: order + 1]
    a = Polynomial(variate, coeffs_a, 0.0, 1.5)
    b = Polynomial(variate, coeffs_b, 3.0, 4.0)  # end to end, 1.5 m apart
    i_a, i_b, t_a, t_b, n = 4, 5, 6, 7, 8
    piv_a, piv_b = 0.75, 3.5
    state = np.array([0.1, 0.2, 0.3, 9.0, a.c0, b.c0, 0.0, 0.0])
    pts = merge_points(a, i_a, 1e-4, b, i_b, 3e-4, 5, n, (t_a, piv_a), (t_b, piv_b))
    fit = fit_polynomial(pts, order, variate)
    pivot = centroid_xi(pts, variate)

    def turn(x: np.ndarray) -> float:
        xy = []
        for poly, c0, alpha, piv in ((a, x[i_a], x[t_a], piv_a), (b, x[i_b], x[t_b], piv_b)):
            moved = poly.with_c0(c0)
            centre = moved.points_at(np.array([piv]))[0]
            c, s = np.cos(alpha), np.sin(alpha)
            xy.append(centre + (moved.equally_spaced(5) - centre) @ np.array([[c, -s], [s, c]]).T)
        ps = PointSet(np.vstack(xy), pts.d_state, pts.d_noise, pts.noise_cov, pts.weights)
        slope = float(fit_polynomial(ps, order, variate).poly.slope(pivot))
        return float(np.arctan(slope)) if variate == 1 else float(-np.arctan(slope))

    fd = fd_jacobian(turn, state)
    grad, _ = turn_gradient(pts, fit, pivot)
    np.testing.assert_allclose(grad, fd, rtol=FD_RTOL, atol=FD_ATOL)
    # the pieces' offsets turn the merged wall (1 cm between pieces ~3 m apart: ~1/300 rad)
    assert abs(grad[i_a]) > 0.1 and abs(grad[i_b]) > 0.1
    if order == 1:  # a line's pieces turned counter-clockwise turn it so (curves: not always)
        assert grad[t_a] > 0 and grad[t_b] > 0
    np.testing.assert_array_equal(grad[:4], 0.0)


@pytest.mark.parametrize("variate", [1, 2])
def test_turn_gradient__residual_variance_is_the_least_squares_turn_variance(variate: int) -> None:
    """Two parallel pieces 1 cm apart are not quite one line: the merged line's turn gets the
    textbook weighted least-squares slope variance for a scatter of the fit's RMS at every
    point, σ² Σ w_i² (ξ_i − ξ̄)² / (Σ w_i (ξ_i − ξ̄)²)² (ξ̄ the weighted mean), times the
    slope-to-angle factor 1/(1 + b'²)²; pieces on one line get none."""
    for offset in (0.01, 0.0):
        a = Polynomial(variate, np.array([1.0, 0.0]), 0.0, 2.0)
        b = Polynomial(variate, np.array([1.0 + offset, 0.0]), 2.5, 3.5)
        pts = merge_points(a, 3, 1e-4, b, 4, 3e-4, 5, 5)
        fit = fit_polynomial(pts, 1, variate)
        _, var = turn_gradient(pts, fit, centroid_xi(pts, variate))
        xi = np.concatenate([np.linspace(0.0, 2.0, 5), np.linspace(2.5, 3.5, 5)])
        w = np.concatenate([np.full(5, 1e4), np.full(5, 1e4 / 3)])
        w = w / w.max()
        centred = xi - np.average(xi, weights=w)
        expected = fit.rms**2 * np.sum(w**2 * centred**2) / np.sum(w * centred**2) ** 2
        expected /= (1.0 + fit.poly.coeffs[1] ** 2) ** 2
        assert var == pytest.approx(expected, rel=1e-9, abs=1e-18)
        assert (var > 1e-12) == (offset > 0)  # 1 cm: ~6e-7 rad²; one line: rounding only


# a wall piece: either variate, order 1 to 5 (trailing zeros too), up to 2 m long, possibly a
# single point; shifted copies and pieces of other walls alike
merge_polys = st.builds(
    lambda v, c, lo, w: Polynomial(v, np.array(c), lo, lo + w),
    st.sampled_from([1, 2]),
    st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=6)
    | st.lists(st.sampled_from([0.0, 0.5, -0.25]), min_size=2, max_size=4),
    st.floats(-2.0, 2.0),
    st.floats(0.0, 2.0) | st.just(0.0),
)


@settings(max_examples=300, deadline=None)
@given(p=merge_polys, other=merge_polys, min_overlap=st.sampled_from([0.0, 0.1, 0.5]))
def test_merge_test__the_same_floats_as_the_readable_version(
    p: Polynomial, other: Polynomial, min_overlap: float
) -> None:
    found = np.full(4, np.nan)
    got = map_kernels.merge_test(
        p.variate, p.coeffs, p.lo, p.hi, other.variate, other.coeffs, other.lo, other.hi,
        min_overlap, found,
    )  # fmt: skip
    overlap = overlap_interval(p, other)
    if overlap is None:
        assert got == map_kernels.DISJOINT
        return
    a, b, included = overlap
    if not (included or b - a >= min_overlap):
        assert got == map_kernels.SHORT_OVERLAP
        return
    gamma, angle = merge_gamma(p, other, a, b)
    assert got == map_kernels.MEASURED
    assert found[:3].tolist() == [a, b, gamma]
    assert merge_angle(p, other, a, b, float(found[3])) == angle


def test_join_gamma__the_same_floats_as_the_readable_version() -> None:
    """Pieces of one curve end to end (gaps up to 0.3 m, offsets and turns of a few cm and
    degrees, either variate on either side) and unrelated pieces: the compiled join's offset
    is the readable version's, bit for bit, and None where it is."""
    rng = np.random.default_rng(7)
    joined = 0
    for trial in range(600):
        variate = int(rng.integers(1, 3))
        coeffs = rng.normal(0.0, [1.0, 0.3, 0.05, 0.01][: int(rng.integers(2, 5))])
        lo = float(rng.uniform(-2.0, 1.0))
        mid = lo + float(rng.uniform(0.0, 1.5))
        p = Polynomial(variate, coeffs, lo, mid)
        if trial % 5 == 4:  # an unrelated piece
            shifted = rng.normal(0.0, 1.0, coeffs.size)
        else:  # the curve's next piece, a little off
            shifted = coeffs + rng.normal(0.0, [0.02, 0.03, 0.0, 0.0][: coeffs.size])
        start = mid + float(rng.uniform(0.0, 0.3))
        other = Polynomial(variate, shifted, start, start + float(rng.uniform(0.0, 1.5)))
        for a, b in ((p, other), (other, p)):
            got = join_gamma(a, b, 0.25)
            want = reference_merging.join_gamma(a, b, 0.25)
            assert (got is None) == (want is None)
            if want is not None:
                assert got is not None and got.hex() == want.hex()
                joined += 1
    assert 100 < joined < 1200  # both outcomes are exercised


def test_join_gamma__equals_the_numpy_oracle_bit_for_bit() -> None:
    """End-to-end joins in plain floats give numpy's offsets bit for bit (or both None), on
    random pieces of random walls of either variate placed end to end, some offset, some
    turned, some of equal gaps (ties pick the same pair)."""
    rng = np.random.default_rng(11)
    joined = 0
    for _ in range(400):
        variate = int(rng.integers(1, 3))
        coeffs = np.array([rng.uniform(-1, 1), rng.uniform(-0.5, 0.5), 0.0, 0.0])
        if rng.random() < 0.5:
            coeffs[2:] = rng.uniform(-0.2, 0.2, 2)
        lo = float(rng.uniform(-2, 0))
        mid = lo + float(rng.uniform(0.3, 2.0))
        gap = float(rng.choice([0.0, rng.uniform(0.0, 0.4)]))
        first = Polynomial(variate, coeffs, lo, mid)
        other = coeffs.copy()
        other[0] += float(rng.choice([0.0, rng.normal(0.0, 0.03)]))
        other[1] += float(rng.choice([0.0, rng.normal(0.0, 0.2)]))
        second = Polynomial(variate, other, mid + gap, mid + gap + float(rng.uniform(0.3, 2.0)))
        for a, b in ((first, second), (second, first), (first, first)):
            want = reference_join_gamma(a, b, 0.3)
            assert join_gamma(a, b, 0.3) == want
            joined += want is not None
    assert joined > 100


@settings(max_examples=200, deadline=None)
@given(
    new=merge_polys,
    others=st.lists(merge_polys, min_size=0, max_size=6),
    sides=st.lists(st.sampled_from([-1, 0, 1]), min_size=7, max_size=7),
    joins=st.booleans(),
    gamma_max=st.sampled_from([0.05, 0.35, 2.0]),
)
def test_choose_merge__the_same_choice_as_candidate_by_candidate(
    new: Polynomial, others: list[Polynomial], sides: list[int], joins: bool, gamma_max: float
) -> None:
    """The merge tests of all candidates in one compiled call choose what the readable loop
    over them chose (partner, γ bit for bit, join or overlap): nearby copies of the new piece
    mixed with unrelated ones, faces on either side, with and without joins."""
    rng = np.random.default_rng(len(others))
    near = [  # shifted copies and neighbours of the new piece, so that merges do happen
        Polynomial(new.variate, new.coeffs + rng.normal(0.0, 0.02, new.coeffs.size),
                   new.lo + d, new.hi + d)
        for d in rng.uniform(-0.5, 2.0, 3)
    ]  # fmt: skip
    polys = others + near
    c0s = [float(p.c0) + float(rng.normal(0.0, 0.01)) for p in polys]
    side_of = [sides[j % len(sides)] for j in range(len(polys))]
    join_gap = 0.25 if joins else None
    got = choose_merge(
        new, new.c0, polys, c0s, gamma_max, 0.1, new_side=sides[0], sides=side_of,
        join_gap=join_gap,
    )  # fmt: skip
    want = reference_merging.choose_merge(
        new, new.c0, polys, c0s, gamma_max, 0.1, sides[0], side_of, join_gap
    )
    assert (got is None) == (want is None)
    if got is not None and want is not None:
        assert (got.partner, got.gamma.hex(), got.joined) == (want[0], want[1].hex(), want[2])


@settings(max_examples=200, deadline=None)
@given(
    new=merge_polys,
    walls=st.lists(merge_polys, min_size=0, max_size=7),
    joins=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_merge_gammas__a_tables_rows_as_merge_test_gives_them_one_by_one(
    new: Polynomial, walls: list[Polynomial], joins: bool, seed: int
) -> None:
    """The compiled merge tests over rows of a map's columns (``map_kernels.merge_candidates``
    reading ``table_candidates``) give, row by row, what ``merge_test`` gives for the row's
    polynomial as the map builds it (``table.polys[j].with_c0``, at its own number of
    coefficients, trailing zeros too), the tangents' angle taken by numpy, and else the
    numpy join: the same γ bit for bit, nan where none counts."""
    rng = np.random.default_rng(seed)
    near = [  # shifted copies and neighbours of the new piece, so that merges do happen
        Polynomial(new.variate, new.coeffs + rng.normal(0.0, 0.02, new.coeffs.size),
                   new.lo + d, new.hi + d)
        for d in rng.uniform(-0.5, 2.0, 3)
    ]  # fmt: skip
    table = LandmarkTable(capacity=2)
    for wall in walls + near:
        table.append(wall, pivot=0.0, xi_var=0.0, model_var=0.0, fit_half=1.0)
    c0s = np.array([p.c0 for p in walls + near]) + rng.normal(0.0, 0.01, len(table))
    rows = np.flatnonzero(rng.random(len(table)) < 0.8)  # ascending, as boxes_near gives them
    join_gap = 0.25 if joins else None
    got, joined = merge_gammas(new, table_candidates(table, rows, c0s), 0.1, join_gap=join_gap)
    found = np.empty(4)
    for k, j in enumerate(rows.tolist()):
        other = table.polys[j].with_c0(float(c0s[j]))
        want: float | None = None
        measured = map_kernels.merge_test(
            new.variate, new.coeffs, new.lo, new.hi, other.variate, other.coeffs, other.lo,
            other.hi, 0.1, found,
        )  # fmt: skip
        if measured == map_kernels.MEASURED:
            a, b, gamma, xi_other = found.tolist()
            t_p, t_o = unit_tangent(new, 0.5 * (a + b)), unit_tangent(other, xi_other)
            angle = float(np.arccos(min(abs(float(t_p @ t_o)), 1.0)))
            want = gamma if np.degrees(angle) <= MERGE_ANGLE_DEG else None
        join = want is None and join_gap is not None
        if join:
            want = reference_join_gamma(new, other, join_gap)
        assert bool(joined[k]) == join
        assert got[k].hex() == (math.nan if want is None else want).hex()


@settings(max_examples=100, deadline=None)
@given(
    new=merge_polys,
    walls=st.lists(merge_polys, min_size=0, max_size=9),
    joins=st.booleans(),
    distance=st.sampled_from([0.0, 0.35, 1.0, math.inf]),
    seed=st.integers(0, 2**16),
)
def test_near_merge_gammas__is_boxes_near_then_merge_gammas(
    new: Polynomial, walls: list[Polynomial], joins: bool, distance: float, seed: int
) -> None:
    """``near_merge_gammas`` (one compiled call) gives the rows ``boxes_near`` gives, without
    the excluded one, and ``merge_gammas``' answers over them, bit for bit."""
    rng = np.random.default_rng(seed)
    table = LandmarkTable(capacity=2)
    for wall in [*walls, new]:
        table.append(wall, pivot=0.0, xi_var=0.0, model_var=0.0, fit_half=1.0)
    c0s = np.array([p.c0 for p in [*walls, new]]) + rng.normal(0.0, 0.01, len(table))
    boxes = table.boxes(c0s)
    join_gap = 0.25 if joins else None
    for exclude in (-1, len(table) - 1):
        box = boxes[len(table) - 1]
        rows, got, joined = near_merge_gammas(
            new, table, c0s, boxes, box, distance, 0.1, exclude=exclude, join_gap=join_gap
        )
        want_rows = boxes_near(boxes, box, distance)
        want_rows = want_rows[want_rows != exclude]
        want, want_joined = merge_gammas(
            new, table_candidates(table, want_rows, c0s), 0.1, join_gap=join_gap
        )
        assert rows.tolist() == want_rows.tolist()
        assert got.tobytes() == want.tobytes() and joined.tolist() == want_joined.tolist()

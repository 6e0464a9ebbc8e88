"""Tests of the weighted LMS fits and their Jacobians G_x, G_y (polyslam_env.slam.fitting)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.slam.fit_kernels import principal_variate
from polyslam_env.slam.fitting import (
    PointSet,
    beam_points,
    centroid_xi,
    concat,
    fit_polynomial,
    polynomial_points,
    store_beams,
    stored_points,
)
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.stored import PointArrays
from tests.slam.finite_differences import FD_ATOL, FD_RTOL, fd_jacobian

POSE_COV = np.diag([0.01**2, 0.01**2, 0.005**2])
SIGMA_R = 0.02


def wall_ranges(pose: np.ndarray, angles: np.ndarray, wall: Polynomial) -> np.ndarray:
    """Ranges from ``pose`` along each beam to a line-like wall (first root, bisection-free)."""
    out = np.empty(len(angles))
    for b, beta in enumerate(angles):
        phi = pose[2] + beta
        ts = np.linspace(0.01, 4.0, 4000)
        pts = pose[:2] + ts[:, None] * np.array([np.cos(phi), np.sin(phi)])
        xi, eta = wall.from_xy(pts)
        gap = eta - wall.value(xi)
        k = int(np.flatnonzero(np.sign(gap[1:]) != np.sign(gap[:-1]))[0])
        out[b] = ts[k] - gap[k] * (ts[k + 1] - ts[k]) / (gap[k + 1] - gap[k])
    return out


def wall_for(variate: int) -> tuple[Polynomial, np.ndarray]:
    """A gently curved wall ahead of the robot, and beam angles that hit it."""
    wall = Polynomial(variate, np.array([1.2, 0.15, -0.05, 0.02]), -3.0, 3.0)
    # variate 1: the wall is above (+x²); variate 2: it is ahead (+x¹)
    centre = np.pi / 2 if variate == 1 else 0.0
    return wall, centre + np.deg2rad(np.linspace(-50, 50, 7))


# -- point constructors ------------------------------------------------------------------
def test_beam_points__derivatives_match_finite_differences() -> None:
    rng = np.random.default_rng(1)
    pose = np.array([0.2, -0.1, 0.3])
    ranges = rng.uniform(0.3, 1.8, 5)
    angles = np.deg2rad([90, 45, 0, -45, -90])
    ps = beam_points(pose, POSE_COV, ranges, angles, SIGMA_R, n_state=5)
    for coord in range(2):
        d_pose = fd_jacobian(
            lambda p, c=coord: float(
                beam_points(p, POSE_COV, ranges, angles, SIGMA_R, 5).xy[:, c].sum()
            ),
            pose,
        )
        d_rng = fd_jacobian(
            lambda r, c=coord: float(
                beam_points(pose, POSE_COV, r, angles, SIGMA_R, 5).xy[:, c].sum()
            ),
            ranges,
        )
        np.testing.assert_allclose(d_pose, ps.d_state[:, coord, :3].sum(0), rtol=FD_RTOL)
        np.testing.assert_allclose(d_rng, ps.d_noise[:, coord, :].sum(0), rtol=FD_RTOL)
    assert np.all(ps.d_state[:, :, 3:] == 0)
    np.testing.assert_allclose(ps.noise_cov, SIGMA_R**2 * np.eye(5))
    # weight is 1/‖P‖₂ = 1/0.01² for this diagonal covariance
    np.testing.assert_allclose(ps.weights, 1e4)


def test_beam_points__nonfinite_range_is_rejected() -> None:
    with pytest.raises(ValueError, match="finite"):
        beam_points(np.zeros(3), POSE_COV, np.array([1.0, np.inf]), np.zeros(2), SIGMA_R, 3)


def test_beam_points__anchor_at_same_pose_equals_exact_model() -> None:
    pose = np.array([0.5, 0.4, -0.7])
    ranges = np.array([0.8, 1.1, 1.5])
    angles = np.deg2rad([60.0, 0.0, -60.0])
    exact = beam_points(pose, POSE_COV, ranges, angles, SIGMA_R, 4)
    anchored = beam_points(pose, POSE_COV, ranges, angles, SIGMA_R, 4, anchor_pose=pose)
    for name in ("xy", "d_state", "d_noise", "noise_cov", "weights"):
        # same formulas evaluated two ways: only round-off differs
        np.testing.assert_allclose(getattr(anchored, name), getattr(exact, name), atol=1e-12)


def test_polynomial_points__move_with_their_c0_only() -> None:
    for variate in (1, 2):
        poly = Polynomial(variate, np.array([0.5, 0.2, 0.1, -0.03]), -1.0, 2.0)
        ps = polynomial_points(poly, c0_index=4, c0_var=1e-4, n=5, lo=-1.0, hi=2.0, n_state=6)
        shifted = polynomial_points(poly.with_c0(0.6), 4, 1e-4, 5, -1.0, 2.0, 6)
        np.testing.assert_allclose(shifted.xy - ps.xy, 0.1 * ps.d_state[:, :, 4], atol=1e-12)
        assert np.count_nonzero(ps.d_state) == 5  # one non-zero per point, on c0
        np.testing.assert_allclose(ps.weights, 1e4)


def test_concat__noise_blocks_are_independent() -> None:
    a = beam_points(np.zeros(3), POSE_COV, np.array([1.0, 2.0]), np.array([0.0, 1.0]), 0.1, 4)
    b = beam_points(np.ones(3), POSE_COV, np.array([1.5]), np.array([0.5]), 0.2, 4)
    ab = concat(a, b)
    assert ab.d_noise.shape == (3, 2, 3)
    np.testing.assert_array_equal(ab.noise_cov, np.diag([0.1**2, 0.1**2, 0.2**2]))
    np.testing.assert_array_equal(ab.d_noise[:2, :, 2], 0.0)
    np.testing.assert_array_equal(ab.d_noise[2, :, :2], 0.0)


# -- G_x, G_y by finite differences ------------------------------------------------------------
@pytest.mark.parametrize("variate", [1, 2])
def test_fit_polynomial__jacobians_from_beam_points_match_finite_differences(variate: int) -> None:
    wall, angles = wall_for(variate)
    n_state = 5  # pose + two unrelated landmarks
    pose = np.array([0.1, -0.2, 0.05])
    ranges = wall_ranges(pose, angles, wall)
    ps = beam_points(pose, POSE_COV, ranges, angles, SIGMA_R, n_state)
    fit = fit_polynomial(ps, 3)
    assert fit.poly.variate == variate

    def c0_of_state(x: np.ndarray) -> float:
        return fit_polynomial(
            beam_points(x[:3], POSE_COV, ranges, angles, SIGMA_R, n_state), 3, variate
        ).c0

    def c0_of_noise(e: np.ndarray) -> float:
        return fit_polynomial(
            beam_points(pose, POSE_COV, ranges + e, angles, SIGMA_R, n_state), 3, variate
        ).c0

    x0 = np.concatenate([pose, [0.3, -0.4]])
    np.testing.assert_allclose(fit.Gx[0], fd_jacobian(c0_of_state, x0), rtol=FD_RTOL, atol=FD_ATOL)
    np.testing.assert_allclose(
        fit.Gy[0], fd_jacobian(c0_of_noise, np.zeros(len(ranges))), rtol=FD_RTOL, atol=FD_ATOL
    )
    # the noiseless wall is recovered (ray-march interpolation error ~1e-7 m)
    assert abs(fit.c0 - wall.c0) < 1e-5


@pytest.mark.parametrize("variate", [1, 2])
def test_fit_polynomial__jacobians_from_stored_cluster_points_match_finite_differences(
    variate: int,
) -> None:
    wall, angles = wall_for(variate)
    n_state = 4
    rng = np.random.default_rng(7)
    steps: list[PointArrays] = []
    pose = np.array([0.0, 0.0, 0.0])
    for step in range(3):  # points seen from three successive poses
        pose = (
            pose + np.array([0.1, 0.05, 0.02])
            if variate == 1
            else pose + np.array([0.05, 0.1, 0.02])
        )
        ranges = wall_ranges(pose, angles, wall) + rng.normal(0, SIGMA_R, len(angles))
        steps.append(store_beams(pose, POSE_COV * (1 + step), ranges, angles, SIGMA_R, step))
    stored = PointArrays(*(np.concatenate(column) for column in zip(*steps, strict=True)))
    anchor = pose + np.array([0.02, -0.01, 0.01])  # the current estimate
    fit = fit_polynomial(stored_points(stored, anchor, n_state), 3)
    assert fit.poly.variate == variate

    def c0_of_state(x: np.ndarray) -> float:
        return fit_polynomial(stored_points(stored, anchor, n_state, pose=x[:3]), 3, variate).c0

    def c0_of_noise(e: np.ndarray) -> float:
        return fit_polynomial(stored_points(stored, anchor, n_state, noise=e), 3, variate).c0

    x0 = np.concatenate([anchor, [0.7]])
    np.testing.assert_allclose(fit.Gx[0], fd_jacobian(c0_of_state, x0), rtol=FD_RTOL, atol=FD_ATOL)
    np.testing.assert_allclose(
        fit.Gy[0], fd_jacobian(c0_of_noise, np.zeros(len(stored))), rtol=FD_RTOL, atol=FD_ATOL
    )
    np.testing.assert_allclose(np.diag(fit.V), SIGMA_R**2)


def turned_points(
    poly: Polynomial, c0: float, turn: float, pivot: float, n: int
) -> np.ndarray:  # (n, 2)
    """``polynomial_points``' positions for the state values (c0, turn): the shape with that
    c0, turned by ``turn`` about its point at ``pivot``."""
    moved = poly.with_c0(c0)
    xy = moved.equally_spaced(n, poly.lo, poly.hi)
    centre = moved.points_at(np.array([pivot]))[0]
    c, s = math.cos(turn), math.sin(turn)
    return centre + (xy - centre) @ np.array([[c, -s], [s, c]]).T


def test_polynomial_points__turn_column_is_the_rotation_about_the_pivot() -> None:
    for variate in (1, 2):
        poly = Polynomial(variate, np.array([0.5, 0.2, 0.1, -0.03]), -1.0, 2.0)
        ps = polynomial_points(poly, 4, 1e-4, 5, -1.0, 2.0, 7, turn=(6, 0.3))
        for j in range(5):
            for c in range(2):
                fd = fd_jacobian(
                    lambda a, p=poly, j=j, c=c: float(turned_points(p, 0.5, a[0], 0.3, 5)[j, c]),
                    np.zeros(1),
                )
                assert ps.d_state[j, c, 6] == pytest.approx(fd[0], rel=FD_RTOL, abs=FD_ATOL)
        with pytest.raises(ValueError, match="turn index"):
            polynomial_points(poly, 4, 1e-4, 5, -1.0, 2.0, 7, turn=(4, 0.3))


@pytest.mark.parametrize("variate", [1, 2])
def test_centroid_xi__is_the_point_a_fitted_wall_turns_about(variate: int) -> None:
    # a weighted LS line passes through the points' weighted centroid, so points turned about
    # it give a line turned about it: the fitted wall's offset there does not move, and that
    # is where a shape-fixed c0 measures it. About any other point (the middle of the extent,
    # with the weights bunched at one end) the offset at the centroid moves with the turn
    poly = Polynomial(variate, np.array([0.4, 0.3]), -1.0, 3.0)
    weights = np.r_[np.full(6, 100.0), np.full(4, 1.0)]  # a certain piece and a vague one
    xy = poly.equally_spaced(10, poly.lo, poly.hi)
    pivot = centroid_xi(plain(xy, weights), variate)
    assert pivot < 0.5 * (poly.lo + poly.hi) - 0.5

    def offset_after_turn(about: float) -> Callable[[np.ndarray], float]:
        def offset(a: np.ndarray) -> float:
            turned = turned_points(poly, poly.c0, float(a[0]), about, 10)
            return float(fit_polynomial(plain(turned, weights), 1, variate).poly.value(pivot))

        return offset

    assert fd_jacobian(offset_after_turn(pivot), np.zeros(1))[0] == pytest.approx(0, abs=FD_ATOL)
    mid = 0.5 * (poly.lo + poly.hi)
    assert abs(fd_jacobian(offset_after_turn(mid), np.zeros(1))[0]) > 0.5


def test_fit_polynomial__translating_the_pose_shifts_c0_like_the_wall() -> None:
    # for variate 1 a pure x² translation of every point moves c0 by the same amount
    wall, angles = wall_for(1)
    pose = np.zeros(3)
    ps = beam_points(pose, POSE_COV, wall_ranges(pose, angles, wall), angles, SIGMA_R, 3)
    assert fit_polynomial(ps).Gx[0, 1] == pytest.approx(1.0, abs=1e-9)  # exact up to round-off


# -- fit quality and degenerate inputs ---------------------------------------------------------
def plain(xy: np.ndarray, weights: np.ndarray | None = None) -> PointSet:
    n = len(xy)
    return PointSet(
        xy=xy,
        d_state=np.zeros((n, 2, 3)),
        d_noise=np.zeros((n, 2, 0)),
        noise_cov=np.zeros((0, 0)),
        weights=np.ones(n) if weights is None else weights,
    )


@pytest.mark.parametrize("variate", [1, 2])
def test_fit_polynomial__recovers_noiseless_cubic_exactly(variate: int) -> None:
    truth = Polynomial(variate, np.array([2.5, -0.4, 0.3, -0.07]), 1.0, 4.0)
    fit = fit_polynomial(plain(truth.equally_spaced(12)), 3)
    assert fit.poly.variate == variate
    np.testing.assert_allclose(fit.poly.coeffs, truth.coeffs, atol=1e-9)
    assert (fit.poly.lo, fit.poly.hi) == pytest.approx((1.0, 4.0), abs=1e-12)
    assert fit.rms < 1e-9


def test_fit_polynomial__noisy_points_stay_within_noise() -> None:
    rng = np.random.default_rng(3)
    sigma = 0.01
    truth = Polynomial(1, np.array([1.0, 0.2, -0.1, 0.02]), -2.0, 2.0)
    xy = truth.equally_spaced(200) + np.column_stack([np.zeros(200), rng.normal(0, sigma, 200)])
    fit = fit_polynomial(plain(xy), 3, variate=1)
    xi = np.linspace(-2.0, 2.0, 50)
    # the fitted curve's std error is ~σ·√(4/200) ≈ 1.4 mm; σ itself is > 7 standard errors
    assert np.max(np.abs(fit.poly.value(xi) - truth.value(xi))) < sigma
    assert fit.rms == pytest.approx(sigma, rel=0.2)  # sample std of 200 normals: ±10 % at 2σ


def test_fit_polynomial__weights_match_numpy_weighted_polyfit() -> None:
    rng = np.random.default_rng(5)
    xy = np.column_stack([np.linspace(0, 3, 15), rng.normal(1.0, 0.3, 15)])
    w = rng.uniform(0.1, 100.0, 15)
    fit = fit_polynomial(plain(xy, w), 3, variate=1)
    ref = np.polynomial.polynomial.polyfit(xy[:, 0], xy[:, 1], 3, w=np.sqrt(w))
    np.testing.assert_allclose(fit.poly.coeffs, ref, atol=1e-9)  # two solvers, ~1e-12 apart


def test_fit_polynomial__two_points_give_a_line_through_them() -> None:
    ps = concat(
        beam_points(
            np.zeros(3), POSE_COV, np.array([1.0, 1.2]), np.deg2rad([80.0, 60.0]), SIGMA_R, 3
        )
    )
    fit = fit_polynomial(ps, 3)
    assert fit.order == 1 and len(fit.poly.coeffs) == 4
    assert np.all(np.isfinite(fit.Gx)) and np.all(np.isfinite(fit.Gy))
    xi, eta = fit.poly.from_xy(ps.xy)
    np.testing.assert_allclose(fit.poly.value(xi), eta, atol=1e-12)  # interpolation


def test_fit_polynomial__same_xi_points_give_finite_constant() -> None:
    xy = np.array([[1.0, 0.2], [1.0, 0.4], [1.0, 0.9]])
    fit = fit_polynomial(plain(xy, np.array([1.0, 1.0, 2.0])), 3, variate=1)
    assert fit.order == 0
    assert fit.c0 == pytest.approx((0.2 + 0.4 + 1.8) / 4)  # weighted mean of η
    np.testing.assert_array_equal(fit.poly.coeffs[1:], 0.0)
    assert np.all(np.isfinite(fit.Gx)) and np.isfinite(fit.rms)
    # with the variate left free, the points are vertical, so x¹ = const is chosen
    free = fit_polynomial(plain(xy), 3)
    assert free.poly.variate == 2 and free.c0 == pytest.approx(1.0)


def test_fit_polynomial__single_point() -> None:
    fit = fit_polynomial(plain(np.array([[0.3, 0.7]])), 3)
    assert fit.order == 0 and np.isfinite(fit.c0) and fit.poly.lo == fit.poly.hi


@settings(max_examples=60, deadline=None)
@given(angle=st.floats(0.0, 2 * np.pi), length=st.floats(0.2, 3.0))
def test_principal_variate__follows_the_principal_direction(angle: float, length: float) -> None:
    d = np.array([np.cos(angle), np.sin(angle)])
    wiggle = 0.001  # m, lateral
    # the wiggle tilts the points' principal direction by up to ~2·wiggle/length rad, and
    # ||d₀| − |d₁|| ≈ √2 × the angle to the diagonal: within twice that, either answer is right
    if abs(abs(d[0]) - abs(d[1])) < 2.0 * math.sqrt(2.0) * 2.0 * wiggle / length:
        return
    pts = np.array([1.0, -2.0]) + np.linspace(0, length, 9)[:, None] * d
    pts += wiggle * np.array([-d[1], d[0]]) * np.sin(np.arange(9))[:, None]
    assert principal_variate(pts, np.ones(9)) == (1 if abs(d[0]) > abs(d[1]) else 2)


@pytest.mark.parametrize("variate", [1, 2])
def test_fit_polynomial__shape_fixed_jacobians_match_offset_finite_differences(
    variate: int,
) -> None:
    wall, angles = wall_for(variate)
    rng = np.random.default_rng(9)
    pose = np.array([0.1, 0.1, 0.1])
    ranges = wall_ranges(pose, angles, wall) + rng.normal(0, SIGMA_R, len(angles))
    stored = store_beams(pose, POSE_COV, ranges, angles, SIGMA_R)
    full = fit_polynomial(stored_points(stored, pose, 4), 3)
    fit = fit_polynomial(stored_points(stored, pose, 4), 3, shape_fixed=True)
    assert fit.c0 == pytest.approx(full.c0, abs=1e-12)  # same value, different derivative
    shape = fit.poly.with_c0(0.0)

    def offset(ps: PointSet) -> float:
        """c0 with the shape held: weighted mean of η − B(ξ)."""
        xi, eta = shape.from_xy(ps.xy)
        return float(np.average(eta - shape.value(xi), weights=ps.weights))

    def of_state(x: np.ndarray) -> float:
        return offset(stored_points(stored, pose, 4, pose=x[:3]))

    def of_noise(e: np.ndarray) -> float:
        return offset(stored_points(stored, pose, 4, noise=e))

    x0 = np.concatenate([pose, [0.5]])
    np.testing.assert_allclose(fit.Gx[0], fd_jacobian(of_state, x0), rtol=FD_RTOL, atol=FD_ATOL)
    np.testing.assert_allclose(
        fit.Gy[0], fd_jacobian(of_noise, np.zeros(len(stored))), rtol=FD_RTOL, atol=FD_ATOL
    )

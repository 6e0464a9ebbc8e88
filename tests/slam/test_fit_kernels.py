"""The compiled fit (:mod:`polyslam_env.slam.fit_kernels` through
:func:`~polyslam_env.slam.fitting.fit_polynomial` and ``turn_gradient``) and the cluster's wall
mask against the readable numpy versions they replaced (``tests/slam/reference_fitting.py``).

Both solve the same least-squares problem with backward-stable Householder QR, but numba's QR
goes through scipy's LAPACK and the triangular solves and contractions are loops, so the last
bits differ. The bound: a backward-stable least-squares solution moves by ≲ c·ε·κ² relative
(κ = cond(√W A), the κ² from the residual term; Higham, *Accuracy and Stability*, §20.1), and
the gradients carry one more solve with M = RᵀR (κ² again). With c = 1e3 (the design's size and
the products around the solve) the tolerance is 1e3·ε·κ⁴ relative to each quantity's own scale,
κ computed per case. Orders and variates must be equal (a case at the order test's or the
variate's threshold could go either way; none of these seeded cases is).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from polyslam_env.slam import fit_kernels
from polyslam_env.slam.fit_kernels import wall_mask
from polyslam_env.slam.fitting import (
    PointSet,
    concat,
    fit_polynomial,
    polynomial_points,
    stored_points,
    turn_gradient,
)
from polyslam_env.slam.map_kernels import GAP_SPLIT
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.stored import PointArrays
from tests.slam import reference_fitting as reference
from tests.slam.reference_merging import merge_points

EPS = np.finfo(float).eps


def _case(rng: np.random.Generator) -> PointSet:
    """A noisy curved wall of 4–30 points, anywhere, any direction, random weights and
    random derivatives (the fit only contracts them)."""
    n = int(rng.integers(4, 31))
    t = rng.uniform(-1.0, 1.0, n) * rng.uniform(0.2, 3.0)
    angle, centre = rng.uniform(0.0, np.pi), rng.normal(scale=5.0, size=2)
    bend = rng.uniform(-0.2, 0.2) * t**2
    xy = centre + np.column_stack(
        [np.cos(angle) * t - np.sin(angle) * bend, np.sin(angle) * t + np.cos(angle) * bend]
    )
    xy += rng.normal(scale=0.01, size=(n, 2))
    return PointSet(
        xy, rng.normal(size=(n, 2, 7)), rng.normal(size=(n, 2, n)), np.eye(n) * 4e-4,
        rng.uniform(0.5, 2.0, n),
    )  # fmt: skip


def _tolerance(points: PointSet, variate: int, order: int) -> float:
    """1e3·ε·κ⁴ of the fit's weighted design (module docstring)."""
    xi = points.xy[:, 0] if variate == 1 else points.xy[:, 1]
    scale = max(np.abs(xi).max(), 1e-9)
    w = points.weights / points.weights.max()
    design = np.sqrt(w)[:, None] * np.vander(xi / scale, order + 1, increasing=True)
    return float(1e3 * EPS * np.linalg.cond(design) ** 4)


def _close(got: np.ndarray, want: np.ndarray, tol: float) -> bool:
    return bool(np.abs(got - want).max() <= tol * max(np.abs(want).max(), 1.0))


@pytest.mark.parametrize("shape_fixed", [True, False])
@pytest.mark.parametrize("auto_order, curvature", [(True, False), (False, False), (True, True)])
def test_fit_polynomial__matches_the_numpy_fit_within_its_conditioning(
    shape_fixed: bool, auto_order: bool, curvature: bool
) -> None:
    rng = np.random.default_rng(11)
    for _ in range(150):
        points = _case(rng)
        got = fit_polynomial(points, 3, None, shape_fixed, auto_order, 4e-4, curvature)
        want = reference.fit_polynomial(points, 3, None, shape_fixed, auto_order, 4e-4, curvature)
        assert (got.poly.variate, got.order) == (want.poly.variate, want.order)
        tol = _tolerance(points, want.poly.variate, want.order)
        assert _close(got.poly.coeffs, want.poly.coeffs, tol)
        assert (got.poly.lo, got.poly.hi) == (want.poly.lo, want.poly.hi)  # min / max of ξ
        assert _close(got.Gx, want.Gx, tol) and _close(got.Gy, want.Gy, tol)
        eta_scale = np.abs(points.xy).max()
        assert abs(got.rms - want.rms) <= tol * eta_scale
        # the R factor: RᵀR is the normal matrix of the scaled, weight-normalised design
        xi = points.xy[:, 0] if want.poly.variate == 1 else points.xy[:, 1]
        w = points.weights / points.weights.max()
        a_mat = np.vander(xi / got.scale, got.order + 1, increasing=True)
        assert got.r_factor is not None
        np.testing.assert_allclose(
            got.r_factor.T @ got.r_factor, a_mat.T @ (w[:, None] * a_mat), rtol=tol, atol=tol
        )


def test_fit_polynomial__orders_it_lowers_as_the_numpy_fit() -> None:
    """Too few distinct abscissae and a single point: the same lowered orders and values."""
    xy = np.array([[1.0, 0.2], [1.0, 0.4], [1.0, 0.9], [2.0, 0.5]])
    for n in (1, 3, 4):
        points = PointSet(
            xy[:n], np.zeros((n, 2, 3)), np.zeros((n, 2, 0)), np.zeros((0, 0)), np.ones(n)
        )
        for variate in (None, 1):
            got = fit_polynomial(points, 3, variate)
            want = reference.fit_polynomial(points, 3, variate)
            assert (got.poly.variate, got.order) == (want.poly.variate, want.order)
            np.testing.assert_allclose(got.poly.coeffs, want.poly.coeffs, rtol=0, atol=1e-12)


def _arc_rate(c2: float, n_fits: int, curvature_test: bool) -> float:
    """How often 16 hits 0.8 m along a wall η = c2·ξ² with 2 cm noise (a new landmark's
    cluster) are fitted at order ≥ 2, over ``n_fits`` seeded draws."""
    sigma, xi = 0.02, np.linspace(-0.4, 0.4, 16)
    rng = np.random.default_rng(3)
    curved = 0
    for _ in range(n_fits):
        eta = c2 * xi**2 + rng.normal(0.0, sigma, xi.size)
        points = PointSet(np.column_stack([xi, eta]), np.zeros((16, 2, 3)),
                          np.zeros((16, 2, 16)), np.eye(16) * sigma**2, np.ones(16))  # fmt: skip
        fit = fit_polynomial(points, 3, None, True, True, sigma**2, curvature_test)
        curved += fit.order >= 2
    return curved / n_fits


def test_curvature_test__finds_short_arcs_at_its_theoretical_power() -> None:
    """``slam.curvature_test``: with the noise known, the residual drop from a line to a
    parabola over σ² is the order-2 coefficient's z², noncentral χ²(1, λ) with
    λ = c2²·Σ q_i²/σ² (q = ξ² off the line's columns), while the χ² test over N − 2 dof sees
    the same λ spread over 14 dof. On a straight wall (λ = 0) order ≥ 2 comes at the two tests'
    levels, between 1 % and 2 %; on a 0.8 m piece of a wall of radius 2.6 m (sagitta 3 cm, the
    floor family's inner corridor wall) the χ² test alone finds it with its power (6.7 %),
    the curvature test at least with its own (30.5 %). Each rate within the binomial 99.9 %
    interval of its theoretical probability, over 600 draws."""
    n, level = 600, 0.01
    xi = np.linspace(-0.4, 0.4, 16)
    q = xi**2 - np.mean(xi**2)
    c2 = 1.0 / (2.0 * 2.6)
    lam = c2**2 * float(q @ q) / 0.02**2
    p_all = scipy.stats.ncx2.sf(scipy.stats.chi2.ppf(1 - level, 14), 14, lam)
    p_one = scipy.stats.ncx2.sf(scipy.stats.chi2.ppf(1 - level, 1), 1, lam)

    def within(rate: float, lo_p: float, hi_p: float) -> bool:
        lo = scipy.stats.binom.interval(0.999, n, lo_p)[0] / n
        hi = scipy.stats.binom.interval(0.999, n, hi_p)[1] / n
        return lo <= rate <= hi

    straight = _arc_rate(0.0, n, True)
    assert within(straight, level, 2 * level), straight
    assert within(_arc_rate(c2, n, False), p_all, p_all), (p_all, lam)
    assert within(_arc_rate(c2, n, True), p_one, p_one + p_all), (p_one, lam)


def test_turn_gradient__matches_the_numpy_gradient_within_its_conditioning() -> None:
    rng = np.random.default_rng(12)
    for _ in range(60):
        points = _case(rng)
        fit = reference.fit_polynomial(points, 3, None, True, True, 4e-4)
        pivot = float(np.mean(points.xy[:, 0 if fit.poly.variate == 1 else 1]))
        got, got_var = turn_gradient(points, fit, pivot)
        want, want_var = reference.turn_gradient(points, fit, pivot)
        tol = _tolerance(points, fit.poly.variate, fit.order)
        assert _close(got, want, tol)
        assert abs(got_var - want_var) <= tol * max(want_var, 1e-12)


def test_turn_gradient__the_numpy_form_on_the_same_qr_bit_for_bit() -> None:
    """The compiled turn gradient computes the numpy form's floats (its residual through the
    same BLAS gemv, its sums in numpy's orders): on the compiled QR and coefficient gradient
    the two agree exactly, on curved walls of 1–30 points of both variates and orders 0–3,
    sparse derivatives with exact zeros as a merge's are, and merges of two sampled lines."""
    rng = np.random.default_rng(41)
    cases = 0
    for k in range(160):
        points = _case(rng) if k % 4 else _sparse_case(rng)
        for order in (1, 2, 3):
            fit = fit_polynomial(points, order, None, True, bool(k % 2), 4e-4)
            xi = points.xy[:, 0 if fit.poly.variate == 1 else 1]
            pivot = float(rng.uniform(xi.min(), xi.max()))
            got, got_var = turn_gradient(points, fit, pivot)
            want, want_var = reference.turn_gradient_with(
                points, fit, pivot, fit_kernels.weighted_qr, fit_kernels.coefficient_gradient
            )
            assert got.tobytes() == want.tobytes() and got_var == want_var
            cases += fit.poly.variate == 2
    assert cases > 40  # both variates were exercised


def _sparse_case(rng: np.random.Generator) -> PointSet:
    """1–12 points on a line with derivatives on a few state entries only (as a merge's
    points sampled on landmarks: exact zeros elsewhere)."""
    n = int(rng.integers(1, 13))
    t = np.linspace(-1.0, 1.0, n) * rng.uniform(0.2, 3.0)
    angle = rng.uniform(0.0, np.pi)
    xy = rng.normal(scale=5.0, size=2) + np.column_stack([np.cos(angle) * t, np.sin(angle) * t])
    d_state = np.zeros((n, 2, 9))
    d_state[:, rng.integers(2), rng.integers(3, 9)] = 1.0
    d_state[:, :, rng.integers(3, 9)] = rng.normal(size=(n, 2))
    weights = np.full(n, rng.uniform(10.0, 1e4))
    return PointSet(xy, d_state, np.zeros((n, 2, 0)), np.zeros((0, 0)), weights)


def test_polynomial_points__the_numpy_points_bit_for_bit() -> None:
    """Points sampled on a landmark (one compiled call) are the numpy form's, signed zeros
    included: 1–8 points, both variates, with and without a turn, pivots on a sample (an
    exact zero in π − π_c) and off; a merge's set is its two polynomials' stacked."""
    rng = np.random.default_rng(43)
    for k in range(120):
        n, n_state = int(rng.integers(1, 9)), 9
        lo = float(rng.uniform(-3.0, 3.0))
        hi = lo + float(rng.uniform(0.0, 2.0)) * (k % 7 != 0)  # a point-like extent too
        poly = Polynomial(int(rng.integers(1, 3)), rng.normal(size=4) * [1, 0.5, 0.1, 0.02], lo, hi)
        xis = np.linspace(lo, hi, n)
        pivot = float(xis[n // 2] if k % 2 else rng.uniform(lo, hi + 1e-9))
        turn = None if k % 3 == 0 else (int(rng.integers(5, 9)), pivot)
        c0_var = float(rng.uniform(1e-5, 1e-2))
        got = polynomial_points(poly, 4, c0_var, n, lo, hi, n_state, turn)
        want = reference.polynomial_points(poly, 4, c0_var, n, lo, hi, n_state, turn)
        for name in ("xy", "d_state", "d_noise", "noise_cov", "weights"):
            assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name
        other = Polynomial(1, np.array([0.3, 0.1, 0.0, 0.0]), -1.0, 1.0)
        merged = merge_points(poly, 4, c0_var, other, 3, 2e-3, n, n_state, turn, None)
        stacked = concat(want, reference.polynomial_points(other, 3, 2e-3, n, -1.0, 1.0, n_state))
        for name in ("xy", "d_state", "d_noise", "noise_cov", "weights"):
            assert getattr(merged, name).tobytes() == getattr(stacked, name).tobytes(), name


def test_stored_points__the_numpy_points_bit_for_bit() -> None:
    """Stored points attached to the current pose (one compiled call) are the numpy form's
    floats at the anchor, 1–20 points anywhere; evaluated at another pose (the model's
    finite-difference checks) they agree to rounding (R's cos/sin: 1e-12 m on metres)."""
    rng = np.random.default_rng(44)
    for _ in range(200):
        n = int(rng.integers(1, 21))
        angles = rng.uniform(-np.pi, np.pi, n)
        points = PointArrays(
            rng.normal(scale=4.0, size=(n, 2)), np.column_stack([np.cos(angles), np.sin(angles)]),
            rng.uniform(0.005, 0.05, n), rng.uniform(1.0, 1e3, n), np.zeros((n, 3)),
            np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
        )  # fmt: skip
        anchor = rng.normal(size=3)
        got = stored_points(points, anchor, 7)
        want = reference.stored_points(points, anchor, 7)
        for name in ("xy", "d_state", "d_noise", "noise_cov", "weights"):
            assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name
        pose = anchor + rng.normal(scale=0.05, size=3)
        moved = stored_points(points, anchor, 7, pose=pose)
        np.testing.assert_allclose(
            moved.xy, reference.stored_points(points, anchor, 7, pose=pose).xy, rtol=0, atol=1e-12
        )


def _cluster(rng: np.random.Generator) -> np.ndarray:
    """8–20 noisy points of a straight wall, a corner (either arm longer), a bent wall or a
    wall with a doorway gap, anywhere, any direction, shuffled as clusters come."""
    n = int(rng.integers(8, 21))
    kind = rng.integers(4)
    t = np.sort(rng.uniform(0.0, 0.4, n))
    local = np.column_stack([t, np.zeros(n)])
    if kind == 1:  # a corner: the last points turn by 60–120°
        k = int(rng.integers(3, n - 3))
        turn = rng.uniform(np.pi / 3, 2 * np.pi / 3)
        s = t[k:] - t[k]
        local[k:] = local[k] + np.column_stack([np.cos(turn) * s, np.sin(turn) * s])
    elif kind == 2:  # bent by 10–20° over the cluster
        local[:, 1] = rng.uniform(0.2, 0.4) * t**2
    elif kind == 3:  # a gap of 0.6–1 m after some of the points
        local[int(rng.integers(2, n - 2)) :, 0] += rng.uniform(0.6, 1.0)
    angle = rng.uniform(0.0, 2 * np.pi)
    c, s_ = np.cos(angle), np.sin(angle)
    xy = local @ np.array([[c, s_], [-s_, c]]) + rng.normal(scale=4.0, size=2)
    xy += rng.normal(scale=0.01, size=xy.shape)
    return np.ascontiguousarray(xy[rng.permutation(n)])


def test_wall_mask__the_same_points_as_the_numpy_split() -> None:
    """Straight, cornered, bent and gapped clusters: the same mask exactly (the MSAC scores
    and gaps differ by rounding only, far below the seeded cases' margins)."""
    rng = np.random.default_rng(13)
    kept = set()
    for _ in range(200):
        xy = _cluster(rng)
        got = wall_mask(xy, 0.03, 3, np.radians(30.0), GAP_SPLIT)
        want = reference.wall_mask(xy, 0.03, 3, np.radians(30.0), GAP_SPLIT)
        np.testing.assert_array_equal(got, want)
        kept.add(int(want.sum()) == len(xy))
    assert kept == {True, False}  # some clusters split, some kept whole

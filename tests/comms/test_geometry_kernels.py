"""The compiled geometry of a received chain (``comms/kernels.py``) against its numpy oracle
(``tests/comms/reference_geometry.py``), bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.comms import kernels
from polyslam_env.comms.alignment import frame_points
from polyslam_env.comms.exchange import (
    _fit_chain,
    chain_points,
    normal_variance,
    received_geometry,
    refit_variance_floor,
)
from polyslam_env.core.geometry import rotation
from polyslam_env.slam.fitting import PointSet
from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.polynomial import Polynomial
from tests.comms import reference_geometry as ref


def _chains(rng: np.random.Generator) -> list[np.ndarray]:
    """Chains of 1–300 points: random walks, chains of random curves (as the exchange samples
    them), and chains with repeated points (a zero step: the norm's floor)."""
    out = [rng.normal(0.0, 2.0, (n, 2)) for n in (1, 2, 3, 7, 300)]
    for _ in range(30):
        lo = float(rng.uniform(-3.0, 2.0))
        coeffs = rng.normal(0.0, [1.0, 0.5, 0.2, 0.05])
        poly = Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + float(rng.uniform(0.02, 4.0)))
        out.append(np.array(chain_points(poly, 0.005, 0.05)))
    repeated = rng.normal(0.0, 1.0, (6, 2))
    repeated[2] = repeated[1]
    repeated[4] = repeated[3] = repeated[5]
    out.append(repeated)
    return out


def test_received_geometry__is_the_numpy_oracle_bit_for_bit() -> None:
    """Points, ∂p/∂T, normals and normal σ of random chains under random transforms and
    covariances equal the numpy the exchange ran before (``np.gradient``, BLAS's products,
    ``np.einsum``): gemm for N ≥ 2, gemv for one point, sums in einsum's order."""
    rng = np.random.default_rng(7)
    for q in _chains(rng):
        for _ in range(4):
            t = np.array([*rng.normal(0.0, 3.0, 2), rng.uniform(-np.pi, np.pi)])
            a = rng.normal(0.0, 0.05, (3, 3))
            cov_t = a @ a.T
            xy, dp_dt, normals, sigma = received_geometry(q, t, rotation(float(t[2])), cov_t)
            want_xy, want_dp = ref.frame_points(q, t)
            want_normals = ref.chain_normals(q, t)
            assert np.array_equal(xy, want_xy) and np.array_equal(dp_dt, want_dp)
            assert np.array_equal(frame_points(q, t)[0], want_xy)
            assert np.array_equal(normals, want_normals)
            assert np.array_equal(sigma, ref.normal_sigma(want_normals, want_dp, cov_t))
            assert np.array_equal(kernels.unit_tangents(q), ref.tangents(q))
            shift = rotation(float(t[2])) @ np.array([0.0, 1.0])
            for rows in (slice(None), slice(0, 0), slice(0, 1), slice(0, 2), slice(0, 3)):
                got = refit_variance_floor(normals[rows], cov_t, shift, 1e-4)
                assert got == ref.refit_variance_floor(normals[rows], cov_t, shift, 1e-4)


def test_received_geometry__a_nan_point_stays_nan() -> None:
    """A NaN in the chain gives NaN normals and σ where numpy's do (np.maximum keeps NaN),
    and the floor over them is NaN, as numpy's min."""
    q = np.array([[0.0, 0.0], [1.0, np.nan], [2.0, 0.0], [3.0, 0.0]])
    t = np.array([0.1, -0.2, 0.3])
    cov_t = np.diag([1e-4, 2e-4, 3e-5])
    _, _, normals, sigma = received_geometry(q, t, rotation(0.3), cov_t)
    want = ref.normal_sigma(ref.chain_normals(q, t), ref.frame_points(q, t)[1], cov_t)
    assert np.array_equal(np.isnan(sigma), np.isnan(want)) and np.isnan(sigma).any()
    assert np.isnan(kernels.variance_floor(normals, cov_t, np.array([0.0, 1.0]), 1e-4))


def test_point_jacobians__are_the_numpy_oracle_bit_for_bit() -> None:
    """A received chain's Jacobians w.r.t. the state and the noise equal numpy's batched
    products (BLAS: FMA chains), for one point and many, a (3, 6) noise Jacobian sliced out
    of a wider one (not contiguous: numpy copies it), and a state wider than the pose."""
    rng = np.random.default_rng(8)
    for n_pts in (1, 2, 5, 80):
        for n_state in (3, 7):
            dp_dt = rng.normal(0.0, 1.0, (n_pts, 2, 3))
            d_state = rng.normal(0.0, 1.0, (3, 3))
            d_noise = rng.normal(0.0, 1.0, (3, 9))[:, 3:]
            shift = rotation(float(rng.uniform(-3.0, 3.0))) @ np.array([1.0, 0.0])
            got = kernels.point_jacobians(
                dp_dt, d_state, np.ascontiguousarray(d_noise), shift, n_state
            )
            want = ref.point_jacobians(dp_dt, d_state, d_noise, shift, n_state)
            assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_largest_residual__numpys_max_of_the_residuals() -> None:
    """The compiled largest |η − p(ξ)| is numpy's ``np.max(np.abs(eta − poly.value(xi)))``
    bit for bit, on points near random polynomials of either variate and order 1–5 (zero
    tails too), and nan where a point is nan."""
    rng = np.random.default_rng(3)
    for trial in range(300):
        coeffs = rng.normal(0.0, [1.0, 0.5, 0.1, 0.02, 0.01, 0.003][: int(rng.integers(2, 7))])
        if trial % 4 == 0:
            coeffs[-1] = 0.0
        poly = Polynomial(int(rng.integers(1, 3)), coeffs, -2.0, 3.0)
        xy = poly.points_at(rng.uniform(-2.0, 3.0, int(rng.integers(1, 40))))
        xy = xy + rng.normal(0.0, 0.02, xy.shape)
        xi, eta = poly.from_xy(xy)
        want = float(np.max(np.abs(eta - poly.value(xi))))
        assert kernels.largest_residual(xy, poly.variate, poly.coeffs) == want
    xy[0, 1] = np.nan
    assert np.isnan(kernels.largest_residual(xy, 1, poly.coeffs))


def test_chain_fit__is_the_fit_by_fit_loop_bit_for_bit() -> None:
    """A received chain's refit in one compiled call (``exchange._fit_chain``) gives the fit
    of the order-by-order loop through ``fit_polynomial`` (``reference_geometry.fit_chain``):
    the same variate, padded coefficients, extent, order, RMS, G_x, G_y and largest residual,
    on chains of straight and curved walls of either variate, 2–60 points, with and without
    auto order, at tolerances that stop it at each order."""
    rng = np.random.default_rng(11)
    for trial in range(200):
        coeffs = rng.normal(0.0, [1.0, 0.5, [0.0, 0.2][trial % 2], 0.03 * (trial % 3 == 0)])
        lo = float(rng.uniform(-3.0, 2.0))
        poly = Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + float(rng.uniform(0.1, 4.0)))
        n, n_state, k = int(rng.integers(2, 61)), int(rng.integers(3, 30)), 4
        xy = poly.points_at(np.sort(rng.uniform(poly.lo, poly.hi, n)))
        xy = xy + rng.normal(0.0, [0.0, 0.002, 0.02][trial % 3], xy.shape)
        a = rng.normal(0.0, 0.1, (k, k))
        points = PointSet(
            xy, rng.normal(0.0, 1.0, (n, 2, n_state)), rng.normal(0.0, 1.0, (n, 2, k)), a @ a.T,
            np.ones(n),
        )  # fmt: skip
        for auto_order in (True, False):
            for tol in (1e-9, 0.003, 0.03, 1.0):
                got, worst, finite = _fit_chain(points, 3, auto_order, tol)
                want, want_worst = ref.fit_chain(points, 3, auto_order, tol)
                assert worst == want_worst
                jacobians = np.concatenate([want.Gx.ravel(), want.Gy.ravel()])
                assert finite == bool(np.isfinite(want.c0) and np.isfinite(jacobians).all())
                assert (got.poly.variate, got.poly.lo, got.poly.hi) == (
                    want.poly.variate, want.poly.lo, want.poly.hi,
                )  # fmt: skip
                assert np.array_equal(got.poly.coeffs, want.poly.coeffs)
                assert (got.c0, got.rms, got.order) == (want.c0, want.rms, want.order)
                assert np.array_equal(got.Gx, want.Gx) and np.array_equal(got.Gy, want.Gy)
                assert got.V is points.noise_cov


def test_chain_fit__a_nan_point_raises_as_the_loop_did() -> None:
    """A chain with a NaN point raises the fit's own error, the same as the fit-by-fit loop,
    not a fit with NaN coefficients."""
    xy = np.array([[0.0, 0.0], [0.5, np.nan], [1.0, 0.1], [1.5, 0.1]])
    points = PointSet(xy, np.zeros((4, 2, 5)), np.zeros((4, 2, 1)), np.eye(1), np.ones(4))
    errors = []
    for fit_chain in (_fit_chain, ref.fit_chain):
        with pytest.raises(ValueError) as error:
            fit_chain(points, 3, True, 0.01)
        errors.append((error.type, str(error.value)))
    assert errors[0] == errors[1]


def test_better_cover__is_the_per_landmark_rule_bit_for_bit() -> None:
    """Rule 1 of a received piece's fusion in one call (``comms.kernels.better_cover``) picks
    the landmarks whose ``exchange.normal_variance`` is at most the limit and covers the
    points ``reference_geometry.covered_points`` covers with them, on tables of random walls
    (orders 1–3 with zero tails, either variate, a c0 in the state unlike the fit's) and
    points on, near and off them."""
    rng = np.random.default_rng(21)
    for _ in range(60):
        table, n = LandmarkTable(), int(rng.integers(1, 12))
        for _ in range(n):
            coeffs = rng.normal(0.0, [1.0, 0.4, 0.1, 0.02])
            coeffs[int(rng.integers(2, 5)) :] = 0.0  # a line, a quadratic or a cubic
            lo = float(rng.uniform(-3.0, 2.0))
            poly = Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + float(rng.uniform(0.2, 3)))
            table.append(poly, 0.5 * (poly.lo + poly.hi), 0.0, 0.0, 0.5, evidence=(-9.0, 9.0))
        a = rng.normal(0.0, 0.02, (3 + 2 * n, 3 + 2 * n))
        cov = a @ a.T
        c0s = rng.normal(0.0, 1.0, n)
        rows = np.flatnonzero(rng.random(n) < 0.7)
        walls = [table.poly(int(r)).with_c0(float(c0s[r])) for r in rows]
        xy = np.concatenate(
            [w.points_at(rng.uniform(w.lo - 0.3, w.hi + 0.3, 6)) for w in walls]
            + [rng.normal(0.0, 2.0, (5, 2))]
        )
        xy += rng.normal(0.0, 0.03, xy.shape)
        limit = float(np.median(np.diagonal(cov))) * 0.9
        variances = [normal_variance(table.poly(int(r)), float(cov[3 + r, 3 + r])) for r in rows]
        want = [w for w, var in zip(walls, variances, strict=True) if var <= limit]
        better, covered = kernels.better_cover(
            xy, rows, limit, table.variate, table.shape, table.order, table.sizes, c0s,
            table.lo, table.hi, cov, 0.05,
        )  # fmt: skip
        assert better == len(want)
        assert np.array_equal(covered, ref.covered_points(xy, want, 0.05))


def test_table_walls__is_the_numpy_oracle_bit_for_bit() -> None:
    """A landmark table's rows as the refinement's walls and their normal variances, in one
    compiled call (``kernels.table_walls``), against the numpy ``exchange._table_walls`` ran
    and ``exchange.normal_variance`` per wall: every array's bits, on tables of mixed orders
    (a zero-padded shape buffer), rows in any order, none, or all."""
    rng = np.random.default_rng(5)
    for case in range(300):
        n = int(rng.integers(1, 40))
        width = int(rng.integers(2, 6))  # the buffer's columns: orders up to width − 1
        order = rng.integers(1, width, n).astype(np.int64)
        shape = rng.normal(0.0, [0.0, 0.5, 0.2, 0.05, 0.01][:width], (n, width))
        for r in range(n):
            shape[r, order[r] + 1 :] = 0.0
        variate = rng.integers(1, 3, n).astype(np.int64)
        c0s = rng.normal(0.0, 3.0, n)
        lo = rng.uniform(-4.0, 2.0, n)
        hi = lo + rng.uniform(0.0, 3.0, n)
        cov = rng.normal(0.0, 0.01, (3 + 2 * n, 3 + 2 * n))
        cov = cov @ cov.T
        if case % 3 == 0:
            rows = np.arange(n, dtype=np.int64)
        elif case % 3 == 1:
            rows = rng.permutation(n)[: int(rng.integers(0, n + 1))].astype(np.int64)
        else:
            rows = np.zeros(0, dtype=np.int64)
        got = kernels.table_walls(rows, order, variate, shape, c0s, lo, hi, cov)
        want = ref.table_walls(rows, order, variate, shape, c0s, lo, hi, cov)
        for g, w in zip(got, want, strict=True):
            assert g.shape == w.shape and g.dtype == w.dtype
            assert g.tobytes() == w.tobytes()

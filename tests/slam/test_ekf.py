"""EKF core: Jacobians, algebra against the textbook forms, PSD, NEES consistency, divergence."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.core.geometry import compose
from polyslam_env.slam.ekf import (
    augment,
    augment_pair,
    divergence_ratio,
    is_diverging,
    nees,
    predict,
    remove,
    thresholds,
    update_sparse_inplace,
    wrap_angle,
)
from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.measurement import BeamHit, cast, range_rows
from polyslam_env.slam.polynomial import Polynomial
from tests.slam.reference import motion_jacobians, predict_dense, update

P0 = np.diag([0.05**2, 0.05**2, 0.0175**2])
BEAMS = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T / n + 0.1 * np.eye(n))


def assert_symmetric_psd(cov: np.ndarray) -> None:
    np.testing.assert_array_equal(cov, cov.T)  # every operation symmetrises exactly
    scale = max(1.0, float(np.abs(cov).max()))
    assert np.linalg.eigvalsh(cov).min() >= -1e-12 * scale  # rounding only, relative to P


# -- prediction -----------------------------------------------------------------------------------
@settings(max_examples=50, deadline=None)
@given(
    pose=st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-np.pi, np.pi)),
    odo=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
)
def test_motion_jacobians__match_finite_differences(
    pose: tuple[float, float, float], odo: tuple[float, float, float]
) -> None:
    x, u = np.array(pose), np.array(odo)
    F, L = motion_jacobians(x, u)
    step = 1e-6
    for col in range(3):
        d = np.zeros(3)
        d[col] = step
        dF = wrap_angle_diff(compose(x + d, u), compose(x - d, u)) / (2 * step)
        dL = wrap_angle_diff(compose(x, u + d), compose(x, u - d)) / (2 * step)
        # 1e-7: central differences of sin/cos with |second derivative| ≤ 1 m: error ~ 1e-12
        np.testing.assert_allclose(F[:, col], dF, atol=1e-7)
        np.testing.assert_allclose(L[:, col], dL, atol=1e-7)


def wrap_angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a - b
    d[2] = wrap_angle(d[2])
    return d


def test_predict__equals_dense_formula_and_leaves_landmarks() -> None:
    rng = np.random.default_rng(1)
    n = 7
    mean = rng.normal(size=3 + n)
    cov = random_spd(rng, 3 + n, 0.01)
    u, W = np.array([0.1, 0.02, 0.05]), np.diag([1e-4, 2e-4, 3e-5])
    new_mean, new_cov = predict(mean, cov, u, W)
    want_mean, want_cov = predict_dense(mean, cov, u, W)  # F P Fᵀ + L W Lᵀ
    # 1e-14: the same products in a different order
    np.testing.assert_allclose(new_cov, want_cov, atol=1e-14)
    np.testing.assert_allclose(new_mean, want_mean, atol=1e-14)
    np.testing.assert_array_equal(new_cov[3:, 3:], cov[3:, 3:])
    np.testing.assert_array_equal(new_mean[3:], mean[3:])
    assert abs(new_mean[2]) <= np.pi


# -- update ---------------------------------------------------------------------------------------
def sparse_h(rng: np.random.Generator, k: int, n_state: int) -> np.ndarray:
    """Rows like the range model's: a pose part and one c0 entry."""
    H = np.zeros((k, n_state))
    H[:, :3] = rng.normal(size=(k, 3))
    H[np.arange(k), rng.integers(3, n_state, size=k)] = rng.normal(size=k)
    return H


def test_update__equals_textbook_joseph_form() -> None:
    rng = np.random.default_rng(2)
    n_state, k = 12, 5
    mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
    H, R = sparse_h(rng, k, n_state), random_spd(rng, k, 1e-3)
    z_hat = rng.normal(size=k)
    z = z_hat + 0.01 * rng.normal(size=k)
    result = update(mean, cov, z, z_hat, H, R, gate_prob=1.0)
    assert result.accepted.all()
    S = H @ cov @ H.T + R
    K = np.linalg.solve(S, H @ cov).T
    IKH = np.eye(n_state) - K @ H
    expected_cov = IKH @ cov @ IKH.T + K @ R @ K.T
    expected_mean = mean + K @ (z - z_hat)
    expected_mean[2] = wrap_angle(expected_mean[2])
    # 1e-12: the same algebra in another association order on O(1) numbers
    np.testing.assert_allclose(result.cov, expected_cov, atol=1e-12)
    np.testing.assert_allclose(result.mean, expected_mean, atol=1e-12)


@pytest.mark.parametrize("n_state", [4, 12, 60])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_update_sparse_inplace__equals_dense_update(n_state: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = 5
    mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
    h_pose, h_c0 = rng.normal(size=(k, 3)), rng.normal(size=k)
    c0_index = rng.integers(3, n_state, size=k)  # two rows may share a landmark
    r = rng.uniform(1e-4, 1e-3, size=k)
    H = np.zeros((k, n_state))
    H[:, :3] = h_pose
    H[np.arange(k), c0_index] = h_c0
    innovation = 0.05 * rng.normal(size=k)
    innovation[0] = 50.0  # an outlier the gate must drop in both
    dense = update(mean, cov, innovation, np.zeros(k), H, np.diag(r))
    new_mean, new_cov = mean.copy(), cov.copy()
    accepted, nis = update_sparse_inplace(new_mean, new_cov, innovation, h_pose, c0_index, h_c0, r)
    np.testing.assert_array_equal(accepted, dense.accepted)
    assert not accepted[0] and accepted[1:].any()
    # 1e-12 relative: the same quantities in another association order (S, K and the
    # polarised Joseph products), on a well-conditioned S
    np.testing.assert_allclose(nis, dense.nis, rtol=1e-12)
    np.testing.assert_allclose(new_mean, dense.mean, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(new_cov, dense.cov, rtol=1e-10, atol=1e-14)
    assert_symmetric_psd(new_cov)


@pytest.mark.parametrize("n_lm", [1, 6, 30])
def test_update_sparse_inplace__considered_states__equal_the_textbook_schmidt_filter(
    n_lm: int,
) -> None:
    """State [pose, c0 × n, α × n], rows on the pose, a c0 and its α; the α block considered.
    The textbook Schmidt–Kalman update: K = P Hᵀ S⁻¹ with the considered rows of K set to zero,
    then the Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ, literally, with dense H. Then: the
    considered means and their own block never move, their cross-covariances do, and the
    result is a valid (symmetric PSD) covariance."""
    rng = np.random.default_rng(n_lm)
    k, n_state = 4, 3 + 2 * n_lm
    mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
    h_pose, h_c0, h_alpha = rng.normal(size=(k, 3)), rng.normal(size=k), rng.normal(size=k)
    c0_index = rng.integers(3, 3 + n_lm, size=k)
    alpha_index = c0_index + n_lm
    r = rng.uniform(1e-4, 1e-3, size=k)
    H = np.zeros((k, n_state))
    H[:, :3] = h_pose
    H[np.arange(k), c0_index] = h_c0
    H[np.arange(k), alpha_index] += h_alpha
    innovation = 0.05 * rng.normal(size=k)
    S = H @ cov @ H.T + np.diag(r)
    K = np.linalg.solve(S, H @ cov).T
    K[3 + n_lm :] = 0.0  # considered: no gain
    IKH = np.eye(n_state) - K @ H
    expected_cov = IKH @ cov @ IKH.T + K @ np.diag(r) @ K.T
    expected_mean = mean + K @ innovation
    expected_mean[2] = wrap_angle(expected_mean[2])
    new_mean, new_cov = mean.copy(), cov.copy()
    accepted, _ = update_sparse_inplace(
        new_mean, new_cov, innovation, h_pose, c0_index, h_c0, r, gate_prob=1.0,
        alpha_index=alpha_index, h_alpha=h_alpha, consider_from=3 + n_lm,
    )  # fmt: skip
    assert accepted.all()
    np.testing.assert_allclose(new_mean, expected_mean, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(new_cov, expected_cov, rtol=1e-10, atol=1e-14)
    block = slice(3 + n_lm, n_state)
    np.testing.assert_array_equal(new_mean[block], mean[block])
    np.testing.assert_array_equal(new_cov[block, block], cov[block, block])
    assert not np.allclose(new_cov[:3, block], cov[:3, block])
    assert_symmetric_psd(new_cov)


def test_update_sparse_inplace__stays_exactly_symmetric_over_many_updates() -> None:
    rng = np.random.default_rng(7)
    n_state = 40
    mean, cov = np.zeros(n_state), random_spd(rng, n_state, 0.01)
    for _ in range(200):
        k = int(rng.integers(1, 6))
        update_sparse_inplace(
            mean,
            cov,
            0.01 * rng.normal(size=k),
            rng.normal(size=(k, 3)),
            rng.integers(3, n_state, size=k),
            rng.normal(size=k),
            np.full(k, 4e-4),
            1.0,
        )
        cov[:3, :3] += 1e-4 * np.eye(3)  # some process noise so P does not collapse
    assert_symmetric_psd(cov)


def test_update_sparse_inplace__nothing_accepted_leaves_state() -> None:
    rng = np.random.default_rng(3)
    mean, cov = rng.normal(size=6), random_spd(rng, 6, 1e-4)
    before_mean, before_cov = mean.copy(), cov.copy()
    accepted, nis = update_sparse_inplace(
        mean, cov, np.array([5.0]), np.ones((1, 3)), np.array([4]), np.ones(1), np.full(1, 1e-4)
    )
    assert not accepted.any() and nis[0] > 100
    np.testing.assert_array_equal(mean, before_mean)
    np.testing.assert_array_equal(cov, before_cov)


def test_update__gate_rejects_outliers_and_unusable_beams() -> None:
    rng = np.random.default_rng(4)
    n_state = 6
    mean, cov = np.zeros(n_state), 1e-4 * np.eye(n_state)
    H = sparse_h(rng, 4, n_state)
    R = 0.02**2 * np.eye(4)
    z_hat = np.array([1.0, 1.0, 1.0, np.inf])
    z = np.array([1.01, 2.0, np.nan, 1.0])  # fine, outlier, no return, no prediction
    result = update(mean, cov, z, z_hat, H, R)
    assert result.accepted.tolist() == [True, False, False, False]
    s0 = H[0] @ cov @ H[0] + R[0, 0]
    assert result.nis[0] == pytest.approx(0.01**2 / s0, rel=1e-12)  # exact formula
    assert np.isnan(result.nis[2:]).all()
    nothing = update(mean, cov, z[1:3], z_hat[1:3], H[1:3], R[1:3, 1:3])
    assert not nothing.accepted.any()
    np.testing.assert_array_equal(nothing.cov, cov)


# -- augmentation / removal -----------------------------------------------------------------------
def test_augment__equals_full_jacobian_formula() -> None:
    rng = np.random.default_rng(5)
    n_state, k = 6, 4
    mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
    Gx, Gy, V = rng.normal(size=(1, n_state)), rng.normal(size=(1, k)), random_spd(rng, k, 1e-3)
    new_mean, new_cov = augment(mean, cov, 0.7, Gx, Gy, V)
    G = np.zeros((n_state + 1, n_state + k))  # g(X, y) = [X; c0(X, y)]
    G[:n_state, :n_state] = np.eye(n_state)
    G[n_state, :n_state], G[n_state, n_state:] = Gx[0], Gy[0]
    joint = np.zeros((n_state + k, n_state + k))
    joint[:n_state, :n_state], joint[n_state:, n_state:] = cov, V
    # 1e-14: same products, different association order
    np.testing.assert_allclose(new_cov, G @ joint @ G.T, atol=1e-14)
    assert new_mean[-1] == 0.7 and np.array_equal(new_mean[:-1], mean)


def _numpy_augment(
    mean: np.ndarray, cov: np.ndarray, value: float, gx: np.ndarray, gy: np.ndarray, V: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The oracle of the compiled augment: numpy's products, then the grown state by hand."""
    cross = cov @ gx
    var = gx @ cross + gy @ V @ gy
    n = mean.size
    out = np.empty((n + 1, n + 1))
    out[:n, :n], out[:n, n], out[n, :n], out[n, n] = cov, cross, cross, var
    return np.append(mean, value), out


@pytest.mark.parametrize("n_state", [3, 4, 9, 41, 120, 603])
def test_augment__compiled_products_are_numpys_bit_for_bit(n_state: int) -> None:
    """The compiled augment (one call: BLAS's gemv and dot through numba) gives numpy's
    floats, at state sizes of a new map to a 300-landmark one; the pair (a c0, then its turn
    over the grown state, put in place by an order) gives the two numpy steps' floats."""
    rng = np.random.default_rng(n_state)
    for k in (1, 2, 7, 13):
        mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
        gx, gy, V = rng.normal(size=n_state), rng.normal(size=k), random_spd(rng, k, 1e-3)
        want = _numpy_augment(mean, cov, 0.7, gx, gy, V)
        got = augment(mean, cov, 0.7, gx[None, :], gy[None, :], V)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
        turn_gx, turn_var = rng.normal(size=n_state + 1), float(rng.uniform(0.0, 1e-3))
        order = rng.permutation(n_state + 2)
        second = _numpy_augment(*want, 0.0, turn_gx, np.ones(1), np.array([[turn_var]]))
        got = augment_pair(mean, cov, 0.7, gx, gy, V, turn_gx, turn_var, order)
        assert np.array_equal(got[0], second[0][order])
        assert np.array_equal(got[1], second[1][np.ix_(order, order)])
    with pytest.raises(ValueError, match="second entry"):
        augment_pair(mean, cov, 0.7, gx, gy, V, turn_gx[1:], 0.0, order)


def test_remove__undoes_augment_and_moves_a_copied_landmark() -> None:
    rng = np.random.default_rng(6)
    mean, cov = rng.normal(size=8), random_spd(rng, 8, 0.01)
    grown = augment(mean, cov, 1.0, rng.normal(size=8), rng.normal(size=2), np.eye(2))
    back_mean, back_cov = remove(*grown, [8])
    np.testing.assert_array_equal(back_mean, mean)
    np.testing.assert_array_equal(back_cov, cov)
    # copy landmark 4 (Gx = e_4, no new noise), then drop the original: a permutation.
    e4 = np.eye(8)[4]
    moved = remove(*augment(mean, cov, mean[4], e4, np.zeros(1), np.zeros((1, 1))), 4)
    order = [0, 1, 2, 3, 5, 6, 7, 4]
    np.testing.assert_array_equal(moved[0], mean[order])
    np.testing.assert_allclose(moved[1], cov[np.ix_(order, order)], atol=1e-15)  # e4·P·e4
    two = remove(mean, cov, [6, 3])  # several at once, in any order: the rest as they were
    rest = [0, 1, 2, 4, 5, 7]
    np.testing.assert_array_equal(two[0], mean[rest])
    np.testing.assert_array_equal(two[1], cov[np.ix_(rest, rest)])
    assert two[1].flags.c_contiguous
    with pytest.raises(ValueError, match="landmark state indices"):
        remove(mean, cov, [2])


# a seeded random sequence of operations: the seed is the only input (a plain parameter)
@pytest.mark.parametrize("seed", range(15))
def test_ekf_operations__keep_covariance_symmetric_psd(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mean = np.zeros(3)
    cov = P0.copy()
    for _ in range(150):
        op = rng.integers(4)
        n_state = mean.size
        if op == 0:
            mean, cov = predict(mean, cov, rng.normal(0, 0.1, 3), np.diag([1e-4, 1e-4, 1e-5]))
        elif op == 1 and n_state > 3:
            k = int(rng.integers(1, 6))
            H = sparse_h(rng, k, n_state)
            z_hat = rng.uniform(0.2, 2.0, k)
            z = z_hat + rng.normal(0, 0.05, k)
            mean, cov = update(mean, cov, z, z_hat, H, 0.02**2 * np.eye(k)).mean_cov
        elif op == 2 or n_state == 3:
            k = int(rng.integers(1, 8))
            V = np.diag(rng.uniform(1e-4, 1e-2, k))
            mean, cov = augment(
                mean, cov, rng.normal(), rng.normal(size=n_state), rng.normal(size=k), V
            )
        else:
            mean, cov = remove(mean, cov, int(rng.integers(3, n_state)))
        assert_symmetric_psd(cov)


def test_ekf_functions__leave_their_inputs_untouched() -> None:
    rng = np.random.default_rng(9)
    mean, cov = rng.normal(size=6), random_spd(rng, 6, 0.01)
    mean_copy, cov_copy = mean.copy(), cov.copy()
    predict(mean, cov, np.array([0.1, 0.0, 0.2]), np.eye(3) * 1e-4)
    H = sparse_h(rng, 3, 6)
    update(mean, cov, np.ones(3), np.ones(3) * 1.01, H, np.eye(3) * 1e-2, gate_prob=1.0)
    augment(mean, cov, 0.0, np.ones(6), np.ones(1), np.eye(1))
    remove(mean, cov, [4])
    np.testing.assert_array_equal(mean, mean_copy)
    np.testing.assert_array_equal(cov, cov_copy)


# -- divergence and NEES helpers ------------------------------------------------------------------
def test_divergence_ratio__zero_at_zero_one_at_kp0_and_thresholds_clip() -> None:
    K = 150.0
    assert divergence_ratio(np.zeros((3, 3)), P0, K) == pytest.approx(0.0, abs=1e-15)
    assert divergence_ratio(K * P0, P0, K) == pytest.approx(1.0, abs=1e-15)
    assert divergence_ratio(3 * K * P0, P0, K) < 0  # why f > 1 can never flag divergence
    assert thresholds(0.5, 0.1, 0.3) == pytest.approx(0.2, abs=1e-15)
    assert thresholds(-2.0, 0.1, 0.3) == 0.1 and thresholds(4.0, 0.1, 0.3) == 0.3


def test_is_diverging__covariance_beyond_k_p0() -> None:
    K = 150.0
    assert not is_diverging(0.5 * K * P0, P0, K)
    beyond = 0.5 * K * P0
    beyond[2, 2] = 1.01 * K * P0[2, 2]  # heading alone exceeds K P0
    assert is_diverging(beyond, P0, K)


def test_nees__wraps_heading_and_uses_inverse_covariance() -> None:
    cov = np.diag([0.01, 0.04, 0.0025])
    e = np.array([0.1, -0.2, 2 * np.pi + 0.05])
    assert nees(e, cov) == pytest.approx(1.0 + 1.0 + 1.0, rel=1e-12)  # 0.05²/0.0025 = 1


# -- Monte Carlo with known landmarks -------------------------------------------------------------
WALLS = [
    Polynomial(1, np.array([-1.4, 0.05, -0.02, 0.003]), -3.0, 3.0),  # floor
    Polynomial(1, np.array([1.8, 0.0, -0.03, 0.002]), -3.0, 3.0),  # ceiling
    Polynomial(2, np.array([-2.5, 0.0, 0.05, 0.0]), -2.0, 2.5),  # left
    Polynomial(2, np.array([2.6, -0.04, 0.03, 0.0]), -2.0, 2.5),  # right
]
WALL_ROWS = LandmarkTable()
for _wall in WALLS:
    WALL_ROWS.append(_wall, pivot=0.0, xi_var=0.0, model_var=0.0, fit_half=1.0)
SIN_10 = np.sin(np.deg2rad(10.0))
START = np.array([0.0, -0.4, 0.0])
SIGMA_RANGE, SIGMA_C0 = 0.02, 0.03


def run_filter(
    rng: np.random.Generator,
    steps: int,
    W_true: np.ndarray,
    W_filter: np.ndarray,
    range_bias: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
    """One run: true pose ~ N(START, P0), true c0 ~ N(nominal, σ_c0²), circle of radius 0.8 m.

    Returns the NEES per step (steps,), final pose covariance, final mean, and the NIS of
    every finite beam (accepted or not).
    """
    nominal = np.array([w.c0 for w in WALLS])
    true_c0 = nominal + rng.normal(0.0, SIGMA_C0, len(WALLS))
    true_pose = START + rng.multivariate_normal(np.zeros(3), P0)
    mean = np.concatenate([START, nominal])
    cov = np.diag(np.concatenate([np.diag(P0), np.full(len(WALLS), SIGMA_C0**2)]))
    u_true = np.array([0.08, 0.0, 0.1])
    out, all_nis = np.empty(steps), []
    for k in range(steps):
        u_meas = u_true + rng.multivariate_normal(np.zeros(3), W_true)
        true_pose = compose(true_pose, u_true)
        mean, cov = predict(mean, cov, u_meas, W_filter)
        truth = [h.t if h else np.inf for h in _cast(true_pose, true_c0)]
        z = np.array(truth) + rng.normal(0.0, SIGMA_RANGE, BEAMS.size) + range_bias
        returns = np.flatnonzero(np.isfinite(z))
        x, y, theta = mean[:3].tolist()
        rows = range_rows(  # the SLAM's rows: a hit, not near-tangent, with a return
            x,
            y,
            theta,
            BEAMS[returns],
            z[returns],
            WALL_ROWS.arrays(),
            mean[3:],
            2.0,
            SIN_10,
            SIGMA_RANGE**2,
        )
        if rows.innovation.size:
            _, nis = update_sparse_inplace(mean, cov, *rows)
            all_nis.extend(nis.tolist())
        out[k] = nees(true_pose - mean[:3], cov[:3, :3])
    return out, cov[:3, :3], mean, all_nis


def _cast(pose: np.ndarray, c0s: np.ndarray) -> list[BeamHit | None]:
    """The SLAM's measurement model on the known walls with their c0s (n,)."""
    x, y, theta = pose.tolist()
    every = list(range(len(WALLS)))
    return cast(x, y, theta, BEAMS.tolist(), every, WALL_ROWS.rows(), c0s.tolist(), 2.0)


W_ODO = np.diag([0.01**2, 0.01**2, np.deg2rad(0.5) ** 2])
RUNS, STEPS = 60, 60


def nees_band(runs: int) -> tuple[float, float]:
    """Two-sided 95 % band of the run-averaged NEES of a 3-D state over ``runs`` runs."""
    chi2 = scipy.stats.chi2(3 * runs)
    return chi2.ppf(0.025) / runs, chi2.ppf(0.975) / runs


@pytest.mark.slow
def test_ekf_known_landmarks__nees_is_consistent() -> None:
    """Run-averaged NEES per step lies in its 95 % χ² band on ≥ 85 % of the steps.

    Runs are independent, so at each step R·NEES̄ ~ χ²(3R) for a consistent filter, and the
    band is exact up to linearisation. Steps of one run are correlated, so a test on the
    grand mean would need that correlation; instead we count steps inside the per-step band
    (95 % expected; 85 % leaves room for the correlated excursions of 60 runs).
    """
    rng = np.random.default_rng(2024)
    table = np.array([run_filter(rng, STEPS, W_ODO, W_ODO)[0] for _ in range(RUNS)])
    per_step = table.mean(axis=0)  # (steps,)
    lo, hi = nees_band(RUNS)
    inside = np.mean((per_step >= lo) & (per_step <= hi))
    assert inside >= 0.85, f"{inside:.0%} of steps inside [{lo:.2f}, {hi:.2f}]"
    # 2.5 … 3.5: the grand mean of a consistent filter is 3; this guards against a NEES
    # that sits inside the band only by being wide (its per-step std is ≈ 0.3).
    assert 2.5 < per_step.mean() < 3.5


@pytest.mark.slow
def test_ekf_overconfident_filter__fails_nees_and_is_flagged_diverging() -> None:
    """Far too little process noise and biased ranges: NEES leaves the band, flags fire."""
    rng = np.random.default_rng(7)
    runs = 20
    flagged, tables = [], []
    for _ in range(runs):
        nees_k, cov_pose, _, nis = run_filter(rng, STEPS, W_ODO, W_ODO * 1e-4, range_bias=0.1)
        tables.append(nees_k)
        flagged.append(is_diverging(cov_pose, P0, 150.0, nis=np.array(nis[-25:])))
    per_step = np.mean(tables, axis=0)
    assert per_step[-1] > nees_band(runs)[1]
    assert all(flagged)


@pytest.mark.slow
def test_is_diverging__quiet_for_consistent_filter() -> None:
    rng = np.random.default_rng(8)
    flags = []
    for _ in range(20):
        _, cov_pose, _, nis = run_filter(rng, STEPS, W_ODO, W_ODO)
        flags.append(is_diverging(cov_pose, P0, 150.0, nis=np.array(nis[-25:])))
    # the NIS window test has a 0.1 % false-alarm rate per window: 20 windows ⇒ ≤ 1 expected
    assert sum(flags) <= 1

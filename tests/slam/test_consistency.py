"""Honest uncertainty: the anchored start, first-estimates Jacobians, P0's share of the pose.

Unit level: FEJ propagation against its definition, the start-error covariance against finite
differences of the pose composition and a Monte-Carlo draw. Episode level (tests/environment/
test_consistency_episodes.py): NEES over seeded runs on a large generated map.
"""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.core.geometry import compose
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import predict, predict_inplace, start_error_cov, start_error_covs
from polyslam_env.slam.robot import PolySlam
from tests.slam.finite_differences import FD_ATOL, FD_RTOL, fd_jacobian
from tests.slam.reference import motion_jacobians, predict_dense
from tests.slam.reference_floats import fma_matmul

P0 = SlamConfig().p0
W = SlamConfig().odom_cov


def test_predict__first_estimate_at_the_current_pose__equals_the_standard_prediction() -> None:
    """Without an update between two predictions the first estimate is the current pose,
    so FEJ and the textbook F coincide (to rounding: a and b are formed differently)."""
    rng = np.random.default_rng(0)
    mean = np.array([1.2, -0.7, 0.4, 0.3, -1.1])
    a = rng.normal(size=(5, 5))
    cov = a @ a.T / 5 + 0.1 * np.eye(5)
    u = np.array([0.05, 0.002, 0.03])
    got = predict(mean, cov, u, W, first_xy=(1.2, -0.7))
    want = predict_dense(mean, cov, u, W)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12, atol=1e-15)


def test_predict__fej_jacobians_chain_depends_only_on_the_end_points() -> None:
    """Huang et al.'s property: with x̂_{k|k−1} in every F, Φ(k, 0) = F_{k−1} ⋯ F_0 equals
    I + [−Δy, Δx, 0]ᵀ e₂ᵀ with Δ = x̂_{k|k−1} − x̂_0, whatever the updates did in between.
    Each F is recovered from the prediction itself: predicting a covariance whose only
    entries are the heading variance and the pose–landmark column exposes F's third column."""
    rng = np.random.default_rng(1)
    mean = np.zeros(4)  # pose and one landmark
    start = mean[:3].copy()
    chain = np.eye(3)
    first_xy: tuple[float, float] | None = None
    for _ in range(30):
        u = np.array([rng.uniform(0.0, 0.1), rng.normal(0.0, 0.005), rng.normal(0.0, 0.1)])
        probe = np.zeros((4, 4))
        probe[2, 3] = probe[3, 2] = 1.0  # cov(θ, c0) = 1: F P_pl gives F[:, 2]
        m = mean.copy()
        predict_inplace(m, probe, u, np.zeros((3, 3)), first_xy)
        F = np.eye(3)
        F[:2, 2] = probe[:2, 3]
        chain = F @ chain
        mean = m
        first_xy = (float(mean[0]), float(mean[1]))
        mean[:3] += rng.normal(0.0, [0.01, 0.01, 0.005])  # an update's correction
    delta = np.array(first_xy) - start[:2]
    want = np.eye(3)
    want[0, 2], want[1, 2] = -delta[1], delta[0]
    np.testing.assert_allclose(chain, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (3.0, -2.0, 0.7), (-12.0, 8.5, -2.9)])
def test_start_error_cov__is_the_composition_jacobian_times_p0(pose: tuple[float, ...]) -> None:
    """J = ∂(e ⊕ x)/∂e at e = 0 by central differences of :func:`compose`."""
    x = np.array(pose)
    J = np.column_stack(
        [fd_jacobian(lambda e, k=k: float(compose(e, x)[k]), np.zeros(3)) for k in range(3)]
    ).T
    np.testing.assert_allclose(start_error_cov(x, P0), J @ P0 @ J.T, rtol=FD_RTOL, atol=FD_ATOL)


def test_start_error_covs__each_pose_as_the_readable_product_bit_for_bit() -> None:
    """The compiled J P0 Jᵀ against the readable product of each pose on an FMA-based BLAS
    (:func:`~tests.slam.reference_floats.fma_matmul`, exact rationals: what numpy's matmul
    gave on the goldens' pinned OpenBLAS before the kernel), on random poses and full and
    diagonal P0s: the same floats, and the lone pose's form the same."""
    rng = np.random.default_rng(5)
    for trial in range(30):
        a = rng.normal(size=(3, 3))
        p0, poses = a @ a.T, rng.normal(scale=20.0, size=(4, 3))
        if trial % 3 == 0:
            p0 = np.diag(np.diag(p0))
        got = start_error_covs(poses, p0)
        for pose, cov in zip(poses, got, strict=True):
            J = np.array([[1.0, 0.0, -pose[1]], [0.0, 1.0, pose[0]], [0.0, 0.0, 1.0]])
            product = fma_matmul(fma_matmul(J, p0), J.T)
            np.testing.assert_array_equal(cov, 0.5 * (product + product.T), strict=True)
            np.testing.assert_array_equal(start_error_cov(pose, p0), cov)


def test_start_error_cov__matches_monte_carlo_of_the_start_offset() -> None:
    """Draw e ~ N(0, P0), compose with a pose 10 m out: the sample covariance of e ⊕ x lies
    within 4 standard errors of J P0 Jᵀ entrywise (first order: P0's heading σ is 1°, so the
    neglected second-order term is ~σ_θ² = 3e-4 relative)."""
    rng = np.random.default_rng(2)
    x = np.array([8.0, 6.0, 0.3])
    e = rng.multivariate_normal(np.zeros(3), P0, size=40_000)
    samples = np.array([compose(ei, x) for ei in e])
    want = start_error_cov(x, P0)
    got = np.cov(samples.T)
    se = np.sqrt((want**2 + np.outer(np.diag(want), np.diag(want))) / len(e))  # Wishart s.e.
    assert np.all(np.abs(got - want) <= 4 * se + 1e-3 * np.abs(want))


def test_robot__starts_certain_relative_to_its_true_start_and_reports_p0_in_its_frame() -> None:
    slam = PolySlam(SlamConfig(), np.deg2rad([90.0, 0.0, -90.0]), 5.0)
    np.testing.assert_array_equal(slam.pose_cov_relative, np.zeros((3, 3)))
    np.testing.assert_allclose(slam.pose_cov, P0, rtol=0, atol=0)


def test_robot__pose_covariance_never_below_the_propagated_p0_bound() -> None:
    """Driving in a square room, mapping its walls: P − J P0 Jᵀ stays PSD at every
    step (the filter's own P_S is a covariance), so the reported uncertainty never claims to
    know the unobservable start offset better than P0 does."""
    cfg = SlamConfig()
    slam = PolySlam(cfg, np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0]), 5.0)
    rng = np.random.default_rng(3)
    pose = np.zeros(3)
    for k in range(300):
        u = np.array([0.03, 0.0, 0.02 if k % 100 < 50 else -0.02])
        pose = compose(pose, u)
        # a square room 8 m a side around the start: the ranges to its walls, noisy
        ranges = _ranges_in_square(pose, slam.beam_angles, 4.0) + rng.normal(0, 0.02, 5)
        ranges[ranges > slam.max_range] = np.inf
        slam.step(u + rng.normal(0.0, [0.001, 0.001, np.radians(0.01)]), ranges)
        gap = slam.pose_cov - start_error_cov(slam.mean, cfg.p0)
        scale = float(np.abs(slam.pose_cov).max())
        assert np.linalg.eigvalsh(0.5 * (gap + gap.T)).min() >= -1e-12 * scale
    assert slam.n_landmarks > 0


def _ranges_in_square(pose: np.ndarray, angles: np.ndarray, half: float) -> np.ndarray:
    """Ranges (B,) from ``pose`` to the walls of the square [−half, half]², no limit."""
    phi = pose[2] + angles
    c, s = np.cos(phi), np.sin(phi)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (half - pose[0]) / c, (-half - pose[0]) / c)
        ty = np.where(s > 0, (half - pose[1]) / s, (-half - pose[1]) / s)
    return np.minimum(np.abs(tx), np.abs(ty))


def test_motion_jacobian_oracle_still_matches_finite_differences() -> None:
    """The oracle the FEJ test compares with (reference.motion_jacobians) is itself right."""
    pose, u = np.array([0.3, 0.2, 0.9]), np.array([0.05, 0.01, 0.02])
    F, _ = motion_jacobians(pose, u)
    F_fd = np.column_stack(
        [fd_jacobian(lambda p, k=k: float(compose(p, u)[k]), pose) for k in range(3)]
    ).T
    np.testing.assert_allclose(F, F_fd, rtol=FD_RTOL, atol=FD_ATOL)

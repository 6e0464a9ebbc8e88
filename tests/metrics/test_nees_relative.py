"""``nees_rel``: the filter's own NEES, relative to the true start, without the start offset."""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import between, compose, wrap_remainder
from polyslam_env.metrics.episode import RobotRun, nees_relative
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import start_error_cov


def test_nees_relative__is_the_mean_nees_against_the_filters_own_covariance() -> None:
    """A run whose reported covariances are P_S + J P0 Jᵀ, estimated relative to a true start
    offset from the frame by e₀: nees_rel is the mean of eᵀP_S⁻¹e over steps 1..K with e the
    error relative to the true start, computed here directly (and e₀ does not enter)."""
    rng = np.random.default_rng(0)
    p0 = SlamConfig().p0
    frame = np.array([2.0, 1.0, 0.3])
    e0 = np.array([0.04, -0.03, 0.015])
    true_start = compose(frame, e0)
    rel_truth = np.cumsum(rng.normal(0.0, [0.2, 0.05, 0.05], (20, 3)), axis=0)
    rel_truth[0] = 0.0
    p_s = [np.diag([1e-4, 2e-4, 1e-5]) * (k + 1) for k in range(20)]
    errors = np.array([rng.multivariate_normal(np.zeros(3), p) for p in p_s])
    est = rel_truth - errors
    covs = np.array([p + start_error_cov(e, p0) for p, e in zip(p_s, est, strict=True)])
    truth_abs = compose(true_start, rel_truth)
    run = RobotRun(frame, truth_abs, est, covs, [], np.zeros((0, 2)), np.zeros(19), False, 0, p0=p0)
    want = []
    for k in range(1, 20):
        e = between(true_start, truth_abs[k], wrap_remainder) - est[k]
        e[2] = wrap_remainder(float(e[2]))
        want.append(float(e @ np.linalg.solve(p_s[k], e)))
    assert abs(nees_relative(run) - np.mean(want)) < 1e-9 * np.mean(want)

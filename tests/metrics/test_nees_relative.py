"""``nees_rel``: the filter's own NEES, relative to the true start, without the start offset;
``start_nees``: that offset against P0."""

from __future__ import annotations

import numpy as np

import polyslam_env
from policies.base import make_team
from polyslam_env.apps.rollout import run_episode
from polyslam_env.core.geometry import between, compose, wrap_remainder
from polyslam_env.environment.parallel import PolySlamParallelEnv
from polyslam_env.metrics.episode import RobotRun, nees_relative, start_nees
from polyslam_env.metrics.pose import nees_band
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import start_error_cov
from tests.stats import standard_normal_failures


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


def test_start_nees__is_the_start_offset_against_p0() -> None:
    """start_nees = e₀ᵀP0⁻¹e₀ for the true start frame ⊕ e₀; 0 without a start-error model."""
    p0 = SlamConfig().p0
    frame = np.array([2.0, 1.0, 0.3])
    e0 = np.array([0.04, -0.03, 0.015])
    truth = compose(frame, e0)[None]
    run = RobotRun(frame, truth, np.zeros((1, 3)), p0[None], [], np.zeros((0, 2)), np.zeros(0),
                   False, 0, p0=p0)  # fmt: skip
    assert abs(start_nees(run) - e0 @ np.linalg.solve(p0, e0)) < 1e-9
    run.p0 = None
    assert start_nees(run) == 0.0


def test_start_nees__of_the_envs_start_draws_is_chi2_3() -> None:
    """The env draws each true start from P0 and the metric reads it back against P0: over 40
    seeded one-step episodes of 3 robots each value is e₀ᵀP0⁻¹e₀ of that robot's drawn offset
    (to rounding), the 120 offsets whitened by P0 pass the mean, per-axis and correlation checks
    of ``tests.stats.standard_normal_failures`` (offsets with x and y correlated have the same
    χ²(3) mean, so the mean alone could not see them; the correlation check catches full
    correlation at n = 120 with probability ≈ 1: R₀₁² ≈ 120 against χ²(3)'s 0.1 % tail 16.3), and
    their mean lies in the 99 % band of a mean of 120 χ²(3) values (a redraw where a robot does
    not fit is rare: 5 cm starts with clearance to spare)."""
    p0 = SlamConfig().p0
    chol = np.linalg.cholesky(p0)
    env = polyslam_env.parallel_env(map="paper", num_robots=3, max_steps=1)  # no generation
    values, whitened = [], []
    for seed in range(40):
        env.reset(seed=seed)
        state = env.unwrapped.episode
        e0 = between(state.start_poses, state.world.poses, wrap_remainder)  # (3, 3)
        _, _, _, _, infos = env.step({a: env.action_space(a).sample() * 0 for a in env.agents})
        got = [infos[a]["metrics"]["start_nees"] for a in infos]
        want = [float(e @ np.linalg.solve(p0, e)) for e in e0]
        np.testing.assert_allclose(got, want, rtol=1e-12)  # a 3 × 3 solve's rounding
        values += got
        whitened.append(np.linalg.solve(chol, e0.T).T)
    assert standard_normal_failures(np.concatenate(whitened)) == []
    lo, hi = nees_band(3, len(values), 0.99)
    assert lo <= np.mean(values) <= hi


def test_nees_relative__subtracts_exactly_the_start_share_the_report_added() -> None:
    """With the exchange on (a frontier team of 3 on the paper map meets within 150 steps),
    the covariance ``nees_rel`` uses at every step of every robot (the reported one minus
    J P0 Jᵀ at the reported estimate) is the filter's own ``pose_cov_relative`` of that step,
    to rounding: the exchange changes the filter's P_S, never the start share, so ``nees_rel``
    rising with the exchange is the filter's (its P_S after fusing received walls), not the
    metric's over-subtraction (docs/results/floors.md)."""
    env = polyslam_env.parallel_env(map="paper", max_steps=150, initial_error=True)
    own: list[list[np.ndarray]] = [[], [], []]

    def record(env: PolySlamParallelEnv) -> None:
        assert env.episode is not None
        if env.episode.step_count > 0:
            for i, slam in enumerate(env.episode.slams):
                own[i].append(slam.pose_cov_relative.copy())

    result = run_episode(env, make_team("frontier", env), 3, on_step=record)
    assert sum(m["rendezvous"] for m in result.robots.values()) > 0
    assert env.episode is not None
    p0 = SlamConfig().p0
    for i, history in enumerate(env.episode.histories):
        subtracted = history.cov[1:] - np.array([start_error_cov(e, p0) for e in history.est[1:]])
        np.testing.assert_allclose(subtracted, np.array(own[i]), rtol=0.0, atol=1e-12)

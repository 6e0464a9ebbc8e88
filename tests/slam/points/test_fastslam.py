"""The point back-ends as filters: weights, exactness without noise, NEES, consensus, seeds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from polyslam_env.core.seeding import make_rngs
from polyslam_env.slam.points import (
    PointFastSlam,
    PointSlamBackend,
    PointSlamConfig,
    SharedMapFastSlam,
    algorithm_config,
)
from polyslam_env.world.kinematic import KinematicEpisode, simulate_episode
from tests.slam.points.driving import SHORT_WORLD, drive, landmark_errors

BACKENDS = ("fastslam2", "em_fastslam", "mblcc", "multirobot_known_start")


def team(
    name: str, config: PointSlamConfig, episode: KinematicEpisode, seed: int
) -> list[PointSlamBackend]:
    starts = [r.initial_pose for r in episode.robots]
    rngs = make_rngs(seed, ["team", *(f"r{i}" for i in range(len(starts)))])
    if name == "multirobot_known_start":
        joint = SharedMapFastSlam(config, np.array(starts), rngs["team"])
        return [joint.robot(i) for i in range(len(starts))]
    cfg = algorithm_config(name, config)
    return [PointFastSlam(cfg, p, rngs[f"r{i}"], robot_id=i) for i, p in enumerate(starts)]


@pytest.mark.parametrize("name", BACKENDS)
def test_weights__stay_normalised_and_finite(name: str) -> None:
    episode = simulate_episode(SHORT_WORLD, seed=4)
    backends = team(name, PointSlamConfig(), episode, seed=4)

    def check(_: int, backend: PointSlamBackend) -> None:
        log_w = (
            backend.team.log_weights if name == "multirobot_known_start" else backend.log_weights
        )  # type: ignore[attr-defined]
        assert np.all(np.isfinite(log_w))
        assert np.exp(log_w).sum() == pytest.approx(1.0, abs=1e-12)  # ≤ N ulp-sized roundings
        mean, cov = backend.pose()
        assert np.all(np.isfinite(mean)) and np.all(np.linalg.eigvalsh(cov) > -1e-12)

    drive(backends, episode, after_step=check)


@pytest.mark.parametrize("name", BACKENDS)
def test_noise_free_motion_and_sensing__recover_landmarks_exactly(name: str) -> None:
    """Exact controls, a filter that knows the motion is exact (σ_V = σ_G = 0) and exact
    measurements: every particle stays on the true path and every landmark EKF starts at and
    stays on the truth. The bound 1e-9 m is float rounding of ~2500 car steps and trig on
    30 m ranges (≈ 1e-13 m each), with margin."""
    world = SHORT_WORLD.replace(sigma_v=0.0, sigma_g_deg=0.0, sigma_r=0.0, sigma_b_deg=0.0)
    episode = simulate_episode(world, seed=1)
    backends = team(name, PointSlamConfig(sigma_v=0.0, sigma_g_deg=0.0), episode, seed=1)
    drive(backends, episode)
    for backend, robot in zip(backends, episode.robots, strict=True):
        assert len(backend.landmarks().ids) > 10
        assert landmark_errors(backend, episode.landmarks).max() < 1e-9
        assert np.abs(backend.pose()[0][:2] - robot.true_poses[-1, :2]).max() < 1e-9


def test_fastslam2_landmark_ekfs__pass_nees_with_known_poses() -> None:
    """With exact poses each landmark EKF is a plain EKF; over M runs the final errors'
    NEES e'Σ⁻¹e summed over all L landmarks is χ²(2L) if the filter is consistent (runs and,
    given the poses, landmarks are independent). Check it lies in the two-sided 95 % χ²
    interval. One robot, one particle (with σ_V = σ_G = 0 all particles are equal anyway)."""
    world = SHORT_WORLD.replace(
        sigma_v=0.0, sigma_g_deg=0.0, paths=SHORT_WORLD.paths[:1], speeds=(4.0,)
    )
    config = PointSlamConfig(particles=1, sigma_v=0.0, sigma_g_deg=0.0)
    total, count = 0.0, 0
    for seed in range(20):
        episode = simulate_episode(world, seed)
        robot = episode.robots[0]
        slam = PointFastSlam(config, robot.initial_pose, np.random.default_rng(seed))
        drive([slam], episode)
        lm = slam.landmarks()
        err = lm.means - episode.landmarks[lm.ids]
        total += float(np.einsum("mi,mij,mj->", err, np.linalg.inv(lm.covs), err))
        count += len(lm.ids)
    low, high = chi2.ppf([0.025, 0.975], 2 * count)
    assert low < total < high, f"mean NEES {total / count:.3f} per landmark (2 expected)"


def test_consensus_with_zero_step__equals_the_independent_filters() -> None:
    episode = simulate_episode(SHORT_WORLD, seed=2)
    config = algorithm_config("em_fastslam")
    apart = team("em_fastslam", config, episode, seed=2)
    drive(apart, episode, exchange=False)
    zero = team("em_fastslam", config.replace(consensus_step=0.0), episode, seed=2)
    drive(zero, episode, exchange=True)
    pulled = team("mblcc", config, episode, seed=2)
    drive(pulled, episode, exchange=True)
    for a, b, c in zip(apart, zero, pulled, strict=True):
        np.testing.assert_array_equal(a.landmarks().means, b.landmarks().means)
        np.testing.assert_array_equal(a.pose()[0], b.pose()[0])
        assert not np.array_equal(a.landmarks().means, c.landmarks().means)


@pytest.mark.parametrize("name", BACKENDS)
def test_seeded_runs__are_bit_identical(name: str) -> None:
    results = []
    for _ in range(2):
        episode = simulate_episode(SHORT_WORLD, seed=7)
        backends = team(name, PointSlamConfig(), episode, seed=7)
        drive(backends, episode)
        results.append([(b.pose()[0], b.landmarks().means) for b in backends])
    for (p1, m1), (p2, m2) in zip(*results, strict=True):
        np.testing.assert_array_equal(p1, p2)
        np.testing.assert_array_equal(m1, m2)

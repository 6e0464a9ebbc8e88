"""The kinematic world of seed 003: routes, episodes, seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.world.kinematic import KinematicConfig, simulate_episode, true_route


@pytest.mark.parametrize("robot", range(3))
def test_true_route__reaches_every_waypoint_within_the_steering_limits(robot: int) -> None:
    config = KinematicConfig()
    commands, poses = true_route(config, robot)
    path = np.asarray(config.paths[robot])
    for waypoint in path[1:]:
        assert np.hypot(*(poses[:, :2] - waypoint).T).min() < config.waypoint_radius
    assert np.all(commands[:, 0] == config.speeds[robot])
    assert np.abs(commands[:, 1]).max() <= math.radians(config.max_steer_deg) + 1e-12
    rate = np.abs(np.diff(commands[:, 1])).max() / config.dt
    assert rate <= math.radians(config.steer_rate_deg) + 1e-9
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    np.testing.assert_allclose(step, config.speeds[robot] * config.dt, rtol=1e-12)


def test_episode__bit_identical_for_a_seed_and_different_across_seeds() -> None:
    a, b, c = (simulate_episode(KinematicConfig(), s) for s in (5, 5, 6))
    np.testing.assert_array_equal(a.landmarks, b.landmarks)
    for ra, rb in zip(a.robots, b.robots, strict=True):
        np.testing.assert_array_equal(ra.controls, rb.controls)
        for (ia, za), (ib, zb) in zip(ra.sweeps, rb.sweeps, strict=True):
            np.testing.assert_array_equal(ia, ib)
            np.testing.assert_array_equal(za, zb)
    assert not np.array_equal(a.landmarks, c.landmarks)


def test_episode__sweeps_every_observe_every_periods_from_the_true_poses() -> None:
    config = KinematicConfig()
    episode = simulate_episode(config, 0)
    for r, robot in enumerate(episode.robots):
        commands, poses = true_route(config, r)
        k = config.observe_every
        assert robot.controls.shape == (len(commands) // k, k, 2)
        np.testing.assert_array_equal(robot.true_poses[0], poses[k])
        noise = robot.controls.reshape(-1, 2) - commands[: robot.controls.size // 2]
        # ≈ 2500 draws: the sample std has relative standard error ≈ 1.4 %; 10 % is 7 of them
        assert abs(noise[:, 0].std() - config.sigma_v) < 0.1 * config.sigma_v
        assert all(len(ids) > 0 for ids, _ in robot.sweeps)  # the field keeps landmarks in view


def test_config__rejects_mismatched_speeds_and_paths() -> None:
    with pytest.raises(ConfigError, match="speeds"):
        KinematicConfig(speeds=(4.0,))

"""The centralised Gymnasium env ``polyslam/Team-v0``: checkers, registration, team semantics."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import polyslam_env  # registers the Gymnasium ids
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.team import TEAM_ENV_ID, TeamEnv

SMALL = {"map": "two_rooms", "num_robots": 2, "max_steps": 15}


def test_team_env__passes_gymnasium_check_env() -> None:
    env = TeamEnv(**SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the non-normalised Box action space warning
        check_env(env, skip_render_check=True)


def test_team_env__passes_sb3_check_env() -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the non-normalised Box action space warning
        sb3_check_env(TeamEnv(**SMALL), warn=False)


def test_gymnasium_make__builds_team_env_with_overrides() -> None:
    env = gymnasium.make(TEAM_ENV_ID, **SMALL)
    assert isinstance(env.unwrapped, TeamEnv)
    obs, _ = env.reset(seed=0)
    assert env.unwrapped.par_env.config.num_robots == 2
    assert obs.shape == env.observation_space.shape
    assert env.action_space.shape == (4,)
    env.close()


def test_team_env__observation_is_robots_in_order_and_reward_is_sum() -> None:
    env = TeamEnv(**SMALL)
    par = polyslam_env.parallel_env(**SMALL)
    obs, _ = env.reset(seed=3)
    pobs, _ = par.reset(seed=3)
    np.testing.assert_array_equal(obs, np.concatenate([pobs["robot_0"], pobs["robot_1"]]))
    action = np.array([0.2, 0.5, 0.1, -0.3], dtype=np.float32)
    obs, reward, *_ = env.step(action)
    pobs, prew, *_ = par.step({"robot_0": action[:2], "robot_1": action[2:]})
    np.testing.assert_array_equal(obs, np.concatenate([pobs["robot_0"], pobs["robot_1"]]))
    assert reward == pytest.approx(prew["robot_0"] + prew["robot_1"], rel=1e-12)  # float sum


def test_team_env__mean_reward_is_sum_over_robots() -> None:
    rng = np.random.default_rng(0)
    total, mean = TeamEnv(**SMALL), TeamEnv(team_reward="mean", **SMALL)
    total.reset(seed=1)
    mean.reset(seed=1)
    for _ in range(5):
        a = rng.uniform(-1, 1, 4).astype(np.float32) * total.action_space.high
        r_sum = total.step(a)[1]
        r_mean = mean.step(a)[1]
        assert r_mean == pytest.approx(r_sum / 2, rel=1e-12)  # same episode, only the division


def test_team_env__truncates_at_max_steps_with_team_metrics() -> None:
    env = TeamEnv(**SMALL)
    env.reset(seed=0)
    zero = np.zeros(4, dtype=np.float32)
    for k in range(1, 16):
        _, _, terminated, truncated, info = env.step(zero)
        assert (terminated, truncated) == (False, k == 15)
    assert "coverage" in info["team"]
    with pytest.raises(RuntimeError, match="reset"):
        env.step(zero)


def test_team_env__failed_robot_gets_zero_observation_and_actions_ignored() -> None:
    env = TeamEnv(**{**SMALL, "faults": [[1, 3]]})
    obs, _ = env.reset(seed=0)
    d = obs.shape[0] // 2
    a = np.array([0.2, 0.0, 0.2, 0.0], dtype=np.float32)
    for k in range(1, 6):
        obs, _, terminated, truncated, info = env.step(a)
        assert not (terminated or truncated)
        assert np.any(obs[:d] != 0.0)
        assert np.all(obs[d:] == 0.0) == (k >= 3)
        assert ("robot_1" in info["robots"]) == (k <= 3)


def test_team_env__rejects_discrete_actions() -> None:
    with pytest.raises(ConfigError, match="action.mode"):
        TeamEnv(action__mode="discrete", **SMALL)

"""``ppo_drive``: the run-time loop is the training env's, and checkpoints of another kind are
refused with one line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import polyslam_env
from policies.base import CheckpointError, PolicyContext, make_team
from policies.drive import DrivePolicy
from polyslam_env.apps.drive_env import DriveEnv
from polyslam_env.environment.config import EnvConfig

SMALL = {"map": "generator:office_floor", "num_robots": 2, "max_steps": 24, "slam_enabled": False}


def _tiny_model(env: DriveEnv, path: Path) -> Path:
    from stable_baselines3 import PPO

    from polyslam_env.environment.vector import vectorise

    venv = vectorise(env, 1)
    PPO("MlpPolicy", venv, n_steps=8, batch_size=8, seed=0, policy_kwargs={"net_arch": [8]}).save(
        path
    )
    venv.close()
    return path


def test_ppo_drive__plays_the_training_envs_episode(tmp_path: Path) -> None:
    # The network's mean action fed to the training env, against DrivePolicy on the plain env
    # with the same episode seed: the same coverage series, bit for bit (progress weight 0,
    # so the rewards are the env's own and must match too).
    cfg = EnvConfig.from_dict(SMALL)
    ckpt = _tiny_model(DriveEnv([cfg]), tmp_path / "drive.zip")
    train = DriveEnv([cfg], progress=0.0)
    obs: Any
    obs, _ = train.reset(seed=5)
    policy = DrivePolicy(PolicyContext.from_env(train.env, "robot_0"), ckpt)
    rng = np.random.default_rng(0)
    totals = dict.fromkeys(train.possible_agents, 0.0)
    while train.agents:
        obs, rew, *_ = train.step({a: policy.unit_action(obs[a], rng) for a in train.agents})
        for a, r in rew.items():
            totals[a] += r
    env = polyslam_env.parallel_env(cfg)
    team = make_team("ppo_drive", env, checkpoint=ckpt)
    obs, _ = env.reset(seed=train.episode_seed)
    team.reset(train.episode_seed)
    plain = dict.fromkeys(env.possible_agents, 0.0)
    while env.agents:
        obs, rew, *_ = env.step(team.act(obs, rng))
        for a, r in rew.items():
            plain[a] += float(r)
    assert train.env.episode is not None and env.episode is not None
    assert train.env.episode.coverage_series == env.episode.coverage_series
    assert totals == plain


def test_ppo_drive__a_checkpoint_of_another_kind_is_refused_with_one_line(tmp_path: Path) -> None:
    from stable_baselines3 import PPO

    from polyslam_env.environment.vector import make_vec_env

    venv = make_vec_env({**SMALL, "max_steps": 5}, 1)
    ckpt = tmp_path / "velocity.zip"
    PPO("MlpPolicy", venv, n_steps=8, batch_size=8, policy_kwargs={"net_arch": [8]}).save(ckpt)
    venv.close()
    env = polyslam_env.parallel_env(EnvConfig.from_dict(SMALL))
    with pytest.raises(CheckpointError, match="not a driving network") as err:
        make_team("ppo_drive", env, checkpoint=ckpt)
    assert "\n" not in str(err.value)

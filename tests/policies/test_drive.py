"""``ppo_drive``: the run-time loop is the training env's, and checkpoints of another kind are
refused with one line."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import polyslam_env
from policies.base import CheckpointError, PolicyContext, make_team
from policies.drive import FEATURES, DrivePolicy, TeamDriveGuide, TeamDrivePolicy
from policies.radio import Radio
from polyslam_env.apps.drive_env import DriveEnv
from polyslam_env.environment.config import EnvConfig
from tests.policies.test_team import corridor_maps

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


@pytest.mark.parametrize(("team", "name"), [(False, "ppo_drive"), (True, "ppo")])
def test_ppo_drive__plays_the_training_envs_episode(tmp_path: Path, team: bool, name: str) -> None:
    # The network's mean action fed to the training env, against the registered policy on the
    # plain env with the same episode seed: the same coverage series, bit for bit (progress
    # weight 0, so the rewards are the env's own and must match too). With team guides
    # (--policy ppo) the goal messages sent and heard must match as well.
    cfg = EnvConfig.from_dict(SMALL)
    ckpt = _tiny_model(DriveEnv([cfg]), tmp_path / "drive.zip")
    train = DriveEnv([cfg], progress=0.0, team=team)
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
    played = make_team(name, env, checkpoint=ckpt)
    assert all(isinstance(p, TeamDrivePolicy) == team for p in played.policies.values())
    obs, _ = env.reset(seed=train.episode_seed)
    played.reset(train.episode_seed)
    plain = dict.fromkeys(env.possible_agents, 0.0)
    while env.agents:
        obs, rew, *_ = env.step(played.act(obs, rng))
        for a, r in rew.items():
            plain[a] += float(r)
    assert train.env.episode is not None and env.episode is not None
    assert train.env.episode.coverage_series == env.episode.coverage_series
    assert totals == plain
    guides = train.guides[train._current]
    assert [guides[a].metrics() for a in env.possible_agents] == [
        p.metrics() for p in played.policies.values()
    ]
    if team:  # one radio for the team (messages: test_team_drive_guide__...)
        first, second = played.policies.values()
        assert isinstance(first, TeamDrivePolicy) and isinstance(second, TeamDrivePolicy)
        assert first.radio is second.radio


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


def _sensing(guide: TeamDriveGuide, pose: np.ndarray, sees: np.ndarray) -> None:
    """Make ``guide``'s next observations read ``pose`` (3,) and camera detections ``sees``
    (k, 2), no beam return (its own map is the test's)."""

    def sense(observation: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        guide._step += 1
        return pose, np.full(len(guide.context.beam_angles), np.inf), sees

    guide._sense = sense  # type: ignore[method-assign]


@pytest.mark.parametrize("mutual", [False, True])
def test_team_drive_guide__hears_a_mates_goal_and_its_path_points_elsewhere(
    mutual: bool,
) -> None:
    """The corridor of tests/policies/test_team.py, through the guides' own step (observe):
    robot 0 plans for the left end and announces it while it sees robot 1; robot 1, at the
    next step, hears it only if it saw robot 0 at that step too (a mutual sighting), and then
    heads for the right end: the path point its network sees lies ahead (+x), not behind."""
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=2)
    radio = Radio(2)
    first, second = (
        TeamDriveGuide(PolicyContext.from_env(env, a), radio=radio) for a in env.possible_agents
    )
    corridor_maps(first, second)
    pose_0, pose_1 = np.array([-1.6, 0.4, 0.0]), np.array([-1.6, -0.4, 0.0])
    sees_1 = np.array([[0.8, -0.5 * math.pi]])  # robot 0 sees robot 1 0.8 m to its right
    sees_0 = np.array([[0.8, 0.5 * math.pi]]) if mutual else np.zeros((0, 2))
    _sensing(first, pose_0, sees_1)
    _sensing(second, pose_1, sees_0)
    first.observe(None)
    assert first.goal is not None and first.map.centre(*first.goal)[0] < 0  # the left end
    assert radio.messages_sent[0] == 1
    second.observe(None)  # step 1: robot 0's message is of this step, heard at the next
    second.observe(None)
    assert second.goal is not None
    goes_right = second.map.centre(*second.goal)[0] > 0
    assert goes_right == mutual
    assert second.metrics()["goal_messages_received"] == float(mutual)
    far_cos = second.features()[len(second.context.beam_angles) + FEATURES.index("far_cos")]
    assert (far_cos > 0) == mutual  # the network is shown the way to the heard-free end

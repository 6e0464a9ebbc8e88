"""The goal-choice training env: PettingZoo's API, one step per decision, and the same
episode as the shipped policy's run-time loop."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import polyslam_env
from policies.base import PolicyContext
from policies.goals import CANDIDATES, GoalPolicy, feature_size
from polyslam_env.apps.goal_env import GoalChoiceEnv
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig

SMALL = {"map": "generator:office_floor", "num_robots": 2, "max_steps": 48}


def _config(**kwargs: object) -> EnvConfig:
    return EnvConfig.from_dict({**SMALL, **kwargs})


def test_goal_env__passes_pettingzoo_parallel_api_test() -> None:
    parallel_api_test(GoalChoiceEnv([_config()]), num_cycles=8)


def test_goal_env__one_step_is_decide_every_env_steps() -> None:
    env = GoalChoiceEnv([_config()], decide_every=8)
    obs, _ = env.reset(seed=1)
    assert set(obs) == set(env.possible_agents)
    assert all(o.shape == (feature_size(),) for o in obs.values())
    steps = []
    while env.agents:
        env.step(dict.fromkeys(env.agents, 0))
        assert env.env.episode is not None
        steps.append(env.env.episode.step_count)
    assert steps == [8, 16, 24, 32, 40, 48]
    assert env.action_space("robot_0").n == CANDIDATES


def test_goal_env__an_episode_is_the_run_time_loop_of_goal_policy() -> None:
    # Slot 0 every decision in the training env, against GoalPolicy.act (which picks slot 0)
    # on the plain env with the same episode seed: same rewards and coverage, bit for bit.
    goals = GoalChoiceEnv([_config()])
    goals.reset(seed=3)
    assert goals.episode_seed is not None
    totals = dict.fromkeys(goals.possible_agents, 0.0)
    while goals.agents:
        _, rewards, *_ = goals.step(dict.fromkeys(goals.agents, 0))
        for a, r in rewards.items():
            totals[a] += r
    env = polyslam_env.parallel_env(_config())
    obs, _ = env.reset(seed=goals.episode_seed)
    team = {a: GoalPolicy(PolicyContext.from_env(env, a)) for a in env.possible_agents}
    rng = np.random.default_rng(0)
    plain = dict.fromkeys(env.possible_agents, 0.0)
    while env.agents:
        chunk = dict.fromkeys(env.possible_agents, 0.0)  # summed per decision, as goals does
        for _ in range(goals.decide_every):
            obs, rewards, *_ = env.step({a: team[a].act(obs[a], rng) for a in env.agents})
            for a, r in rewards.items():
                chunk[a] += float(r)
        for a in plain:
            plain[a] += chunk[a]
    assert totals == plain
    assert goals.env.episode is not None and env.episode is not None
    assert goals.env.episode.coverage_series == env.episode.coverage_series


def test_goal_env__episodes_draw_maps_and_seeds_below_the_limit() -> None:
    env = GoalChoiceEnv([_config(), _config(map="generator:warehouse")], seed_limit=50)
    env.reset(seed=0)
    picked, seeds = set(), set()
    for _ in range(12):
        env.reset()
        picked.add(env._current)
        assert env.episode_seed is not None
        seeds.add(env.episode_seed)
    assert picked == {0, 1}
    assert max(seeds) < 50


def test_goal_env__same_seed_same_decisions_and_rewards() -> None:
    runs = []
    for _ in range(2):
        env = GoalChoiceEnv([_config()])
        obs, _ = env.reset(seed=11)
        trace = [obs["robot_0"]]
        while env.agents:
            obs, rew, *_ = env.step({a: k % CANDIDATES for k, a in enumerate(env.agents)})
            trace += [obs["robot_0"], np.array([rew["robot_1"]])]
        runs.append(np.concatenate(trace))
    assert np.array_equal(*runs)


@pytest.mark.parametrize(
    ("configs", "match"),
    [
        ([], "no env config"),
        ([_config(), _config(num_robots=3)], "same num_robots"),
        ([_config(faults=[[1, 5]])], "faults"),
    ],
)
def test_goal_env__bad_configs_are_named(configs: list[EnvConfig], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        GoalChoiceEnv(configs)

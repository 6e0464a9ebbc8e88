"""Envs pickle (for SubprocVecEnv, Ray, multiprocessing), before and after ``reset``.

A restored env is not just loadable: mid-episode it continues exactly as the original does.
"""

from __future__ import annotations

import pickle
from typing import Any

import cloudpickle
import gymnasium
import numpy as np
import pytest

import polyslam_env

DUMPERS = [
    pytest.param((pickle.dumps, pickle.loads), id="pickle"),
    pytest.param((cloudpickle.dumps, cloudpickle.loads), id="cloudpickle"),
]


def _actions(env: Any, k: int) -> dict[str, np.ndarray]:
    """Deterministic actions that drive the robots around (so the world state matters)."""
    return {
        a: np.array([0.1, 0.4 * np.sin(0.3 * k + i)], dtype=np.float32)
        for i, a in enumerate(env.agents)
    }


@pytest.mark.parametrize("dumper", DUMPERS)
def test_parallel_env__pickles_constructed_and_mid_episode(dumper: Any) -> None:
    dumps, loads = dumper
    env = polyslam_env.parallel_env(map="two_rooms", max_steps=60, coverage_target=None)
    fresh = loads(dumps(env))
    assert fresh.possible_agents == env.possible_agents
    env.reset(seed=11)
    for k in range(10):
        env.step(_actions(env, k))
    copy = loads(dumps(env))
    for k in range(10, 40):
        a, b = env.step(_actions(env, k)), copy.step(_actions(copy, k))
        for agent in a[0]:
            np.testing.assert_array_equal(a[0][agent], b[0][agent])
        assert a[1:4] == b[1:4]
        assert [i["reward_terms"] for i in a[4].values()] == [
            i["reward_terms"] for i in b[4].values()
        ]


@pytest.mark.parametrize("dumper", DUMPERS)
def test_aec_env__pickles_constructed_and_after_reset(dumper: Any) -> None:
    dumps, loads = dumper
    env = polyslam_env.env(map="two_rooms")
    loads(dumps(env))
    env.reset(seed=2)
    copy = loads(dumps(env))
    for _ in range(6):
        agent = env.agent_selection
        assert copy.agent_selection == agent
        action = np.array([0.05, 0.1], dtype=np.float32)
        env.step(action)
        copy.step(action)
    np.testing.assert_array_equal(env.observe(agent), copy.observe(agent))


@pytest.mark.parametrize("dumper", DUMPERS)
def test_gymnasium_team_env__pickles_constructed_and_after_reset(dumper: Any) -> None:
    dumps, loads = dumper
    env = gymnasium.make("polyslam/Team-v0", map="two_rooms")
    loads(dumps(env))
    env.reset(seed=4)
    copy = loads(dumps(env))
    action = env.action_space.sample()
    a, b = env.step(action), copy.step(action)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1:4] == b[1:4]


def test_env_factory_closure__cloudpickles_by_value() -> None:
    """What SubprocVecEnv and Ray ship to workers: a closure over the package module, pickled
    by value. (This failed while the package swapped its module class.)"""

    def make_factory() -> Any:
        return lambda: polyslam_env.parallel_env(map="two_rooms")

    factory = cloudpickle.loads(cloudpickle.dumps(make_factory()))
    env = factory()
    observations, _ = env.reset(seed=0)
    assert set(observations) == set(env.possible_agents)

"""Reward terms are pure functions of the stages' outputs; combine weights them."""

from __future__ import annotations

import copy

import numpy as np

from polyslam_env.environment import stages
from polyslam_env.environment.config import RewardConfig
from polyslam_env.environment.parallel import REWARD_TERMS, parallel_env
from polyslam_env.environment.rewards import MapChanges, combine, reward_terms
from polyslam_env.environment.state import EpisodeState


def _fingerprint(state: EpisodeState) -> tuple:
    """What the reward bookkeeping could touch: coverage grid, series, completeness, bytes."""
    grid = state.coverage
    return (
        grid.swept.tobytes(),
        list(state.coverage_series),
        list(state.completeness),
        list(state.bytes_sent),
        [dict(state.exchange.counters(i)) for i in range(2)] if state.exchange else None,
    )


def test_reward_terms__are_pure_same_terms_twice_and_state_unchanged() -> None:
    env = parallel_env(map="two_rooms", num_robots=2)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(3):
        env.step({a: rng.uniform([0.0, -0.5], [0.2, 0.5]) for a in env.agents})
    state = env.episode
    assert state is not None
    acting = {"robot_0": 0, "robot_1": 1}
    collided = np.array([True, False])
    gains = np.array([0.25, 0.0])
    changes = MapChanges({0: 0.1, 1: 0.0}, {0: 120, 1: 0})
    before = _fingerprint(state)
    inputs = copy.deepcopy((collided, gains, changes))
    first = reward_terms(acting, collided, gains, changes)
    second = reward_terms(acting, collided, gains, changes)
    assert first == second
    assert _fingerprint(state) == before
    np.testing.assert_array_equal(collided, inputs[0])
    np.testing.assert_array_equal(gains, inputs[1])
    assert changes == inputs[2]
    assert tuple(first["robot_0"]) == REWARD_TERMS
    assert first["robot_0"] == {
        "coverage": 0.25,
        "mapping": 0.1,
        "bytes": -0.12,
        "collision": -1.0,
        "time": -1.0,
    }


def test_sweep_coverage__gains_once_then_nothing_new_from_the_same_pose() -> None:
    env = parallel_env(map="two_rooms", num_robots=2)
    env.reset(seed=1)
    state = env.episode
    assert state is not None
    assert len(state.coverage_series) == 1  # the sweep at reset
    again = stages.sweep_coverage(state)  # same poses and ranges as the reset sweep
    assert again.tolist() == [0.0, 0.0]
    assert len(state.coverage_series) == 2


def test_map_bookkeeping__returns_the_changes_it_applied() -> None:
    env = parallel_env(map="paper", max_steps=40)
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    seen_change = False
    while env.agents:
        _, _, _, _, infos = env.step(
            {a: rng.uniform(env.action_space(a).low, env.action_space(a).high) for a in env.agents}
        )
        state = env.episode
        assert state is not None
        for agent, info in infos.items():
            i = int(agent.split("_")[1])
            assert -info["reward_terms"]["bytes"] * 1000.0 >= 0.0
            seen_change |= info["reward_terms"]["mapping"] != 0.0
            if state.exchange is not None:
                assert state.bytes_sent[i] == state.exchange.counters(i)["bytes_sent"]
    assert seen_change


def test_combine__weights_terms_and_shares_the_mean() -> None:
    terms = {
        "robot_0": {"coverage": 1.0, "mapping": 0.0, "bytes": 0.0, "collision": -1.0, "time": -1.0},
        "robot_1": {"coverage": 0.0, "mapping": 0.5, "bytes": 0.0, "collision": 0.0, "time": -1.0},
    }
    weights = RewardConfig()
    own = combine(terms, weights)
    for agent, t in terms.items():
        assert own[agent] == sum(getattr(weights, k) * v for k, v in t.items())
    shared = combine(terms, RewardConfig(shared=True))
    assert shared["robot_0"] == shared["robot_1"] == float(np.mean(list(own.values())))

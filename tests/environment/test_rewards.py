"""Reward terms are pure functions of the stages' outputs; combine weights them."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from polyslam_env.environment import stages
from polyslam_env.environment.config import RewardConfig
from polyslam_env.environment.parallel import REWARD_TERMS, parallel_env
from polyslam_env.environment.rewards import MapChanges, combine, reward_terms
from polyslam_env.environment.state import EpisodeState
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import SlamStepInfo


def _fingerprint(state: EpisodeState) -> tuple:
    """What the reward bookkeeping could touch: coverage grid, series, completeness, bytes."""
    grid = state.coverage
    return (
        grid.swept.tobytes(),
        list(state.coverage_series),
        list(state.completeness),
        list(state.map_error),
        list(state.bytes_sent),
        [dict(state.exchange.counters(i)) for i in range(2)] if state.exchange else None,
    )


def test_reward_terms__are_pure_same_terms_twice_and_state_unchanged() -> None:
    env = parallel_env(map="two_rooms", num_robots=2, initial_error=False)  # starts as stated
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(3):
        env.step({a: rng.uniform([0.0, -0.5], [0.2, 0.5]) for a in env.agents})
    state = env.episode
    assert state is not None
    acting = {"robot_0": 0, "robot_1": 1}
    collided = np.array([True, False])
    gains = np.array([0.25, 0.0])
    changes = MapChanges({0: 0.1, 1: 0.0}, {0: 120, 1: 0}, {0: 0.02, 1: 0.0})
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
        "map_error": -0.02,
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
        "robot_2": {"coverage": 0.0, "map_error": -0.3, "time": -1.0},
    }
    weights = RewardConfig()
    own = combine(terms, weights)
    for agent, t in terms.items():
        assert own[agent] == sum(getattr(weights, k) * v for k, v in t.items())
    shared = combine(terms, RewardConfig(shared=True))
    assert shared["robot_0"] == shared["robot_1"] == float(np.mean(list(own.values())))


# -- the map_error term -------------------------------------------------------------------------
#: Robot 0 of ``two_rooms`` starts at (0.5, 0.5) facing +x: in its frame the true wall y = 0 is
#: y = −0.5, and over ξ ∈ [0, 1.5] (x from 0.5 to 2 m) every other wall is ≥ 0.5 m away.
_WALL_C0, _LENGTH = -0.5, 1.5
_CHANGED = SlamStepInfo(0, 0.0, 1, 5, 1, 0, 0, 0.08, 0.1, 0.0, False)  # one landmark created


def _line(offset: float) -> list[Polynomial]:
    """One straight polynomial parallel to the wall y = 0, ``offset`` m inside the room."""
    return [Polynomial(1, np.array([_WALL_C0 + offset, 0.0, 0.0, 0.0]), 0.0, _LENGTH)]


def _map_error_term(
    state: EpisodeState, monkeypatch: pytest.MonkeyPatch, offset: float, info: SlamStepInfo | None
) -> float:
    """The unweighted map_error term of robot 0 after its map becomes ``_line(offset)``."""
    monkeypatch.setattr(state.slams[0], "polynomials", lambda: _line(offset))
    acting = {"robot_0": 0}
    changes = stages.map_bookkeeping(state, acting, [info, None], None)
    terms = reward_terms(acting, np.zeros(2, bool), np.zeros(2), changes)
    return terms["robot_0"]["map_error"]


def _fresh_state() -> EpisodeState:
    env = parallel_env(map="two_rooms", num_robots=2, initial_error=False)  # starts as stated
    env.reset(seed=0)
    assert env.episode is not None
    return env.episode


def test_map_error_term__worse_map_negative_better_positive_unchanged_zero(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from polyslam_env.environment.rewards import MAPPING_STEP

    state = _fresh_state()
    # On the wall: δ = 0 at every sample (1e-12 m: float round-off of the transform).
    assert abs(_map_error_term(state, monkeypatch, 0.0, _CHANGED)) < 1e-12
    # 0.2 m off: ∫δ ds grows by 0.2 m times the sampled length, which is the length rounded up
    # to whole samples: n = ⌊L/step⌋ + 1 samples of `step` each, so between L and L + step.
    worse = _map_error_term(state, monkeypatch, 0.2, _CHANGED)
    assert -0.2 * (_LENGTH + MAPPING_STEP) - 1e-12 <= worse <= -0.2 * _LENGTH
    # Back on the wall: the same amount back, positive.
    assert _map_error_term(state, monkeypatch, 0.0, _CHANGED) == pytest.approx(-worse, abs=1e-12)
    # A step without a structural map change is not re-evaluated: exactly 0 …
    assert _map_error_term(state, monkeypatch, 0.3, None) == 0.0
    no_change = _CHANGED._replace(created=0)
    assert _map_error_term(state, monkeypatch, 0.3, no_change) == 0.0
    # … and re-evaluating an unchanged map gives exactly 0 as well.
    _map_error_term(state, monkeypatch, 0.1, _CHANGED)
    assert _map_error_term(state, monkeypatch, 0.1, _CHANGED) == 0.0


def test_map_error_term__a_step_whose_only_change_is_a_link_is_re_evaluated(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A link turns stored lines (slam/links.py): a structural change like a refit, so the
    step's map is evaluated again, here 0.2 m off: the same −0.2 m × length as above."""
    from polyslam_env.environment.rewards import MAPPING_STEP

    state = _fresh_state()
    _map_error_term(state, monkeypatch, 0.0, _CHANGED)
    only_linked = _CHANGED._replace(created=0, linked=1)
    worse = _map_error_term(state, monkeypatch, 0.2, only_linked)
    assert -0.2 * (_LENGTH + MAPPING_STEP) - 1e-12 <= worse <= -0.2 * _LENGTH


def test_map_error_term__deleting_a_correct_map_earns_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    state = _fresh_state()
    _map_error_term(state, monkeypatch, 0.0, _CHANGED)
    monkeypatch.setattr(state.slams[0], "polynomials", lambda: [])
    changes = stages.map_bookkeeping(state, {"robot_0": 0}, [_CHANGED, None], None)
    assert abs(changes.map_error[0]) < 1e-12  # the map had no error to remove
    assert changes.completeness[0] < 0.0  # but the mapping term loses its completeness


def test_map_error_term__weight_zero_removes_it() -> None:
    terms = {"robot_0": {"coverage": 0.5, "map_error": -0.7, "time": -1.0}}
    without = {"robot_0": {"coverage": 0.5, "time": -1.0}}
    assert combine(terms, RewardConfig(map_error=0.0)) == combine(without, RewardConfig())
    assert combine(terms, RewardConfig())["robot_0"] < combine(without, RewardConfig())["robot_0"]

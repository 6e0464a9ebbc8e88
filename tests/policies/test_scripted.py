"""Scripted policies: oracles (coverage, collisions, paper paths) and the policy plumbing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import polyslam_env
from policies import PolicyContext, PolicyError, TeamPolicy, make_policy, make_team
from policies.frontier import OwnMap
from polyslam_env.apps.rollout import EpisodeResult, run_episode
from polyslam_env.core.errors import PolyslamError
from polyslam_env.scenarios.paths import load_paths
from polyslam_env.world.replay import replay_paths


def _episode(policy: str, seed: int, **overrides: object) -> EpisodeResult:
    env = polyslam_env.parallel_env(**overrides)
    return run_episode(env, make_team(policy, env), seed)


# -- oracles ----------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frontier__three_robots_cover_80_percent_of_cave_within_60_steps(seed: int) -> None:
    # Full SLAM: the policy plans on its own estimated map. Measured: 80 % after 19–29 steps
    # for seeds 0–2, so 60 steps leaves a 2× margin for numerical differences across machines.
    result = _episode("frontier", seed, map="cave", num_robots=3, max_steps=60, coverage_target=0.8)
    assert result.team["coverage"] >= 0.8, result.coverage


@pytest.mark.parametrize(
    ("policy", "world_map", "rate"),
    [
        # frontier and wall_follow avoid walls (beams + own map) and robots (camera). Measured
        # ≤ 2 % of robot-steps with a collision; 5 % allows a few unlucky scrapes.
        ("frontier", "two_rooms", 0.05),
        ("frontier", "office", 0.05),
        ("frontier", "paper", 0.05),
        ("wall_follow", "two_rooms", 0.05),
        ("wall_follow", "office", 0.05),
        # random ignores its sensors by design: measured 13–17 % of robot-steps; 35 % bounds it.
        ("random", "paper", 0.35),
        ("random", "office", 0.35),
    ],
)
def test_scripted__collision_rate_is_bounded(policy: str, world_map: str, rate: float) -> None:
    result = _episode(policy, 3, map=world_map, num_robots=3, max_steps=50, coverage_target=1.0)
    collisions = sum(m["collisions"] for m in result.robots.values())
    assert collisions <= rate * 3 * result.steps, collisions


def test_paper__true_poses_follow_replay_paths() -> None:
    paths = load_paths("paper")
    replay = replay_paths(paths)
    env = polyslam_env.parallel_env(  # the paper's setting: robots start on the paths' starts
        map="paper", num_robots=3, coverage_target=None, max_steps=120, initial_error=False
    )
    team = make_team("paper", env)
    poses = []
    run_episode(env, team, 5, on_step=lambda e: poses.append(e.episode.world.poses.copy()))
    poses_arr = np.array(poses)  # (K+1, N, 3)
    k = len(poses_arr)
    assert k == 121
    # Same world, same commands (rounded to float32: ~1e-8 m/s) → the same trajectory up to
    # float noise; 1 mm / 1 mrad would still reveal an off-by-one step (0.05 m per step).
    assert np.allclose(poses_arr[..., :2], replay.poses[:k, :, :2], atol=1e-3)
    dth = np.remainder(poses_arr[..., 2] - replay.poses[:k, :, 2] + math.pi, 2 * math.pi) - math.pi
    assert np.max(np.abs(dth)) < 1e-3


def test_paper__other_map_raises_naming_the_map() -> None:
    env = polyslam_env.parallel_env(map="two_rooms", num_robots=3)
    with pytest.raises(PolicyError, match="two_rooms"):
        make_policy("paper", env, "robot_0")


def test_paper__discrete_actions_raise() -> None:
    env = polyslam_env.parallel_env(map="paper", action__mode="discrete")
    with pytest.raises(PolicyError, match="continuous"):
        make_policy("paper", env, "robot_0")


# -- plumbing ---------------------------------------------------------------------------------
def test_make_policy__unknown_name_lists_the_names() -> None:
    env = polyslam_env.parallel_env(map="two_rooms")
    with pytest.raises(PolyslamError, match="unknown policy 'nope'") as err:
        make_policy("nope", env, "robot_0")
    assert all(name in str(err.value) for name in ("frontier", "paper", "random", "wall_follow"))


def test_make_policy__checkpoint_for_scripted_policy_raises() -> None:
    env = polyslam_env.parallel_env(map="two_rooms")
    with pytest.raises(PolicyError, match="checkpoint"):
        make_policy("frontier", env, "robot_0", checkpoint="x.zip")


@pytest.mark.parametrize("policy", ["frontier", "wall_follow", "random"])
def test_policies__discrete_grid_mode_actions_are_in_space(policy: str) -> None:
    env = polyslam_env.parallel_env(
        map="two_rooms",
        num_robots=2,
        max_steps=8,
        action__mode="discrete",
        observation__mode="grid",
    )
    team = make_team(policy, env)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    while env.agents:
        actions = team.act(obs, rng)
        assert all(env.action_space(a).contains(actions[a]) for a in env.agents)
        obs, *_ = env.step(actions)


def test_random__same_rng_same_actions_inside_the_box() -> None:
    env = polyslam_env.parallel_env(map="two_rooms")
    obs, _ = env.reset(seed=0)
    runs = []
    for _ in range(2):
        policy = make_policy("random", env, "robot_0")
        policy.reset(0)
        rng = np.random.default_rng(7)
        runs.append(np.array([policy.act(obs["robot_0"], rng) for _ in range(20)]))
    assert np.array_equal(runs[0], runs[1])
    assert all(env.action_space("robot_0").contains(a) for a in runs[0])
    assert np.ptp(runs[0][:, 1]) > 0.1  # it does move: ω spans more than 0.1 of ±1.5 rad/s


def test_team_policy__maps_each_present_agent_to_its_action() -> None:
    env = polyslam_env.parallel_env(map="two_rooms", num_robots=3)
    team = make_team("wall_follow", env)
    obs, _ = env.reset(seed=0)
    del obs["robot_1"]
    actions = team.act(obs, np.random.default_rng(0))
    assert isinstance(team, TeamPolicy)
    assert sorted(actions) == ["robot_0", "robot_2"]


@settings(max_examples=25, deadline=None)
@given(
    v=st.floats(-5, 5),
    w=st.floats(-5, 5),
    mode=st.sampled_from(["continuous", "discrete"]),
)
def test_context_action__always_in_the_action_space(v: float, w: float, mode: str) -> None:
    env = polyslam_env.parallel_env(map="two_rooms", action__mode=mode)
    ctx = PolicyContext.from_env(env, "robot_0")
    assert env.action_space("robot_0").contains(ctx.action(v, w))


@settings(max_examples=30, deadline=None)
@given(
    heading=st.floats(-math.pi, math.pi),
    x=st.floats(-1, 1),
    y=st.floats(-1, 1),
)
def test_own_map__rotated_free_local_grid_leaves_no_holes(
    heading: float, x: float, y: float
) -> None:
    own = OwnMap(8.0, 0.1)
    local = np.zeros((3, 11, 11), dtype=bool)
    local[1] = True  # all free
    own.integrate_local(np.array([x, y, heading]), local, 0.2)
    # Every own cell whose centre lies ≥ one cell diagonal (0.15 m) inside the rotated
    # 2.2 m square must be marked: the sampling lattice is finer than a cell side / √2.
    ii, jj = np.mgrid[0 : own.n, 0 : own.n]
    centres = np.stack([jj + 0.5, ii + 0.5], axis=-1) * own.res + own.origin  # (n, n, 2)
    c, s = math.cos(heading), math.sin(heading)
    rel = centres - (x, y)
    ego = np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]], -1)
    inside = np.all(np.abs(ego) <= 1.1 - 0.15, axis=-1)
    assert own.free[inside].all()
    outside = np.any(np.abs(ego) > 1.1 + 0.15, axis=-1)
    assert not own.free[outside].any()

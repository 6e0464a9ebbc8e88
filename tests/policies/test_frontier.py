"""Frontier exploration: acts on observations only, deterministic, team claims, map size."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from scipy import ndimage

import polyslam_env
from policies import make_policy, make_team
from policies.frontier import BACK_OFF_STEPS, GAIN_RAYS, FrontierPolicy, grid_path, visible_gain

LARGE = {"width": 24, "height": 14, "min_room_size": 1.5, "max_room_size": 5}


def _rollout(env: Any, seed: int, steps: int) -> tuple[list[Any], list[Any]]:
    """(observations, actions) of the first ``steps`` steps of a seeded frontier episode."""
    team = make_team("frontier", env)
    obs, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = np.random.default_rng(seed)
    seen, done = [], []
    while env.agents and len(done) < steps:
        actions = team.act(obs, rng)
        seen.append(obs)
        done.append(actions)
        obs, *_ = env.step(actions)
    return seen, done


def test_frontier__actions_are_a_function_of_the_observations_alone() -> None:
    # Replaying an episode's observations into a policy built from *another* env (another
    # layout, other true poses) gives the same actions: nothing but the observations and
    # the public facts reach the policy, so its goals cannot use ground truth.
    kwargs = {"map": "generator:rooms", "map_params": {"width": 8, "height": 5}}
    env = polyslam_env.parallel_env(**kwargs, num_robots=2)
    observations, actions = _rollout(env, seed=5, steps=60)
    other = polyslam_env.parallel_env(**kwargs, num_robots=2)
    other.reset(seed=99)
    for agent in env.possible_agents:
        policy = make_policy("frontier", other, agent)
        policy.reset(5)
        rng = np.random.default_rng(0)
        replay = [policy.act(obs[agent], rng) for obs in observations]
        assert all(np.array_equal(a, b[agent]) for a, b in zip(replay, actions, strict=True))


def test_frontier__same_seed_same_actions() -> None:
    runs = [
        _rollout(polyslam_env.parallel_env(map="generator:rooms", num_robots=3), 4, 80)[1]
        for _ in range(2)
    ]
    assert len(runs[0]) > 20
    for a, b in zip(*runs, strict=True):
        assert a.keys() == b.keys()
        assert all(np.array_equal(a[k], b[k]) for k in a)


def test_frontier__own_map_holds_a_large_map_from_any_start() -> None:
    env = polyslam_env.parallel_env(map="generator:rooms", map_params=LARGE)
    policy = make_policy("frontier", env, "robot_0")
    assert isinstance(policy, FrontierPolicy)
    # every point of the 24 × 14 m box is within its diagonal of any start, whatever the
    # start heading; one max range more is the margin for estimate drift
    reach = math.hypot(24, 14) + env.public_facts()["max_range"]
    assert -policy.map.origin >= reach  # the grid is centred on the start


def test_frontier__frontiers_on_a_seen_robots_side_are_claimed() -> None:
    env = polyslam_env.parallel_env(map="two_rooms", num_robots=2)
    policy = make_policy("frontier", env, "robot_0")
    assert isinstance(policy, FrontierPolicy)
    policy.reset(0)
    pose = np.array([0.0, 0.0, 0.5 * math.pi])  # facing +y
    policy._claim(pose, np.array([[1.0, 0.0]]))  # a robot 1 m straight ahead: at (0, 1)
    points = np.array([[0.0, 3.0], [0.0, -3.0], [3.0, 0.4], [3.0, 0.6], [0.0, 20.0]])
    claimed = policy._claimed(points, policy._claims)
    # beyond it: claimed; behind us: ours; the bisector is y = 0.5; past claim_radius: ours
    assert claimed.tolist() == [True, False, False, True, False]
    policy._step += policy.claim_steps
    policy._claim(pose, np.zeros((0, 2)))
    assert not policy._claims  # claims expire


def test_free_start__leads_out_of_a_corner_without_nearing_the_walls() -> None:
    """A robot pushed deep into a corner (one cell from two walls, the zone inflated by 0.35
    m around them) gets a path out of the zone; the cells freed for it are never closer to a
    wall than its own. (Freeing only its 8 neighbours, whose clearance is at most 0.2 m, left
    it no way out: a robot was trapped for ~35 steps, turning in place while its plan
    alternated between a goal and none.)"""
    res, inflate = 0.1, 0.35
    obst = np.zeros((30, 30), dtype=bool)
    obst[0, :] = obst[:, 0] = True  # the corner's two walls
    clearance = ndimage.distance_transform_edt(~obst) * res
    passable = clearance > inflate
    start = (1, 1)  # 0.1 m from both walls
    assert not passable[start]
    before = passable.copy()
    FrontierPolicy._free_start(passable, clearance, start, inflate / res + 1.0)
    dist, _ = grid_path(passable, np.ones_like(clearance), start)
    assert np.isfinite(dist[before]).all()  # every cell clear of the zone is reachable
    freed = passable & ~before
    assert np.all(clearance[freed] >= clearance[start])
    assert not passable[obst].any()


@pytest.mark.parametrize("policy", ["frontier", "frontier_team"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frontier__team_covers_80_percent_of_a_generated_map_within_a_stated_budget(
    seed: int, policy: str
) -> None:
    # Budget from a hard bound: a step's beams mark at most n_beams · (r_max/res + 1) cells
    # of res², so 3 robots need at least T = 0.8 · A / (3 · that) steps for 80 % of the free
    # area A. The budget is 24 T: in rooms at most 2.5 m wide a beam ends at a wall within
    # about half its range (×2), a 0.3 m step re-marks most cells of the forward beams (×2),
    # every room is a dead end entered and left by its door (×2), turning to a new goal
    # costs steps without travel (×1.5), and the robots do not share their maps, so each
    # sweeps space a teammate has already covered until they meet (×2). The bound counts
    # every beam's cells as its own, which holds for beams 22.5° apart (neighbours share cells
    # only within 0.25 m): the robots get that nine-beam sensor. With the default's 11.25°
    # neighbours share cells out to 0.5 m, so a scan marks far fewer than 17 beams' worth.
    env = polyslam_env.parallel_env(
        map="generator:rooms",
        map_params={"width": 10, "height": 6},
        num_robots=3,
        max_steps=1000,
        coverage_target=0.8,
        world__range_sensor__angles_deg=[90.0 - 22.5 * i for i in range(9)],
    )
    team = make_team(policy, env)
    obs, _ = env.reset(seed=seed)
    team.reset(seed)
    state = env.episode
    assert state is not None
    facts = env.public_facts()
    res = state.coverage.resolution
    area = state.coverage.n_free * res**2  # m²
    per_step = len(facts["beam_angles"]) * (facts["max_range"] / res + 1) * res**2  # m²
    budget = math.ceil(24 * 0.8 * area / (3 * per_step))
    rng = np.random.default_rng(seed)
    while env.agents and state.step_count < budget:
        obs, *_ = env.step(team.act(obs, rng))
    assert state.coverage.coverage >= 0.8, (state.step_count, budget)


# -- active loop closing (frontier_closing) -------------------------------------------------
def test_relative_pose_std__is_the_filters_own_covariance_read_from_the_observation() -> None:
    """The observation's pose deviations less the start prior's share J P0 Jᵀ give back the
    filter's P_S (``pose_cov_relative``) to float32 precision of the observed deviations;
    without SLAM there is none."""
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=2, initial_error=True)
    ctx = make_policy("frontier", env, "robot_1").context
    observations, _ = _rollout(env, seed=3, steps=120)
    obs, _, _, _, _ = env.step(
        make_team("frontier", env).act(observations[-1], np.random.default_rng(0))
    )
    got = ctx.relative_pose_std(obs["robot_1"])
    want = np.sqrt(np.diag(env.unwrapped.episode.slams[1].pose_cov_relative))
    assert got is not None and want[0] > 1e-3  # grown from 0 at the start
    # float32 deviations: relative error 6e-8 of σ², against the P0 share of up to (0.3 m)²
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    bare = polyslam_env.parallel_env(map="generator:warehouse", num_robots=2, slam_enabled=False)
    obs, _ = bare.reset(seed=3)
    assert (
        make_policy("frontier", bare, "robot_0").context.relative_pose_std(obs["robot_0"]) is None
    )


def _open_room_policy(**kwargs: Any) -> FrontierPolicy:
    """A frontier_closing policy whose own map is one empty 6 × 6 m room around the origin."""
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=1)
    policy = make_policy("frontier_closing", env, "robot_0", **kwargs)
    assert isinstance(policy, FrontierPolicy) and policy.close_loops
    m = policy.map
    rows, cols = m.cells(np.array([[-3.0, -3.0], [3.0, 3.0]]))
    m.free[rows[0] : rows[1] + 1, cols[0] : cols[1] + 1] = True
    m.occ[rows[0] - 1, cols[0] - 1 : cols[1] + 2] = True
    m.occ[rows[1] + 1, cols[0] - 1 : cols[1] + 2] = True
    m.occ[rows[0] - 1 : rows[1] + 2, cols[0] - 1] = True
    m.occ[rows[0] - 1 : rows[1] + 2, cols[1] + 1] = True
    m.rebuild()  # the grids were written directly: bring the clearance and frontier along
    return policy


def test_safe_speed__a_robot_within_the_margin_of_a_wall_drives_along_it_but_not_into_it() -> None:
    """A robot 5 cm from a mapped wall, inside its radius + 4 cm margin: driving along the wall
    or away from it keeps its clearance and goes at full speed; driving into it does not move
    (before, every arc there was refused, and a robot so placed stood for 15 steps while each
    replanned path led straight on). In the open, full speed."""
    policy = _open_room_policy()
    ctx = policy.context
    rows, cols = policy.map.cells(np.array([[-3.0, 0.0]]))
    wall = policy.map.centre(int(rows[0]), int(cols[0]) - 1)
    assert policy.map.obstacles[int(rows[0]), int(cols[0]) - 1]
    x = float(wall[0]) + 0.5 * policy.map.res + 0.05  # 5 cm from the wall's cell
    assert 0.05 < ctx.robot_radius + 0.04
    speeds = {
        name: policy._safe_speed(np.array([x, 0.0, heading]), ctx.v_max, 0.0)
        for name, heading in (("along", 0.5 * math.pi), ("away", 0.0), ("into", math.pi))
    }
    assert speeds == {"along": ctx.v_max, "away": ctx.v_max, "into": 0.0}
    assert policy._safe_speed(np.array([0.0, 0.0, 0.3]), ctx.v_max, 0.2) == ctx.v_max


def _anchor(policy: FrontierPolicy, x: float, y: float) -> tuple[int, int]:
    rows, cols = policy.map.cells(np.array([[x, y]]))
    policy._anchors[rows[0], cols[0]] = True
    return int(rows[0]), int(cols[0])


def test_plan_anchor__goes_to_the_nearest_anchor_by_path_within_reach() -> None:
    """Of the anchors, the one nearest by path and at least ``min_goal`` away is the goal
    (the one under the robot is not); one farther than ``close_reach`` is never chosen, and
    with none in reach the loop closing ends."""
    policy = _open_room_policy(close_reach=4.0)
    pose = np.array([-2.0, 0.0, 0.0])
    _anchor(policy, -2.0, 0.1)  # under the robot: nearer than min_goal
    far = _anchor(policy, 2.5, 0.0)  # 4.5 m: beyond reach
    near = _anchor(policy, -2.0, 2.0)  # 2 m
    _anchor(policy, 0.0, -2.5)  # ~3.2 m
    policy._closing = True
    policy._plan_anchor(pose)
    assert policy._closing and policy.goal == near and policy.path is not None
    assert np.hypot(*(policy.path[-1] - pose[:2])) == pytest.approx(2.0, abs=0.1)
    policy._anchors[:] = False
    policy._anchors[far] = True
    policy._plan_anchor(pose)
    assert not policy._closing and policy.goal != far  # out of reach: back to exploring


def test_plan_anchor__never_heads_for_an_anchor_it_cannot_reach() -> None:
    """With ``close_reach`` unbounded (the default), an anchor walled off from the robot (its
    path length infinite) is no goal: before, it was one, its "path" the goal cell alone, and
    on Willow (seed 3, robot_2 from step ~500) a robot in a pocket of clutter took that lone
    far waypoint, found it blocked by its beams, dropped it, and planned it again every other
    step, turning on the spot for the rest of the episode. With no anchor in reach the loop
    closing ends."""
    policy = _open_room_policy()
    assert policy.close_reach == math.inf
    m = policy.map
    rows, cols = m.cells(np.array([[1.0, 1.0], [2.0, 2.0]]))  # a walled-off 1 m box
    m.occ[rows[0] - 1, cols[0] - 1 : cols[1] + 2] = True
    m.occ[rows[1] + 1, cols[0] - 1 : cols[1] + 2] = True
    m.occ[rows[0] - 1 : rows[1] + 2, cols[0] - 1] = True
    m.occ[rows[0] - 1 : rows[1] + 2, cols[1] + 1] = True
    m.rebuild()
    walled = _anchor(policy, 1.5, 1.5)
    pose = np.array([-2.0, 0.0, 0.0])
    policy._closing = True
    policy._plan_anchor(pose)
    assert not policy._closing and policy.goal != walled
    reachable = _anchor(policy, -2.0, 2.0)
    policy._closing = True
    policy._plan_anchor(pose)
    assert policy._closing and policy.goal == reachable


def _sigma_steps(policy: FrontierPolicy) -> Callable[[float], bool]:
    """A function that plays one step of ``policy``'s loop-closing switch at the origin with
    the filter's position σ ``s`` (m) and returns whether a closing is on."""
    state = {"std": np.zeros(3)}
    policy.context = _with_std(policy.context, state)
    pose = np.zeros(3)

    def sigma(s: float) -> bool:
        state["std"] = np.array([s, 0.0, 0.001])
        policy._step += 1
        return policy._closing_now(pose, None)

    return sigma


def test_closing__starts_above_close_above_and_ends_below_close_below() -> None:
    """The loop closing's switch on the filter's own position σ (√(σx² + σy²) of P_S):
    anchors where σ < ``anchor_below``, a closing once σ > ``close_above`` (and an anchor
    exists), its end once σ < ``close_below``, then ``close_rest`` steps without one."""
    policy = _open_room_policy(close_above=0.03, close_below=0.02, anchor_below=0.01, close_rest=5)
    sigma = _sigma_steps(policy)
    assert not sigma(0.005) and policy._anchors.sum() == 1  # anchored here
    assert not sigma(0.029)  # below close_above
    assert sigma(0.031) and policy.closings == 1
    assert sigma(0.021)  # still above close_below
    assert not sigma(0.019)  # done: rest for 5 steps
    assert not any(sigma(0.04) for _ in range(4))
    assert sigma(0.04) and policy.closings == 2


def test_closing__spends_at_most_close_share_of_the_steps_closing_loops() -> None:
    """The budget: a loop closing starts only while the steps spent closing are at most
    ``close_share`` of the steps so far (with ``shape_shift: pose``'s honest σ on Willow the
    closings, unbounded, took 35–45 % of the steps and the teams' coverage fell below 0.85);
    the steps are counted and reported by ``metrics``."""
    policy = _open_room_policy(
        close_above=0.03, close_below=0.02, anchor_below=0.01, close_rest=0, close_share=0.25
    )
    sigma = _sigma_steps(policy)
    assert not sigma(0.005)  # step 1: anchored
    assert all(sigma(0.04) for _ in range(9))  # steps 2–10 closing: 9 steps
    assert not sigma(0.01)  # step 11: done
    # 9 closing steps are within 0.25 of the steps only from step 36 on
    closing = {step: sigma(0.04) for step in range(12, 41)}
    assert not any(closing[step] for step in range(12, 36)) and all(
        closing[s] for s in range(36, 41)
    )
    assert policy.metrics() == {"closings": 2.0, "closing_steps": 9.0 + 5.0}
    assert (
        make_policy(
            "frontier",
            polyslam_env.parallel_env(map="generator:warehouse", num_robots=1),
            "robot_0",
        ).metrics()
        == {}
    )


def test_closing__gives_up_after_close_timeout_and_forgets_that_anchor() -> None:
    """A loop closing that neither reaches its anchor nor its σ within ``close_timeout`` steps
    (a robot stalled on its way: on Willow one closing lasted 1,714 steps) ends, and the
    anchors within 1 m of its goal are forgotten; others stay."""
    policy = _open_room_policy(
        close_above=0.03, close_below=0.02, anchor_below=0.01, close_timeout=10, close_share=1.0
    )
    pose = np.array([-2.0, 0.0, 0.0])
    goal = _anchor(policy, -2.0, 2.0)
    other = _anchor(policy, 2.0, -2.0)
    state = {"std": np.array([0.04, 0.0, 0.001])}
    policy.context = _with_std(policy.context, state)
    policy._step += 1
    assert policy._closing_now(pose, None)
    policy._plan_anchor(pose)
    assert policy.goal == goal
    for _ in range(9):
        policy._step += 1
        assert policy._closing_now(pose, None)
    policy._step += 1
    assert not policy._closing_now(pose, None)  # 10 steps: given up
    assert not policy._anchors[goal] and policy._anchors[other]


def _with_std(context: Any, state: dict) -> Any:
    """``context`` whose relative_pose_std returns ``state["std"]``."""

    class Fixed(type(context)):  # type: ignore[misc]
        def relative_pose_std(self, observation: Any) -> np.ndarray:
            return state["std"]

    fixed = object.__new__(Fixed)
    fixed.__dict__.update(context.__dict__)
    return fixed


def test_frontier_closing__bad_thresholds_are_named() -> None:
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=1)
    with pytest.raises(ValueError, match="anchor_below <= close_below <= close_above"):
        make_policy("frontier_closing", env, "robot_0", close_below=0.05)
    with pytest.raises(ValueError, match="close_reach must be > 0"):
        make_policy("frontier_closing", env, "robot_0", close_reach=0.0)
    with pytest.raises(ValueError, match=r"close_share must be in \[0, 1\], got 1.5"):
        make_policy("frontier_closing", env, "robot_0", close_share=1.5)
    with pytest.raises(ValueError, match="close_timeout must be >= 1, got 0"):
        make_policy("frontier_closing", env, "robot_0", close_timeout=0)
    assert not make_policy("frontier", env, "robot_0").close_loops  # off by default


def _visible_gain_oracle(
    known: np.ndarray, obstacles: np.ndarray, row: int, col: int, reach: int
) -> float:
    """One cell's visible gain, walked ray by ray and cell by cell in plain Python."""
    h, w = known.shape
    seen = 0
    for j in range(GAIN_RAYS):
        angle = 2.0 * math.pi * j / GAIN_RAYS
        for k in range(1, reach + 1):
            r, c = round(row + k * math.sin(angle)), round(col + k * math.cos(angle))
            if not (0 <= r < h and 0 <= c < w) or obstacles[r, c]:
                break
            seen += int(not known[r, c])
    return seen / (GAIN_RAYS * reach)


def test_visible_gain__counts_what_rays_reach_not_the_space_behind_a_wall() -> None:
    """A known room closed by a wall along row 10, unknown beyond it, and an open unknown
    stretch to the east: a cell by the wall sees none of the space behind it (the square gain
    counts it), a cell facing the open stretch sees some; every cell matches the oracle."""
    known = np.zeros((30, 30), dtype=bool)
    obstacles = np.zeros((30, 30), dtype=bool)
    known[:10, :20] = True  # the room; east of column 20 it is open and unknown
    obstacles[10, :20] = True  # the wall, beyond which it is unknown
    known[10, :20] = True
    reach = 8
    rows, cols = np.array([9, 5, 5, 0]), np.array([5, 19, 5, 29])
    gain = visible_gain(known, obstacles, rows, cols, reach)
    assert gain.dtype == np.float32
    expected = [
        _visible_gain_oracle(known, obstacles, r, c, reach) for r, c in zip(rows, cols, strict=True)
    ]
    np.testing.assert_allclose(gain, expected, rtol=1e-6)
    assert gain[0] == 0.0  # by the wall: everything unknown within reach is behind it
    square = ndimage.uniform_filter((~known).astype(float), 2 * reach + 1, mode="constant")
    assert square[9, 5] > 0.25  # the square gain counts the space behind the wall
    assert gain[1] > 0.25  # facing the open stretch
    assert gain[2] == 0.0  # in the middle of the known room


def test_frontier__gain_mode_is_checked_and_visible_plans() -> None:
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=1)
    with pytest.raises(ValueError, match="gain must be one of square, visible"):
        make_policy("frontier", env, "robot_0", gain="seen")
    team = make_team("frontier", env, gain="visible")
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(30):
        obs, *_ = env.step(team.act(obs, rng))
    moved = float(
        np.hypot(
            *(env.unwrapped.episode.world.poses[0][:2] - env.unwrapped.episode.start_poses[0][:2])
        )
    )
    assert moved > 0.5  # it explores (30 steps of up to 0.3 m)


def test_back_off__a_robot_stalled_against_another_drives_away_then_plans_again() -> None:
    env = polyslam_env.parallel_env(map="two_rooms", num_robots=2)
    policy = make_policy("frontier", env, "robot_0")
    assert isinstance(policy, FrontierPolicy)
    policy.reset(0)
    pose = np.array([1.0, 1.0, 0.0])
    policy._trail = [pose[:2].copy()] * 8  # stalled
    policy.goal, policy.path = (5, 5), np.array([[2.0, 1.0]])
    # a robot 5 cm from touching (avoid_robots keeps 0.1 m), 0.2 rad left of ahead
    contact = np.array([[2 * policy.context.robot_radius + 0.05, 0.2]])
    clear = np.full(len(policy.context.beam_angles), 5.0)
    assert not policy._backing_off(pose, clear, np.array([[1.5, 0.2]]))  # far enough to pass
    assert policy._backing_off(pose, clear, contact)
    assert policy._back_off is not None
    assert math.remainder(policy._back_off[0] - (0.2 + math.pi), 2 * math.pi) == pytest.approx(0)
    # it heads away from the other robot, turning on the spot first
    v, omega = policy._head(pose, policy._back_off[0], clear)
    assert v == 0.0 and omega != 0.0
    policy._step += BACK_OFF_STEPS  # then it plans again, that goal rested
    assert not policy._backing_off(pose, clear, np.zeros((0, 2)))
    assert policy.path is None and policy.goal is None and (5, 5) in policy._blacklist


def test_escape__a_stalled_robot_with_no_path_backs_off_toward_its_longest_beam() -> None:
    """Wall following in a pocket of clutter (Willow, seed 3: robot_0 from step ~1,150 with
    ranges of 0.16-0.24 m) turned on the spot one way for the wall on the left and back for
    the one ahead, every step, for the rest of the episode. Stalled with no path, the robot
    now backs off toward its longest beam for ``BACK_OFF_STEPS``; with a path, or moving, it
    does not."""
    env = polyslam_env.parallel_env(map="two_rooms", num_robots=1)
    policy = make_policy("frontier", env, "robot_0")
    assert isinstance(policy, FrontierPolicy)
    policy.reset(0)
    pose = np.array([1.0, 1.0, 0.3])
    angles = policy.context.beam_angles
    ranges = np.full(len(angles), 0.2)
    longest = len(angles) // 3
    ranges[longest] = 1.5
    none = np.zeros((0, 2))
    policy._trail = [pose[:2] + np.array([0.02 * k, 0.0]) for k in range(8)]  # moving
    assert not policy._backing_off(pose, ranges, none)
    policy._trail = [pose[:2].copy()] * 8  # stalled
    policy.path = np.array([[2.0, 1.0]])  # with a path: the stall rests its goal instead
    assert not policy._backing_off(pose, ranges, none)
    policy.path = None
    assert policy._backing_off(pose, ranges, none)
    assert policy._back_off is not None
    want = pose[2] + float(angles[longest])
    assert math.remainder(policy._back_off[0] - want, 2 * math.pi) == pytest.approx(0)
    _, omega = policy._head(pose, policy._back_off[0], ranges)
    assert omega != 0.0  # turning toward the open beam first


def test_escape__heads_where_the_own_map_lets_it_drive_even_behind_it() -> None:
    """Willow, seed 7 (closing, ``pose``): robot_2 stood in a channel of clutter whose way out
    lay behind it, where its ±90° beams do not reach (all 0.17-0.20 m). The escape takes the
    heading its own map lets it drive fastest when the longest beam's way is blocked there."""
    policy = _open_room_policy()
    m = policy.map
    pose = np.array([0.0, 0.0, 0.0])  # facing +x
    # a U of walls: just ahead, and on both sides from behind the robot to ahead of it
    boxes = [((0.15, -1.0), (0.3, 1.0)), ((-0.3, 0.2), (0.3, 0.35)), ((-0.3, -0.35), (0.3, -0.2))]
    for low, high in boxes:  # (x, y) corners
        (r0, r1), (c0, c1) = m.cells(np.array([low, high]))
        m.occ[r0 : r1 + 1, c0 : c1 + 1] = True
    m.rebuild()
    assert m.obstacles[m.cell(0.2, 0.0)] and m.obstacles[m.cell(0.0, 0.25)]
    ranges = np.full(len(policy.context.beam_angles), 0.2)
    policy._trail = [pose[:2].copy()] * 8
    policy.path = None
    assert policy._backing_off(pose, ranges, np.zeros((0, 2)))
    direction = policy._back_off[0]
    assert abs(math.remainder(direction - pose[2], 2 * math.pi)) > 0.5 * math.pi  # behind it
    assert policy._safe_speed(np.array([0.0, 0.0, direction]), policy.context.v_max, 0.0) > 0


def test_back_off__two_robots_that_meet_round_a_corner_part_again() -> None:
    """The loop, seed 4, exchange on: robots 1 and 2 meet round the corridor's corner at
    step 37, 0.28 m apart when their cameras first see each other. Before the back-off they
    stayed there, each turning away and back, for 460 steps. Now no two robots stay within
    0.35 m of each other for 30 steps in a row: a stall is 8 steps, a back-off 8 more, and
    30 leaves room for a second try."""
    env = polyslam_env.parallel_env(
        map="generator:loop", num_robots=3, initial_error=True, max_steps=150, coverage_target=None
    )
    team = make_team("frontier", env)
    obs, _ = env.reset(seed=4)
    team.reset(4)
    rng = np.random.default_rng([4, 1])
    state = env.episode
    assert state is not None
    close = np.zeros((3, 3), dtype=int)
    while env.agents:
        obs, *_ = env.step(team.act(obs, rng))
        xy = np.array([state.world.poses[i][:2] for i in range(3)])
        near = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) < 0.35
        close = np.where(near, close + 1, 0)
        np.fill_diagonal(close, 0)
        assert close.max() < 30, close

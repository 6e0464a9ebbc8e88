"""Coordinated frontier exploration (``frontier_team``): Burgard's discount against its oracle,
goal messages (bytes, frames, mutual sightings), the choice a heard goal changes, seeding."""

from __future__ import annotations

import math
import zlib
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import polyslam_env
from policies import make_policy, make_team
from policies.planner import team_discount
from policies.radio import (
    Area,
    GoalMessage,
    Radio,
    area_in_own_frame,
    decode,
    encode,
    goal_in_own_frame,
    mutual_sighting,
)
from policies.team import TeamFrontierPolicy
from tests.policies import reference

_EPS = np.finfo(float).eps


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    points=st.integers(0, 40),
    goals=st.integers(0, 5),
    reach=st.floats(0.1, 10.0),
)
def test_team_discount__is_burgards_product_of_one_minus_visibility(
    seed: int, points: int, goals: int, reach: float
) -> None:
    """The compiled discount is the readable Π (1 − P(d)) up to the rounding of 1 − (1 − x):
    within one ulp of 1 per factor, so K goals at most K·eps apart (each factor ≤ 1)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-8.0, 8.0, (points, 2))
    g = rng.uniform(-8.0, 8.0, (goals, 2))
    fast = team_discount(p, g, reach)
    slow = reference.team_discount(p, g, reach)
    assert fast.shape == (points,)
    np.testing.assert_allclose(fast, slow, rtol=0.0, atol=max(goals, 1) * _EPS)


def test_team_discount__zero_at_a_goal_one_beyond_reach_linear_between() -> None:
    goals = np.array([[0.0, 0.0]])
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, -3.0], [4.0, 0.0], [9.0, 9.0]])
    assert team_discount(points, goals, 4.0).tolist() == [0.0, 0.25, 0.75, 1.0, 1.0]
    assert team_discount(points, np.zeros((0, 2)), 4.0).tolist() == [1.0] * 5
    two = np.array([[0.0, 0.0], [2.0, 0.0]])  # both see (1, 0) with P = 3/4: 1/4 · 1/4 left
    assert team_discount(np.array([[1.0, 0.0]]), two, 4.0).tolist() == [1 / 16]


def test_goal_message__round_trips_and_its_bytes_are_its_length() -> None:
    message = GoalMessage(2, 77, np.array([[1.2, -0.5], [0.7, 2.0]]), np.array([[3.0, -1.5]]))
    data = encode(message)
    assert len(data) == 14 + 8 * 2 + 8 * 1  # the layout of policies.radio's doc
    back = decode(data)
    assert (back.sender, back.step) == (2, 77)
    f32 = np.float32
    assert np.array_equal(back.detections, message.detections.astype(f32).astype(float))
    assert np.array_equal(back.goals, message.goals.astype(f32).astype(float))
    for broken in (data[:-1], data[:5], bytes([0x50]) + data[1:], data[:-1] + b"\x00"):
        with pytest.raises(ValueError, match="goal message"):
            decode(broken)
    radio = Radio(3)
    radio.send(2, data)
    radio.send(2, data)
    assert radio.bytes_sent == [0, 0, 2 * len(data)] and radio.messages_sent == [0, 0, 2]
    assert radio.heard(0) == [data] and radio.heard(2) == []


def test_goal_in_own_frame__places_a_mates_goal_from_a_mutual_sighting() -> None:
    """Two robots in a world frame, each with its own start frame: the receiver's estimate of
    the sender's goal, from the two bearings and the distance, is the goal (brute force)."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        start_r, start_s = rng.uniform(-5, 5, 3), rng.uniform(-5, 5, 3)  # frames in the world
        pose_r, pose_s = rng.uniform(-3, 3, 3), rng.uniform(-3, 3, 3)  # in their own frames
        world_r = _compose(start_r, pose_r)
        world_s = _compose(start_s, pose_s)
        goal_world = rng.uniform(-10, 10, 2)
        d = math.hypot(*(world_s[:2] - world_r[:2]))
        seen = [d, _bearing(world_r, world_s[:2])]
        back = _bearing(world_s, world_r[:2])
        goal_body = _to_body(world_s, goal_world)
        got = goal_in_own_frame(pose_r, np.array(seen), back, goal_body)
        want = _to_body(start_r, goal_world)  # the goal in the receiver's start frame
        np.testing.assert_allclose(got, want, atol=1e-9)


def test_mutual_sighting__pairs_by_distance_and_refuses_ambiguity() -> None:
    own = np.array([[1.0, 0.3], [1.4, -2.0]])
    assert mutual_sighting(own, np.array([[1.42, 1.0]]), 0.06) == (1, 0)
    assert mutual_sighting(own, np.array([[1.2, 1.0]]), 0.06) is None  # no fit
    assert mutual_sighting(own, np.array([[1.2, 1.0]]), 0.25) is None  # two fit
    assert mutual_sighting(np.zeros((0, 2)), np.array([[1.0, 0.0]]), 0.06) is None


def _corridor_team(**kwargs: Any) -> tuple[TeamFrontierPolicy, TeamFrontierPolicy]:
    """Two ``frontier_team`` robots sharing a radio, each with the same own map: a corridor
    6 m × 1.6 m (x −3 … 3), walls along its sides, open (unknown) at both ends, and a post
    mapped at either end 3 m beyond (so that the unknown ends lie inside the planner's
    window, whose border counts as known); ``kwargs`` go to the policies."""
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=2)
    team = make_team("frontier_team", env, **kwargs)
    first, second = team.policies.values()
    assert isinstance(first, TeamFrontierPolicy) and isinstance(second, TeamFrontierPolicy)
    assert first.radio is second.radio
    corridor_maps(first, second)
    return first, second


def corridor_maps(*policies: TeamFrontierPolicy) -> None:
    """Give each of ``policies`` the corridor own map of :func:`_corridor_team`."""
    for policy in policies:
        m = policy.map
        rows, cols = m.cells(np.array([[-3.0, -0.8], [3.0, 0.8]]))
        m.free[rows[0] : rows[1] + 1, cols[0] : cols[1] + 1] = True
        m.occ[rows[0] - 1, cols[0] : cols[1] + 1] = True
        m.occ[rows[1] + 1, cols[0] : cols[1] + 1] = True
        posts = m.cells(np.array([[-6.0, 0.0], [6.0, 0.0]]))
        m.occ[posts] = True
        m.rebuild()


def test_second_robot__goes_elsewhere_because_of_the_first_robots_announced_goal() -> None:
    """Both robots stand near the corridor's left end: alone, each would explore there. Robot
    0 plans, and announces its goal while the two see each other; robot 1, which saw robot 0
    at that step, hears it, is asked to replan (robot 0 ranks first) and heads for the right
    end. Robot 1 that did not see robot 0 then (no mutual sighting) does not hear the message
    and picks the left end as robot 0 did."""
    first, second = _corridor_team()
    pose_0, pose_1 = np.array([-1.6, 0.4, 0.0]), np.array([-1.6, -0.4, 0.0])
    sees_1 = np.array([[0.8, -0.5 * math.pi]])  # robot 0 sees robot 1 0.8 m to its right
    sees_0 = np.array([[0.8, 0.5 * math.pi]])  # and robot 1 sees robot 0 to its left
    first._step = second._step = 1
    first._plan(pose_0)
    first._announce(pose_0, sees_1)
    assert first.goal is not None and first.map.centre(*first.goal)[0] < 0  # the left end
    second._plan(pose_1)
    alone = second.goal
    assert alone is not None and second.map.centre(*alone)[0] < 0  # the same end, alone
    sent = first.radio.heard(1)[0]  # with its explored area: the corridor, known to both
    area = decode(sent).area
    assert area is not None
    deflated = len(zlib.compress(np.packbits(area.cells, axis=None).tobytes(), 9))
    # the module doc's layout: 37 + 8k + 8g + L bytes, one detection, one goal, L deflated
    assert first.radio.bytes_sent[0] == len(sent) == 37 + 8 + 8 + deflated

    second._announce(pose_1, np.zeros((0, 2)))  # it did not see robot 0 at that step
    second._step = 2
    assert not second._listen() and not second.heard
    second._plan(pose_1)
    assert second.goal == alone

    second._announce(pose_1, sees_0)  # now as if it had: step 1 again, with the sighting
    second._step, first._step = 1, 1
    first._announce(pose_0, sees_1)
    second._step = 2
    assert second._listen()  # a lower-index team-mate's goal discounts its own: replan
    heard = second.heard[0][0][0]
    np.testing.assert_allclose(heard, first.map.centre(*first.goal), atol=1e-5)  # float32
    second._plan(pose_1)
    assert second.goal is not None and second.map.centre(*second.goal)[0] > 0  # the right end
    assert second.metrics()["goal_messages_received"] == 1.0


def test_explored_area__round_trips_and_a_broken_one_is_a_one_line_error() -> None:
    rng = np.random.default_rng(3)
    cells = rng.random((7, 13)) < 0.4
    area = Area(np.array([1.5, -2.25, 0.75]), (-4, 9), cells, 0.2)
    message = GoalMessage(1, 5, np.array([[1.0, 0.5]]), np.array([[2.0, 0.0]]), area)
    data = encode(message)
    packed = len(data) - (37 + 8 + 8)  # the layout of policies.radio's doc: L bytes of cells
    assert packed > 0 and data[1] == 2
    back = decode(data).area
    assert back is not None and back.corner == (-4, 9) and back.cell == 0.2
    assert np.array_equal(back.cells, cells)
    np.testing.assert_allclose(back.pose, area.pose.astype(np.float32), rtol=0, atol=0)
    assert decode(encode(GoalMessage(1, 5, message.detections, message.goals))).area is None
    for broken in (data[:-1], data[:40], data[:-6] + b"\x00\x00" + data[-4:]):
        with pytest.raises(ValueError, match="goal message"):
            decode(broken)


def test_area_in_own_frame__places_a_mates_explored_cells_from_a_mutual_sighting() -> None:
    """A sender's explored cells, known in the world: the receiver places each cell's four
    quarter centres where they are in its own start frame (brute force, exact readings)."""
    rng = np.random.default_rng(7)
    for _ in range(30):
        start_r, start_s = rng.uniform(-5, 5, 3), rng.uniform(-5, 5, 3)
        pose_r, pose_s = rng.uniform(-3, 3, 3), rng.uniform(-3, 3, 3)
        world_r, world_s = _compose(start_r, pose_r), _compose(start_s, pose_s)
        d = math.hypot(*(world_s[:2] - world_r[:2]))
        seen = np.array([d, _bearing(world_r, world_s[:2])])
        back = _bearing(world_s, world_r[:2])
        cells = rng.random((4, 5)) < 0.5
        area = Area(pose_s, (int(rng.integers(-20, 20)), int(rng.integers(-20, 20))), cells, 0.2)
        got = area_in_own_frame(pose_r, seen, back, area).reshape(-1, 4, 2)
        for (x, y), quarters in zip(area.centres(), got, strict=True):
            for q, (dx, dy) in zip(quarters, [(-1, -1), (1, -1), (-1, 1), (1, 1)], strict=True):
                world = _compose(start_s, np.array([x + 0.05 * dx, y + 0.05 * dy, 0.0]))[:2]
                np.testing.assert_allclose(q, _to_body(start_r, world), atol=1e-9)


def test_area_discount__is_the_untold_share_of_the_unknown_gain_square() -> None:
    """Against a brute-force count over each point's square, on a random map and area."""
    first, _ = _corridor_team()
    m, half = first.map, first.gain_cells
    rng = np.random.default_rng(11)
    first.team_area[:] = rng.random(first.team_area.shape) < 0.3
    points = np.vstack([rng.uniform(-4.0, 4.0, (40, 2)), [[1e4, 0.0]]])  # the last off the map
    got = first.area_discount(points)
    unknown = ~m.layers.known.reshape(m.n, m.n)
    for p, value in zip(points[:-1], got[:-1], strict=True):
        row, col = m.cell(*p)  # type: ignore[misc]
        box = np.s_[max(row - half, 0) : row + half + 1, max(col - half, 0) : col + half + 1]
        total = np.count_nonzero(unknown[box])
        told = np.count_nonzero(unknown[box] & first.team_area[box])
        assert value == (1.0 - told / total if total else 1.0)
    assert got[-1] == 1.0


@pytest.mark.parametrize("share_area", [True, False])
def test_second_robot__leaves_the_room_a_team_mate_explored(share_area: bool) -> None:
    """Robot 0 came down the corridor from a room beyond its left end (its own map holds the
    room) and heads away (a goal 20 m off, which discounts nothing here); robot 1 knows only
    the corridor and stands near the left end, so alone it would explore there. Over a mutual
    sighting robot 0's message brings the room: robot 1 replans and heads for the right end.
    Without the area (``share_area=False``) it hears the goal only and keeps the left end."""
    first, second = _corridor_team(share_area=share_area)
    room = first.map.cells(np.array([[-6.0, -2.0], [-3.0, 2.0]]))
    first.map.free[room[0][0] : room[0][1] + 1, room[1][0] : room[1][1] + 1] = True
    first.map.rebuild()
    pose_0, pose_1 = np.array([-1.6, 0.4, 0.0]), np.array([-1.6, -0.4, 0.0])
    sees_1, sees_0 = np.array([[0.8, -0.5 * math.pi]]), np.array([[0.8, 0.5 * math.pi]])
    second._step = 1
    second._plan(pose_1)
    alone = second.goal
    assert alone is not None and second.map.centre(*alone)[0] < 0  # the left end, alone
    first._step = 1
    first.goal = first.map.cell(0.0, 20.0)
    first._announce(pose_0, sees_1)
    second._announce(pose_1, sees_0)
    second._step = 2
    assert second._listen() is share_area  # the goal it heard discounts nothing here
    second._plan(pose_1)
    assert second.goal is not None
    assert bool(second.map.centre(*second.goal)[0] > 0) is share_area
    assert second.metrics()["goal_areas_received"] == float(share_area)


def _actions(seed: int, steps: int) -> list[dict[str, Any]]:
    env = polyslam_env.parallel_env(map="generator:office_floor", num_robots=3)
    team = make_team("frontier_team", env)
    obs, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = np.random.default_rng(seed)
    out = []
    while env.agents and len(out) < steps:
        actions = team.act(obs, rng)
        out.append({a: np.asarray(v).tolist() for a, v in actions.items()})
        obs, *_ = env.step(actions)
    out.append({a: p.metrics() for a, p in team.policies.items()})
    return out


def test_frontier_team__same_seed_same_actions_and_messages() -> None:
    assert _actions(4, 40) == _actions(4, 40)


def test_frontier_team__one_robot_alone_has_its_own_radio_and_no_checkpoint() -> None:
    env = polyslam_env.parallel_env(map="generator:office_floor", num_robots=2)
    policy = make_policy("frontier_team", env, "robot_1")
    assert isinstance(policy, TeamFrontierPolicy) and policy.radio.bytes_sent == [0, 0]
    with pytest.raises(ValueError, match="takes no checkpoint"):
        make_team("frontier_team", env, checkpoint="x.zip")
    with pytest.raises(ValueError, match="team_range must be > 0"):
        make_team("frontier_team", env, team_range=0.0)


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def _to_body(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = point[0] - pose[0], point[1] - pose[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy])


def _bearing(pose: np.ndarray, point: np.ndarray) -> float:
    return math.atan2(point[1] - pose[1], point[0] - pose[0]) - pose[2]

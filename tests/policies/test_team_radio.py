"""``frontier_team`` over a radio longer than the camera (the env's ``channel.range`` above the
camera's): the medium's distance test, the message that carries its sender's pose, the frame
kept from a first sighting, and the goal a team-mate heard through it with no sighting."""

from __future__ import annotations

import math

import numpy as np
import pytest

import polyslam_env
from policies import make_team
from policies.radio import (
    GoalMessage,
    Radio,
    decode,
    encode,
    mate_in_own_frame,
    own_frame_of,
)
from policies.team import TeamFrontierPolicy
from polyslam_env.core.geometry import compose, transform_points
from tests.policies.test_team import _bearing, _compose, _to_body, corridor_maps


def test_pose_message__round_trips_in_26_plus_8k_plus_8g_bytes() -> None:
    pose = np.array([1.5, -2.25, 0.75])
    message = GoalMessage(1, 5, np.zeros((0, 2)), np.array([[2.0, 0.0], [1.0, 1.0]]), pose=pose)
    data = encode(message)
    assert len(data) == 26 + 8 * 0 + 8 * 2 and data[1] == 3  # the layout of policies.radio's doc
    back = decode(data)
    assert back.area is None and back.pose is not None
    np.testing.assert_allclose(back.pose, pose.astype(np.float32), rtol=0, atol=0)
    assert decode(encode(GoalMessage(1, 5, message.detections, message.goals))).pose is None
    with pytest.raises(ValueError, match="goal message"):
        decode(data[:-5] + data[-4:])


def test_radio__reaches_whom_the_medium_says_were_in_range_when_it_was_sent() -> None:
    links = np.array([[True, True, False], [True, True, False], [False, False, True]])
    radio = Radio(3, links=lambda: links)
    radio.send(0, b"x")
    links = np.ones((3, 3), dtype=bool)  # robot 2 comes in range after the post
    assert radio.reached(0, 1) and not radio.reached(0, 2) and not radio.reached(0, 0)
    assert not radio.reached(1, 0)  # robot 1 posted nothing
    plain = Radio(2)
    plain.send(0, b"x")
    assert not plain.reached(0, 1)  # without the medium only a mutual sighting carries it


def test_radio_links__is_the_channels_range_on_true_positions_and_only_when_longer() -> None:
    """The env's test against brute force; the default env (channel = camera = 1.5 m) keeps
    the sighting-only radio, so ``frontier_team`` is unchanged there."""
    env = polyslam_env.parallel_env(map="generator:office_floor", num_robots=3, channel__range=4.5)
    env.reset(seed=2)
    poses = env.unwrapped.episode.world.poses
    want = [[math.dist(p[:2], q[:2]) <= 4.5 for q in poses] for p in poses]
    assert env.unwrapped.radio_links().tolist() == want
    far = make_team("frontier_team", env).policies["robot_0"]
    assert isinstance(far, TeamFrontierPolicy) and far.radio.links is not None
    plain = make_team("frontier_team", polyslam_env.parallel_env(map="generator:office_floor"))
    assert plain.policies["robot_0"].radio.links is None  # type: ignore[attr-defined]


def test_own_frame_of__places_a_later_goal_from_an_earlier_sighting() -> None:
    """A receiver keeps the sender's start frame from a mutual sighting; the sender moves on
    (both do) and announces a goal in its body frame with its own-frame pose: through the
    kept frame it lands where it is (brute force over random start frames, exact readings)."""
    rng = np.random.default_rng(5)
    for _ in range(30):
        start_r, start_s = rng.uniform(-5, 5, 3), rng.uniform(-5, 5, 3)
        pose_r, pose_s = rng.uniform(-3, 3, 3), rng.uniform(-3, 3, 3)
        world_r, world_s = _compose(start_r, pose_r), _compose(start_s, pose_s)
        seen = np.array([math.dist(world_r[:2], world_s[:2]), _bearing(world_r, world_s[:2])])
        back = _bearing(world_s, world_r[:2])
        frame = own_frame_of(mate_in_own_frame(pose_r, seen, back), pose_s)
        later, goal_body = rng.uniform(-8, 8, 3), rng.uniform(-4, 4, 2)
        got = transform_points(goal_body, compose(frame, later))
        world_goal = _compose(_compose(start_s, later), np.array([*goal_body, 0.0]))[:2]
        np.testing.assert_allclose(got, _to_body(start_r, world_goal), atol=1e-9)


def _far_corridor_team() -> tuple[TeamFrontierPolicy, TeamFrontierPolicy, list[bool]]:
    """The corridor of ``tests/policies/test_team.py`` with a 10 m radio, whose medium says
    the two robots are in range while the returned flag is True."""
    env = polyslam_env.parallel_env(map="generator:warehouse", num_robots=2, channel__range=10.0)
    first, second = make_team("frontier_team", env).policies.values()
    assert isinstance(first, TeamFrontierPolicy) and isinstance(second, TeamFrontierPolicy)
    in_range = [True]
    first.radio.links = lambda: np.full((2, 2), in_range[0])
    corridor_maps(first, second)
    return first, second, in_range


@pytest.mark.parametrize("in_range", [True, False])
def test_far_radio__a_team_mate_met_once_is_heard_later_without_a_sighting(
    in_range: bool,
) -> None:
    """Step 1 the robots meet near the corridor's left end (robot 0 heads 20 m off, which
    discounts nothing): each keeps the other's frame, and robot 1 alone picks the left end.
    Step 30, out of sight, robot 0 announces the left end too: robot 1 within radio range
    hears it through the kept frame, replans and heads right; out of range it hears nothing
    and keeps the left end. Before the meeting robot 0 sends nothing while it sees nobody."""
    first, second, link = _far_corridor_team()
    link[0] = in_range
    pose_0, pose_1 = np.array([-1.6, 0.4, 0.0]), np.array([-1.6, -0.4, 0.0])
    sees_1, sees_0 = np.array([[0.8, -0.5 * math.pi]]), np.array([[0.8, 0.5 * math.pi]])
    nobody = np.zeros((0, 2))
    first._step = second._step = 1
    first.goal = first.map.cell(0.0, 20.0)
    first._announce(pose_0, nobody)  # unmet: nothing goes out
    assert first.radio.messages_sent == [0, 0]
    second._plan(pose_1)
    alone = second.goal
    assert alone is not None and second.map.centre(*alone)[0] < 0  # the left end, alone
    first._announce(pose_0, sees_1)
    second._announce(pose_1, sees_0)
    first._step = second._step = 2
    assert not second._listen() and not first._listen()  # 20 m off: no discount
    for policy in (first, second):  # both frames are the corridor's: the identity (float32)
        (frame,) = policy.frames.values()
        np.testing.assert_allclose(frame, 0.0, atol=1e-6)

    first._step = second._step = 30
    moved = np.array([-0.5, 0.0, math.pi])
    first.goal = alone
    first._announce(moved, nobody)
    assert decode(first.radio.heard(1)[0]).step == 30
    second._announce(pose_1, nobody)
    second._step = 31
    assert second._listen() is in_range  # robot 0 ranks first and wants its goal
    assert second.metrics()["goal_messages_unseen"] == float(in_range)
    if in_range:
        np.testing.assert_allclose(second.heard[0][0][0], first.map.centre(*alone), atol=1e-5)
    second._plan(pose_1)
    assert second.goal is not None
    assert bool(second.map.centre(*second.goal)[0] > 0) is in_range

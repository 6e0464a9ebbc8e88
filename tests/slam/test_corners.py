"""Corners of a wall map (slam/corners.py): position, heading and shape against geometry worked
out by hand or by brute force, the kinds of meeting that make a corner and those that do not,
and invariance under a rigid motion of the whole map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import rotation
from polyslam_env.slam.corners import CornerConfig, wall_corners
from polyslam_env.slam.polynomial import Polynomial


def _line(p: tuple[float, float], q: tuple[float, float]) -> Polynomial:
    """The segment p–q as a first-order polynomial, in the variate its direction favours."""
    (x0, y0), (x1, y1) = p, q
    if abs(x1 - x0) >= abs(y1 - y0):
        b = (y1 - y0) / (x1 - x0)
        return Polynomial(1, np.array([y0 - b * x0, b]), min(x0, x1), max(x0, x1))
    b = (x1 - x0) / (y1 - y0)
    return Polynomial(2, np.array([x0 - b * y0, b]), min(y0, y1), max(y0, y1))


def _face(poly: Polynomial, toward: tuple[float, float]) -> int:
    """The side (±1) of ``poly`` that faces the point ``toward``: +η or −η."""
    xi, eta = poly.from_xy(np.asarray(toward, dtype=float))
    return 1 if float(eta) > float(poly.value(float(xi))) else -1


def test_l_corner__inside_a_room__position_heading_opening_and_concave() -> None:
    """Two walls of a room that stop 0.2 and 0.3 m short of their corner at (0, 0), seen from
    inside (the room is x > 0, y > 0): the corner at (0, 0), heading 45° (the bisector of the
    arms along +x and +y), opening 90°, concave (+1)."""
    floor = _line((0.2, 0.0), (4.0, 0.0))
    side = _line((0.0, 0.3), (0.0, 3.0))
    inside = (1.0, 1.0)
    corners = wall_corners([floor, side], [_face(floor, inside), _face(side, inside)])
    assert len(corners) == 1
    np.testing.assert_allclose(corners.positions[0], [0.0, 0.0], atol=1e-12)
    assert corners.headings is not None
    assert corners.headings[0] == pytest.approx(math.pi / 4, abs=1e-12)
    np.testing.assert_allclose(corners.descriptors[0], [math.pi / 2, 1.0], atol=1e-12)


def test_l_corner__seen_from_outside__is_convex() -> None:
    """The same two walls seen from outside (a box's corner, the robot at (−1, −1)): convex."""
    floor = _line((0.2, 0.0), (4.0, 0.0))
    side = _line((0.0, 0.3), (0.0, 3.0))
    outside = (-1.0, -1.0)
    corners = wall_corners([floor, side], [_face(floor, outside), _face(side, outside)])
    assert corners.descriptors[0, 1] == -1.0
    unknown = wall_corners([floor, side], [0, 0])
    assert unknown.descriptors[0, 1] == 0.0


def test_t_junction__arm_on_the_observed_face() -> None:
    """A partition ending on the middle of a long wall (x = 0 from y = −3 to 3), the partition
    along +x from (0.25, 1): seen from above (y > 1) the corner is at (0, 1), its arms along +x
    and +y (heading 45°); seen from below, along +x and −y (heading −45°)."""
    wall = _line((0.0, -3.0), (0.0, 3.0))
    partition = _line((0.25, 1.0), (4.0, 1.0))
    for toward, heading in (((2.0, 2.0), math.pi / 4), ((2.0, 0.0), -math.pi / 4)):
        sides = [_face(wall, toward), _face(partition, toward)]
        corners = wall_corners([wall, partition], sides)
        assert len(corners) == 1
        np.testing.assert_allclose(corners.positions[0], [0.0, 1.0], atol=1e-12)
        assert corners.headings is not None
        assert corners.headings[0] == pytest.approx(heading, abs=1e-12)
        np.testing.assert_allclose(corners.descriptors[0], [math.pi / 2, 1.0], atol=1e-12)
    # a partition whose face is unknown cannot tell which side the T's corner is on
    assert len(wall_corners([wall, partition], [0, 0])) == 0


def test_no_corner__pieces_of_one_wall_far_ends_and_short_walls() -> None:
    """Collinear pieces of a wall (across a doorway) make no corner; nor do walls that stop
    further than ``reach`` from where they would meet, nor walls shorter than ``min_length``;
    two walls at 45° do (above ``min_angle_deg``) with opening 45° (or 135°)."""
    cfg = CornerConfig()
    left, right = _line((0.0, 0.0), (3.0, 0.0)), _line((3.6, 0.0), (7.0, 0.0))
    assert len(wall_corners([left, right], [1, 1], cfg)) == 0
    far = _line((0.0, cfg.reach + 0.05), (0.0, 3.0))
    floor = _line((cfg.reach + 0.05, 0.0), (4.0, 0.0))
    assert len(wall_corners([floor, far], [1, 1], cfg)) == 0
    stub = _line((0.0, 0.1), (0.0, 0.1 + 0.9 * cfg.min_length))
    assert len(wall_corners([_line((0.1, 0.0), (4.0, 0.0)), stub], [1, 1], cfg)) == 0
    slant = _line((0.1, 0.1), (3.0, 3.0))
    corners = wall_corners([_line((0.1, 0.0), (4.0, 0.0)), slant], [1, 1], cfg)
    assert len(corners) == 1
    assert corners.descriptors[0, 0] == pytest.approx(math.pi / 4, abs=1e-12)


def test_curved_wall__corner_where_the_tangent_meets_the_curve__brute_force() -> None:
    """A straight wall's end tangent extended onto a cubic wall: the corner is where that line
    crosses the curve, found here by brute force (the sign change of the curve's offset from
    the line on a 1e-6 m grid), to 1e-6 m."""
    cubic = Polynomial(2, np.array([0.05, 0.02, -0.03, 0.01]), -1.0, 3.0)  # x = f(y)
    wall = _line((0.4, 1.2), (4.0, 1.5))  # ends 0.35 m or so from the cubic
    corners = wall_corners([cubic, wall], [1, 1])
    assert len(corners) == 1
    start = wall.points_at(np.array([wall.lo]))[0]
    direction = start - wall.points_at(np.array([wall.hi]))[0]
    direction /= np.linalg.norm(direction)
    s = np.arange(0.0, 1.0, 1e-6)
    line = start + s[:, None] * direction
    offset = line[:, 0] - cubic.value(line[:, 1])
    k = int(np.flatnonzero(np.diff(np.sign(offset)))[0])
    np.testing.assert_allclose(corners.positions[0], line[k], atol=2e-6)


def test_rigid_motion__corners_move_with_the_map_and_keep_their_shape() -> None:
    """A room (four walls stopping short of their corners, one partition) and the same room
    moved by a rigid transform: the corners of the moved map are the moved corners, headings
    turned by θ, descriptors unchanged."""
    segments = [
        ((0.2, 0.0), (5.8, 0.0)),
        ((6.0, 0.3), (6.0, 3.7)),
        ((5.7, 4.0), (0.3, 4.0)),
        ((0.0, 3.8), (0.0, 0.2)),
        ((3.0, 0.25), (3.0, 2.0)),
    ]
    inside = (1.5, 3.0)
    theta, t = 0.7, np.array([2.0, -1.0])
    turn = rotation(theta)

    def moved(p: tuple[float, float]) -> tuple[float, float]:
        q = turn @ np.asarray(p) + t
        return float(q[0]), float(q[1])

    walls = [_line(p, q) for p, q in segments]
    walls_moved = [_line(moved(p), moved(q)) for p, q in segments]
    here = wall_corners(walls, [_face(w, inside) for w in walls])
    there = wall_corners(walls_moved, [_face(w, moved(inside)) for w in walls_moved])
    assert len(here) == len(there) == 5  # four room corners and the partition's T on the floor
    order = np.lexsort(np.round(here.positions, 6).T)
    expected = here.positions[order] @ turn.T + t
    got_order = np.lexsort(np.round((there.positions - t) @ turn, 6).T)  # by unmoved place
    np.testing.assert_allclose(there.positions[got_order], expected, atol=1e-9)
    assert here.headings is not None and there.headings is not None
    turned = here.headings[order] + theta
    diff = np.angle(np.exp(1j * (there.headings[got_order] - turned)))
    np.testing.assert_allclose(diff, 0.0, atol=1e-9)
    np.testing.assert_allclose(there.descriptors[got_order], here.descriptors[order], atol=1e-9)


def test_corner_config__bad_values_name_the_field() -> None:
    with pytest.raises(ConfigError, match="corners.reach"):
        CornerConfig(reach=0.0)
    with pytest.raises(ConfigError, match="corners.min_angle_deg"):
        CornerConfig(min_angle_deg=95.0)

"""The frontier policy's controller: pure pursuit along a planned path, the speed the front
beams allow, and the speed that keeps the robot off mapped obstacles.

Per step it is a handful of scalar operations and two compiled calls (:func:`speed_cap`,
:func:`safe_speed`), with no Python loop over beams, cells or waypoints.
"""

from __future__ import annotations

import math

import numpy as np

from policies.base import PolicyContext
from policies.scripted import beam_index
from polyslam_env.core.jit import njit

__all__ = ["TURN_FIRST", "Controller", "arc_clearance", "safe_speed", "speed_cap"]

#: rad: a robot further than this off its heading turns on the spot before it drives on.
TURN_FIRST = 0.7


@njit
def speed_cap(
    angles: np.ndarray, ranges: np.ndarray, radius: float, v_max: float, dt: float
) -> float:
    """Fastest safe forward speed given the beams (``angles`` rad, ``ranges`` m, inf: no
    return) within 60° of straight ahead: each short beam in the robot's lane (its radius
    + 0.2 m) caps the speed to the travel it leaves (less the radius and 0.1 m) in one step."""
    cap = v_max
    for i in range(angles.shape[0]):
        r = ranges[i]
        if abs(angles[i]) < math.radians(60) and math.isfinite(r):
            ahead = r * math.cos(angles[i]) - radius - 0.1
            side = abs(r * math.sin(angles[i]))
            if side < radius + 0.2:
                cap = min(cap, max(ahead, 0.0) / dt)
    return cap


@njit
def arc_clearance(
    xs: np.ndarray,
    ys: np.ndarray,
    disk: np.ndarray,
    obst: np.ndarray,
    origin: float,
    res: float,
    n: int,
) -> float:
    """Distance (m) from the nearest of the points (``xs``, ``ys``) (P,) to the nearest
    obstacle cell (its square) among the cells holding a point + one of the ``disk`` offsets
    (D, 2); inf for none."""
    best = math.inf
    for p in range(xs.shape[0]):
        for d in range(disk.shape[0]):
            col = math.floor((xs[p] + disk[d, 0] - origin) / res)
            row = math.floor((ys[p] + disk[d, 1] - origin) / res)
            if 0 <= row < n and 0 <= col < n and obst[row * n + col]:
                gx = max(abs(xs[p] - ((col + 0.5) * res + origin)) - 0.5 * res, 0.0)
                gy = max(abs(ys[p] - ((row + 0.5) * res + origin)) - 0.5 * res, 0.0)
                best = min(best, math.hypot(gx, gy))
    return best


@njit
def safe_speed(
    pose: np.ndarray,
    v: float,
    omega: float,
    times: np.ndarray,
    disk: np.ndarray,
    obst: np.ndarray,
    origin: float,
    res: float,
    n: int,
) -> float:
    """``v``, halved (at most three times, else 0) until the arc driven at (v, ``omega``),
    sampled at ``times`` (T,) s, keeps the robot off mapped obstacles: no obstacle cell within
    the ``disk`` (D, 2) around any point of the arc, or, when one already is that close, none
    closer than now (a robot that came within the margin of a wall beside or behind it may
    drive on, away or along; refusing every arc there left one standing for 15 steps while
    each replanned path led straight on)."""
    x0, y0, th0 = pose[0], pose[1], pose[2]
    here = np.array([x0])
    now = arc_clearance(here, np.array([y0]), disk, obst, origin, res, n)
    xs, ys = np.empty(times.shape[0]), np.empty(times.shape[0])
    for _ in range(4):
        for i in range(times.shape[0]):
            if abs(omega) > 1e-6:
                th = th0 + omega * times[i]
                xs[i] = x0 + v / omega * (math.sin(th) - math.sin(th0))
                ys[i] = y0 - v / omega * (math.cos(th) - math.cos(th0))
            else:
                xs[i] = x0 + v * times[i] * math.cos(th0)
                ys[i] = y0 + v * times[i] * math.sin(th0)
        # inf: no obstacle within reach; 1e-9 m: the rounding of an arc along a wall
        if arc_clearance(xs, ys, disk, obst, origin, res, n) >= now - 1e-9:
            return v
        v *= 0.5
    return 0.0


def _robot_disk(radius: float, res: float) -> np.ndarray:  # (D, 2)
    """Offsets (half a cell apart) covering the robot's radius + 4 cm."""
    keep = radius + 0.04
    r = np.arange(-keep, keep + 1e-9, 0.5 * res)
    disk = np.stack(np.meshgrid(r, r), axis=-1).reshape(-1, 2)  # (D, 2)
    return disk[np.hypot(disk[:, 0], disk[:, 1]) <= keep]


class Controller:
    """(v, ω) commands for a robot with the limits of ``context`` on a map of ``res`` m cells:
    pure pursuit to a look-ahead point ``lookahead`` m along the path, capped by the front
    beams and kept off mapped obstacles."""

    def __init__(self, context: PolicyContext, res: float, lookahead: float) -> None:
        ctx = self.context = context
        self.lookahead = float(lookahead)
        self.disk = _robot_disk(ctx.robot_radius, res)
        self.times = np.linspace(0.25, 1.0, 4) * ctx.dt  # (T,) s along one step's arc
        self.angles = np.ascontiguousarray(ctx.beam_angles, dtype=float)
        self.left = beam_index(ctx.beam_angles, math.pi / 4)
        self.right = beam_index(ctx.beam_angles, -math.pi / 4)

    def pursue(
        self, path: np.ndarray, pose: np.ndarray, ranges: np.ndarray
    ) -> tuple[float, float, bool]:
        """Pure pursuit of ``path`` (P, 2) from ``pose`` (3,), then limited by the front
        beams ``ranges`` (B,): (v, ω, whether the path is blocked ahead and should be
        replanned with the new hits in the map)."""
        ctx = self.context
        target = path[_lookahead(path, pose[0], pose[1], self.lookahead)]
        dx, dy = target[0] - pose[0], target[1] - pose[1]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        fx, fy = c * dx + s * dy, -s * dx + c * dy  # target in the robot frame
        dist, alpha = math.hypot(fx, fy), math.atan2(fy, fx)
        if abs(alpha) > TURN_FIRST:
            return 0.0, self.turn_rate(alpha), False
        v = min(ctx.v_max, 0.8 * dist / ctx.dt)
        v = min(v, self.speed_cap(ranges))
        omega = 2.0 * math.sin(alpha) / max(dist, 1e-6) * v + 0.3 * alpha / ctx.dt
        blocked = v < 0.02
        if blocked:  # turn toward the roomier side
            omega = 0.8 * ctx.omega_max * (1.0 if ranges[self.left] >= ranges[self.right] else -1.0)
        return v, min(max(omega, -ctx.omega_max), ctx.omega_max), blocked

    def head(self, pose: np.ndarray, direction: float, ranges: np.ndarray) -> tuple[float, float]:
        """(v, ω) that drive toward the own-frame ``direction`` (rad): on the spot while it
        is more than :data:`TURN_FIRST` off, then forward within the front beams' cap."""
        alpha = math.remainder(direction - pose[2], 2 * math.pi)
        if abs(alpha) > TURN_FIRST:
            return 0.0, self.turn_rate(alpha)
        return min(0.5 * self.context.v_max, self.speed_cap(ranges)), self.turn_rate(alpha)

    def turn_rate(self, alpha: float) -> float:
        """ω (rad/s) that turns by ``alpha`` (rad) in one step, within ±ω_max."""
        ctx = self.context
        return min(max(alpha / ctx.dt, -ctx.omega_max), ctx.omega_max)

    def speed_cap(self, ranges: np.ndarray) -> float:
        """:func:`speed_cap` for this robot."""
        ctx = self.context
        return speed_cap(self.angles, ranges, ctx.robot_radius, ctx.v_max, ctx.dt)

    def safe_speed(
        self, pose: np.ndarray, v: float, omega: float, obst: np.ndarray, origin: float, res: float
    ) -> float:
        """:func:`safe_speed` of (v, ω) from ``pose`` on the flat obstacle grid ``obst``
        (n·n,) of a map with lower-left corner (``origin``, ``origin``) and ``res`` m cells."""
        n = math.isqrt(obst.shape[0])
        return safe_speed(pose, v, omega, self.times, self.disk, obst, origin, res, n)


@njit
def _lookahead(path: np.ndarray, x: float, y: float, lookahead: float) -> int:
    """Index of the pursuit target on ``path`` (P, 2): the first waypoint from the nearest one
    on that is at least ``lookahead`` m from (x, y), else the last."""
    nearest, best = 0, math.inf
    for i in range(path.shape[0]):
        d = math.hypot(path[i, 0] - x, path[i, 1] - y)
        if d < best:
            nearest, best = i, d
    for i in range(nearest, path.shape[0]):
        if math.hypot(path[i, 0] - x, path[i, 1] - y) >= lookahead:
            return i
    return path.shape[0] - 1

"""Scripted policies: ``paper`` (replay the paper paths), ``wall_follow`` and ``random``.

The frontier explorer lives in :mod:`policies.frontier`. All of them act on the
observation and the :class:`~policies.base.PolicyContext` only.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from policies.base import Policy, PolicyContext, PolicyError
from polyslam_env.core.resources import maps_dir, resolve_file
from polyslam_env.scenarios.paths import Paths, load_paths

__all__ = [
    "PaperPolicy",
    "RandomPolicy",
    "WallFollowPolicy",
    "avoid_robots",
    "beam_index",
    "wall_follow_command",
]


def _map_file(paths: Paths) -> Path:
    """The map file the paths were designed on (a built-in name or a path)."""
    return resolve_file(paths.map, maps_dir(), "map", PolicyError).resolve()


class PaperPolicy(Policy):
    """Replays precomputed paths (default: the paper's): robot i's command k at its step k,
    then stands still. Needs continuous actions, the paths' map and dt, and a path per robot.
    """

    def __init__(self, context: PolicyContext, paths: str = "paper") -> None:
        super().__init__(context)
        self.paths: Paths = load_paths(paths)
        self._check(context)
        self._k = 0

    def _check(self, ctx: PolicyContext) -> None:
        name = self.paths.name
        if ctx.action_mode != "continuous":
            raise PolicyError(
                f"policy 'paper' replays (v, omega) commands and needs action.mode='continuous',"
                f" got {ctx.action_mode!r}"
            )
        if ctx.map_file != _map_file(self.paths):
            raise PolicyError(
                f"policy 'paper': paths {name!r} are for map {self.paths.map!r},"
                f" the env's map is {ctx.map!r}"
            )
        if ctx.index >= self.paths.num_robots:
            raise PolicyError(
                f"policy 'paper': paths {name!r} have {self.paths.num_robots} robots, no path for"
                f" {ctx.agent}"
            )
        if not math.isclose(ctx.dt, self.paths.dt):
            raise PolicyError(
                f"policy 'paper': paths {name!r} need dt={self.paths.dt}, the env has {ctx.dt}"
            )

    def reset(self, seed: int | None = None) -> None:
        self._k = 0

    def act(self, observation: Any, rng: np.random.Generator) -> np.ndarray:
        """The next recorded command, (0, 0) after the end of the paths."""
        k, self._k = self._k, self._k + 1
        if k >= self.paths.num_steps:
            return np.zeros(2, dtype=np.float32)
        return np.asarray(self.paths.commands[self.context.index, k], dtype=np.float32)


def beam_index(angles: np.ndarray, target: float) -> int:
    """The beam whose angle (rad) is nearest to ``target`` (rad)."""
    diff = np.abs(np.remainder(angles - target + math.pi, 2 * math.pi) - math.pi)  # (B,)
    return int(np.argmin(diff))


def contact_gap(distance: Any, ctx: PolicyContext) -> Any:
    """m of free travel left before touching a robot seen ``distance`` m away (centres; a
    float or an array): the two radii and a 0.1 m margin off."""
    return distance - 2 * ctx.robot_radius - 0.1


def avoid_robots(
    v: float, omega: float, detections: np.ndarray, ctx: PolicyContext, keep: float = 0.45
) -> tuple[float, float]:
    """(v, ω) adjusted for robots the camera sees ahead (the beams do not see robots).

    A robot within ``keep`` m of the centre and ±80° of the heading caps the forward speed to
    the gap left and turns us away from it; one straight ahead is passed on the right (both
    robots do the same, so they do not mirror each other into a collision).
    """
    for d, bearing in detections:
        if d > keep + ctx.v_max * ctx.dt or abs(bearing) > math.radians(80):
            continue
        gap = contact_gap(d, ctx)
        v = min(v, max(gap * math.cos(bearing), 0.0) / ctx.dt)
        if d < keep + 0.5 * ctx.v_max * ctx.dt:
            away = -1.0 if bearing >= -math.radians(10) else 1.0
            omega = away * max(abs(omega), 0.6 * ctx.omega_max)
    return v, omega


def wall_follow_command(
    ranges: np.ndarray, ctx: PolicyContext, distance: float = 0.4, prev_error: float = 0.0
) -> tuple[float, float, float]:
    """Right-hand wall following on the beams: ``(v, ω, error)``.

    Keeps the right-hand wall at ``distance`` (PD on the error, which is returned for the next
    call's derivative), turns left in place when something is close ahead, and arcs right when
    the right-hand wall ends (a corner or a door to go round).
    """
    a = ctx.beam_angles
    front = ranges[beam_index(a, 0.0)]
    front_right = ranges[beam_index(a, -math.pi / 4)]
    right = ranges[beam_index(a, -math.pi / 2)]
    left = ranges[beam_index(a, math.pi / 2)]
    front_left = ranges[beam_index(a, math.pi / 4)]
    stop = distance + ctx.robot_radius
    if left < ctx.robot_radius + 0.1 or front_left < ctx.robot_radius + 0.2:
        return 0.0, -0.6 * ctx.omega_max, 0.0  # scraping the left side: turn away on the spot
    if front < stop or front_right < 0.75 * stop:
        return 0.0, 0.8 * ctx.omega_max, 0.0
    wall = min(right, front_right * math.cos(math.pi / 4))
    if not math.isfinite(wall) or wall > 2.0 * distance:
        return 0.5 * ctx.v_max, -0.5 * ctx.omega_max, 0.0
    error = distance - wall  # > 0: too close to the wall, turn left
    omega = 2.0 * error + 1.0 * (error - prev_error) / ctx.dt
    omega = float(np.clip(omega, -ctx.omega_max, ctx.omega_max))
    v = ctx.v_max * (1.0 - 0.6 * abs(omega) / ctx.omega_max)
    v = min(v, max(front - stop, 0.0) / ctx.dt)
    return v, omega, error


class WallFollowPolicy(Policy):
    """Right-hand wall following on the range beams (no map, no pose)."""

    def __init__(self, context: PolicyContext, distance: float = 0.4) -> None:
        super().__init__(context)
        if not distance > 0:
            raise PolicyError(f"wall_follow: distance must be > 0, got {distance!r}")
        self.distance = float(distance)
        self._error = 0.0

    def reset(self, seed: int | None = None) -> None:
        self._error = 0.0

    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        ranges = self.context.ranges(observation)
        v, omega, self._error = wall_follow_command(
            ranges, self.context, self.distance, self._error
        )
        v, omega = avoid_robots(v, omega, self.context.detections(observation), self.context)
        return self.context.action(v, omega)


class RandomPolicy(Policy):
    """Uniform random actions drawn with the given rng.

    Continuous actions are smoothed, ``a ← s·a + (1 − s)·u`` with ``u`` uniform in the box
    (``smoothing=0`` gives i.i.d. uniform actions); smoothing makes the robot wander instead
    of jittering on the spot. Discrete actions are uniform indices.
    """

    def __init__(self, context: PolicyContext, smoothing: float = 0.5) -> None:
        super().__init__(context)
        if not 0.0 <= smoothing < 1.0:
            raise PolicyError(f"random: smoothing must be in [0, 1), got {smoothing!r}")
        self.smoothing = float(smoothing)
        self._last: np.ndarray | None = None

    def reset(self, seed: int | None = None) -> None:
        self._last = None

    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        space = self.context.action_space
        if isinstance(space, spaces.Discrete):
            discrete: Any = space  # gymnasium 1.2 and 1.4 type start and n differently
            return np.int64(discrete.start + rng.integers(discrete.n))
        assert isinstance(space, spaces.Box)
        u = rng.uniform(space.low, space.high)  # (2,)
        a = u if self._last is None else self.smoothing * self._last + (1 - self.smoothing) * u
        self._last = a
        return np.asarray(a, dtype=space.dtype)

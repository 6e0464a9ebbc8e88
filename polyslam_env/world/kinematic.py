"""A kinematic world for point-landmark SLAM: the seed 003 experiment without physics.

Cars at 3.5–4 m/s over 30 m sensor ranges gain nothing from pymunk, so this world is the
seed's car model (eq. 14) stepped exactly along preset paths, a random landmark field and the
range-bearing sensor of :mod:`polyslam_env.world.point_sensor`.

Truth: each robot follows its waypoints by the steering law of Bailey's FastSLAM simulator
(which the seed's model, noise and 30 m range match; the seed states no steering law): the
steering angle G turns towards the next waypoint at most ``steer_rate`` per second and stays
within ±``max_steer``. The true trajectory is therefore fixed by the config, not the seed.
What a robot reports: the commanded (V, G) plus Gaussian noise (σ_V, σ_G) every period dt
(its odometry), and every ``observe_every`` periods one sweep of noisy range-bearing
measurements with known landmark ids. A robot stops when it reaches its last waypoint.

Randomness: one seed → named streams (``core.seeding``): ``layout`` (landmarks), ``motion``
(control noise, robot by robot), ``sensor`` (measurement noise, robot by robot, sweep by
sweep). Same seed and config ⇒ bit-identical episode.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.config import Config, check_positive
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import wrap_angle
from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.point_sensor import sense_points

Waypoints = tuple[tuple[float, float], ...]

#: The three preset paths (first point = start): r1 a loop through the middle of the field,
#: r2 and r3 arcs north and south of it, all three starting within 20 m of each other so
#: that they share landmarks at the start and where the paths run close.
SEED_PATHS: tuple[Waypoints, ...] = (
    (
        (0.0, 0.0),
        (40.0, 20.0),
        (80.0, 20.0),
        (120.0, 0.0),
        (80.0, -20.0),
        (40.0, -20.0),
        (5.0, 0.0),
    ),
    ((0.0, 10.0), (30.0, 40.0), (70.0, 50.0), (110.0, 40.0), (135.0, 10.0), (110.0, -10.0)),
    ((0.0, -10.0), (30.0, -40.0), (70.0, -50.0), (110.0, -40.0), (135.0, -10.0), (110.0, 10.0)),
)


@dataclass(frozen=True)
class KinematicConfig(Config):
    """The seed's §4.1 world (angles in degrees)."""

    speeds: tuple[float, ...] = (4.0, 3.8, 3.5)  # m/s, V1..V3
    paths: tuple[Waypoints, ...] = SEED_PATHS
    dt: float = 0.025  # s, control (odometry) period
    observe_every: int = 8  # periods between sensor sweeps (0.2 s)
    wheelbase: float = 4.0  # m, D
    max_steer_deg: float = 30.0
    steer_rate_deg: float = 20.0  # per second
    waypoint_radius: float = 4.0  # m: next waypoint when this close
    landmarks: int = 80
    field: tuple[float, float, float, float] = (-25.0, -70.0, 150.0, 70.0)  # x0, y0, x1, y1
    max_range: float = 30.0  # m
    sigma_v: float = 0.3  # m/s
    sigma_g_deg: float = 3.0
    sigma_r: float = 0.2  # m
    sigma_b_deg: float = 2.0

    def validate(self) -> None:
        if len(self.speeds) != len(self.paths) or not self.paths:
            raise ConfigError("speeds: one speed per path, at least one path")
        for i, path in enumerate(self.paths):
            if len(path) < 2:
                raise ConfigError(f"paths[{i}]: needs a start and at least one waypoint")
        for name in ("dt", "wheelbase", "max_steer_deg", "steer_rate_deg", "max_range"):
            check_positive(name, getattr(self, name))
        for i, v in enumerate(self.speeds):
            check_positive(f"speeds[{i}]", v)
        if self.observe_every < 1 or self.landmarks < 1:
            raise ConfigError("observe_every and landmarks: must be >= 1")
        x0, y0, x1, y1 = self.field
        if not (x1 > x0 and y1 > y0):
            raise ConfigError(f"field: needs x0 < x1 and y0 < y1, got {self.field}")

    @property
    def num_robots(self) -> int:
        return len(self.paths)


def car_step(pose: np.ndarray, speed: float, steer: float, dt: float, base: float) -> np.ndarray:
    """The true car model (eq. 14 with its speed factor) over one period."""
    x, y, phi = pose
    return np.array(
        [
            x + speed * dt * math.cos(phi + steer),
            y + speed * dt * math.sin(phi + steer),
            float(wrap_angle(phi + speed * dt * math.sin(steer) / base)),
        ]
    )


@functools.lru_cache(maxsize=16)
def true_route(config: KinematicConfig, robot: int) -> tuple[np.ndarray, np.ndarray]:
    """Robot ``robot``'s true commands (K, 2) and poses (K + 1, 3) to its last waypoint."""
    path = np.asarray(config.paths[robot], dtype=float)
    speed = config.speeds[robot]
    d0 = path[1] - path[0]
    pose = np.array([path[0, 0], path[0, 1], math.atan2(d0[1], d0[0])])
    max_g, rate = math.radians(config.max_steer_deg), math.radians(config.steer_rate_deg)
    length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    limit = int(5 * length / (speed * config.dt))  # a car that cannot reach a point circles
    steer, target = 0.0, 1
    poses: list[np.ndarray] = [pose]
    commands: list[tuple[float, float]] = []
    while target < len(path):
        if np.hypot(*(path[target] - pose[:2])) < config.waypoint_radius:
            target += 1
            continue
        if len(commands) >= limit:
            raise ConfigError(f"paths[{robot}]: waypoint {target} is out of the car's reach")
        goal = math.atan2(path[target, 1] - pose[1], path[target, 0] - pose[0])
        turn = float(wrap_angle(goal - pose[2] - steer))
        steer = float(
            np.clip(steer + np.clip(turn, -rate * config.dt, rate * config.dt), -max_g, max_g)
        )
        commands.append((speed, steer))
        pose = car_step(pose, speed, steer, config.dt, config.wheelbase)
        poses.append(pose)
    return np.array(commands), np.array(poses)


@dataclass(frozen=True)
class RobotRecord:
    """One robot's episode, sweep by sweep (S sweeps, ``observe_every`` = K periods each)."""

    initial_pose: np.ndarray  # (3,)
    true_poses: np.ndarray  # (S, 3) at each sweep
    controls: np.ndarray  # (S, K, 2) measured (V, G) before each sweep
    sweeps: tuple[tuple[np.ndarray, np.ndarray], ...]  # S × (ids (m,), z (m, 2))


@dataclass(frozen=True)
class KinematicEpisode:
    """Ground truth and what each robot sensed."""

    landmarks: np.ndarray  # (M, 2)
    robots: tuple[RobotRecord, ...]

    @property
    def sweeps(self) -> int:
        """Sweeps of the longest robot run (shorter runs stop earlier)."""
        return max(len(r.sweeps) for r in self.robots)


def landmark_field(config: KinematicConfig, rng: np.random.Generator) -> np.ndarray:
    """Landmarks (M, 2) uniform over the field."""
    x0, y0, x1, y1 = config.field
    return rng.uniform((x0, y0), (x1, y1), size=(config.landmarks, 2))


def simulate_episode(config: KinematicConfig, seed: int) -> KinematicEpisode:
    """One seeded episode: landmarks, each robot's true poses, noisy controls and sweeps."""
    rngs = make_rngs(seed, ("layout", "motion", "sensor"))
    landmarks = landmark_field(config, rngs["layout"])
    sigma_c = np.array([config.sigma_v, math.radians(config.sigma_g_deg)])
    sigma_z = (config.sigma_r, math.radians(config.sigma_b_deg))
    k = config.observe_every
    robots = []
    for r in range(config.num_robots):
        commands, poses = true_route(config, r)
        s = len(commands) // k
        measured = commands[: s * k] + rngs["motion"].standard_normal((s * k, 2)) * sigma_c
        at_sweep = poses[k : s * k + 1 : k]
        sweeps = tuple(
            sense_points(p, landmarks, config.max_range, sigma_z, rngs["sensor"]) for p in at_sweep
        )
        robots.append(RobotRecord(poses[0].copy(), at_sweep, measured.reshape(s, k, 2), sweeps))
    return KinematicEpisode(landmarks, tuple(robots))

"""Run robots with SLAM on a map without the RL environment.

:func:`simulate` drives a team along scripted commands (the paper's precomputed paths, any
``(N, K, 2)`` array, or a simple reactive controller), runs each robot's :class:`PolySlam`
on its own odometry and ranges, and records what the metrics need. It runs the env's own
stages (:mod:`polyslam_env.environment.stages`: simulate → sense → SLAM → exchange → record),
so an episode here and in the env cannot drift apart. Tests and the paper reproduction use
it; :func:`~polyslam_env.metrics.episode.robot_metrics` turns a run into the paper's numbers
(:class:`RobotRun` and :func:`robot_metrics` are re-exported from
:mod:`polyslam_env.metrics.episode`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from polyslam_env.comms.channel import ChannelConfig
from polyslam_env.comms.exchange import ExchangeStep, RendezvousExchange
from polyslam_env.core.errors import ConfigError, MapFileError
from polyslam_env.core.geometry import compose_inverse
from polyslam_env.core.seeding import make_rngs
from polyslam_env.environment import stages
from polyslam_env.metrics.episode import COMMS_METRICS, RobotRun, TeamHistory, robot_metrics
from polyslam_env.scenarios.paths import builtin_paths, load_paths
from polyslam_env.slam.config import SlamConfig, slam_preset
from polyslam_env.slam.ekf import start_error_covs
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import WorldConfig, paper_world_config
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World

__all__ = [
    "COMMS_METRICS",
    "Controller",
    "RobotRun",
    "SimulationResult",
    "robot_metrics",
    "simulate",
    "wall_follow_controller",
]

#: controller(step, scans (N, B)) -> commands (N, 2); it sees only the robots' own ranges.
Controller = Callable[[int, np.ndarray], np.ndarray]


@dataclass
class SimulationResult:
    """A finished simulation: the layout, one :class:`RobotRun` per robot, and settings."""

    layout: Layout
    runs: list[RobotRun]
    seed: int | None
    steps: int
    meta: dict[str, Any] = field(default_factory=dict)
    shadow_runs: dict[int, RobotRun] = field(default_factory=dict)  # robot → its lone SLAM

    def metrics(self) -> list[dict[str, float]]:
        return [robot_metrics(run, self.layout) for run in self.runs]


def wall_follow_controller(
    world_config: WorldConfig, speed: float = 0.08, distance: float = 0.4
) -> Controller:
    """A reactive right-hand wall follower on each robot's own (noisy) ranges.

    It needs the beams at −90°, −45° and 0° (the default sensor has them); it turns left in
    place when the way ahead is blocked and steers to keep the right wall at ``distance``.
    """
    angles = np.asarray(world_config.range_sensor.angles_deg)
    try:
        front, right_diag, right = (
            int(np.flatnonzero(np.isclose(angles, a))[0]) for a in (0.0, -45.0, -90.0)
        )
    except IndexError:
        raise ValueError("wall_follow_controller needs beams at 0, -45 and -90 degrees") from None
    omega_max = world_config.robot.omega_max

    def control(step: int, scans: np.ndarray) -> np.ndarray:
        out = np.zeros((len(scans), 2))
        for i, scan in enumerate(scans):
            ahead = min(scan[front], scan[right_diag] * np.cos(np.pi / 4) * 1.6)
            if ahead < distance + 0.05:
                out[i] = (0.0, 0.6)
                continue
            side = scan[right] if np.isfinite(scan[right]) else 2 * distance
            turn = float(np.clip(-1.5 * (side - distance), -0.8, 0.8))
            out[i] = (speed, np.clip(turn, -omega_max, omega_max))
        return out

    return control


def simulate(
    map: str | Layout = "paper",
    *,
    commands: np.ndarray | None = None,
    controller: Controller | None = None,
    num_robots: int | None = None,
    steps: int | None = None,
    seed: int | None = 0,
    world_config: WorldConfig | None = None,
    slam_config: SlamConfig | None = None,
    initial_error: bool = False,
    progress: Callable[[int], None] | None = None,
    exchange: bool | ChannelConfig | RendezvousExchange = False,
    shadow: Sequence[int] = (),
) -> SimulationResult:
    """Run ``num_robots`` robots with SLAM for ``steps`` control periods.

    Motion comes from ``commands`` (N, K, 2) of (v, ω) if given, else from ``controller``,
    else from the map's built-in paths when there are some (the ``paper`` map), else from
    :func:`wall_follow_controller`. ``progress`` is called with each finished step.

    Each robot estimates in its own frame and starts at x̂ = 0 with covariance P0. With
    ``initial_error=False`` (the paper's setting) that frame sits exactly at the true start
    pose, so the initial error is zero while P0 is not and the standard NEES is below 3 by
    construction. ``initial_error=True`` draws the robot's true offset from its frame origin
    from N(0, P0) (stream ``"anchor"``), the setting in which a consistent filter's NEES is 3.

    ``exchange`` turns on rendezvous map exchange (SPEC §4) after every SLAM step: ``True``
    for the default :class:`ChannelConfig`, a config, or a ready :class:`RendezvousExchange`
    (e.g. one that logs payload sizes). Its counters land in ``RobotRun.comms`` and its
    messages in ``meta["exchange"]``. Off, the run is exactly as without it (and no camera
    frames are taken). Step numbers are the env's: the exchange runs as step ``k`` after the
    ``k``-th control period (1-based; ``sent_step``/``delivered_step`` count so), while
    ``controller(k, scans)`` and ``commands[:, k]`` index the command to apply, from 0.

    The loop runs the env's stages (:mod:`polyslam_env.environment.stages`): simulate →
    sense → SLAM → exchange → record. ``RobotRun.hit_points`` are the true points the beams
    hit (noiseless ranges of each step's ray cast, placed with the true pose).

    Without ``world_config`` / ``slam_config`` the run is the paper's: its five beams
    (:func:`~polyslam_env.world.config.paper_world_config`) and the ``paper`` SLAM preset.

    ``shadow`` lists robots that get a second, lone SLAM fed the very same odometry and
    ranges but never exchanging: their single-robot result on the identical episode
    (``SimulationResult.shadow_runs``), as in the paper's Fig 8. Shadows change nothing else.
    """
    wcfg = world_config or paper_world_config()
    scfg = slam_config or slam_preset("paper")
    if scfg.backend != "polynomial":
        raise ConfigError(
            f"slam.backend: simulate runs the polynomial EKF along scripted paths; {scfg.backend!r}"
            " runs in the env (polyslam run / evaluate with a config) and in polyslam reproduce"
        )
    layout = map if isinstance(map, Layout) else load_map(map)
    if num_robots is not None and num_robots > layout.num_start_poses:
        raise MapFileError(
            f"map {layout.name!r}: start_poses has {layout.num_start_poses} poses,"
            f" num_robots={num_robots} needs one each"
        )
    controller, num_robots, steps = _motion(layout, wcfg, commands, controller, num_robots, steps)

    world = World(layout, wcfg, num_robots, make_rngs(seed))
    slams = [
        PolySlam(scfg, wcfg.range_sensor.angles, wcfg.range_sensor.max_range)
        for _ in range(num_robots)
    ]
    frames = world.poses.copy()
    if initial_error:
        anchor = make_rngs(seed, ["anchor"])["anchor"]
        for i in range(num_robots):
            e0 = anchor.multivariate_normal(np.zeros(3), scfg.p0)
            frames[i] = compose_inverse(world.poses[i], e0)
    shadow = list(shadow)
    if any(not 0 <= i < num_robots for i in shadow):
        raise ValueError(f"shadow: robot indices must be in [0, {num_robots}), got {shadow}")
    shadows = [
        PolySlam(scfg, wcfg.range_sensor.angles, wcfg.range_sensor.max_range) for _ in shadow
    ]
    every = slams + shadows  # the exchanging SLAMs, then the lone shadows
    robots = list(range(num_robots)) + shadow  # every[j] runs on world robot robots[j]
    history = TeamHistory(
        frames[robots],
        np.array([s.pose for s in every]),
        np.array([s.pose_cov for s in every]),
        world.poses[robots],
        scfg.p0,
        np.asarray(wcfg.range_sensor.angles),
    )
    ex = _make_exchange(exchange, num_robots, seed, wcfg, scfg)
    angles = np.asarray(wcfg.range_sensor.angles)
    log: list[dict[str, Any]] = []
    sensing = stages.sense(world, camera=False)  # what the controller sees first
    for k in range(1, steps + 1):
        commands = np.asarray(controller(k - 1, sensing.ranges), dtype=float)
        result = stages.simulate(world, commands)
        sensing = stages.sense(world, camera=ex is not None)
        infos = stages.run_slam(every, robots, world.active, result.odometry, sensing.ranges)
        if ex is not None:
            delivered = stages.exchange_maps(ex, k, slams, world.active, sensing, angles)
            log += _delivered_log(delivered)
        poses = np.array([s.pose for s in every])  # each pose_cov, the team's in one call
        covs = np.array([s.pose_cov_relative for s in every]) + start_error_covs(poses, scfg.p0)
        estimates = poses, covs
        stages.record(history, robots, world, sensing, estimates, infos, result.collided)
        if progress is not None:
            progress(k)
    all_runs = [history.robot(j).run(s.polynomials()) for j, s in enumerate(every)]
    runs, lone_runs = all_runs[:num_robots], dict(zip(shadow, all_runs[num_robots:], strict=True))
    if ex is None:
        return SimulationResult(layout, runs, seed, steps, shadow_runs=lone_runs)
    for i, run in enumerate(runs):
        run.comms = ex.counters(i)
    return SimulationResult(
        layout, runs, seed, steps, meta={"exchange": log}, shadow_runs=lone_runs
    )


def _motion(
    layout: Layout,
    world_config: WorldConfig,
    commands: np.ndarray | None,
    controller: Controller | None,
    num_robots: int | None,
    steps: int | None,
) -> tuple[Controller, int, int]:
    """The controller, team size and number of steps :func:`simulate` runs (see there)."""
    if commands is None and controller is None:
        commands = _builtin_commands(layout.name)
    if commands is not None:
        commands = np.asarray(commands, dtype=float)
        if commands.ndim != 3 or commands.shape[2] != 2:
            raise ValueError(f"commands: expected shape (N, K, 2), got {commands.shape}")
        num_robots = num_robots or commands.shape[0]
        steps = steps or commands.shape[1]
        if commands.shape[0] < num_robots or commands.shape[1] < steps:
            raise ConfigError(
                f"commands: shape {commands.shape} is too small for {num_robots} robots"
                f" × {steps} steps"
            )
    num_robots = num_robots or min(3, layout.num_start_poses)
    steps = 200 if steps is None else steps
    if commands is not None:
        table = commands
        controller = lambda k, _scans: table[:num_robots, k]  # noqa: E731
    elif controller is None:
        controller = wall_follow_controller(world_config)
    return controller, num_robots, steps


def _make_exchange(
    exchange: bool | ChannelConfig | RendezvousExchange,
    num_robots: int,
    seed: int | None,
    wcfg: WorldConfig,
    scfg: SlamConfig,
) -> RendezvousExchange | None:
    """The exchange :func:`simulate` asked for (None when off); channel stream ``"channel"``."""
    if isinstance(exchange, RendezvousExchange):
        if exchange.num_robots != num_robots:
            raise ValueError(
                f"exchange: built for {exchange.num_robots} robots, the run has {num_robots}"
            )
        return exchange
    if exchange is False:
        return None
    config = ChannelConfig() if exchange is True else exchange
    rng = make_rngs(seed, ["channel"])["channel"]
    return stages.make_exchange(config, num_robots, rng, wcfg, scfg)


def _delivered_log(step: ExchangeStep) -> list[dict[str, Any]]:
    """The messages one exchange step delivered, as plain dicts (``meta["exchange"]``)."""
    return [
        {
            "sender": d.sender,
            "receiver": d.receiver,
            "kind": d.kind,
            "bytes": d.bytes,
            "n_polynomials": d.n_polynomials,
            "sent_step": d.sent_step,
            "delivered_step": d.delivered_step,
            "attempts": d.attempts,
        }
        for d in step.delivered
    ]


@functools.cache
def _builtin_commands(map_name: str) -> np.ndarray | None:
    """The precomputed paths shipped for a built-in map, if any (read-only; read from their
    YAML files once per process: parsing them cost more than a paper episode's SLAM)."""
    for name in builtin_paths():
        paths = load_paths(name)
        if paths.map == map_name:
            return paths.commands
    return None

"""The episode state of ``polyslam_v0``: everything one episode owns, in one dataclass.

:class:`EpisodeState` is made by :func:`~polyslam_env.environment.stages.new_episode` at
``reset``, held as ``env.episode`` (None before the first reset) and passed through the stages
of :mod:`polyslam_env.environment.stages`; the env object itself keeps only what it was
constructed with (config, spaces, layout source, encoder, renderer). Every field exists from
``reset`` on; nothing is added later. :class:`Sensing` is one step's sensor readings, kept in
the state because the step's observations read them. :func:`estimate` is what a robot
believes of its own pose (read-only).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from polyslam_env import metrics
from polyslam_env.comms.consensus import ConsensusExchange
from polyslam_env.comms.exchange import RendezvousExchange
from polyslam_env.comms.seif_exchange import SeifMapExchange
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment.observations import BeliefGrid, MapSampler
from polyslam_env.metrics.episode import RobotHistory
from polyslam_env.slam.backends import SlamRobot
from polyslam_env.slam.features import FeatureBook
from polyslam_env.world.physics import World
from polyslam_env.world.sensors import Detection

if TYPE_CHECKING:
    from polyslam_env.world.point_sensor import PillarReading

__all__ = ["EpisodeState", "Sensing", "estimate", "estimates"]


@dataclass(frozen=True)
class Sensing:
    """What the sensors read at the end of one step (or at reset).

    ``true_ranges`` are the noiseless ranges of the same ray cast as ``ranges``: they place the
    beam hit points of the histories (the true points the beams hit), never observations.
    """

    ranges: np.ndarray  # (N, B) noisy, inf = no return
    true_ranges: np.ndarray  # (N, B) noiseless, inf = no return
    detections: list[list[Detection]]  # per robot, the robots its camera sees
    pillars: tuple[PillarReading, ...] = ()  # per robot, with the pillar sensor on


@dataclass
class EpisodeState:
    """One episode of the env; robot ``i`` is agent ``robot_i``."""

    rngs: dict[str, np.random.Generator]  # named streams (layout, motion, sensor, camera, …)
    world: World  # pymunk world: true poses, physics, sensors
    coverage: metrics.CoverageGrid  # team coverage of the free cells (ground truth)
    start_poses: np.ndarray  # (N, 3) each robot's frame in the absolute frame
    angles: np.ndarray  # (B,) beam angles β_i
    slams: list[SlamRobot]  # one per robot (slam.backend), or empty with slam_enabled=False
    exchange: RendezvousExchange | None  # polynomial map exchange (None: off, no SLAM, points)
    consensus: ConsensusExchange | None  # MBLCC's landmark consensus (slam.backend: mblcc)
    # SEIF map fusion between robots (slam.backend: seif, channel.mode: alignment)
    seif_exchange: SeifMapExchange | None
    features: list[FeatureBook]  # per robot: its pillar map (empty list: not alignment mode)
    beliefs: list[BeliefGrid]  # per robot: cells its beams swept / hit, own frame
    samplers: list[MapSampler]  # per robot: its polynomials as points, cached
    histories: list[RobotHistory]  # per robot: what the end-of-episode metrics need
    sensing: Sensing  # the latest readings (observations use them)
    last_rendezvous: list[int | None]  # per robot: step of its last rendezvous
    completeness: list[float]  # per robot: map completeness behind the ``mapping`` term
    map_error: list[float]  # per robot: map error ∫δ ds (m²) behind the ``map_error`` term
    bytes_sent: list[int]  # per robot: bytes sent up to the last step (``bytes`` term)
    links: list[tuple[int, int]]  # pairs (i < j) that see each other (rendering)
    coverage_series: list[float]  # team coverage after each step (0: after reset)
    step_count: int = 0  # control steps done


def estimate(state: EpisodeState, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Robot i's pose (3,) and covariance (3, 3) in its start frame (truth without SLAM)."""
    if state.slams:
        return state.slams[i].pose, state.slams[i].pose_cov
    return between(state.start_poses[i], state.world.poses[i], wrap_remainder), np.zeros((3, 3))


def estimates(state: EpisodeState) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every robot's :func:`estimate` (without SLAM, the truth of all robots in one call)."""
    if state.slams:
        return [(slam.pose, slam.pose_cov) for slam in state.slams]
    truth = between(state.start_poses, state.world.poses, wrap_remainder)  # (N, 3)
    return [(pose, np.zeros((3, 3))) for pose in truth]

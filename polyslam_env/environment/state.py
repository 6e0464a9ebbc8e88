"""The episode state of ``polyslam_v0``: everything one episode owns, in one dataclass.

:class:`EpisodeState` is made by :func:`~polyslam_env.environment.stages.new_episode` at
``reset``, held as ``env.episode`` (None before the first reset) and passed through the stages
of :mod:`polyslam_env.environment.stages`; the env object itself keeps only what it was
constructed with (config, spaces, layout source, encoder, renderer). Every field exists from
``reset`` on; nothing is added later. Per-robot numbers are (N,) arrays, robot i's at i.
:class:`~polyslam_env.environment.sensing.Sensing` is one step's sensor readings, kept in the
state because the step's observations read them. :func:`estimate` is what a robot believes of
its own pose (read-only).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from polyslam_env import metrics
from polyslam_env.comms.consensus import ConsensusExchange
from polyslam_env.comms.exchange import RendezvousExchange
from polyslam_env.comms.seif_exchange import SeifMapExchange
from polyslam_env.environment.backends import TeamSlam
from polyslam_env.environment.observations import BeliefGrid
from polyslam_env.environment.sensing import Sensing
from polyslam_env.metrics.episode import RobotHistory, TeamHistory
from polyslam_env.slam.features import FeatureBook
from polyslam_env.world.physics import World

__all__ = ["NEVER", "EpisodeState", "Sensing", "estimate", "estimates"]

#: ``EpisodeState.last_rendezvous`` of a robot that never met anyone.
NEVER = -1


@dataclass
class EpisodeState:
    """One episode of the env; robot ``i`` is agent ``robot_i``."""

    rngs: dict[str, np.random.Generator]  # named streams (layout, motion, sensor, camera, …)
    world: World  # pymunk world: true poses, physics, sensors
    coverage: metrics.CoverageGrid  # team coverage of the free cells (ground truth)
    start_poses: np.ndarray  # (N, 3) each robot's frame in the absolute frame
    angles: np.ndarray  # (B,) beam angles β_i
    slam: TeamSlam  # the team's SLAM (slam.backend) and its exchange, see environment.backends
    beliefs: list[BeliefGrid]  # per robot: cells its beams swept / hit, own frame
    history: TeamHistory  # what the end-of-episode metrics need, one slot per robot
    histories: list[RobotHistory]  # per robot: its slot of ``history``
    sensing: Sensing  # the latest readings (observations use them)
    last_rendezvous: np.ndarray  # (N,) int64: step of each robot's last rendezvous, or NEVER
    rendezvous: np.ndarray  # (N,) int64: rendezvous of each robot so far
    completeness: np.ndarray  # (N,) map completeness behind the ``mapping`` term
    map_error: np.ndarray  # (N,) map error ∫δ ds (m²) behind the ``map_error`` term
    bytes_sent: np.ndarray  # (N,) int64: bytes sent up to the last step (``bytes`` term)
    links: list[tuple[int, int]]  # pairs (i < j) that see each other (rendering)
    coverage_series: list[float]  # team coverage after each step (0: after reset)
    step_count: int = 0  # control steps done

    # -- what the team's SLAM owns, by the names the state had before it owned it -------------
    @property
    def slams(self) -> Sequence[Any]:
        """The per-robot filters (robot i's at i); empty without SLAM."""
        return self.slam.robots

    @property
    def exchange(self) -> RendezvousExchange | None:
        """The polynomial map exchange (None: off, no SLAM, or a point back-end)."""
        return self.slam.map_exchange

    @property
    def consensus(self) -> ConsensusExchange | None:
        """MBLCC's landmark consensus (``slam.backend: mblcc`` with a channel), else None."""
        return self.slam.consensus

    @property
    def seif_exchange(self) -> SeifMapExchange | None:
        """The SEIF map fusion (``slam.backend: seif``, ``channel.mode: alignment``), else None."""
        return self.slam.fusion

    @property
    def features(self) -> list[FeatureBook]:
        """Per robot: its pillar map (empty list: not the polynomial exchange's alignment mode
        on pillars)."""
        return list(self.slam.features)


def estimate(state: EpisodeState, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Robot i's pose (3,) and covariance (3, 3) in its start frame (truth without SLAM)."""
    poses, covs = estimates(state)
    return poses[i], covs[i]


def estimates(state: EpisodeState) -> tuple[np.ndarray, np.ndarray]:
    """Every robot's pose estimate (N, 3) and covariance (N, 3, 3), each in its start frame
    (the truth, with zero covariance, without SLAM)."""
    return state.slam.estimates(state.world, state.start_poses)

"""``multirobot_known_start``: the seed's comparison, ref. [10] (Howard 2006), in the form its
setting allows: robots with known initial poses in one global frame, one Rao-Blackwellised
particle filter over the *joint* team trajectory and *one shared map*.

Each particle holds every robot's pose and a single set of landmark EKFs; every robot's
controls and sweeps update its own pose block (FastSLAM 2.0 proposal, as for the per-robot
filters, or with ``proposal: motion`` the motion model's: the seed does not say which its
ref. [10] used) and the shared landmarks, and resampling copies whole particles (all poses
and the map together), so every robot's sweep may resample every robot's trajectory. With
known starting poses Howard's time-reversed replay of the past is not needed: all data enter
as they arrive. It is a centralised estimator: communication is not
modelled (every robot's data reach the filter at once), so export/import exchange nothing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from polyslam_env.slam.points import particles as pt
from polyslam_env.slam.points.config import PointSlamConfig
from polyslam_env.slam.points.fastslam import SweepResult, sweep
from polyslam_env.slam.points.interface import LandmarkMap, LandmarkMessage, PointMeasurements


class SharedMapFastSlam:
    """The team's joint filter; :meth:`robot` gives each robot's back-end handle."""

    def __init__(
        self, config: PointSlamConfig, initial_poses: np.ndarray, rng: np.random.Generator
    ) -> None:
        self.config = config.replace(em_move=False, consensus_step=0.0)
        n = config.particles
        self._rng = rng
        self.poses = [pt.PoseBlock.at(p, n) for p in np.asarray(initial_poses, float)]
        self.map = pt.LandmarkBlock(n)
        self.log_weights = np.full(n, -np.log(n))
        self.estimates = [pt.pose_estimate(b.poses, self.log_weights) for b in self.poses]
        self.last_sweep: SweepResult | None = None  # diagnostics of the latest robot's step

    def robot(self, index: int) -> SharedMapRobot:
        return SharedMapRobot(self, index)

    def step_robot(self, index: int, controls: np.ndarray, meas: PointMeasurements) -> None:
        """Robot ``index``'s controls and sweep into the joint filter."""
        self.last_sweep = sweep(
            self.poses, index, self.map, self.log_weights, controls, meas, self.config, self._rng
        )
        self.log_weights, self.estimates[index] = (
            self.last_sweep.log_weights,
            self.last_sweep.estimate,
        )


class SharedMapRobot:
    """One robot's view of :class:`SharedMapFastSlam` (a ``PointSlamBackend``)."""

    def __init__(self, team: SharedMapFastSlam, index: int) -> None:
        self.team = team
        self.robot_id = index

    def step(self, controls: np.ndarray, measurements: PointMeasurements) -> None:
        self.team.step_robot(self.robot_id, controls, measurements)

    @property
    def last_sweep(self) -> SweepResult | None:
        """The joint filter's latest step, whichever robot's it was."""
        return self.team.last_sweep

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        mean, cov = self.team.estimates[self.robot_id]
        return mean.copy(), cov.copy()

    def landmarks(self) -> LandmarkMap:
        means, covs = pt.map_estimate(self.team.map, self.team.log_weights)
        return LandmarkMap(np.array(self.team.map.ids, dtype=np.int64), means, covs)

    def export_message(self) -> LandmarkMessage:
        return LandmarkMessage(self.robot_id, np.zeros(0, np.int64), np.zeros((0, 2)))

    def import_messages(self, messages: Sequence[LandmarkMessage]) -> None:
        """Nothing to import: the map is already shared."""

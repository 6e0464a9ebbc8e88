"""FastSLAM 2.0, EM-FastSLAM and MBLCC-FastSLAM for one robot (seed 003, §§2–3).

One sensor sweep (:func:`sweep`) follows the seed's steps in order:

1. predict each particle's pose Gaussian through the controls since the last sweep;
2. build FastSLAM 2.0's proposal by an EKF update of that Gaussian with every re-observed
   landmark (or, with ``proposal: motion``, keep the prediction itself: FastSLAM 1.0's
   proposal), and draw each particle's pose from it;
3. weight by eq. 3 (likelihood × motion prior / proposal), normalise;
4. EM-FastSLAM only: the attraction-repulsion move (``em``), then eq. 3 again at the moved
   poses; ``em_passes`` times;
5. take the pose estimate (weighted mean and covariance), then resample (systematic) when
   N_eff < 0.75 N;
6. update the landmark EKFs from the final poses (eqs. 9–13), MBLCC adding ε Σ_n (μ^n − μ)
   towards the other robots' best-particle estimates, and start EKFs for new landmarks.

:class:`PointFastSlam` is the thin stateful shell that holds one robot's particles between
sweeps and implements :class:`~polyslam_env.slam.points.interface.PointSlamBackend`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from polyslam_env.slam.points import models
from polyslam_env.slam.points import particles as pt
from polyslam_env.slam.points.config import PointSlamConfig
from polyslam_env.slam.points.em import em_move
from polyslam_env.slam.points.interface import LandmarkMap, LandmarkMessage, PointMeasurements

Neighbours = tuple[np.ndarray, np.ndarray]  # Σ_n μ^n (m, 2), count (m,) per re-observed landmark


class SweepResult(NamedTuple):
    """What one :func:`sweep` leaves: the new weights and estimate, and for diagnostics the
    effective sample size before resampling and each particle's parent."""

    log_weights: np.ndarray  # (N,) normalised
    best: int  # the particle that had the largest weight before resampling (after it)
    estimate: tuple[np.ndarray, np.ndarray]  # robot's pose mean (3,), cov (3, 3)
    effective_size: float  # N_eff of the weights the resampling decision saw
    parents: np.ndarray  # (N,) int: particle k descends from particle parents[k] of before


def sweep(
    blocks: Sequence[pt.PoseBlock],
    active: int,
    landmarks: pt.LandmarkBlock,
    log_w: np.ndarray,
    controls: np.ndarray,
    meas: PointMeasurements,
    config: PointSlamConfig,
    rng: np.random.Generator,
    neighbours: Neighbours | None = None,
) -> SweepResult:
    """One FastSLAM step of robot ``active`` on particles whose other pose blocks (robots
    sharing the map) are resampled along. The robot's pose estimate comes from the weighted
    particles before resampling: the same mean in expectation, without the resampling's
    noise, and a spread that resampling a few particles down to copies of one would zero."""
    block = blocks[active]
    noise = np.diag(np.square(config.measurement_sigmas))
    width = models.control_width(config)
    pt.predict(block, np.asarray(controls, float).reshape(-1, width), config)
    known = np.array([int(i) in landmarks.slots for i in meas.ids], dtype=bool)
    slots = landmarks.slots_of(meas.ids[known])
    z_known = meas.z[known]
    lm_means, lm_covs = landmarks.means[:, slots], landmarks.covs[:, slots]

    prior = (block.poses, block.covs)
    optimal = config.proposal == "fastslam2" and known.any()
    prop = pt.proposal(*prior, lm_means, lm_covs, z_known, noise) if optimal else prior
    x = pt.sample(rng, *prop)
    weights = pt.normalise(log_w + pt.log_weight(x, prior, prop, lm_means, lm_covs, z_known, noise))
    if config.em_move and known.any():
        for _ in range(config.em_passes):
            moved = em_move(rng, x, np.exp(weights), np.asarray(config.em_mobility))
            if moved is x:  # equal weights: every further pass would stand still too
                break
            x = moved
            inc = pt.log_weight(x, prior, prop, lm_means, lm_covs, z_known, noise)
            weights = pt.normalise(log_w + inc)
    block.poses, block.covs = x, np.zeros_like(block.covs)
    estimate = pt.pose_estimate(x, weights)  # before resampling, which only adds noise

    best = int(np.argmax(weights))
    n = len(weights)
    ess = pt.effective_size(weights)
    parents = np.arange(n)
    if ess < config.resample_fraction * n:
        parents = pt.systematic_resample(rng, weights)
        for b in blocks:
            b.take(parents)
        landmarks.take(parents)
        weights = np.full(n, -np.log(n))
        best = int(np.flatnonzero(parents == best)[0])

    if known.any():
        means, covs = pt.update_landmarks(
            landmarks.means[:, slots],
            landmarks.covs[:, slots],
            block.poses,
            z_known,
            noise,
            config.consensus_step,
            neighbours,
        )
        landmarks.means[:, slots], landmarks.covs[:, slots] = means, covs
    if not known.all():
        landmarks.add(meas.ids[~known], *pt.init_landmarks(block.poses, meas.z[~known], noise))
    return SweepResult(weights, best, estimate, ess, parents)


def gather_neighbours(ids: np.ndarray, messages: Sequence[LandmarkMessage]) -> Neighbours:
    """Σ_n μ^n and the count n for each id in ``ids`` over the messages that carry it."""
    total = np.zeros((len(ids), 2))
    count = np.zeros(len(ids))
    where = {int(i): k for k, i in enumerate(ids)}
    for msg in messages:
        for lid, mean in zip(msg.ids, msg.means, strict=True):
            k = where.get(int(lid))
            if k is not None:
                total[k] += mean
                count[k] += 1.0
    return total, count


class PointFastSlam:
    """One robot's FastSLAM 2.0 / EM-FastSLAM / MBLCC-FastSLAM, by ``config``'s switches.

    Starts with every particle at ``initial_pose`` (the seed's robots work in one known global
    frame, which MBLCC's exchange of landmark coordinates needs).
    """

    def __init__(
        self,
        config: PointSlamConfig,
        initial_pose: np.ndarray,
        rng: np.random.Generator,
        robot_id: int = 0,
    ) -> None:
        self.config = config
        self.robot_id = robot_id
        self._rng = rng
        n = config.particles
        self.poses = pt.PoseBlock.at(initial_pose, n)
        self.map = pt.LandmarkBlock(n)
        self.log_weights = np.full(n, -np.log(n))
        self._estimate = pt.pose_estimate(self.poses.poses, self.log_weights)
        self._best = 0
        self._last_ids = np.zeros(0, dtype=np.int64)
        self._inbox: list[LandmarkMessage] = []
        self.last_sweep: SweepResult | None = None  # diagnostics of the latest step

    def step(self, controls: np.ndarray, measurements: PointMeasurements) -> None:
        neighbours = None
        if self._inbox:
            neighbours = gather_neighbours(
                np.array([i for i in measurements.ids if int(i) in self.map.slots], np.int64),
                self._inbox,
            )
        self.last_sweep = sweep(
            [self.poses],
            0,
            self.map,
            self.log_weights,
            controls,
            measurements,
            self.config,
            self._rng,
            neighbours,
        )
        self.log_weights, self._best, self._estimate = self.last_sweep[:3]
        self._last_ids = measurements.ids.copy()
        self._inbox = []

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self._estimate[0].copy(), self._estimate[1].copy()

    def landmarks(self) -> LandmarkMap:
        means, covs = pt.map_estimate(self.map, self.log_weights)
        return LandmarkMap(np.array(self.map.ids, dtype=np.int64), means, covs)

    def best_landmarks(self) -> LandmarkMap:
        """The map of the particle that had the largest weight at the last sweep (the
        "most probable map" seed 004 aligns), rather than the weighted mixture."""
        m = len(self.map.ids)
        means = self.map.means[self._best, :m].copy()
        covs = self.map.covs[self._best, :m].copy()
        return LandmarkMap(np.array(self.map.ids, dtype=np.int64), means, covs)

    def export_message(self) -> LandmarkMessage:
        slots = self.map.slots_of(self._last_ids)
        return LandmarkMessage(
            self.robot_id, self._last_ids.copy(), self.map.means[self._best, slots]
        )

    def import_messages(self, messages: Sequence[LandmarkMessage]) -> None:
        """Keep the others' messages for the next step's eq. 12 (with ε = 0, as FastSLAM 2.0
        and EM-FastSLAM run, its term adds exactly zero: the filters stay independent)."""
        self._inbox = [m for m in messages if m.sender != self.robot_id]

"""A robot's map of point features (pillars), kept beside its SLAM for aligning maps.

Robots that never see each other can still merge maps if they can find the transform between
their frames from what both mapped (seed 004). The features are the pillars the pillar sensor
reports: range and bearing to the centre, with a noisy appearance descriptor. A robot tells
its own sightings of one pillar apart by the sensor's pillar id (the seeds' known data
association within one robot); between robots only positions and descriptors travel, so an
aligner has to match them by appearance and geometry.

Each sighting places the pillar with the robot's SLAM pose estimate of that step
(``slam.points.models.locate``); a feature's position is the mean of its placements and its
descriptor the mean of its observed descriptors. The positions are not corrected when the
SLAM later corrects its past (they are not in the filter's state): the aligners' support
threshold (0.4 m) and the outlier-dropping refinement absorb that drift, and the exchange
refines the transform on the walls both maps hold before fusing anything
(``comms.alignment``).
"""

from __future__ import annotations

import numpy as np

from polyslam_env.slam.alignment import FeatureMap
from polyslam_env.slam.points.models import locate

__all__ = ["FeatureBook"]


class FeatureBook:
    """Running means of one robot's pillar sightings, in its own frame."""

    def __init__(self, descriptor_dim: int) -> None:
        self.dim = int(descriptor_dim)
        self._slot: dict[int, int] = {}  # sensor id → row
        self._xy = np.zeros((16, 2))  # sums of placements
        self._desc = np.zeros((16, self.dim))  # sums of descriptors
        self._count = np.zeros(16, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._slot)

    def add(
        self, pose: np.ndarray, ids: np.ndarray, z: np.ndarray, descriptors: np.ndarray
    ) -> None:
        """One sweep: pillars ``ids`` (m,) seen at (range, bearing) ``z`` (m, 2) with
        descriptors (m, d), from the estimated pose (3,)."""
        if len(ids) == 0:
            return
        points, _ = locate(np.asarray(pose, dtype=float)[None, :], np.asarray(z, dtype=float))
        rows = np.array([self._row(int(i)) for i in ids], dtype=np.int64)
        np.add.at(self._xy, rows, points)
        np.add.at(self._desc, rows, np.asarray(descriptors, dtype=float).reshape(len(ids), -1))
        np.add.at(self._count, rows, 1)

    def _row(self, pillar: int) -> int:
        row = self._slot.get(pillar)
        if row is None:
            row = len(self._slot)
            if row == len(self._count):
                self._xy = np.vstack([self._xy, np.zeros_like(self._xy)])
                self._desc = np.vstack([self._desc, np.zeros_like(self._desc)])
                self._count = np.concatenate([self._count, np.zeros_like(self._count)])
            self._slot[pillar] = row
        return row

    def feature_map(self, min_sightings: int = 1) -> FeatureMap:
        """The features seen at least ``min_sightings`` times: mean positions and descriptors,
        in order of first sighting (no sensor ids: they do not travel)."""
        n = len(self._slot)
        keep = np.flatnonzero(self._count[:n] >= min_sightings)
        count = self._count[keep, None].astype(float)
        return FeatureMap(self._xy[keep] / count, self._desc[keep] / count)

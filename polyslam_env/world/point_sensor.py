"""Range-bearing sensors for point landmarks with known identities (seed 003, eq. 15).

* :func:`sense_points` — the seed's sensor for the kinematic runner: a pure function of the
  pose, the landmark positions and a random generator; no occlusion (the seed's sensor sees
  every landmark within range).
* :class:`PillarSensor` — the pymunk world's pillars (``Layout.pillars``, circles): range and
  bearing to the centres of the pillars within range, field of view and line of sight (walls
  and other pillars occlude; robots do not, like the camera's), each with a noisy appearance
  descriptor (seed 004's landmark descriptors). Every pillar has a true descriptor drawn once
  per world; a sighting adds noise to each number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.world import kernels
from polyslam_env.world.config import PillarSensorConfig
from polyslam_env.world.nearby import WallIndex


def _no_ids() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class PillarReading:
    """One robot's pillar sightings of one step, in pillar order."""

    ids: np.ndarray = field(default_factory=_no_ids)  # (m,) int64, index in Layout.pillars
    z: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (m, 2): range m, bearing
    descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (m, d)


class PillarSensor:
    """See the module docstring. Noise is drawn for every robot-pillar pair at every call,
    seen or not (range, bearing, then the descriptor's d numbers), so the stream a generator
    produces does not depend on the geometry."""

    def __init__(self, config: PillarSensorConfig, pillars: np.ndarray, rng: np.random.Generator):
        self.config = config
        self.pillars = np.ascontiguousarray(np.asarray(pillars, dtype=float).reshape(-1, 3))
        self.half_fov = math.radians(config.fov_deg) / 2.0
        #: (P, d) the pillars' true appearance descriptors, N(0, I)
        self.descriptors = rng.standard_normal((len(self.pillars), config.descriptor_dim))

    def visible(
        self, poses: np.ndarray, active: np.ndarray, walls: WallIndex
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noiseless (mask, distance, bearing), each (N, P): row = robot, column = pillar."""
        p = np.ascontiguousarray(np.asarray(poses, dtype=float).reshape(-1, 3))
        shape = (len(p), len(self.pillars))
        mask, dist, bearing = np.zeros(shape, dtype=bool), np.empty(shape), np.empty(shape)
        cfg = self.config
        kernels.pillar_visible(
            p, np.asarray(active, dtype=bool), cfg.max_range, self.half_fov, cfg.fov_deg < 360.0,
            *walls.arrays, self.pillars, mask, dist, bearing,
        )  # fmt: skip
        return mask, dist, bearing

    def sense(
        self, poses: np.ndarray, active: np.ndarray, walls: WallIndex, rng: np.random.Generator
    ) -> list[PillarReading]:
        """Per robot, its noisy sightings (ranges clipped to ≥ 0, bearings wrapped)."""
        mask, dist, bearing = self.visible(poses, active, walls)
        cfg = self.config
        n, count = mask.shape
        noise = rng.standard_normal((n, count, 2 + cfg.descriptor_dim))
        out = []
        for i in range(n):
            ids = np.flatnonzero(mask[i])
            e = noise[i, ids]
            z = np.column_stack(
                [
                    np.maximum(dist[i, ids] + cfg.sigma_range * e[:, 0], 0.0),
                    wrap_angle(bearing[i, ids] + cfg.sigma_bearing * e[:, 1]),
                ]
            )
            desc = self.descriptors[ids] + cfg.descriptor_sigma * e[:, 2:]
            out.append(PillarReading(ids.astype(np.int64), z, desc))
        return out


def sense_points(
    pose: np.ndarray,
    landmarks: np.ndarray,
    max_range: float,
    sigmas: tuple[float, float],
    rng: np.random.Generator | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Ids (m,) and noisy (range m, bearing rad) (m, 2) of the landmarks (M, 2) within
    ``max_range`` of ``pose`` (3,) [x, y, φ], in id order; ``rng=None`` gives exact values.

    Noise is Gaussian with standard deviations ``sigmas`` = (σ_r, σ_θ), the bearing wrapped to
    (−π, π]; one pair of normal draws per visible landmark, in id order.
    """
    d = np.asarray(landmarks, dtype=float) - np.asarray(pose[:2], dtype=float)
    r = np.hypot(d[:, 0], d[:, 1])
    ids = np.flatnonzero(r <= max_range).astype(np.int64)
    z = np.stack([r[ids], np.arctan2(d[ids, 1], d[ids, 0]) - pose[2]], axis=1)
    if rng is not None:
        z = z + rng.standard_normal(z.shape) * np.asarray(sigmas, dtype=float)
    z[:, 1] = wrap_angle(z[:, 1])
    return ids, z

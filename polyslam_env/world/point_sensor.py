"""A range-bearing sensor for point landmarks with known identities (seed 003, eq. 15).

A pure function of the pose, the landmark positions and a random generator, so the kinematic
runner uses it now and the pymunk world (pillars) can later. No occlusion: the seed's sensor
sees every landmark within range.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle


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

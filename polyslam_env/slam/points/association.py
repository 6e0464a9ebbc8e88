"""Data association for anonymous point measurements: nearest neighbour with χ² gating.

The seed's filters assume each measurement names its landmark. Without identities
(``world.pillar_sensor.identities: false``) the robot decides itself which landmark a
(range, bearing) reading belongs to. For every reading j and map landmark k the innovation
v = z_j − h(x̂, m̂_k) has covariance

    S_jk = H_x P_x H_xᵀ + H_m Σ_k H_mᵀ + R

(the pose–landmark cross-covariance is left out: a nearest-neighbour gate, not an update), and
d²_jk = vᵀ S⁻¹ v is χ²(2) for the right landmark. Pairs are taken greedily by increasing d²,
each reading and each landmark at most once (one reading per landmark and sweep, as the filters
require), while d² is inside the ``gate`` quantile. A reading left over whose nearest landmark
is further than the ``new`` quantile starts a new landmark; one in between is ambiguous and
dropped (it could be either a known landmark seen badly or a new one close to it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polyslam_env.slam.points import models

__all__ = ["Association", "associate"]


@dataclass(frozen=True)
class Association:
    """For each reading: the slot of its landmark (−1: none), and whether it starts one."""

    slots: np.ndarray  # (m,) int64, index into the map, −1 for new or dropped readings
    new: np.ndarray  # (m,) bool, readings that start a new landmark


def associate(
    pose: np.ndarray,
    pose_cov: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray,
    z: np.ndarray,
    noise: np.ndarray,
    gate: float,
    new: float,
) -> Association:
    """Readings z (m, 2) against the landmarks means (K, 2), covs (K, 2, 2) seen from the
    pose (3,) with covariance (3, 3), sensor noise (2, 2); ``gate`` ≤ ``new`` are χ²(2)
    thresholds on d² (see the module docstring)."""
    m, k = len(z), len(means)
    slots = np.full(m, -1, dtype=np.int64)
    if k == 0:
        return Association(slots, np.ones(m, dtype=bool))
    z_hat, h_pose, h_point = models.observe(pose[None], means)  # (K, 2), (K, 2, 3), (K, 2, 2)
    s = (
        h_pose @ pose_cov @ h_pose.swapaxes(-1, -2)
        + h_point @ covs @ h_point.swapaxes(-1, -2)
        + noise
    )  # (K, 2, 2)
    v = models.residual(np.repeat(z[:, None, :], k, axis=1), np.broadcast_to(z_hat, (m, k, 2)))
    d2 = np.einsum("mki,kij,mkj->mk", v, np.linalg.inv(s), v)  # (m, K)
    taken = np.zeros(k, dtype=bool)
    for flat in np.argsort(d2, axis=None, kind="stable"):
        j, slot = divmod(int(flat), k)
        if d2[j, slot] > gate:
            break
        if slots[j] < 0 and not taken[slot]:
            slots[j] = slot
            taken[slot] = True
    fresh = (slots < 0) & (d2.min(axis=1) > new)
    return Association(slots, fresh)

"""Nearest-neighbour association with χ² gating for anonymous point readings."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from polyslam_env.slam.points import models
from polyslam_env.slam.points.association import associate

GATE, NEW = chi2.ppf([0.99, 0.9999], 2)
NOISE = np.diag([0.03**2, np.radians(1.0) ** 2])
POSE = np.array([1.0, -0.5, 0.4])
POSE_COV = np.diag([1e-6, 1e-6, 1e-8])


def landmarks(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n landmarks at least 1 m apart around the pose, with tiny covariances."""
    rng = np.random.default_rng(seed)
    points: list[np.ndarray] = []
    while len(points) < n:
        p = POSE[:2] + rng.uniform(-4, 4, 2)
        if all(np.hypot(*(p - q)) > 1.0 for q in points) and np.hypot(*(p - POSE[:2])) > 0.5:
            points.append(p)
    return np.array(points), np.tile(np.eye(2) * 1e-6, (n, 1, 1))


def test_associate__noise_free_readings_find_their_landmarks_in_any_order() -> None:
    means, covs = landmarks(8)
    order = np.random.default_rng(1).permutation(8)[:5]
    z = models.observe(POSE[None], means[order])[0]
    out = associate(POSE, POSE_COV, means, covs, z, NOISE, GATE, NEW)
    np.testing.assert_array_equal(out.slots, order)
    assert not out.new.any()


def test_associate__empty_map_makes_every_reading_new() -> None:
    z = np.array([[1.0, 0.2], [2.0, -1.0]])
    out = associate(POSE, POSE_COV, np.zeros((0, 2)), np.zeros((0, 2, 2)), z, NOISE, GATE, NEW)
    np.testing.assert_array_equal(out.slots, [-1, -1])
    np.testing.assert_array_equal(out.new, [True, True])


def test_associate__gates_join_new_and_ambiguous_by_mahalanobis_distance() -> None:
    """A reading off its landmark's prediction by a range error of k σ has d² ≈ k² (the
    landmark's and pose's covariances are negligible here): 2σ joins (4 < 9.21), 3.5σ is
    ambiguous (12.25, between the gates) and dropped, 5σ starts a new landmark (25 > 18.42)."""
    means, covs = landmarks(1)
    z_hat = models.observe(POSE[None], means)[0][0]
    for k, slot, new in ((2.0, 0, False), (3.5, -1, False), (5.0, -1, True)):
        z = (z_hat + np.array([k * 0.03, 0.0]))[None]
        out = associate(POSE, POSE_COV, means, covs, z, NOISE, GATE, NEW)
        assert (out.slots[0], bool(out.new[0])) == (slot, new), k


def test_associate__a_landmark_takes_one_reading_the_closest() -> None:
    """Two readings near one landmark: the closer joins it; the other, 3.5σ off, is dropped
    (one reading per landmark and sweep)."""
    means, covs = landmarks(1)
    z_hat = models.observe(POSE[None], means)[0][0]
    z = np.array([z_hat + np.array([3.5 * 0.03, 0.0]), z_hat + np.array([0.5 * 0.03, 0.0])])
    out = associate(POSE, POSE_COV, means, covs, z, NOISE, GATE, NEW)
    np.testing.assert_array_equal(out.slots, [-1, 0])
    np.testing.assert_array_equal(out.new, [False, False])


def test_associate__pose_uncertainty_widens_the_gate() -> None:
    """The same 5σ range error joins when the pose's own uncertainty explains it."""
    means, covs = landmarks(1)
    z_hat = models.observe(POSE[None], means)[0][0]
    z = (z_hat + np.array([5 * 0.03, 0.0]))[None]
    loose = np.diag([0.1**2, 0.1**2, 1e-8])
    assert associate(POSE, loose, means, covs, z, NOISE, GATE, NEW).slots[0] == 0

"""SEIF map fusion without relative poses: right transform on overlapping pieces, no fusion of
unrelated places, information collapsed correctly."""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.slam.points import PointMeasurements
from polyslam_env.slam.points.seif import PointSeif
from polyslam_env.slam.points.seif_fusion import (
    CHI2_2DOF_99,
    FusionConfig,
    InformationMap,
    find_fusion,
    fuse,
)
from polyslam_env.world.kinematic import simulate_episode
from tests.slam.points.test_seif import WORLD, _filter_config


def _piece(seed: int, first: int, last: int) -> tuple[InformationMap, np.ndarray]:
    """The sweeps first..last−1 of robot 0 mapped alone from its own origin; the true pose
    of that origin."""
    robot = simulate_episode(WORLD, seed).robots[0]
    seif = PointSeif(_filter_config(), np.zeros(3))
    for k in range(first, last):
        seif.step(robot.controls[k], PointMeasurements(*robot.sweeps[k]))
    h, _ = seif.landmark_information()
    start = robot.initial_pose if first == 0 else robot.true_poses[first - 1]
    return InformationMap(seif.mu[3:].reshape(-1, 2), h, np.array(seif.ids)), start


def test_fusion__consecutive_pieces__right_transform_and_only_true_pairs() -> None:
    a, start_a = _piece(0, 0, 40)
    b, start_b = _piece(0, 40, 80)
    found = find_fusion(a, b, np.random.default_rng(0))
    assert found is not None
    truth = between(start_a, start_b, wrap_remainder)
    e = found.transform - truth
    e[2] = wrap_remainder(float(e[2]))
    # both pieces' maps are off by ~0.1 m (σ_r = 0.1 m): the transform within 0.5 m and 1°
    assert np.hypot(e[0], e[1]) < 0.5 and abs(np.degrees(e[2])) < 1.0
    assert np.all(a.ids[found.pairs[:, 0]] == b.ids[found.pairs[:, 1]])


def test_fusion__maps_of_unrelated_places__not_fused() -> None:
    """Pieces of two different landmark fields (seeds 0 and 1) share no place."""
    rng = np.random.default_rng(1)
    for first in (0, 40, 80):
        a, _ = _piece(0, first, first + 40)
        b, _ = _piece(1, first, first + 40)
        assert find_fusion(a, b, rng) is None


def test_fuse__collapsing_adds_information_and_keeps_every_other_landmark() -> None:
    """Fusing two maps: the fused map has |A| + |B| − pairs landmarks, and a collapsed
    landmark's marginal information is at least each side's (information only adds)."""
    a, _ = _piece(0, 0, 40)
    b, _ = _piece(0, 40, 80)
    found = find_fusion(a, b, np.random.default_rng(0))
    assert found is not None
    fused = fuse(a, b, found)
    assert len(fused) == len(a) + len(b) - len(found.pairs)
    cov_a, cov_f = a.covariances(), fused.covariances()
    for i, _ in found.pairs:
        # Σ_fused ≤ Σ_A in the PSD order
        assert np.linalg.eigvalsh(cov_a[i] - cov_f[i]).min() >= -1e-12
    np.testing.assert_array_equal(fused.information, fused.information.T)


def test_fusion_gate__is_scipy_stats_chi2_quantile_bit_for_bit() -> None:
    """The gate is computed without importing scipy.stats (a second of every process's
    start); it must be the very number scipy.stats gives, or fusion decisions would move."""
    import scipy.stats

    assert CHI2_2DOF_99 == float(scipy.stats.chi2.ppf(0.99, 2))
    assert FusionConfig().gate == CHI2_2DOF_99 and FusionConfig().gain == 0.5 * CHI2_2DOF_99

"""The range-bearing point sensor (seed 003, eq. 15)."""

from __future__ import annotations

import numpy as np

from polyslam_env.world.point_sensor import sense_points


def test_exact_sensing__sees_only_landmarks_in_range_with_true_range_and_bearing() -> None:
    landmarks = np.array([[10.0, 0.0], [0.0, 29.9], [0.0, -30.1], [-5.0, 5.0]])
    pose = np.array([0.0, 0.0, np.pi / 2])
    ids, z = sense_points(pose, landmarks, 30.0, (0.2, 0.035), None)
    np.testing.assert_array_equal(ids, [0, 1, 3])
    np.testing.assert_allclose(z[:, 0], [10.0, 29.9, np.hypot(5, 5)])
    np.testing.assert_allclose(z[:, 1], [-np.pi / 2, 0.0, np.pi / 4], atol=1e-15)


def test_noise__has_the_configured_standard_deviations() -> None:
    """Sample std of n = 4000 draws has relative standard error 1/√(2n) ≈ 1.1 %; 5 % is
    over four standard errors."""
    landmarks = np.array([[20.0, 0.0]])
    rng = np.random.default_rng(0)
    z = np.array(
        [sense_points(np.zeros(3), landmarks, 30.0, (0.2, 0.035), rng)[1][0] for _ in range(4000)]
    )
    np.testing.assert_allclose(z.std(axis=0), [0.2, 0.035], rtol=0.05)
    assert abs(z[:, 0].mean() - 20.0) < 4 * 0.2 / np.sqrt(4000)

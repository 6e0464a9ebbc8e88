"""The point filters' car and range-bearing models: Jacobians and agreement with the world."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from polyslam_env.slam.points import models
from polyslam_env.world.kinematic import car_step
from polyslam_env.world.point_sensor import sense_points
from tests.slam.finite_differences import FD_ATOL, FD_RTOL, FD_STEP


def fd_matrix(func: Callable[[np.ndarray], np.ndarray], x0: np.ndarray) -> np.ndarray:
    """Central differences of a vector function (angles in the output wrapped)."""
    cols = []
    for j in range(len(x0)):
        e = np.zeros(len(x0))
        e[j] = FD_STEP
        d = func(x0 + e) - func(x0 - e)
        cols.append(np.arctan2(np.sin(d), np.cos(d)) / (2 * FD_STEP))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("seed", range(5))
def test_move_jacobians__match_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = rng.uniform([-10, -10, -3], [10, 10, 3])
    ctrl = rng.uniform([1, -0.5], [5, 0.5])
    _, jp, jc = models.move(pose, ctrl[0], ctrl[1], 0.025, 4.0)
    fp = fd_matrix(lambda p: models.move(p, ctrl[0], ctrl[1], 0.025, 4.0)[0], pose)
    fc = fd_matrix(lambda c: models.move(pose, c[0], c[1], 0.025, 4.0)[0], ctrl)
    np.testing.assert_allclose(jp, fp, rtol=FD_RTOL, atol=FD_ATOL)
    np.testing.assert_allclose(jc, fc, rtol=FD_RTOL, atol=FD_ATOL)


@pytest.mark.parametrize("seed", range(5))
def test_observe_and_locate_jacobians__match_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = rng.uniform([-10, -10, -3], [10, 10, 3])
    point = pose[:2] + rng.uniform(2, 20) * np.array([np.cos(a := rng.uniform(-3, 3)), np.sin(a)])
    z, jp, jm = models.observe(pose, point)
    np.testing.assert_allclose(
        jp, fd_matrix(lambda p: models.observe(p, point)[0], pose), rtol=FD_RTOL, atol=FD_ATOL
    )
    np.testing.assert_allclose(
        jm, fd_matrix(lambda m: models.observe(pose, m)[0], point), rtol=FD_RTOL, atol=FD_ATOL
    )
    back, jz = models.locate(pose, z)
    np.testing.assert_allclose(back, point, atol=1e-12)

    def loc(zz: np.ndarray) -> np.ndarray:
        return models.locate(pose, zz)[0]

    cols = [(loc(z + e) - loc(z - e)) / (2 * FD_STEP) for e in np.eye(2) * FD_STEP]
    np.testing.assert_allclose(jz, np.stack(cols, axis=-1), rtol=FD_RTOL, atol=FD_ATOL)


def test_filter_models__agree_with_the_worlds_ground_truth() -> None:
    """The estimator's copies of eq. 14 and eq. 15 are the world's (up to float rounding)."""
    rng = np.random.default_rng(3)
    pose = np.array([1.0, -2.0, 0.4])
    for _ in range(50):
        v, g = rng.uniform(1, 5), rng.uniform(-0.5, 0.5)
        truth = car_step(pose, v, g, 0.025, 4.0)
        np.testing.assert_allclose(models.move(pose, v, g, 0.025, 4.0)[0], truth, atol=1e-14)
        pose = truth
    landmarks = rng.uniform(-30, 30, size=(40, 2))
    ids, z = sense_points(pose, landmarks, 30.0, (0.2, 0.03), None)
    np.testing.assert_allclose(models.observe(pose, landmarks[ids])[0], z, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_move_odometry_jacobians__match_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = rng.uniform([-10, -10, -3], [10, 10, 3])
    u = rng.uniform([-0.05, -0.01, -0.1], [0.3, 0.01, 0.1])
    _, jp, ju = models.move_odometry(pose, u)
    np.testing.assert_allclose(
        jp, fd_matrix(lambda p: models.move_odometry(p, u)[0], pose), rtol=FD_RTOL, atol=FD_ATOL
    )
    np.testing.assert_allclose(
        ju, fd_matrix(lambda v: models.move_odometry(pose, v)[0], u), rtol=FD_RTOL, atol=FD_ATOL
    )


def test_move_odometry__is_the_unicycle_composition_of_every_pose() -> None:
    """Batched poses move exactly as each alone, and as the pose composition the polynomial
    EKF predicts with (``core.geometry.compose``)."""
    from polyslam_env.core.geometry import compose

    rng = np.random.default_rng(7)
    poses = rng.uniform([-5, -5, -3], [5, 5, 3], (6, 3))
    u = np.array([0.2, -0.01, 0.05])
    batch, jp, ju = models.move_odometry(poses, u)
    for k, pose in enumerate(poses):
        alone, jp1, ju1 = models.move_odometry(pose, u)
        np.testing.assert_array_equal(batch[k], alone)
        np.testing.assert_array_equal(jp[k], jp1)
        np.testing.assert_array_equal(ju[k], ju1)
        np.testing.assert_array_equal(alone, compose(pose, u))

"""The filters' motion and measurement models, vectorised over any leading axes.

Motion is the seed's car model (eq. 14, with the speed factor its print drops): driven by the
measured speed V and steering angle G over a period dt, wheelbase D,

    x' = x + V dt cos(φ + G),   y' = y + V dt sin(φ + G),   φ' = φ + V dt sin(G) / D.

In the RL env the robots are differential drives that report odometry, so the filters there
use the odometry model instead (:func:`move_odometry`): the pose composed with the measured
increment u = (dx, dy, dθ) in the robot frame, as the polynomial EKF predicts (SPEC §3).
:func:`motion` picks the model a :class:`~polyslam_env.slam.points.config.PointSlamConfig`
names and returns its noise covariance with it.

Measurements are range and bearing to a point landmark (eq. 15). These are the estimator's own
copies of the models; the world's ground truth (``world.kinematic``, ``world.point_sensor``)
has its own, and a test checks that the two agree.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import compose, wrap_angle
from polyslam_env.slam.points.config import PointSlamConfig


def move(
    poses: np.ndarray, speed: float, steer: float, dt: float, wheelbase: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses (..., 3) after one period; also ∂/∂pose (..., 3, 3) and ∂/∂(V, G) (..., 3, 2)."""
    heading = poses[..., 2] + steer
    c, s = np.cos(heading), np.sin(heading)
    step = speed * dt
    out = np.empty_like(poses)
    out[..., 0] = poses[..., 0] + step * c
    out[..., 1] = poses[..., 1] + step * s
    out[..., 2] = wrap_angle(poses[..., 2] + step * np.sin(steer) / wheelbase)
    shape = poses.shape[:-1]
    jac_pose = np.zeros((*shape, 3, 3))
    jac_pose[..., 0, 0] = jac_pose[..., 1, 1] = jac_pose[..., 2, 2] = 1.0
    jac_pose[..., 0, 2] = -step * s
    jac_pose[..., 1, 2] = step * c
    jac_ctrl = np.zeros((*shape, 3, 2))
    jac_ctrl[..., 0, 0] = dt * c
    jac_ctrl[..., 0, 1] = -step * s
    jac_ctrl[..., 1, 0] = dt * s
    jac_ctrl[..., 1, 1] = step * c
    jac_ctrl[..., 2, 0] = dt * np.sin(steer) / wheelbase
    jac_ctrl[..., 2, 1] = step * np.cos(steer) / wheelbase
    return out, jac_pose, jac_ctrl


def move_odometry(
    poses: np.ndarray, odometry: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses (..., 3) composed with the odometry increment (3,) (dx, dy, dθ in the robot
    frame); also ∂/∂pose (..., 3, 3) and ∂/∂u (..., 3, 3)."""
    dx, dy = float(odometry[0]), float(odometry[1])
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    out = compose(poses, np.asarray(odometry, dtype=float))
    shape = poses.shape[:-1]
    jac_pose = np.zeros((*shape, 3, 3))
    jac_pose[..., 0, 0] = jac_pose[..., 1, 1] = jac_pose[..., 2, 2] = 1.0
    jac_pose[..., 0, 2] = -s * dx - c * dy
    jac_pose[..., 1, 2] = c * dx - s * dy
    jac_u = np.zeros((*shape, 3, 3))
    jac_u[..., 0, 0] = jac_u[..., 1, 1] = c
    jac_u[..., 0, 1] = -s
    jac_u[..., 1, 0] = s
    jac_u[..., 2, 2] = 1.0
    return out, jac_pose, jac_u


def control_width(config: PointSlamConfig) -> int:
    """Numbers per control: 2 for the car (V, G), 3 for odometry (dx, dy, dθ)."""
    return 2 if config.motion == "car" else 3


def motion(
    poses: np.ndarray, control: np.ndarray, config: PointSlamConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One period of ``config.motion``: poses (..., 3) after it, ∂/∂pose (..., 3, 3),
    ∂/∂control (..., 3, c) and the control noise covariance (c, c)."""
    if config.motion == "car":
        out, jac_pose, jac_ctrl = move(
            poses, float(control[0]), float(control[1]), config.dt, config.wheelbase
        )
    else:
        out, jac_pose, jac_ctrl = move_odometry(poses, control)
    return out, jac_pose, jac_ctrl, np.diag(np.square(config.control_sigmas))


def observe(poses: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted (range, bearing) (..., 2) of points (..., 2) from poses (..., 3).

    Also the Jacobians ∂z/∂pose (..., 2, 3) and ∂z/∂point (..., 2, 2).
    """
    dx = points[..., 0] - poses[..., 0]
    dy = points[..., 1] - poses[..., 1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    z = np.stack([r, wrap_angle(np.arctan2(dy, dx) - poses[..., 2])], axis=-1)
    jac_point = np.empty((*z.shape[:-1], 2, 2))
    jac_point[..., 0, 0] = dx / r
    jac_point[..., 0, 1] = dy / r
    jac_point[..., 1, 0] = -dy / q
    jac_point[..., 1, 1] = dx / q
    jac_pose = np.zeros((*z.shape[:-1], 2, 3))
    jac_pose[..., :, :2] = -jac_point
    jac_pose[..., 1, 2] = -1.0
    return z, jac_pose, jac_point


def locate(poses: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The point (..., 2) a measurement z (..., 2) places, and ∂point/∂z (..., 2, 2)."""
    angle = poses[..., 2] + z[..., 1]
    c, s = np.cos(angle), np.sin(angle)
    point = np.stack([poses[..., 0] + z[..., 0] * c, poses[..., 1] + z[..., 0] * s], axis=-1)
    jac = np.empty((*point.shape[:-1], 2, 2))
    jac[..., 0, 0] = c
    jac[..., 0, 1] = -z[..., 0] * s
    jac[..., 1, 0] = s
    jac[..., 1, 1] = z[..., 0] * c
    return point, jac


def residual(z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
    """z − ẑ with the bearing wrapped to (−π, π]."""
    v = z - z_hat
    v[..., 1] = wrap_angle(v[..., 1])
    return v


def pose_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a − b for poses, the heading wrapped."""
    d = a - b
    d[..., 2] = wrap_angle(d[..., 2])
    return d

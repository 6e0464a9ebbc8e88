"""Relative pose at a rendezvous and the transform that carries maps between start frames.

The SE(2) algebra (compose, inverse and their Jacobians) is :mod:`polyslam_env.core.geometry`;
a pose ``(x, y, θ)`` of frame B in frame A is the homogeneous transform ``T_{B,A}`` with
``p_A = R(θ) p_B + (x, y)``. What lives here is specific to the camera measurement.

Rendezvous geometry (SPEC §4, paper §3.2 with its typo fixed): robot j measures range ``d``
and bearing ``α_j`` (from its own axis) to robot l; robot l measures bearing ``α_l`` to j.
Then l sits at ``d (cos α_j, sin α_j)`` in j's body frame and ``θ_l − θ_j = π + α_j − α_l``.
The map transform is ``T_{l0,j0} = T_{j,j0} · T_{l,j} · T_{l,l0}⁻¹``.

Every function that a filter linearises comes with an analytic Jacobian (``*_with_jacobian``)
so the caller can propagate measurement and estimate covariance.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import (
    compose_with_jacobians,
    inverse_with_jacobian,
    wrap_angle,
)


# -- rendezvous measurement -> relative pose ----------------------------------------------------
def relative_pose(d: float, alpha_j: float, alpha_l: float) -> np.ndarray:
    """Pose (3,) of robot l in robot j's body frame from range ``d`` and the two bearings."""
    return relative_pose_with_jacobian(d, alpha_j, alpha_l)[0]


def relative_pose_with_jacobian(
    d: float, alpha_j: float, alpha_l: float
) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose (3,) and its Jacobian (3, 3) w.r.t. ``(d, α_j, α_l)``."""
    c, s = np.cos(alpha_j), np.sin(alpha_j)
    pose = np.array([d * c, d * s, float(wrap_angle(np.pi + alpha_j - alpha_l))])
    jac = np.array(
        [
            [c, -d * s, 0.0],
            [s, d * c, 0.0],
            [0.0, 1.0, -1.0],
        ]
    )
    return pose, jac


def relative_pose_covariance(
    d: float, alpha_j: float, alpha_l: float, sigma_d: float, sigma_bearing: float
) -> np.ndarray:
    """Covariance (3, 3) of :func:`relative_pose` for independent range and bearing noise."""
    _, jac = relative_pose_with_jacobian(d, alpha_j, alpha_l)
    noise = np.diag([sigma_d**2, sigma_bearing**2, sigma_bearing**2])
    return jac @ noise @ jac.T


# -- the rendezvous map transform -------------------------------------------------------------
def frame_transform(
    est_pose_j: np.ndarray, rel_pose_lj: np.ndarray, est_pose_l: np.ndarray
) -> np.ndarray:
    """``T_{l0,j0} = T_{j,j0} T_{l,j} T_{l,l0}⁻¹`` (3,): maps l's map frame into j's.

    ``est_pose_j`` is j's estimate in its own start frame, ``rel_pose_lj`` the pose of l in
    j's body frame (:func:`relative_pose`), ``est_pose_l`` l's estimate in its start frame.
    """
    return frame_transform_with_jacobian(est_pose_j, rel_pose_lj, est_pose_l)[0]


def frame_transform_with_jacobian(
    est_pose_j: np.ndarray, rel_pose_lj: np.ndarray, est_pose_l: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`frame_transform` (3,) and its Jacobian (3, 9).

    The Jacobian's columns are ordered ``(est_pose_j, rel_pose_lj, est_pose_l)``, three each.
    """
    u, du_dj, du_drel = compose_with_jacobians(est_pose_j, rel_pose_lj)
    inv_l, dinv_dl = inverse_with_jacobian(est_pose_l)
    out, dout_du, dout_dinv = compose_with_jacobians(u, inv_l)
    jac = np.hstack([dout_du @ du_dj, dout_du @ du_drel, dout_dinv @ dinv_dl])  # (3, 9)
    return out, jac

"""Relative pose at a rendezvous and the SE(2) algebra that carries maps between frames.

A pose ``(x, y, θ)`` of frame B in frame A is also the homogeneous transform ``T_{B,A}`` that
maps B coordinates to A coordinates: ``p_A = R(θ) p_B + (x, y)``. Composition
``compose(a, b)`` is the matrix product ``T_a T_b`` and ``inverse(a)`` the matrix inverse.

Rendezvous geometry (SPEC §4, paper §3.2 with its typo fixed): robot j measures range ``d``
and bearing ``α_j`` (from its own axis) to robot l; robot l measures bearing ``α_l`` to j.
Then l sits at ``d (cos α_j, sin α_j)`` in j's body frame and ``θ_l − θ_j = π + α_j − α_l``.
The map transform is ``T_{l0,j0} = T_{j,j0} · T_{l,j} · T_{l,l0}⁻¹``.

Every function that a filter linearises comes with an analytic Jacobian (``*_with_jacobian``)
so the caller can propagate measurement and estimate covariance.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle


def _pose(pose: np.ndarray) -> np.ndarray:
    p = np.asarray(pose, dtype=float)
    if p.shape != (3,):
        raise ValueError(f"a pose must have shape (3,), got {p.shape}")
    return p


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


# -- SE(2) ---------------------------------------------------------------------------------------
def as_matrix(pose: np.ndarray) -> np.ndarray:
    """Homogeneous matrix (3, 3) of a pose."""
    x, y, th = _pose(pose)
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def from_matrix(matrix: np.ndarray) -> np.ndarray:
    """Pose (3,) of a homogeneous matrix (3, 3)."""
    m = np.asarray(matrix, dtype=float)
    return np.array([m[0, 2], m[1, 2], float(np.arctan2(m[1, 0], m[0, 0]))])


def apply(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (…, 2) given in the frame ``pose`` mapped into its parent frame."""
    x, y, th = _pose(pose)
    c, s = np.cos(th), np.sin(th)
    p = np.asarray(points, dtype=float)
    return np.stack([x + c * p[..., 0] - s * p[..., 1], y + s * p[..., 0] + c * p[..., 1]], axis=-1)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a ⊕ b`` (3,): the pose whose matrix is ``T_a T_b``; heading wrapped."""
    return compose_with_jacobians(a, b)[0]


def compose_with_jacobians(
    a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``a ⊕ b`` (3,) and its Jacobians (3, 3) w.r.t. ``a`` and ``b``."""
    ax, ay, ath = _pose(a)
    bx, by, bth = _pose(b)
    c, s = np.cos(ath), np.sin(ath)
    out = np.array([ax + c * bx - s * by, ay + s * bx + c * by, float(wrap_angle(ath + bth))])
    j_a = np.array([[1.0, 0.0, -s * bx - c * by], [0.0, 1.0, c * bx - s * by], [0.0, 0.0, 1.0]])
    j_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return out, j_a, j_b


def inverse(a: np.ndarray) -> np.ndarray:
    """``a⁻¹`` (3,): the pose whose matrix is ``T_a⁻¹``; heading wrapped."""
    return inverse_with_jacobian(a)[0]


def inverse_with_jacobian(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a⁻¹`` (3,) and its Jacobian (3, 3) w.r.t. ``a``."""
    x, y, th = _pose(a)
    c, s = np.cos(th), np.sin(th)
    out = np.array([-c * x - s * y, s * x - c * y, float(wrap_angle(-th))])
    jac = np.array([[-c, -s, s * x - c * y], [s, -c, c * x + s * y], [0.0, 0.0, -1.0]])
    return out, jac


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

"""Relative pose at a rendezvous and the transform that carries maps between start frames.

The SE(2) algebra (compose, inverse and their Jacobians) is :mod:`polyslam_env.core.geometry`;
a pose ``(x, y, θ)`` of frame B in frame A is the homogeneous transform ``T_{B,A}`` with
``p_A = R(θ) p_B + (x, y)``. What lives here is specific to the camera measurement.

Rendezvous geometry (SPEC §4, paper §3.2 with its typo fixed): robot j measures range ``d``
and bearing ``α_j`` (from its own axis) to robot l; robot l measures bearing ``α_l`` to j.
Then l sits at ``d (cos α_j, sin α_j)`` in j's body frame and ``θ_l − θ_j = π + α_j − α_l``.
The map transform is ``T_{l0,j0} = T_{j,j0} · T_{l,j} · T_{l,l0}⁻¹``.

Every function that a filter linearises comes with an analytic Jacobian (``*_with_jacobian``)
so the caller can propagate measurement and estimate covariance. The exchange runs them once
per delivered message as one compiled call, :func:`rendezvous_transform`.
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.geometry import (
    compose_with_jacobians,
    inverse_with_jacobian,
    wrap_angle,
)
from polyslam_env.core.jit import njit
from polyslam_env.slam.kernels import fma_product3, wrap


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


# -- compiled: the exchange's transform of one delivery -------------------------------------------
@njit
def delivery_transform(
    receiver_pose: np.ndarray,  # (3,)
    sighting_pose: np.ndarray,  # (3,)
    distance: float,
    bearing_receiver: float,
    bearing_sender: float,
    sender_pose: np.ndarray,  # (3,)
    range_var: float,
    bearing_var: float,
    pose_var: np.ndarray,  # (3,)
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rendezvous_transform` of a delivery whose receiver measured ``distance`` and
    ``bearing_receiver`` when its pose estimate was ``sighting_pose``: the motion since is
    ``sighting_pose⁻¹ ⊕ receiver_pose`` (``geometry.inverse`` and ``compose``)."""
    back = _inverse(sighting_pose[0], sighting_pose[1], sighting_pose[2])
    motion = _compose(back, (receiver_pose[0], receiver_pose[1], receiver_pose[2]))
    return rendezvous_transform(
        receiver_pose, np.array([motion[0], motion[1], motion[2]]), distance, bearing_receiver,
        bearing_sender, sender_pose, range_var, bearing_var, pose_var,
    )  # fmt: skip


@njit
def rendezvous_transform(
    receiver_pose: np.ndarray,  # (3,)
    motion_since: np.ndarray,  # (3,)
    distance: float,
    bearing_receiver: float,
    bearing_sender: float,
    sender_pose: np.ndarray,  # (3,)
    range_var: float,
    bearing_var: float,
    pose_var: np.ndarray,  # (3,)
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``exchange.map_transform`` and the covariance of its noise in one call: T (3,),
    ∂T/∂(receiver's current pose) (3, 3), ∂T/∂[relative pose | sender pose] (3, 6) and the
    noise's covariance (6, 6), block-diagonal: :func:`relative_pose_covariance` with the
    camera's ``range_var`` and ``bearing_var``, then ``diag(pose_var)``.

    The receiver measured ``distance`` and ``bearing_receiver`` when its pose was
    ``receiver_pose ⊕ motion_since⁻¹``. The operations of the numpy functions above
    (``core.geometry``'s compose and inverse, their Jacobians, Python's float modulo for the
    wrap), the 3 × 3 products as numpy's matmul runs them on OpenBLAS's gemm
    (:func:`_product3`); the numpy form is the oracle in ``tests/comms/reference_geometry.py``
    (one message cost ~0.3 ms in it, nearly all numpy's per-call cost on 3-vectors)."""
    undo = _inverse(motion_since[0], motion_since[1], motion_since[2])
    now = (receiver_pose[0], receiver_pose[1], receiver_pose[2])
    then = _compose(now, undo)
    j_then = _jacobian_a(now, undo)
    # relative pose of the sender in the receiver's body frame, and its Jacobian
    c, s = math.cos(bearing_receiver), math.sin(bearing_receiver)
    rel = (distance * c, distance * s, wrap(math.pi + bearing_receiver - bearing_sender))
    d_rel = np.zeros((3, 3))
    d_rel[0, 0], d_rel[0, 1] = c, -distance * s
    d_rel[1, 0], d_rel[1, 1] = s, distance * c
    d_rel[2, 1], d_rel[2, 2] = 1.0, -1.0
    # T = (then ⊕ rel) ⊕ sender⁻¹ and its Jacobian (3, 9): (then, rel, sender)
    u = _compose(then, rel)
    du_dthen, du_drel = _jacobian_a(then, rel), _jacobian_b(then[2])
    sender = (sender_pose[0], sender_pose[1], sender_pose[2])
    inv_sender = _inverse(sender[0], sender[1], sender[2])
    cl, sl = math.cos(sender[2]), math.sin(sender[2])
    dinv = np.zeros((3, 3))
    dinv[0, 0], dinv[0, 1], dinv[0, 2] = -cl, -sl, sl * sender[0] - cl * sender[1]
    dinv[1, 0], dinv[1, 1], dinv[1, 2] = sl, -cl, cl * sender[0] + sl * sender[1]
    dinv[2, 2] = -1.0
    out = _compose(u, inv_sender)
    dout_du, dout_dinv = _jacobian_a(u, inv_sender), _jacobian_b(u[2])
    transform = np.array([out[0], out[1], out[2]])
    d_then = _product3(dout_du, du_dthen, False)
    d_state = _product3(d_then, j_then, False)
    d_noise = np.empty((3, 6))
    d_noise[:, :3] = _product3(dout_du, du_drel, False)
    d_noise[:, 3:] = _product3(dout_dinv, dinv, False)
    # the noise's covariance: J diag(σ_d², σ_α², σ_α²) Jᵀ of the relative pose, the pose's
    camera = np.zeros((3, 3))
    camera[0, 0], camera[1, 1], camera[2, 2] = range_var, bearing_var, bearing_var
    noise_cov = np.zeros((6, 6))
    noise_cov[:3, :3] = _product3(_product3(d_rel, camera, False), d_rel, True)
    for k in range(3):
        noise_cov[3 + k, 3 + k] = pose_var[k]
    return transform, d_state, d_noise, noise_cov


@njit
def _inverse(x: float, y: float, theta: float) -> tuple[float, float, float]:
    """``geometry.inverse`` of one pose."""
    c, s = math.cos(theta), math.sin(theta)
    return -c * x - s * y, s * x - c * y, wrap(-theta)


@njit
def _compose(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> tuple[float, float, float]:
    """``geometry.compose`` of two poses."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2])


@njit
def _jacobian_a(a: tuple[float, float, float], b: tuple[float, float, float]) -> np.ndarray:
    """∂(a ⊕ b)/∂a (3, 3) as ``geometry.compose_with_jacobians`` builds it."""
    c, s = math.cos(a[2]), math.sin(a[2])
    out = np.eye(3)
    out[0, 2] = -s * b[0] - c * b[1]
    out[1, 2] = c * b[0] - s * b[1]
    return out


@njit
def _jacobian_b(theta: float) -> np.ndarray:
    """∂(a ⊕ b)/∂b (3, 3) of a pose a with heading ``theta``."""
    c, s = math.cos(theta), math.sin(theta)
    out = np.eye(3)
    out[0, 0], out[0, 1] = c, -s
    out[1, 0], out[1, 1] = s, c
    return out


@njit
def _product3(a: np.ndarray, b: np.ndarray, transposed: bool) -> np.ndarray:
    """a b (or a bᵀ when ``transposed``) of 3 × 3 matrices as numpy's matmul computes it on
    OpenBLAS's gemm (:func:`~polyslam_env.slam.kernels.fma_product3`: each entry a chain of
    fused multiply-adds along the inner index from 0, the zeros included, which settle the
    sign of an exact zero), as a new array."""
    out = np.empty((3, 3))
    fma_product3(a, b, transposed, out)
    return out

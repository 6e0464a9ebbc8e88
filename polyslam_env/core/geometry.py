"""Small planar geometry shared by every layer (numpy only, so ``slam/`` may use it too).

Angles: :func:`wrap_angle` (and its float twin :func:`wrap_scalar`) and the exact
:func:`wrap_remainder`. SE(2): a pose ``(x, y, θ)`` of frame B in frame A is also the transform
``p_A = R(θ) p_B + (x, y)`` (a homogeneous matrix), so :func:`compose` is the matrix
product, :func:`inverse` the matrix inverse, :func:`between` (``a⁻¹ ⊕ b``) the pose of
``b`` seen from ``a`` and :func:`compose_inverse` (``a ⊕ b⁻¹``) the frame in which ``a`` reads
``b``. Callers use these instead of writing their own; each keeps the exact floating-point
operations of the copy it replaced, so results stayed bit for bit the same.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from polyslam_env.core.jit import njit


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles (any shape) wrapped to (−π, π]: π − ((π − a) mod 2π), in one compiled call
    (:func:`_wrap_into`; numpy's four calls on a few angles cost 3 µs)."""
    a = np.asarray(angle, dtype=float)
    out = np.empty(a.shape)
    _wrap_into(np.ascontiguousarray(a.reshape(-1)), out.reshape(-1))
    return out


@njit
def _wrap_into(angles: np.ndarray, out: np.ndarray) -> None:
    """:func:`wrap_angle` of ``angles`` (M,) into ``out`` (M,): the formula of
    :func:`wrap_scalar` (Python's float modulo is numpy's mod, sign rules included)."""
    for i in range(angles.size):
        out[i] = math.pi - (math.pi - angles[i]) % (2.0 * math.pi)


def wrap_scalar(angle: float) -> float:
    """:func:`wrap_angle` of one float, without numpy's per-call cost (same formula)."""
    return math.pi - (math.pi - angle) % (2.0 * math.pi)


def wrap_remainder(angle: Any) -> Any:
    """Angles (a float or an array) wrapped to [−π, π] by the exact IEEE remainder (no rounding
    of small angles, unlike :func:`wrap_angle`, which maps 1e-20 to 0); numpy has no IEEE
    remainder, so arrays go element by element through :func:`math.remainder`."""
    a = np.asarray(angle, dtype=float)
    if a.ndim == 0:
        return math.remainder(angle, 2.0 * math.pi)
    flat = [math.remainder(x, 2.0 * math.pi) for x in a.ravel().tolist()]
    return np.array(flat).reshape(a.shape)


@njit
def symmetric_eigvals3(a: np.ndarray) -> tuple[float, float, float]:
    """Eigenvalues (ascending) of a symmetric 3×3 matrix in closed form (lower triangle read).

    The trigonometric solution of the characteristic cubic (Smith, 1961): with q = tr A / 3
    and p² = ‖A − qI‖²_F / 6, the eigenvalues are q + 2p·cos(φ + 2πk/3), φ = acos(det B / 2)/3,
    B = (A − qI)/p, at a twentieth of the cost of ``np.linalg.eigvalsh`` on one 3×3 matrix
    (the SLAM asks for two spectral norms per step, inside its compiled step). Accurate to a
    few ulps of ‖A‖ except where two eigenvalues (nearly) coincide: acos is steep at ±1, so
    that pair is off by up to ~1e-8·p (the other eigenvalue stays exact to ulps). That is
    harmless for what the SLAM does with them (LMS weights, thresholds), and tested in
    tests/core/test_geometry.py. Compiled (Python's float operations, same order).
    """
    a00, a10, a11 = a[0, 0], a[1, 0], a[1, 1]
    a20, a21, a22 = a[2, 0], a[2, 1], a[2, 2]
    off = a10 * a10 + a20 * a20 + a21 * a21
    if off == 0.0:  # diagonal: sort the three (Python's sorted: stable, by <)
        d0, d1, d2 = a00, a11, a22
        if d1 < d0:
            d0, d1 = d1, d0
        if d2 < d1:
            d1, d2 = d2, d1
            if d1 < d0:
                d0, d1 = d1, d0
        return d0, d1, d2
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0)
    det = (
        b00 * (b11 * b22 - a21 * a21)
        - a10 * (a10 * b22 - a21 * a20)
        + a20 * (a10 * a21 - b11 * a20)
    )
    half_det = det / (2.0 * p * p * p)
    clipped = -1.0 if -1.0 > half_det else half_det  # Python's min(max(h, −1), 1)
    clipped = 1.0 if 1.0 < clipped else clipped
    phi = math.acos(clipped) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return smallest, 3.0 * q - largest - smallest, largest


# -- SE(2) ----------------------------------------------------------------------------------------
def _columns(first: Any, *rest: Any) -> np.ndarray:  # (…, k)
    """``np.stack([first, *rest], axis=-1)`` of float arrays (or scalars) of ``first``'s shape,
    written into one new array: the same values without ``np.stack``'s dozen Python-level
    calls (these run several times per env step)."""
    out = np.empty((*np.asarray(first).shape, 1 + len(rest)))
    out[..., 0] = first
    for k, column in enumerate(rest, 1):
        out[..., k] = column
    return out


def _poses(pose: np.ndarray) -> np.ndarray:  # (…, 3)
    p = np.asarray(pose, dtype=float)
    if p.ndim == 0 or p.shape[-1] != 3:
        raise ValueError(f"a pose must have shape (3,) or (…, 3), got {p.shape}")
    return p


def _pose(pose: np.ndarray) -> np.ndarray:  # (3,)
    p = np.asarray(pose, dtype=float)
    if p.shape != (3,):
        raise ValueError(f"a pose must have shape (3,), got {p.shape}")
    return p


def rotation(theta: float) -> np.ndarray:  # (2, 2)
    """Rotation matrix R(θ)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def beam_endpoints(origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """End points (…, 2) of beams from ``origins`` (…, 2) along absolute ``angles`` (…) over
    ``ranges`` (…): ``origin + r·(cos φ, sin φ)``, broadcast (an inf or NaN range gives a
    non-finite end point)."""
    direction = _columns(np.cos(angles), np.sin(angles))  # (…, 2)
    return np.asarray(origins + np.asarray(ranges)[..., None] * direction)


def transform_points(points: np.ndarray, pose: np.ndarray) -> np.ndarray:  # (…, 2)
    """Points (…, 2) given in the frame whose pose in its parent is ``pose`` (3,), mapped into
    the parent: ``(x + c·p₀ − s·p₁, y + s·p₀ + c·p₁)``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    p = np.asarray(points, dtype=float)
    return _columns(
        pose[0] + c * p[..., 0] - s * p[..., 1], pose[1] + s * p[..., 0] + c * p[..., 1]
    )


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # (…, 3)
    """``a ⊕ b``: the pose whose matrix is ``T_a T_b``; poses (3,) or (…, 3), broadcast.

    Also the unicycle motion model f(pose, u) with odometry ``u = b`` in the robot frame.
    Heading wrapped with :func:`wrap_angle`.
    """
    a, b = _poses(a), _poses(b)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return _columns(x, y, wrap_angle(a[..., 2] + b[..., 2]))


def compose_with_jacobians(
    a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`compose` of two poses (3,) and its Jacobians (3, 3) w.r.t. ``a`` and ``b``."""
    a, b = _pose(a), _pose(b)
    c, s = np.cos(a[2]), np.sin(a[2])
    bx, by = b[0], b[1]
    j_a = np.array([[1.0, 0.0, -s * bx - c * by], [0.0, 1.0, c * bx - s * by], [0.0, 0.0, 1.0]])
    j_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return compose(a, b), j_a, j_b


def inverse(a: np.ndarray) -> np.ndarray:  # (…, 3)
    """``a⁻¹``: the pose whose matrix is ``T_a⁻¹``; poses (3,) or (…, 3); heading wrapped."""
    a = _poses(a)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x, y = a[..., 0], a[..., 1]
    return _columns(-c * x - s * y, s * x - c * y, wrap_angle(-a[..., 2]))


def inverse_with_jacobian(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`inverse` of a pose (3,) and its Jacobian (3, 3)."""
    a = _pose(a)
    c, s = np.cos(a[2]), np.sin(a[2])
    x, y = a[0], a[1]
    jac = np.array([[-c, -s, s * x - c * y], [s, -c, c * x + s * y], [0.0, 0.0, -1.0]])
    return inverse(a), jac


def between(
    a: np.ndarray, b: np.ndarray, wrap: Callable[[Any], Any] = wrap_angle
) -> np.ndarray:  # (…, 3)
    """``a⁻¹ ⊕ b``: pose ``b`` expressed in the frame ``a`` (both in the same parent).

    Computed as ``R(θ_a)ᵀ (b_xy − a_xy)`` and ``wrap(θ_b − θ_a)``: the odometry between two
    poses, or an absolute pose in a robot's start frame. Poses (3,) or (…, 3), broadcast.
    ``wrap`` is :func:`wrap_angle` (arrays) or :func:`wrap_remainder` (one pose). Row by row
    in one compiled call (:func:`_between_rows`; the world asks for every robot's odometry
    each step): numpy's dozen calls on three rows took 15 µs.
    """
    a, b = _poses(a), _poses(b)
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    out = np.empty(a.shape)
    rows = out.reshape(-1, 3)  # a view: out is new and contiguous
    turned = wrap is wrap_angle
    _between_rows(
        np.ascontiguousarray(a).reshape(-1, 3), np.ascontiguousarray(b).reshape(-1, 3), turned, rows
    )
    if not turned:  # the kernel left θ_b − θ_a
        out[..., 2] = wrap(out[..., 2])
    return out


@njit
def _between_rows(a: np.ndarray, b: np.ndarray, wrap: bool, out: np.ndarray) -> None:
    """:func:`between` of rows a, b (M, 3) into ``out`` (M, 3): numpy's float operations in
    numpy's order (cos and sin are the C library's in both), θ wrapped as :func:`wrap_angle`
    does (the formula of :func:`wrap_scalar`) when ``wrap``, else left as θ_b − θ_a."""
    for i in range(a.shape[0]):
        c, s = math.cos(a[i, 2]), math.sin(a[i, 2])
        dx, dy = b[i, 0] - a[i, 0], b[i, 1] - a[i, 1]
        out[i, 0] = c * dx + s * dy
        out[i, 1] = -s * dx + c * dy
        turn = b[i, 2] - a[i, 2]
        out[i, 2] = math.pi - (math.pi - turn) % (2.0 * math.pi) if wrap else turn


def compose_inverse(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # (…, 3)
    """``a ⊕ b⁻¹``: the frame F in which pose ``a`` reads ``b`` (``F ⊕ b = a``).

    Computed as ``θ = θ_a − θ_b`` (not wrapped) and ``a_xy − R(θ) b_xy``: a robot's start
    frame from its true pose and the offset its estimate starts at. Poses (3,) or (…, 3).
    """
    a, b = _poses(a), _poses(b)
    theta = a[..., 2] - b[..., 2]
    c, s = np.cos(theta), np.sin(theta)
    x = a[..., 0] - (c * b[..., 0] - s * b[..., 1])
    y = a[..., 1] - (s * b[..., 0] + c * b[..., 1])
    return _columns(x, y, theta)


def transform_covariance(covs: np.ndarray, pose: np.ndarray) -> np.ndarray:  # (…, 3, 3)
    """Pose covariances (…, 3, 3) given in the frame ``pose`` (3,), in its parent frame:
    ``T P Tᵀ`` with ``T = blockdiag(R(θ), 1)`` (a fixed frame adds no uncertainty)."""
    t = np.eye(3)
    t[:2, :2] = rotation(float(pose[2]))
    return np.asarray(t @ np.asarray(covs, dtype=float) @ t.T)

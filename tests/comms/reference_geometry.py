"""A received chain's geometry as readable numpy (the oracles of ``comms/kernels.py``'s
:func:`unit_tangents`, :func:`frame_chain`, :func:`received_geometry`,
:func:`variance_floor`, :func:`chain_fit` and :func:`better_cover`), and a delivery's
transform (the oracle of ``comms/relative_pose.py``'s :func:`rendezvous_transform`): the numpy
the exchange and the transform refinement ran before those were compiled."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from polyslam_env.comms.relative_pose import (
    frame_transform_with_jacobian,
    relative_pose,
    relative_pose_covariance,
)
from polyslam_env.core.geometry import compose, compose_with_jacobians, inverse, rotation
from polyslam_env.slam.fitting import J_ROT, Fit, PointSet, fit_polynomial
from polyslam_env.slam.polynomial import Polynomial


def frame_points(q: np.ndarray, transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """p = R(θ) q + t (N, 2) and ∂p/∂T (N, 2, 3)."""
    rq = q @ rotation(transform[2]).T  # (N, 2)
    dp_dt = np.zeros((len(q), 2, 3))
    dp_dt[:, :, :2] = np.eye(2)
    dp_dt[:, :, 2] = rq @ J_ROT.T
    return transform[:2] + rq, dp_dt


def tangents(chain: np.ndarray) -> np.ndarray:
    """(N, 2) unit tangents along a chain of points (N, 2)."""
    if len(chain) < 2:
        return np.tile([1.0, 0.0], (len(chain), 1))
    d = np.gradient(chain, axis=0)
    return np.asarray(d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12))


def chain_normals(q: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """(N, 2) unit normals of the chain ``q`` turned into the receiver's frame."""
    d = np.gradient(q, axis=0) if len(q) > 1 else np.array([[1.0, 0.0]])
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    out: np.ndarray = np.stack([-d[:, 1], d[:, 0]], axis=1) @ rotation(float(transform[2])).T
    return out


def normal_sigma(normal: np.ndarray, dp_dt: np.ndarray, cov_t: np.ndarray) -> np.ndarray:
    """Each point's σ along its normal from the transform's covariance."""
    g = np.einsum("ni,nij->nj", normal, dp_dt)  # (N, 3) ∂(normal offset)/∂T
    out: np.ndarray = np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", g, cov_t, g), 0.0))
    return out


def refit_variance_floor(
    normals: np.ndarray, cov_t: np.ndarray, shift: np.ndarray, shift_var: float
) -> float:
    """The least nᵀQn over the normals, Q the translation's covariance given the turn plus
    shift_var · shift shiftᵀ."""
    if len(normals) == 0:
        return 0.0
    cov_t = np.asarray(cov_t, dtype=float)
    q = cov_t[:2, :2].copy()
    if cov_t[2, 2] > 0.0:
        q -= np.outer(cov_t[:2, 2], cov_t[2, :2]) / cov_t[2, 2]
    q += shift_var * np.outer(shift, shift)
    return float(np.einsum("ni,ij,nj->n", normals, q, normals).min())


def point_jacobians(
    dp_dt: np.ndarray, d_state: np.ndarray, d_noise: np.ndarray, shift: np.ndarray, n_state: int
) -> tuple[np.ndarray, np.ndarray]:
    """A received chain's ∂p/∂state (N, 2, n_state) and ∂p/∂noise (N, 2, 1 + K)."""
    n_pts = len(dp_dt)
    out_state = np.zeros((n_pts, 2, n_state))
    out_state[:, :, :3] = dp_dt @ d_state
    out_noise = np.concatenate(
        [np.broadcast_to(shift[None, :, None], (n_pts, 2, 1)), dp_dt @ d_noise], axis=2
    )
    return out_state, out_noise


def fit_chain(points: PointSet, order: int, auto_order: bool, tol: float) -> tuple[Fit, float]:
    """``exchange._fit_chain`` fit by fit (its form before :func:`~polyslam_env.comms.kernels.
    chain_fit`): orders 1 … ``order`` through :func:`fit_polynomial` until the largest |η
    residual| is within ``tol``, the coefficients then padded to ``order + 1``."""
    for m in range(1, order + 1) if auto_order else (order,):
        fit = fit_polynomial(points, m, None, shape_fixed=True, auto_order=False)
        xi, eta = fit.poly.from_xy(points.xy)
        worst = float(np.max(np.abs(eta - fit.poly.value(xi))))
        if worst <= tol:
            break
    coeffs = np.zeros(order + 1)
    coeffs[: fit.poly.order + 1] = fit.poly.coeffs
    poly = Polynomial(fit.poly.variate, coeffs, fit.poly.lo, fit.poly.hi)
    return Fit(poly, fit.c0, fit.Gx, fit.Gy, fit.V, fit.rms, fit.order), worst


def covered_points(xy: np.ndarray, polys: Sequence[Polynomial], reach: float) -> np.ndarray:
    """(N,) True where a point (N, 2) lies within ``polys``' extents (its ξ) and within
    ``reach`` (m) of the curve along η: the readable form of the cover in
    :func:`~polyslam_env.comms.kernels.better_cover`."""
    out = np.zeros(len(xy), dtype=bool)
    for poly in polys:
        xi, eta = poly.from_xy(xy)
        out |= (xi >= poly.lo) & (xi <= poly.hi) & (np.abs(eta - poly.value(xi)) <= reach)
    return out


def map_transform(
    receiver_pose: np.ndarray,
    motion_since: np.ndarray,
    distance: float,
    bearing_receiver: float,
    bearing_sender: float,
    sender_pose: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``exchange.map_transform``: T (3,), ∂T/∂(receiver's current pose) (3, 3) and
    ∂T/∂[relative pose | sender pose] (3, 6)."""
    pose_then, j_then, _ = compose_with_jacobians(receiver_pose, inverse(motion_since))
    rel = relative_pose(distance, bearing_receiver, bearing_sender)
    transform, jac = frame_transform_with_jacobian(pose_then, rel, sender_pose)
    return transform, jac[:, :3] @ j_then, jac[:, 3:]


def delivery_transform(
    receiver_pose: np.ndarray,
    sighting_pose: np.ndarray,
    distance: float,
    bearing_receiver: float,
    bearing_sender: float,
    sender_pose: np.ndarray,
    sigma_d: float,
    sigma_bearing: float,
    pose_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``RendezvousExchange._transform``: :func:`map_transform` with the motion since the
    sighting, and the noise's covariance (6, 6)."""
    motion = compose(inverse(sighting_pose), receiver_pose)  # estimated motion since
    out = map_transform(
        receiver_pose, motion, distance, bearing_receiver, bearing_sender, sender_pose
    )
    rel_cov = relative_pose_covariance(
        distance, bearing_receiver, bearing_sender, sigma_d, sigma_bearing
    )
    noise_cov = np.zeros((6, 6))
    noise_cov[:3, :3] = rel_cov
    noise_cov[3:, 3:] = np.diag(pose_var)
    return (*out, noise_cov)


def table_walls(
    rows: np.ndarray,
    order: np.ndarray,
    variate: np.ndarray,
    shape: np.ndarray,
    c0s: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    cov: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``exchange._table_walls`` as numpy ran it (the walls' order, variate, coefficients with
    the current c0 first, extent) and each wall's ``exchange.normal_variance`` of its c0's
    variance (the state's diagonal at 3 + row)."""
    from polyslam_env.comms.exchange import normal_variance

    order_r = order[rows]
    width = int(order_r.max(initial=1)) + 1
    coeffs = shape[rows, :width]  # a copy: [0, b_1, …]
    coeffs[:, 0] = c0s[rows]
    extent = np.stack([lo[rows], hi[rows]], axis=1)
    c0_var = np.diagonal(cov)[3 + rows]
    wall_var = np.array(
        [
            normal_variance(
                Polynomial(int(v), coeffs[k, : int(m) + 1], float(a), float(b)), float(var)
            )
            for k, (v, m, (a, b), var) in enumerate(
                zip(variate[rows], order_r, extent, c0_var, strict=True)
            )
        ]
    ).reshape(-1)
    return order_r, variate[rows], coeffs, extent, wall_var


def square_turn(
    sent: list[tuple[float, float]], held: list[tuple[float, float]], turn: float
) -> float | None:
    """``alignment.square_turn`` in numpy: the length-weighted median of the sent walls'
    square turns (argsort, cumsum, searchsorted)."""
    from polyslam_env.slam.links import off_square

    if not sent or not held:
        return None
    reference = max(held, key=lambda w: w[1])[0]
    turns = np.array([turn - off_square(d + turn - reference) for d, _ in sent])
    weights = np.array([length for _, length in sent])
    order = np.argsort(turns)
    cumulative = np.cumsum(weights[order])
    return float(turns[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])

"""The collinearity rows of a link as ``slam/links.py`` built them from point sets (the
oracle of :func:`~polyslam_env.slam.links.link_rows`, which computes the same entries in
floats): each row's point on each curve and its Jacobian from
:func:`~polyslam_env.slam.fitting.polynomial_points`."""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import rotation
from polyslam_env.slam.fitting import polynomial_points
from polyslam_env.slam.polynomial import Polynomial


def link_rows(
    poly_i: Polynomial,
    c0_index_i: int,
    turn_i: tuple[int, float] | None,
    poly_j: Polynomial,
    c0_index_j: int,
    turn_j: tuple[int, float] | None,
    xis: np.ndarray,
    n_state: int,
) -> tuple[np.ndarray, np.ndarray]:
    """η_i(ξ) − η_j(ξ) at ``xis`` (m,) and its Jacobian (m, ``n_state``): a curve's η at a
    fixed ξ moves by δπ_η − B'(ξ)·δπ_ξ when its point moves by δπ = D δX."""
    xis = np.asarray(xis, dtype=float).reshape(-1)
    eta = 1 if poly_i.variate == 1 else 0  # the column of η in a point (x¹, x²)
    residual = np.zeros(xis.size)
    H = np.zeros((xis.size, n_state))
    for sign, poly, c0_index, turn in (
        (1.0, poly_i, c0_index_i, turn_i),
        (-1.0, poly_j, c0_index_j, turn_j),
    ):
        for row, xi in enumerate(xis.tolist()):
            pts = polynomial_points(poly, c0_index, 1.0, 1, xi, xi, n_state, turn)
            d = pts.d_state[0]  # (2, n_state)
            H[row] += sign * (d[eta] - float(poly.slope(xi)) * d[1 - eta])
            residual[row] += sign * float(pts.xy[0, eta])
    return residual, H


def turned_line(poly: Polynomial, pivot: float, angle: float) -> Polynomial:
    """:func:`~polyslam_env.slam.links.turned_line` in numpy (before
    :func:`~polyslam_env.slam.map_kernels.turned_line`): its oracle, bit for bit."""
    if np.any(poly.coeffs[2:] != 0.0):
        raise ValueError("turned_line: the polynomial must be a straight line")
    slope = float(poly.coeffs[1])
    eta_c = poly.c0 + slope * pivot
    xi_axis, eta_axis = (0, 1) if poly.variate == 1 else (1, 0)
    direction = np.zeros(2)
    direction[xi_axis], direction[eta_axis] = 1.0, slope
    turned = rotation(angle) @ direction
    new_slope = float(turned[eta_axis] / turned[xi_axis])
    coeffs = np.zeros_like(poly.coeffs)
    coeffs[0], coeffs[1] = eta_c - new_slope * pivot, new_slope
    return Polynomial(poly.variate, coeffs, poly.lo, poly.hi)

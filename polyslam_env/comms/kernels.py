"""Compiled kernels of the map exchange (:mod:`~polyslam_env.comms.alignment`).

:func:`match_walls` is the point-to-wall pairing of the transform refinement, point by point
in the numpy version's operations (``tests/comms/test_alignment.py`` holds that version as the
oracle and checks the two bit for bit).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import njit


@njit
def _horner(coeffs: np.ndarray, x: float) -> float:
    """Σ_j coeffs[j] x^j as ``slam.polynomial.polyval`` computes it (``c[-1] + x·0`` first)."""
    n = coeffs.size
    value = coeffs[n - 1] + x * 0.0
    for i in range(2, n + 1):
        value = coeffs[n - i] + value * x
    return value


@njit
def match_walls(
    p: np.ndarray,  # (N, 2) received points in the receiver's frame
    dp_dt: np.ndarray,  # (N, 2, 3) ∂p/∂T
    tangents: np.ndarray,  # (N, 2)
    variate: np.ndarray,  # (W,) int64, 1 or 2
    coeffs: np.ndarray,  # (W, M+1) zero-padded, current c0 first
    extent: np.ndarray,  # (W, 2) lo, hi
    cov_t: np.ndarray,  # (3, 3)
    point_var: np.ndarray,  # (N,)
    wall_var: np.ndarray,  # (W,)
    meets: np.ndarray,  # (W, K) bool: chain k can pair with wall w
    starts: np.ndarray,  # (K+1,) int64: chain k is rows starts[k]:starts[k+1]
    gate: float,  # GATE_SIGMAS
    sin_max: float,  # √(1 − cos²(MAX_ANGLE))
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per point its normalised |r| to the wall it pairs with (inf: none), r, ∂r/∂T (N, 3)
    and that wall (−1: none): the smallest within the gate, same direction, inside the
    extent; walls in order, a later one taking a point only with a strictly smaller score
    (``alignment._match``)."""
    n_pts = p.shape[0]
    best = np.full(n_pts, np.inf)
    residual = np.zeros(n_pts)
    grad = np.zeros((n_pts, 3))
    wall_of = np.full(n_pts, -1, dtype=np.int64)
    width = coeffs.shape[1]
    deriv = np.empty(width - 1)
    g = np.empty(3)
    for w in range(coeffs.shape[0]):
        c = coeffs[w]
        for j in range(1, width):
            deriv[j - 1] = c[j] * float(j)
        lo, hi = extent[w, 0], extent[w, 1]
        for k in range(meets.shape[1]):
            if not meets[w, k]:
                continue
            for i in range(starts[k], starts[k + 1]):
                if variate[w] == 1:
                    xi, eta = p[i, 0], p[i, 1]
                else:
                    xi, eta = p[i, 1], p[i, 0]
                if not (xi >= lo and xi <= hi):
                    continue
                slope = _horner(deriv, xi)
                norm = math.sqrt(1.0 + slope * slope)
                a, b = -slope / norm, 1.0 / norm
                n0, n1 = (a, b) if variate[w] == 1 else (b, a)
                r = (eta - _horner(c, xi)) / math.sqrt(1.0 + slope * slope)
                for j in range(3):
                    g[j] = n0 * dp_dt[i, 0, j] + n1 * dp_dt[i, 1, j]
                quad = 0.0
                for u in range(3):
                    for v in range(3):
                        quad += g[u] * cov_t[u, v] * g[v]
                pred = math.sqrt(quad + point_var[i] + wall_var[w])
                if not abs(n0 * tangents[i, 0] + n1 * tangents[i, 1]) <= sin_max:
                    continue
                score = abs(r) / pred
                if score <= gate and score < best[i]:
                    best[i], residual[i], wall_of[i] = score, r, w
                    grad[i, 0], grad[i, 1], grad[i, 2] = g[0], g[1], g[2]
    return best, residual, grad, wall_of

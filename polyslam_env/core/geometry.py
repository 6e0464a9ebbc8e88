"""Small planar geometry shared by every layer (numpy only, so ``slam/`` may use it too)."""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles (any shape) wrapped to (−π, π]."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi))


def wrap_scalar(angle: float) -> float:
    """:func:`wrap_angle` of one float, without numpy's per-call cost (same formula)."""
    return math.pi - (math.pi - angle) % (2.0 * math.pi)


def symmetric_eigvals3(a: np.ndarray) -> tuple[float, float, float]:
    """Eigenvalues (ascending) of a symmetric 3×3 matrix in closed form (lower triangle read).

    The trigonometric solution of the characteristic cubic (Smith, 1961): with q = tr A / 3
    and p² = ‖A − qI‖²_F / 6, the eigenvalues are q + 2p·cos(φ + 2πk/3), φ = acos(det B / 2)/3,
    B = (A − qI)/p, at a twentieth of the cost of ``np.linalg.eigvalsh`` on one 3×3 matrix
    (the SLAM asks for two spectral norms per step). Accurate to a few ulps of ‖A‖ except
    where two eigenvalues (nearly) coincide: acos is steep at ±1, so that pair is off by up to
    ~1e-8·p (the other eigenvalue stays exact to ulps). That is harmless for what the SLAM
    does with them (LMS weights, thresholds), and tested in tests/test_geometry.py.
    """
    (a00, _, _), (a10, a11, _), (a20, a21, a22) = a.tolist()
    off = a10 * a10 + a20 * a20 + a21 * a21
    if off == 0.0:
        d0, d1, d2 = sorted((a00, a11, a22))
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
    phi = math.acos(min(max(half_det, -1.0), 1.0)) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return smallest, 3.0 * q - largest - smallest, largest

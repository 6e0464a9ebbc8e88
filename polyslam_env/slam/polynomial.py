"""Polynomial wall segments, the landmarks of the polynomial SLAM (SPEC §3).

A segment is ``x² = c0 + Σ_{i=1..m} b_i (x¹)^i`` on ``x¹ ∈ [lo, hi]`` (variate 1) or
``x¹ = c0 + Σ b_i (x²)^i`` on ``x² ∈ [lo, hi]`` (variate 2). The independent variable is
called ξ, the dependent one η; ``coeffs = [c0, b_1, …, b_m]`` in increasing powers.

This module is geometry only: in the SLAM the value of ``c0`` lives in the EKF state and the
shape ``b`` and extent here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as P


@dataclass(frozen=True, eq=False)
class Polynomial:
    """An immutable polynomial segment; see the module docstring for the convention."""

    variate: int  # 1: η = x², ξ = x¹;  2: η = x¹, ξ = x²
    coeffs: np.ndarray  # (m+1,): c0, b_1, …, b_m
    lo: float  # extent on ξ
    hi: float

    def __post_init__(self) -> None:
        if self.variate not in (1, 2):
            raise ValueError(f"variate must be 1 or 2, got {self.variate!r}")
        c = np.asarray(self.coeffs, dtype=float)
        if c.ndim != 1 or len(c) < 2:
            raise ValueError(f"coeffs must be [c0, b1, ...], got shape {c.shape}")
        if not (np.isfinite(c).all() and math.isfinite(self.lo) and math.isfinite(self.hi)):
            raise ValueError("polynomial coefficients and extent must be finite")
        if self.hi < self.lo:
            raise ValueError(f"extent must satisfy lo <= hi, got [{self.lo}, {self.hi}]")
        object.__setattr__(self, "coeffs", c)

    # -- basic evaluation -----------------------------------------------------------------
    @property
    def order(self) -> int:
        return len(self.coeffs) - 1

    @property
    def c0(self) -> float:
        return float(self.coeffs[0])

    @property
    def shape(self) -> np.ndarray:  # (m,): b_1, …, b_m
        return self.coeffs[1:]

    def value(self, xi: np.ndarray | float) -> np.ndarray:
        """η(ξ) = c0 + B(ξ)."""
        return polyval(xi, self.coeffs)

    def slope(self, xi: np.ndarray | float) -> np.ndarray:
        """B'(ξ) = dη/dξ."""
        return polyval(xi, self.coeffs, derivative=1)

    def slope_at(self, xi: float) -> float:
        """B'(ξ) at one ξ, as a float: :meth:`slope`'s value (the same operations), without
        its array; the exchange and the merges ask for one per landmark they weigh."""
        return _polyval_float(float(xi), self.coeffs, 1)

    def max_slope(self) -> float:
        """max |dη/dξ| over the extent [lo, hi], exactly: at an end or where the slope turns
        (a real root of p'' inside the extent), for any order. Up to cubics in plain floats
        (p'' = 2b₂ + 6b₃ξ: one turn at most), the same operations as numpy's ``polyder``,
        ``polytrim`` and ``polyroots`` (checked against them in the tests); the slopes there
        in floats, :meth:`slope_at`'s (the same operations as :meth:`slope` on an array)."""
        at = [self.lo, self.hi]
        if self.coeffs.size == 4:
            rate = 2 * (3 * float(self.coeffs[3]))  # p'' = 2b₂ + rate·ξ
            if rate != 0.0:
                turn = -(2 * float(self.coeffs[2])) / rate
                if self.lo < turn < self.hi:
                    at.append(turn)
        elif self.coeffs.size > 4:
            curvature = P.polytrim(P.polyder(self.coeffs, 2))
            turns = P.polyroots(curvature) if len(curvature) > 1 else np.zeros(0)
            real = turns.real[np.abs(turns.imag) <= 1e-9 * np.maximum(1.0, np.abs(turns.real))]
            at.extend(real[(real > self.lo) & (real < self.hi)].tolist())
        return max(abs(self.slope_at(x)) for x in at)

    def to_xy(self, xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """(ξ, η) pairs to (x¹, x²) points, shape (…, 2) (``np.stack`` on the last axis)."""
        xi, eta = np.asarray(xi), np.asarray(eta)
        if xi.shape != eta.shape:
            raise ValueError(f"to_xy: ξ {xi.shape} and η {eta.shape} must have the same shape")
        out = np.empty((*xi.shape, 2), dtype=np.result_type(xi, eta))
        out[..., 0], out[..., 1] = (xi, eta) if self.variate == 1 else (eta, xi)
        return out

    def from_xy(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x¹, x²) points to (ξ, η)."""
        p = np.asarray(points, dtype=float)
        if self.variate == 1:
            return p[..., 0], p[..., 1]
        return p[..., 1], p[..., 0]

    def normals(self, xi: np.ndarray) -> np.ndarray:
        """Unit normals (n, 2) of the curve at the given ξ, in (x¹, x²): (−B', 1)/√(1 + B'²)
        in (ξ, η), the side of growing η."""
        slope = self.slope(np.asarray(xi, dtype=float))
        norm = np.sqrt(1.0 + slope * slope)
        return self.to_xy(-slope / norm, 1.0 / norm)

    def points_at(self, xi: np.ndarray) -> np.ndarray:
        """Points on the curve at the given ξ, shape (n, 2)."""
        xi = np.asarray(xi, dtype=float)
        return self.to_xy(xi, self.value(xi))

    def endpoints(self) -> np.ndarray:
        """(2, 2): Q_m (at lo) and Q_M (at hi)."""
        return self.points_at(np.array([self.lo, self.hi]))

    def with_c0(self, c0: float) -> Polynomial:
        """The same shape and extent with ``c0`` (validated already but for the new c0: the
        SLAM asks for one per landmark and use)."""
        if not math.isfinite(c0):
            raise ValueError("polynomial coefficients and extent must be finite")
        coeffs = self.coeffs.copy()
        coeffs[0] = c0
        return Polynomial.unchecked(self.variate, coeffs, self.lo, self.hi)

    @staticmethod
    def unchecked(variate: int, coeffs: np.ndarray, lo: float, hi: float) -> Polynomial:
        """A polynomial from parts known valid (a float (m+1,) array, finite, lo ≤ hi: those
        of a valid polynomial or a table's extents), without :meth:`__post_init__`'s checks,
        which cost as much as the rest of a map change's reading of its landmarks."""
        out = object.__new__(Polynomial)
        out.__dict__.update(variate=variate, coeffs=coeffs, lo=lo, hi=hi)  # frozen: not setattr
        return out

    # -- sampling ---------------------------------------------------------------------------
    def sample_arclength(self, step: float = 0.01, dense: int = 512) -> np.ndarray:
        """Points equally spaced by ``step`` of arc length (both ends included), (n, 2)."""
        if self.hi == self.lo:
            return self.points_at(np.array([self.lo]))
        xi = np.linspace(self.lo, self.hi, dense)
        pts = self.points_at(xi)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        n = max(int(np.floor(s[-1] / step)) + 1, 2)
        targets = np.linspace(0.0, s[-1], n)
        return self.points_at(np.interp(targets, s, xi))

    def length(self, dense: int = 512) -> float:
        """Arc length over the extent."""
        xi = np.linspace(self.lo, self.hi, dense)
        return float(np.linalg.norm(np.diff(self.points_at(xi), axis=0), axis=1).sum())

    def equally_spaced(
        self, n: int, lo: float | None = None, hi: float | None = None
    ) -> np.ndarray:
        """``n`` points equally spaced in ξ over [lo, hi] (default: the extent), (n, 2)."""
        a = self.lo if lo is None else lo
        b = self.hi if hi is None else hi
        return self.points_at(np.linspace(a, b, n))


# -- evaluation: Horner's scheme on arrays (one point in floats: kernels.horner) -----------------
def polyval(
    x: np.ndarray | float, coeffs: np.ndarray | Sequence[float], derivative: int = 0
) -> np.ndarray:
    """Σ_j coeffs[j] x^j (increasing powers) at any array ``x``, or its ``derivative``-th
    derivative: the operations of numpy's ``polyval`` (of ``polyder``: the derivative's
    coefficients j·c_j, then Horner's scheme from the top, ``c[-1] + x·0`` first), without
    their per-call checks, so every value is bit-identical to theirs (tested); the reference
    for the other forms."""
    if isinstance(x, float):  # a Python or numpy float: the same operations on floats
        return np.asarray(_polyval_float(x, coeffs, derivative))
    c = np.array(coeffs, dtype=float, ndmin=1)
    if derivative >= len(c):
        c = c[:1] * 0
    else:
        for _ in range(derivative):
            c = c[1:] * np.arange(1, len(c))
    if isinstance(x, tuple | list):
        x = np.asarray(x)
    value = c[-1] + x * 0
    for i in range(2, len(c) + 1):
        value = c[-i] + value * x
    return np.asarray(value)


def _polyval_float(x: float, coeffs: np.ndarray | Sequence[float], derivative: int) -> float:
    """:func:`polyval` at one float in Python floats (IEEE doubles, as numpy's): j·c_j per
    derivative (``c0·0`` past the order), then Horner from ``c[-1] + x·0``; a fraction of the
    array form's time, which the SLAM's and the exchange's scalar calls add up to."""
    c = np.array(coeffs, dtype=float, ndmin=1).tolist()
    n = len(c)
    if derivative >= n:
        c, n = [c[0] * 0], 1
    else:
        for _ in range(derivative):  # in place: no comprehension per call
            for j in range(1, n):
                c[j - 1] = c[j] * j
            n -= 1
    value = c[n - 1] + x * 0
    for i in range(2, n + 1):
        value = c[n - i] + value * x
    return value


def polyval_rows(coeffs: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Row-wise :func:`polyval`: row i of ``coeffs`` (n, m+1) at row i of ``x`` (n, k) → (n, k).

    The operations of ``np.polynomial.polynomial.polyval`` in the same order, so every value
    is bit-identical to it. Rows of lower order are padded with zero leading coefficients:
    ``0 + (±0)·x`` stays zero until the first true coefficient, which is then added exactly.
    """
    value = coeffs[:, -1:] + x * 0
    for i in range(2, coeffs.shape[1] + 1):
        value = coeffs[:, -i, None] + value * x
    return np.asarray(value)

"""The SLAM update's ray casting for a handful of beams, in plain Python floats.

One SLAM step casts its B ≈ 5 beams against the few landmarks within range. The vectorised
:func:`~polyslam_env.slam.measurement.ray_intersections` spends almost all of its time in
the fixed cost of ~100 numpy calls on arrays of a dozen elements; the same algorithm on
Python floats costs a few microseconds per (beam, landmark) pair. This module is that
algorithm, step for step — Taylor coefficients at the robot, F(s) in s = t/r_max, closed-form
roots with the stiff-row fallback and its Newton refinement, the nearest admissible root
(first minimum in (landmark, root) order), one guarded Newton polish, then ξ*, B'(ξ*) and D —
so its hits equal the vectorised ones to rounding (tests/slam/test_beamcast.py checks it
against :func:`~polyslam_env.slam.measurement.ray_intersections` on random maps).

Shapes are passed per landmark (:class:`ShapeRow`, e.g. a
:class:`~polyslam_env.slam.landmarks.LandmarkRow`) with ``shape = (0, b_1, …, b_m)`` trimmed
to the landmark's own order: trailing zero coefficients change no root (the vectorised code
drops them through its degree-drop path).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from polyslam_env.slam.measurement import (
    DEGREE_DROP_TOL,
    IMAG_TOL,
    POLISH_MAX,
    REAL_TOL,
    STIFF_TOL,
    ShapeRow,
)

NAN = math.nan
#: Slack (m) around a landmark's box when deciding whether a beam can reach it: far above the
#: error of any accepted root (the closed forms plus Newton are accurate to ~1e-9 m).
BOX_MARGIN = 1e-3
_TINY = 2.2250738585072014e-308  # smallest normal float: np.finfo(float).tiny


class BeamHit(NamedTuple):
    """The nearest admissible hit of one beam."""

    t: float  # range t* (m)
    landmark: int  # index into the candidates' landmark numbering (state index − 3)
    slope: float  # B'(ξ*)
    denom: float  # D = dη − B'·dξ
    phi: float  # beam heading θ + β
    variate: int  # variate of the landmark hit
    xi: float  # ξ* of the hit

    @property
    def incidence_sine(self) -> float:
        """|sin| of the angle between beam and curve, |D| / √(1 + B'²) (as ``Hits``)."""
        return abs(self.denom) / math.sqrt(1.0 + self.slope * self.slope)

    def jacobian(self) -> tuple[tuple[float, float, float], float]:
        """This range's row of H: (∂h/∂x¹, ∂h/∂x², ∂h/∂θ) and ∂h/∂c0 = 1/D.

        The formulas of :func:`~polyslam_env.slam.measurement.expected_ranges_and_jacobian`
        (see there; tested equal) for one hit.
        """
        inv_d = 1.0 / self.denom
        slope_d = self.slope * inv_d
        cos, sin = math.cos(self.phi), math.sin(self.phi)
        v1 = self.variate == 1
        d_eta, d_xi = (cos, -sin) if v1 else (-sin, cos)  # d(dη)/dφ, d(dξ)/dφ
        h_theta = -self.t * (d_eta - self.slope * d_xi) * inv_d
        return ((slope_d, -inv_d, h_theta) if v1 else (-inv_d, slope_d, h_theta)), inv_d


def cast(
    x: float,
    y: float,
    theta: float,
    beam_angles: Sequence[float],
    candidates: Sequence[int],
    shapes: Sequence[ShapeRow],
    c0s: Sequence[float],
    max_range: float,
    boxes: Sequence[Sequence[float]] | None = None,
) -> list[BeamHit | None]:
    """Per beam, the nearest admissible hit on the ``candidates`` (ascending landmark indices,
    into ``shapes`` and ``c0s``), or None. Same contract as ``ray_intersections``.

    ``boxes`` (one (x_min, x_max, y_min, y_max) per candidate), when given, must hold each
    candidate's curve over its extent (e.g. :meth:`LandmarkArrays.boxes`): a beam whose
    segment passes farther than :data:`BOX_MARGIN` from a box cannot hit that landmark, and
    is not solved against it. The answer is the same; most pairs are skipped.
    """
    taylors: dict[int, list[float]] = {}
    out: list[BeamHit | None] = []
    for beta in beam_angles:
        phi = theta + beta
        cos, sin = math.cos(phi), math.sin(phi)
        best = math.inf
        best_k = -1
        best_coeffs: list[float] = []
        for k, j in enumerate(candidates):
            if boxes is not None and not _meets_box(
                x, y, cos * max_range, sin * max_range, boxes[k]
            ):
                continue
            row = shapes[j]
            lo, hi = row.lo, row.hi
            if row.variate == 1:
                xi0, eta0, dxi, deta = x, y, cos, sin
            else:
                xi0, eta0, dxi, deta = y, x, sin, cos
            taylor = taylors.get(k)
            if taylor is None:
                taylor = taylors[k] = _taylor(row.shape, xi0)
            coeffs = _ray_coeffs(taylor, eta0 - c0s[j], dxi, deta, max_range)
            step = max_range * dxi
            for s in _real_roots(coeffs):
                if s > 0.0 and s <= 1.0 and s < best:
                    xi = xi0 + s * step
                    if lo <= xi <= hi:
                        best, best_k, best_coeffs = s, k, coeffs
        if best_k < 0:
            out.append(None)
            continue
        s = _polish(best_coeffs, best)
        j = candidates[best_k]
        variate = shapes[j].variate
        xi0, dxi, deta = (x, cos, sin) if variate == 1 else (y, sin, cos)
        t = s * max_range
        u = t * dxi
        taylor = taylors[best_k]
        slope, power = 0.0, 1.0
        for order in range(1, len(taylor)):
            slope += order * taylor[order] * power
            power *= u
        out.append(BeamHit(t, j, slope, deta - slope * dxi, phi, variate, xi0 + u))
    return out


def _meets_box(x: float, y: float, dx: float, dy: float, box: Sequence[float]) -> bool:
    """Whether the segment (x, y) → (x + dx, y + dy) passes within BOX_MARGIN of ``box``
    (slab clipping: the segment's parameter interval inside each widened slab)."""
    t0, t1 = 0.0, 1.0
    for start, delta, low, high in ((x, dx, box[0], box[1]), (y, dy, box[2], box[3])):
        low, high = low - BOX_MARGIN, high + BOX_MARGIN
        if delta == 0.0:
            if start < low or start > high:
                return False
            continue
        a, b = (low - start) / delta, (high - start) / delta
        if a > b:
            a, b = b, a
        t0, t1 = max(t0, a), min(t1, b)
        if t0 > t1:
            return False
    return True


def _taylor(b: tuple[float, ...], xi0: float) -> list[float]:
    """T_k = Σ_{i≥k} C(i, k) b_i ξ0^(i−k): B(ξ0 + u) = Σ_k T_k u^k."""
    m = len(b) - 1
    powers = [1.0]
    for _ in range(m):
        powers.append(powers[-1] * xi0)
    return [
        sum(b[i] * (powers[i - k] * math.comb(i, k)) for i in range(k, m + 1)) for k in range(m + 1)
    ]


def _ray_coeffs(
    taylor: list[float], offset: float, dxi: float, deta: float, max_range: float
) -> list[float]:
    """F(s) = (η0 − c0) + s·r·dη − Σ_k T_k (s·r·dξ)^k as coefficients in s."""
    step = dxi * max_range
    coeffs = []
    power = 1.0
    for value in taylor:
        coeffs.append(-value * power)
        power *= step
    coeffs[0] += offset
    coeffs[1] += deta * max_range
    return coeffs


def _real_roots(c: list[float]) -> list[float]:
    """Real roots of Σ_k c[k] s^k (nan-padded), with the vectorised code's stiff fallback."""
    degree = len(c) - 1
    if degree == 0:
        return []
    largest = max(abs(v) for v in c)
    ratio = abs(c[-1]) / max(largest, _TINY)
    if ratio >= STIFF_TOL:
        return _solve(c)
    roots = _real_roots(c[:-1])
    if ratio >= DEGREE_DROP_TOL:
        roots = [_newton(c, s, 2, 1e-2) for s in roots]
    return roots


def _solve(c: list[float]) -> list[float]:
    degree = len(c) - 1
    if degree == 1:
        return [-c[0] / c[1]]
    if degree == 2:
        return _quadratic(c[0], c[1], c[2])
    if degree == 3:
        return _cubic(c[0], c[1], c[2], c[3])
    return _companion(c)


def _quadratic(c: float, b: float, a: float) -> list[float]:
    """Roots of c + b s + a s² (see measurement._quadratic_roots)."""
    disc = b * b - 4.0 * a * c
    if not disc >= -REAL_TOL * (b * b + abs(4.0 * a * c)):
        return [NAN, NAN]
    q = -0.5 * (b + math.copysign(math.sqrt(max(disc, 0.0)), b))
    return [q / a, c / (q if q != 0.0 else 1.0)]


def _cubic(k0: float, k1: float, k2: float, lead: float) -> list[float]:
    """Roots of k0 + k1 s + k2 s² + lead s³ (see measurement._cubic_roots)."""
    a, b, k = k2 / lead, k1 / lead, k0 / lead
    a3 = a / 3.0
    p3 = b / 3.0 - a3 * a3
    h = a3 * a3 * a3 - 0.5 * a3 * b + 0.5 * k
    h2, p3_cubed = h * h, p3 * p3 * p3
    disc = h2 + p3_cubed
    if disc <= REAL_TOL * (h2 + abs(p3_cubed)):  # three real roots: Viète
        neg_p3 = max(-p3, 0.0)
        root_neg_p3 = math.sqrt(neg_p3)
        denom = max(neg_p3 * root_neg_p3, abs(h))
        cos_arg = -h / (denom if denom > 0.0 else 1.0)
        y1 = 2.0 * root_neg_p3 * math.cos(math.acos(cos_arg) / 3.0)
        half_root = 0.5 * math.sqrt(max(-3.0 * y1 * y1 - 12.0 * p3, 0.0))
        return [y1 - a3, -0.5 * y1 + half_root - a3, -0.5 * y1 - half_root - a3]
    u = math.cbrt(-h - math.copysign(math.sqrt(max(disc, 0.0)), h))
    y1 = u - p3 / u if u != 0.0 else u
    return [y1 - a3, NAN, NAN]


def _companion(c: list[float]) -> list[float]:
    """Degree > 3 (orders above the paper's cubics): numpy's eigenvalues, as vectorised."""
    import numpy as np

    d = len(c) - 1
    companion = np.zeros((d, d))
    companion[np.arange(1, d), np.arange(d - 1)] = 1.0
    companion[:, -1] = -np.asarray(c[:d]) / c[d]
    roots = np.linalg.eigvals(companion)
    real = np.abs(roots.imag) <= IMAG_TOL * np.maximum(1.0, np.abs(roots.real))
    return [float(r.real) if ok else NAN for r, ok in zip(roots, real, strict=True)]


def _newton(c: list[float], s: float, steps: int, max_step: float) -> float:
    """Guarded Newton steps on a root ``s`` of Σ_k c[k] s^k (nan stays nan)."""
    for _ in range(steps):
        value, deriv = c[-1] + 0.0 * s, 0.0 * s
        for k in range(len(c) - 2, -1, -1):
            deriv = deriv * s + value
            value = value * s + c[k]
        step = value / deriv if deriv != 0.0 else 0.0
        if abs(step) <= max_step:
            s = s - step
    return s


def _polish(c: list[float], s: float) -> float:
    return _newton(c, s, 1, POLISH_MAX)

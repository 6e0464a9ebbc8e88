"""Range measurement model h of the polynomial SLAM and its Jacobian (SPEC §3), per beam.

A beam leaves the robot at heading φ = θ + β and travels ``t`` metres. It meets a map
polynomial where F(t) = η0 + t·dη − c0 − B(ξ0 + t·dξ) = 0, with (ξ0, η0) the robot position
in the polynomial's (independent, dependent) coordinates and (dξ, dη) the beam direction in
the same order: x¹-variate gives ξ0 = x, η0 = y, dξ = cos φ, dη = sin φ; x²-variate swaps
them. ``B`` is the shape polynomial without constant term; ``c0`` comes from the EKF state.

h is the smallest real root 0 < t ≤ r_max whose ξ lies in the extent, minimised over all
polynomials: Taylor coefficients of B at the robot, F(s) in s = t/r_max, closed-form roots
(degree ≤ 3, companion matrices above) with a stiff-row fallback and its Newton refinement,
the nearest admissible root (first minimum in (landmark, root) order), one guarded Newton
polish, then ξ*, B'(ξ*) and D; :meth:`BeamHit.jacobian` gives the row of H.

One SLAM step casts its B ≈ 5 beams against the few landmarks within range, so this runs on
Python floats: a vectorised version spends its time in the fixed cost of ~100 numpy calls on
arrays of a dozen elements. That vectorised version, over beams × polynomials, is the test
oracle ``tests/slam/reference.py`` (checked against brute force and finite differences);
``tests/slam/test_measurement.py`` checks this module against it on random maps.

Shapes are passed per landmark (:class:`~polyslam_env.slam.landmarks.ShapeRow`, e.g. a
:class:`~polyslam_env.slam.landmarks.LandmarkRow`) with ``shape = (0, b_1, …, b_m)`` trimmed
to the landmark's own order: trailing zero coefficients change no root.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from polyslam_env.slam.landmarks import ShapeRow
from polyslam_env.slam.polynomial import taylor_shift, value_and_slope

#: Leading coefficients below this fraction of the largest coefficient (with t scaled to
#: [0, 1] by r_max) are treated as zero: the degree drops (e.g. a beam parallel to ξ).
DEGREE_DROP_TOL = 1e-8
#: Rows whose leading coefficient is below this fraction of the largest are solved one
#: degree lower and Newton-refined (see :func:`_real_roots`). Closed-form cubic errors grow
#: like eps/ratio²: ~1e-7 at 1e-4, still within reach of POLISH_MAX.
STIFF_TOL = 2e-4
#: A root (in units of r_max) is taken as real when |Im| ≤ this · max(1, |Re|). A double
#: (tangent) root splits into a complex pair of size ~√eps ≈ 1e-8 in floating point.
IMAG_TOL = 1e-6
#: The closed forms take a discriminant down to −REAL_TOL × (its terms' size) as zero, which
#: accepts complex pairs with |Im| ≲ 1e-6 like IMAG_TOL does.
REAL_TOL = 1e-12
#: Largest Newton correction (units of r_max) applied to a winning root.
POLISH_MAX = 1e-6

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
        """|sin| of the angle between beam and curve, |D| / √(1 + B'²); SPEC §3 skips a
        hit below sin 10° (too sensitive to linearise)."""
        return abs(self.denom) / math.sqrt(1.0 + self.slope * self.slope)

    def jacobian(self) -> tuple[tuple[float, float, float], float]:
        """This range's row of H: (∂h/∂x¹, ∂h/∂x², ∂h/∂θ) and ∂h/∂c0 = 1/D.

        Implicit differentiation of F(t*) = 0: ∂h/∂v = −(∂F/∂v)/(∂F/∂t) with ∂F/∂t = D, i.e.
        ∂h/∂ξ0 = B'/D, ∂h/∂η0 = −1/D, ∂h/∂c0 = 1/D and ∂h/∂θ = −t*(dη' − B'·dξ')/D where '
        is d/dφ. For the x¹-variate case this is the SPEC's (B'/D, −1/D,
        −t*(cos φ + B' sin φ)/D, 1/D), for the x²-variate case (−1/D, B'/D,
        t*(sin φ + B' cos φ)/D, 1/D). Tested against finite differences.
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
    into ``shapes`` and ``c0s``), or None. A root counts when it is real,
    0 < t ≤ max_range and its ξ lies in [lo, hi]; the smallest over all candidates wins.

    ``boxes`` (one (x_min, x_max, y_min, y_max) per candidate), when given, must hold each
    candidate's curve over its extent (e.g. :meth:`LandmarkTable.boxes`): a beam whose
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
                taylor = taylors[k] = taylor_shift(row.shape, xi0)
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
    """Real roots of Σ_k c[k] s^k, nan-padded. A row whose leading coefficient is small
    (< STIFF_TOL of its largest) is solved one degree lower and then Newton-refined on the
    full polynomial: the closed forms lose the small roots to cancellation there, while the
    root that goes missing lies at |s| ≳ STIFF_TOL^(−1/3) ≈ 17, outside (0, 1]. Below
    DEGREE_DROP_TOL the leading term is dropped outright."""
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
    """Real roots of c + b s + a s², cancellation-free; nan if none. A slightly negative
    discriminant (relative to its terms) counts as a double root: a ray grazing a curve must
    be found and flagged as tangent, not missed."""
    disc = b * b - 4.0 * a * c
    if not disc >= -REAL_TOL * (b * b + abs(4.0 * a * c)):
        return [NAN, NAN]
    q = -0.5 * (b + math.copysign(math.sqrt(max(disc, 0.0)), b))
    return [q / a, c / (q if q != 0.0 else 1.0)]


def _cubic(k0: float, k1: float, k2: float, lead: float) -> list[float]:
    """Real roots of k0 + k1 s + k2 s² + lead s³, nan-padded: one from Viète's
    trigonometric form (three real roots) or Cardano without cancellation (one), the other
    two from the deflated quadratic; :func:`_newton` refines the winner afterwards."""
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
    """Degree > 3 (orders above the paper's cubics): eigenvalues of the companion matrix."""
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
        value, deriv = value_and_slope(c, s)
        step = value / deriv if deriv != 0.0 else 0.0
        if abs(step) <= max_step:
            s = s - step
    return s


def _polish(c: list[float], s: float) -> float:
    return _newton(c, s, 1, POLISH_MAX)

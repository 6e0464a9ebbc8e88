"""Test oracles: the readable float and numpy versions of the SLAM step's compiled kernels.

Production runs :mod:`polyslam_env.slam.kernels`; these are the versions it ran before
(STYLE habit 20: each numerical piece once in production, its readable form here), and
``test_kernels.py`` checks the kernels against them: bit for bit where the kernel does the same
operations in the same order (the measurement model up to order 3, the rows of H and R, the
association error, the prediction, the boxes), to rounding where it cannot (companion roots of
orders 4–5: complex instead of real LAPACK; the update and the NIS: BLAS's products).

* :func:`cast` — the per-beam ray casting in Python floats, with :class:`BeamHit`'s Jacobian;
* :func:`beam_rows` — ``PolySlam._beam_rows``' loop with the frozen-shape terms;
* :func:`update_sparse_inplace`, :func:`predict_inplace`, :func:`normalised_innovations` — the
  numpy EKF pieces;
* :func:`nearest_by_error`, :func:`boxes`, :func:`boxes_near`;
* :func:`update_scan_two_casts` — the update as composed before it cast once;
* :func:`fma_exact`, :func:`fma_matmul` — a product as an FMA-based BLAS computes it, in exact
  rationals rounded once per multiply-add (the oracle of kernels that replaced such products).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from fractions import Fraction
from math import comb
from typing import NamedTuple

import numpy as np

from polyslam_env.core.geometry import wrap_scalar
from polyslam_env.slam.ekf import _symmetrise, chi2_1dof_quantile
from polyslam_env.slam.kernels import (
    BOX_MARGIN,
    DEGREE_DROP_TOL,
    IMAG_TOL,
    POLISH_MAX,
    REAL_TOL,
    STIFF_TOL,
)
from polyslam_env.slam.landmarks import LandmarkRow, ShapeRow

NAN = math.nan
_TINY = 2.2250738585072014e-308  # smallest normal float: np.finfo(float).tiny


# -- polynomials in floats ------------------------------------------------------------------------
def value_and_slope(
    coeffs: Sequence[float], x: float, c0: float | None = None
) -> tuple[float, float]:
    """(p(x), p'(x)) of one polynomial [c_0, …, c_m] (m ≥ 1) in plain floats, by Horner's
    scheme: the per-beam and per-point loops of the SLAM, where numpy's per-call cost would
    dominate. ``c0``, when given, replaces ``coeffs[0]`` (a landmark's c0 from the state)."""
    value = coeffs[-1]
    slope = 0.0
    for b in coeffs[-2:0:-1]:
        slope = slope * x + value
        value = value * x + b
    slope = slope * x + value
    value = value * x + (coeffs[0] if c0 is None else c0)
    return value, slope


def taylor_shift(coeffs: Sequence[float], x0: float) -> list[float]:
    """Taylor coefficients T_k = Σ_{i≥k} C(i, k) c_i x0^(i−k) of [c_0, …, c_m] about x0, so
    p(x0 + u) = Σ_k T_k u^k, in plain floats (the per-beam ray casting and the per-landmark
    box bounds)."""
    m = len(coeffs) - 1
    powers = [1.0]
    for _ in range(m):
        powers.append(powers[-1] * x0)
    return [
        sum(coeffs[i] * (powers[i - k] * comb(i, k)) for i in range(k, m + 1)) for k in range(m + 1)
    ]


# -- the measurement model, per beam in floats ----------------------------------------------------
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

    def xi_gradient(self) -> tuple[float, float, float, float]:
        """ξ* = ξ_robot + t*·dξ: (∂ξ*/∂x¹, ∂ξ*/∂x², ∂ξ*/∂θ) at fixed t*, and dξ (the factor
        of ∂t*/∂state in ∂ξ*/∂state)."""
        cos, sin = math.cos(self.phi), math.sin(self.phi)
        if self.variate == 1:
            return 1.0, 0.0, -self.t * sin, cos
        return 0.0, 1.0, self.t * cos, sin


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


# -- the rows of H and R (PolySlam._beam_rows) ----------------------------------------------------
class RowModel(NamedTuple):
    """What ``PolySlam._beam_rows`` adds to the measurement model."""

    min_sine: float
    range_sigma: float
    shape_follows_pose: bool
    eps_z: int
    # state index of landmark 0's shape rotation (SlamConfig.shape_rotation "considered");
    # −1: the rotation is the current heading error
    alpha_base: int = -1
    # SlamConfig.shape_shift "pose": a frozen shape's shift along ξ predicted from the pose's
    # current error along ξ, whose variance along x and along y is ``pose_var``
    shift_with_pose: bool = False
    pose_var: tuple[float, float] = (0.0, 0.0)


def beam_rows(
    x: float,
    y: float,
    theta: float,
    angles: Sequence[float] | np.ndarray,
    ranges: Sequence[float] | np.ndarray,
    candidates: Sequence[int],
    rows: Sequence[LandmarkRow],
    c0s: Sequence[float] | np.ndarray,
    max_range: float,
    boxes: Sequence[Sequence[float]],
    model: RowModel,
    turn_var: Sequence[float] | None = None,
    shift_slope: Sequence[float] | None = None,
) -> tuple[np.ndarray, ...] | None:
    """(innovation, h_pose, c0 state index, h_c0, rotation state index, h_α, R diagonal) of
    the beams with a usable hit (``boxes`` per candidate), or None. ``turn_var`` (per
    landmark, default 0): the variance of the heading change since its shape was fitted
    (``PolySlam._turn_var``). With ``model.alpha_base`` ≥ 0 the shape's rotation is its own
    state: the lever term goes to h_α instead of h_θ, and neither the heading drift nor the
    slope's fit variance enters R. ``shift_slope`` (per landmark, default nan: unknown): the
    slope its c0 moves by when its shape shifts along ξ, used with ``model.shift_with_pose``."""
    hits = cast(x, y, theta, list(angles), list(candidates), rows, list(c0s), max_range, boxes)
    range_var = model.range_sigma**2
    in_state = model.alpha_base >= 0
    innovation, h_pose, c0_index, h_c0, variance = [], [], [], [], []
    alpha_index, h_alpha, end_room, xi_grad = [], [], [], []
    for b, hit in enumerate(hits):
        if hit is None or hit.incidence_sine < model.min_sine:
            continue  # no hit, or near-tangent: too sensitive to linearise
        (h_x, h_y, h_theta), inv_d = hit.jacobian()
        row = rows[hit.landmark]
        var = range_var + row.model_var * (inv_d * inv_d)
        h_rot = 0.0
        if model.shape_follows_pose:
            carried = math.nan if shift_slope is None else shift_slope[hit.landmark]
            lever, extra, moved = _shape_terms(row, hit.xi, inv_d, model, carried)
            if hit.variate == 1:
                h_x -= moved
            else:
                h_y -= moved
            turn = (1.0 if hit.variate == 1 else -1.0) * lever * inv_d
            if in_state:
                h_rot = turn
            else:
                h_theta += turn
                extra += turn * turn * (0.0 if turn_var is None else turn_var[hit.landmark])
            var += extra
        innovation.append(float(ranges[b]) - hit.t)
        h_pose.append((h_x, h_y, h_theta))
        c0_index.append(3 + hit.landmark)
        h_c0.append(inv_d)
        alpha_index.append(model.alpha_base + hit.landmark if h_rot != 0.0 else -1)
        h_alpha.append(h_rot)
        variance.append(var)
        end_room.append(min(hit.xi - row.lo, row.hi - hit.xi))
        xi_grad.append(hit.xi_gradient())
    if not innovation:
        return None
    return (
        np.array(innovation),
        np.array(h_pose),
        np.array(c0_index),
        np.array(h_c0),
        np.array(alpha_index),
        np.array(h_alpha),
        np.array(variance),
        np.array(end_room),
        np.array(xi_grad),
    )


def _shape_terms(
    row: LandmarkRow, xi: float, inv_d: float, model: RowModel, carried: float
) -> tuple[float, float, float]:
    """A frozen shape's error in a beam's range: (rotation lever, extra variance, the part of
    ∂h/∂ξ the predicted shift along ξ takes away)."""
    value, slope = value_and_slope(row.shape, xi)
    value_c, slope_c = value_and_slope(row.shape, row.pivot)
    moved = 0.0
    if model.shift_with_pose and not math.isnan(carried):
        # e_f = β e_n + r, the errors nested (the smaller one part of the larger)
        shift = (slope - carried) * inv_d
        now = model.pose_var[0 if row.variate == 1 else 1]
        if now > row.xi_var:
            gain = row.xi_var / now
            left = row.xi_var * (1.0 - gain)
        else:
            gain, left = 1.0, row.xi_var - now
        moved = gain * shift
        extra = shift * shift * left
    else:
        shift = (slope - slope_c) * inv_d
        extra = shift * shift * row.xi_var
    extra += inv_d * inv_d * shape_fit_var(row.shape, (xi - row.pivot) / row.fit_half, model)
    lever = (xi - row.pivot) + slope * (value - value_c)
    return lever, extra, moved


def shape_fit_var(shape: tuple[float, ...], t: float, model: RowModel) -> float:
    """Variance of a frozen shape's η at scaled position t = (ξ* − ξ_c)/half-extent."""
    order = len(shape) - 1 if shape[-1] != 0.0 else 0  # shapes carry no zero tail
    if order == 0:
        return 0.0
    n_fit = model.eps_z + 1
    a = [t**i for i in range(order + 1)]
    inverse = uniform_fit_inverse(n_fit, order)
    quad = 0.0
    for a_i, row in zip(a, inverse, strict=True):
        quad += a_i * sum(m_ij * a_j for m_ij, a_j in zip(row, a, strict=True))
    quad -= 1.0 / n_fit
    if model.alpha_base >= 0:  # the slope's own error is the rotation state's
        quad -= t * t * inverse[1][1]
    return float(model.range_sigma**2 * max(quad, 0.0))


@functools.lru_cache(maxsize=16)
def uniform_fit_inverse(n_points: int, order: int) -> list[list[float]]:
    """(AᵀA)⁻¹ (m+1, m+1) for monomials of t at n points equally spaced over [−1, 1]."""
    a = np.linspace(-1.0, 1.0, n_points)[:, None] ** np.arange(order + 1)
    inverse: list[list[float]] = np.linalg.inv(a.T @ a).tolist()
    return inverse


# -- EKF pieces in numpy --------------------------------------------------------------------------
def predict_inplace(
    mean: np.ndarray,
    cov: np.ndarray,
    odometry: np.ndarray,
    W: np.ndarray,
    first_xy: tuple[float, float] | None = None,
) -> None:
    """:func:`predict` writing into ``mean`` (3+n,) and ``cov`` (3+n, 3+n) (float arrays).

    Without the pure version's (3+n)² copy, for the stateful caller whose per-step cost
    should stay O(n). F = ∂f/∂pose = I + a·e₀e₂ᵀ + b·e₁e₂ᵀ of the unicycle composition
    f(pose, u) = [x + cos θ·dx − sin θ·dy, y + sin θ·dx + cos θ·dy, θ + dθ], with the
    odometry u = (dx, dy, dθ) in the robot frame and L = ∂f/∂u, so F P_pl
    adds a and b times the heading row to the position rows, and the 3×3 pose block is
    written out in plain floats from its upper triangle (symmetric by construction).

    **First-estimates Jacobian** (Huang, Mourikis & Roumeliotis 2008). The standard F takes
    a = −Δy, b = Δx from the *updated* pose x̂_{k|k} to the prediction. Given ``first_xy``,
    the position of this pose's first estimate x̂_{k|k−1} (the prediction before the last
    update), it takes a = −(ŷ_{k+1|k} − ŷ_{k|k−1}), b = x̂_{k+1|k} − x̂_{k|k−1}: every
    Jacobian of a pose is then evaluated at one estimate of it, so the product of the
    propagation Jacobians from step 0 to k depends only on x̂_{k|k−1} − x̂_{0} and the
    linearised system keeps the nonlinear one's unobservable directions (a global rotation
    about the start); the standard F lets each update's correction δx̂ leak in as spurious
    information about the heading.
    """
    x, y, theta = mean[:3].tolist()
    dx, dy, dtheta = np.asarray(odometry, dtype=float).tolist()
    c, s = math.cos(theta), math.sin(theta)
    mean[0] = x + c * dx - s * dy
    mean[1] = y + s * dx + c * dy
    mean[2] = wrap_scalar(theta + dtheta)
    if first_xy is None:
        a, b = -s * dx - c * dy, c * dx - s * dy  # F[0, 2], F[1, 2]
    else:
        a, b = -(float(mean[1]) - first_xy[1]), float(mean[0]) - first_xy[0]
    if cov.shape[0] > 3:
        heading = cov[2, 3:]
        cov[0, 3:] += a * heading
        cov[1, 3:] += b * heading
        cov[3:, 0] = cov[0, 3:]
        cov[3:, 1] = cov[1, 3:]
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = cov[:3, :3].tolist()  # upper triangle
    # F P Fᵀ, F = I + a·e₀e₂ᵀ + b·e₁e₂ᵀ
    f02, f12 = p02 + a * p22, p12 + b * p22
    f00 = p00 + a * p02 + a * f02
    f01 = p01 + a * p12 + b * f02
    f11 = p11 + b * p12 + b * f12
    # L W Lᵀ, L = rotation by θ on (x, y), 1 on θ
    (w00, w01, w02), (w10, w11, w12), (_, _, w22) = np.asarray(W, dtype=float).tolist()
    r00, r01 = c * w00 - s * w10, c * w01 - s * w11  # rows of L W
    r10, r11 = s * w00 + c * w10, s * w01 + c * w11
    q00, q01 = r00 * c - r01 * s, r00 * s + r01 * c
    q11 = r10 * s + r11 * c
    q02, q12 = c * w02 - s * w12, s * w02 + c * w12
    block = (
        (f00 + q00, f01 + q01, f02 + q02),
        (f01 + q01, f11 + q11, f12 + q12),
        (f02 + q02, f12 + q12, p22 + w22),
    )
    cov[:3, :3] = block


def update_sparse_inplace(
    mean: np.ndarray,
    cov: np.ndarray,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    r: np.ndarray,
    gate_prob: float = 0.99,
    work: np.ndarray | None = None,
    gate_value: float | None = None,
    alpha_index: np.ndarray | None = None,
    h_alpha: np.ndarray | None = None,
    consider_from: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Gated, batched EKF update with range rows that touch the pose and one c0 each, in place.

    Row i of H is ``h_pose[i]`` (3,) on the pose and ``h_c0[i]`` on state index
    ``c0_index[i]``; R = diag(``r``) (k,); ``innovation`` (k,) must be finite. Writes the new
    estimate into ``mean`` (3+n,) and ``cov`` (3+n, 3+n) and returns (accepted (k,), nis (k,)).
    ``work`` is an optional (3+n, 3+n) scratch array for the products: a caller that updates
    every step keeps one, because a fresh array that large costs more in page faults than the
    arithmetic that fills it.

    Each measurement is gated on its own normalised innovation ν_i²/S_ii against the χ²
    (1 dof) quantile ``gate_prob`` (1.0 disables the gate); the accepted ones update together
    with the Joseph form P⁺ = (I−KH) P (I−KH)ᵀ + K R Kᵀ (the oracle in tests computes it
    literally), arranged for speed at large n:

    * P Hᵀ = P[:, :3] h_poseᵀ + P[:, c0] h_c0, with no dense H;
    * expanded, the Joseph form is P⁺ = P − (K Wᵀ + W Kᵀ) with W = P Hᵀ − ½ K S (for any
      gain K; here K = P Hᵀ S⁻¹);
    * K Wᵀ + W Kᵀ = Z₊Z₊ᵀ − Z₋Z₋ᵀ with Z± = (K' ± W')/√2, where K' and W' are K and W with
      column l scaled by a_l and 1/a_l (a_l = √(‖W_l‖/‖K_l‖) keeps both terms the size of the
      result, so nothing is lost to cancellation). BLAS computes Z Zᵀ as an exactly
      symmetric syrk, so P⁺ stays exactly symmetric with no (3+n)² transpose pass: O(n²k).

    K comes from a solve with S (SPEC §3: ``solve``, not ``inv``).

    Rows with ``alpha_index[i]`` ≥ 0 also touch that state with ``h_alpha[i]``; the entries
    from ``consider_from`` on get no gain (Schmidt–Kalman; the expanded Joseph form holds
    for any gain).
    """
    k = r.size
    alphas = [] if alpha_index is None else [int(a) for a in alpha_index if a >= 0]
    cols = np.array([0, 1, 2, *c0_index.tolist(), *alphas])  # the state columns H touches
    H = np.zeros((k, 3 + k + len(alphas)))  # row i: h_pose[i], h_c0[i] at 3+i, h_α after
    H[:, :3] = h_pose
    H.flat[3 : k * (3 + k + len(alphas)) : 3 + k + len(alphas) + 1] = h_c0
    if alpha_index is not None and h_alpha is not None:
        col = 3 + k
        for i, a in enumerate(alpha_index.tolist()):
            if a >= 0:
                H[i, col] = h_alpha[i]
                col += 1
    PHt = cov[:, cols] @ H.T  # (3+n, k)
    S = H @ PHt[cols]  # (k, k) = H P Hᵀ
    gate = chi2_1dof_quantile(gate_prob) if gate_value is None else gate_value
    nis_list = [  # k ≤ 5 or so: Python floats beat numpy's per-call cost
        v * v / (s + q)
        for v, s, q in zip(innovation.tolist(), S.diagonal().tolist(), r.tolist(), strict=True)
    ]
    passed = [v <= gate for v in nis_list]
    accepted, nis = np.array(passed), np.array(nis_list)
    if not all(passed):
        if not any(passed):
            return accepted, nis
        a = np.flatnonzero(accepted)
        PHt, S, innovation, r = PHt[:, a], S[np.ix_(a, a)], innovation[a], r[a]
    S = _symmetrise(S)
    S.flat[:: r.size + 1] += r  # + R
    K = np.linalg.solve(S, PHt.T).T  # (3+n, k_a) = P Hᵀ S⁻¹
    if consider_from is not None:
        K[consider_from:] = 0.0
    mean += K @ innovation
    mean[2] = wrap_scalar(float(mean[2]))
    W = PHt - 0.5 * (K @ S)
    k_sq, w_sq = np.einsum("ij,ij->j", K, K).tolist(), np.einsum("ij,ij->j", W, W).tolist()
    scale = [  # a_l, or 1 where a column is zero
        math.sqrt(math.sqrt(ws / ks)) if ks > 0.0 and ws > 0.0 else 1.0
        for ks, ws in zip(k_sq, w_sq, strict=True)
    ]
    sqrt2 = math.sqrt(2.0)
    K *= np.array([a_l / sqrt2 for a_l in scale])
    W /= np.array([a_l * sqrt2 for a_l in scale])
    if work is None or work.shape != cov.shape:
        work = np.empty_like(cov)
    z = K + W
    cov -= np.matmul(z, z.T, out=work)
    K -= W
    cov += np.matmul(K, K.T, out=work)
    return accepted, nis


def update_sparse(
    mean: np.ndarray,
    cov: np.ndarray,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    alpha_index: np.ndarray,
    h_alpha: np.ndarray,
    r: np.ndarray,
    gate: float,
    consider_from: int,
    accepted: np.ndarray,
    nis: np.ndarray,
) -> int:
    """:func:`update_sparse_inplace` with the signature of ``kernels.update_sparse`` (the χ²
    quantile given, outputs written), to stand in for it."""
    ok, values = update_sparse_inplace(
        mean, cov, innovation, h_pose, c0_index, h_c0, r, gate_value=gate,
        alpha_index=alpha_index, h_alpha=h_alpha, consider_from=consider_from,
    )  # fmt: skip
    accepted[:], nis[:] = ok, values
    return int(ok.sum())


def joseph_full(cov: np.ndarray, kt: np.ndarray, wt: np.ndarray) -> None:
    """P⁺ = P − (K Wᵀ + W Kᵀ) over the whole upper triangle, mirrored: the loop
    ``kernels.joseph_blocks`` replaced (in Python floats, the same order of operations)."""
    count, n = kt.shape
    for i in range(n):
        part = [0.0] * (n - i)
        for q in range(count):
            k_i, w_i = float(kt[q, i]), float(wt[q, i])
            for j in range(n - i):
                part[j] += k_i * float(wt[q, i + j]) + w_i * float(kt[q, i + j])
        for j in range(n - i):
            cov[i, i + j] -= part[j]
    for i in range(n):
        for j in range(i):
            cov[i, j] = cov[j, i]


def seen_face_beams(
    mean: np.ndarray,
    angles: np.ndarray,
    beams: np.ndarray,
    assigned: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    step: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``beams`` and ``assigned`` without the beams whose cast at the mean meets its landmark
    from the side opposite to the face the landmark's beams saw (``SlamConfig.seen_faces``),
    readably: a ray crossing the curve towards +η (D > 0) comes from the −η side (−1), one
    crossing towards −η from the +η side (+1); it is kept when it hit nothing, when either
    side is unknown (0), or when the two sides agree."""
    from polyslam_env.slam import columns as c
    from polyslam_env.slam import kernels

    if not switches[c.S_SEEN_FACES]:
        return beams, assigned
    near, _, _ = kernels._scan_model(mean, real, index, n, params, switches, step)
    _, _, landmark, _, denom, _ = kernels.cast_beams(
        mean[0], mean[1], mean[2], angles, beams, params[c.P_REACH], index[c.VARIATE, :n],
        index[c.ORDER, :n], shape[:n], real[c.LO, :n], real[c.HI, :n], mean[3 : 3 + n], near,
        params[c.P_MAX_RANGE],
    )  # fmt: skip
    keep = []
    for j, d in zip(landmark.tolist(), denom.tolist(), strict=True):
        ray_side = -1 if d > 0 else (1 if d < 0 else 0)
        seen_side = int(index[c.SIDE, j]) if j >= 0 else 0
        keep.append(j < 0 or seen_side == 0 or ray_side == 0 or seen_side == ray_side)
    mask = np.array(keep, dtype=bool)
    return beams[mask], assigned[mask]


def update_scan(
    mean: np.ndarray,
    cov: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    beams: np.ndarray,
    assigned: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
) -> int:
    """``kernels.update_scan`` with the numpy update (:func:`update_sparse_inplace`) in place
    of the compiled one and :func:`xi_variances` for ``kernels.ends_in_doubt``, to stand in
    for it. It does not choose beams as ``kernels.steady_beams`` does (``assigned`` is not
    read): where it stands in, no beam hits another landmark than its own or misses it from a
    sigma point."""
    from polyslam_env.slam import columns, kernels

    beams, assigned = seen_face_beams(
        mean, angles, beams, assigned, real, index, shape, n, params, switches, step
    )
    k = beams.size
    rows = (
        np.empty(k), np.empty((k, 3)), np.empty(k, dtype=np.int64), np.empty(k),
        np.empty(k, dtype=np.int64), np.empty(k), np.empty(k), np.empty(k), np.empty((k, 4)),
    )  # fmt: skip
    used = kernels._beam_rows_of(
        mean, cov, angles, ranges, beams, real, index, shape, n, params, switches, fit_inverse,
        step, *rows,
    )  # fmt: skip
    if used == 0:
        return -1
    innovation, h_pose, c0_index, h_c0, alpha_index, h_alpha, variance, room, grad = (
        column[:used] for column in rows
    )
    end_sigma = params[columns.P_END_SIGMA]
    if end_sigma > 0.0:
        keep = room >= end_sigma * np.sqrt(
            xi_variances(cov, h_pose, c0_index, h_c0, alpha_index, h_alpha, grad)
        )
        if not keep.any():
            return -1
        innovation, h_pose, c0_index = innovation[keep], h_pose[keep], c0_index[keep]
        h_c0, alpha_index, h_alpha = h_c0[keep], alpha_index[keep], h_alpha[keep]
        variance = variance[keep]
    reuse = reuse_factors(index[:, :n], switches[columns.S_REUSE_BOUND])
    variance = share_landmark_error(c0_index, variance, params[columns.P_RANGE_VAR], reuse)
    consider_from = 3 + n if switches[columns.S_ROTATION_STATES] else mean.size
    accepted, _ = update_sparse_inplace(
        mean, cov, innovation, h_pose, c0_index, h_c0, variance,
        gate_value=params[columns.P_GATE], alpha_index=alpha_index, h_alpha=h_alpha,
        consider_from=consider_from,
    )  # fmt: skip
    index[columns.USES, np.unique(c0_index[accepted]) - 3] += 1
    return int(accepted.sum())


def xi_variances(
    cov: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    alpha_index: np.ndarray,
    h_alpha: np.ndarray,
    xi_grad: np.ndarray,
) -> np.ndarray:  # (k,)
    """Var(ξ*) of each row's hit, J P Jᵀ with the dense row J = ∂ξ*/∂state: ``xi_grad[:3]``
    on the pose plus dξ = ``xi_grad[3]`` times the row of H (``kernels.ends_in_doubt``)."""
    k, n = c0_index.size, cov.shape[0]
    jac = np.zeros((k, n))
    jac[:, :3] = xi_grad[:, :3] + xi_grad[:, 3:] * h_pose
    jac[np.arange(k), c0_index] += xi_grad[:, 3] * h_c0
    rot = alpha_index >= 0
    jac[np.flatnonzero(rot), alpha_index[rot]] += xi_grad[rot, 3] * h_alpha[rot]
    return np.einsum("ka,ab,kb->k", jac, cov, jac)


def share_landmark_error(
    c0_index: np.ndarray, variance: np.ndarray, range_var: float, reuse: np.ndarray | None = None
) -> np.ndarray:  # (k,)
    """The R diagonal that bounds the joint errors of one update's rows: the part of each
    row's variance beyond the range noise, shared by the n rows on its landmark, times n and
    times its landmark's ``reuse`` weight (default 1: none)."""
    n = np.bincount(c0_index)[c0_index]
    weight = np.ones(c0_index.size) if reuse is None else np.asarray(reuse)[c0_index - 3]
    return np.where(
        (n > 1) | (weight != 1.0), range_var + (n * weight) * (variance - range_var), variance
    )


def reuse_factors(index: np.ndarray, mode: int) -> np.ndarray:  # (n,)
    """Per landmark (columns of ``index``), u(u + 1) for its u-th update since its fit
    (u = uses + 1) where ``mode`` (0 off, 1 curved, 2 all) bounds it, else 1."""
    from polyslam_env.slam import columns

    u = index[columns.USES].astype(float) + 1.0
    bounded = np.full(u.size, mode == 2) | ((mode == 1) & (index[columns.ORDER] >= 2))
    return np.where(bounded, u * (u + 1.0), 1.0)


def normalised_innovations(
    cov: np.ndarray,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    r: np.ndarray,
    alpha_index: np.ndarray | None = None,
    h_alpha: np.ndarray | None = None,
) -> np.ndarray:  # (k,)
    """ν_i² / S_ii for range rows that touch the pose and one c0 each (the rows of
    :func:`update_sparse_inplace`): S_ii = h P_pp hᵀ + 2 h_c h P_pc + h_c² P_cc + r_i with
    h = ``h_pose[i]`` (3,), h_c = ``h_c0[i]``, c = ``c0_index[i]``; cov (3+n, 3+n); rows with
    a rotation state add its terms (the full row h_i P h_iᵀ, written out densely)."""
    P_pp = cov[:3, :3]  # (3, 3)
    P_pc = cov[:3, c0_index]  # (3, k)
    P_cc = cov[c0_index, c0_index]  # (k,)
    s = ((h_pose @ P_pp) * h_pose).sum(axis=1)  # h P_pp hᵀ per row (k rows ≈ 5: no einsum)
    s += 2.0 * h_c0 * (h_pose * P_pc.T).sum(axis=1) + h_c0 * h_c0 * P_cc + r
    if alpha_index is not None and h_alpha is not None:
        for i, a in enumerate(np.asarray(alpha_index).tolist()):
            if a < 0:
                continue
            h = np.zeros(cov.shape[0])
            h[:3], h[c0_index[i]], h[a] = h_pose[i], h_c0[i], h_alpha[i]
            s[i] = h @ cov @ h + r[i]
    return np.asarray(innovation * innovation / s)


# -- association error and boxes ------------------------------------------------------------------
def nearest_by_error(
    xy: Sequence[Sequence[float]],
    candidates: Sequence[int],
    rows: Sequence[ShapeRow],
    c0s: Sequence[float],
    squared: bool = False,
) -> list[tuple[int, float]]:
    """Per point, (index of the landmark with the smallest approximation error ε, that ε) over
    ``candidates``, or (−1, inf) without candidates.

    ε of a point by a polynomial: inside its extent the vertical (variate 1) / horizontal
    (variate 2) distance |η − p(ξ)|; outside, the distance to the nearer end point; metres, or
    the paper's squared form with ``squared=True``. In plain floats: the association compares
    a handful of points with a handful of landmarks per step, and merging a few points with
    one polynomial, where numpy's per-call cost would dominate."""
    ends = []
    for j in candidates:
        row = rows[j]
        c0 = c0s[j]
        ends.append(
            (value_and_slope(row.shape, row.lo, c0)[0], value_and_slope(row.shape, row.hi, c0)[0])
        )
    out = []
    for x, y in xy:
        best, best_err = -1, math.inf
        for k, j in enumerate(candidates):
            row = rows[j]
            xi, eta = (x, y) if row.variate == 1 else (y, x)
            if row.lo <= xi <= row.hi:
                err = abs(eta - value_and_slope(row.shape, xi, c0s[j])[0])
            else:
                eta_lo, eta_hi = ends[k]
                err = min(
                    math.hypot(xi - row.lo, eta - eta_lo), math.hypot(xi - row.hi, eta - eta_hi)
                )
            if squared:
                err = err * err
            if err < best_err:
                best, best_err = j, err
        out.append((best, best_err))
    return out


def boxes(
    c0s: np.ndarray, variate: np.ndarray, lo: np.ndarray, hi: np.ndarray, eta_range: np.ndarray
) -> np.ndarray:
    """Axis-aligned boxes (n, 4) = (x_min, x_max, y_min, y_max) holding each curve."""
    eta = c0s[:, None] + eta_range  # (n, 2)
    v1 = (variate == 1)[:, None]
    xi = np.stack([lo, hi], axis=-1)  # (n, 2)
    return np.concatenate([np.where(v1, xi, eta), np.where(v1, eta, xi)], axis=1)


def boxes_near(boxes: np.ndarray, box: np.ndarray, distance: float) -> np.ndarray:
    """Indices (ascending) of ``boxes`` (n, 4) within ``distance`` of ``box`` (4,)."""
    gap_x = np.maximum(np.maximum(boxes[:, 0] - box[1], box[0] - boxes[:, 1]), 0.0)
    gap_y = np.maximum(np.maximum(boxes[:, 2] - box[3], box[2] - boxes[:, 3]), 0.0)
    return np.flatnonzero(gap_x * gap_x + gap_y * gap_y <= distance * distance)


def fma_exact(a: float, b: float, c: float) -> float:
    """a·b + c rounded once (IEEE 754): exact rationals, and an exact zero signed as IEEE's
    sum of a zero product and a zero addend is (−0 only for −0 + −0)."""
    exact = Fraction(a) * Fraction(b) + Fraction(c)
    if exact != 0:
        return float(exact)
    if (a == 0.0 or b == 0.0) and c == 0.0:
        negative = math.copysign(1.0, a) * math.copysign(1.0, b) < 0 and math.copysign(1.0, c) < 0
        return -0.0 if negative else 0.0
    return 0.0  # non-zero terms cancelling exactly: +0 when rounding to nearest


def fma_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # (m, p)
    """a (m, n) × b (n, p) as OpenBLAS's FMA gemm kernels compute it: each entry a chain of
    :func:`fma_exact` along the inner index from 0 (zeros included)."""
    out = np.empty((a.shape[0], b.shape[1]))
    for r in range(a.shape[0]):
        for c in range(b.shape[1]):
            acc = 0.0
            for k in range(a.shape[1]):
                acc = fma_exact(float(a[r, k]), float(b[k, c]), acc)
            out[r, c] = acc
    return out


def update_scan_two_casts(
    mean: np.ndarray,
    cov: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    beams: np.ndarray,
    assigned: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
) -> int:
    """``kernels.update_scan`` as it was composed before its sigma-point test and its rows
    shared one scan model and one cast at the mean: ``kernels.steady_beams`` casting the
    wanted beams, then ``kernels._beam_rows_of`` casting the steady ones again (each with its
    own ``_scan_model``); the rest as the kernel does it."""
    from polyslam_env.slam import columns as c
    from polyslam_env.slam import kernels

    beams, assigned = seen_face_beams(
        mean, angles, beams, assigned, real, index, shape, n, params, switches, step
    )
    n_beams = beams.size
    end_sigma = params[c.P_END_SIGMA]
    innovation, h_pose = np.empty(n_beams), np.empty((n_beams, 3))
    c0_index, h_c0, variance = np.empty(n_beams, np.int64), np.empty(n_beams), np.empty(n_beams)
    alpha_index, h_alpha = np.empty(n_beams, np.int64), np.empty(n_beams)
    end_room, xi_grad = np.empty(n_beams), np.empty((n_beams, 4))
    if end_sigma > 0.0:
        steady = np.empty(n_beams, np.bool_)
        near, _, _ = kernels._scan_model(mean, real, index, n, params, switches, step)
        kernels.steady_beams(
            mean, cov, angles, beams, assigned, params[c.P_REACH], index[c.VARIATE, :n],
            index[c.ORDER, :n], shape[:n], real[c.LO, :n], real[c.HI, :n], near,
            params[c.P_MAX_RANGE], params[c.P_MIN_SINE], n, end_sigma, steady,
        )  # fmt: skip
        beams = beams[steady]
    k = kernels._beam_rows_of(
        mean, cov, angles, ranges, beams, real, index, shape, n, params, switches, fit_inverse,
        step, innovation, h_pose, c0_index, h_c0, alpha_index, h_alpha, variance, end_room,
        xi_grad,
    )  # fmt: skip
    if k > 0 and end_sigma > 0.0:
        keep = np.empty(k, np.bool_)
        kernels.ends_in_doubt(
            cov, h_pose[:k], c0_index[:k], h_c0[:k], alpha_index[:k], h_alpha[:k],
            end_room[:k], xi_grad[:k], end_sigma, keep,
        )  # fmt: skip
        kept = np.flatnonzero(keep)
        k = kept.size
        innovation[:k], h_pose[:k], c0_index[:k] = innovation[kept], h_pose[kept], c0_index[kept]
        h_c0[:k], alpha_index[:k], h_alpha[:k] = h_c0[kept], alpha_index[kept], h_alpha[kept]
        variance[:k] = variance[kept]
    if k == 0:
        return -1
    reuse = np.empty(n)
    kernels.reuse_factors(index, n, switches[c.S_REUSE_BOUND], reuse)
    kernels.share_landmark_error(c0_index[:k], variance[:k], params[c.P_RANGE_VAR], reuse)
    accepted, nis = np.empty(k, np.bool_), np.empty(k)
    consider_from = 3 + n if switches[c.S_ROTATION_STATES] else mean.size
    used = kernels.update_sparse(
        mean, cov, innovation[:k], h_pose[:k], c0_index[:k], h_c0[:k], alpha_index[:k],
        h_alpha[:k], variance[:k], params[c.P_GATE], consider_from, accepted, nis,
    )  # fmt: skip
    kernels.count_uses(index, n, c0_index[:k], accepted)
    return int(used)

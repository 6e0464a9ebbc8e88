"""Test oracles: slow, readable versions of SLAM pieces that production computes elsewhere.

Production has one implementation of each numerical piece (STYLE habit 20); the versions here
exist only so tests can check the fast ones against them:

* the vectorised measurement model (:func:`ray_intersections`,
  :func:`expected_ranges_and_jacobian`) — beams × polynomials in numpy, checked against brute
  force and finite differences in ``test_reference.py``; production casts a scan per call,
  compiled (:func:`polyslam_env.slam.measurement.cast`), checked against it in
  ``test_measurement.py`` (and bit for bit against the per-beam float version it replaced,
  ``reference_floats.py``, in ``test_kernels.py``);
* the dense EKF update (:func:`update`, any H and R) — production's
  :func:`polyslam_env.slam.ekf.update_sparse_inplace` is checked against it;
* the textbook prediction (:func:`predict_dense`, F P Fᵀ + L W Lᵀ with the Jacobians of
  :func:`motion_jacobians`) — production's :func:`polyslam_env.slam.ekf.predict_inplace`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from math import comb
from typing import NamedTuple

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.ekf import _symmetrise, chi2_1dof_quantile
from polyslam_env.slam.landmarks import PackedPolynomials, PolynomialsLike, pack
from polyslam_env.slam.measurement import (
    DEGREE_DROP_TOL,
    IMAG_TOL,
    POLISH_MAX,
    REAL_TOL,
    STIFF_TOL,
)
from polyslam_env.slam.polynomial import polyval_rows


# -- measurement model, vectorised over beams × polynomials ---------------------------------------
def _powers(x: np.ndarray, order: int) -> np.ndarray:
    """x**0 … x**order stacked on a new last axis, by products (float ** is slow)."""
    out = np.empty((*x.shape, order + 1))
    out[..., 0] = 1.0
    for k in range(1, order + 1):
        out[..., k] = out[..., k - 1] * x
    return out


def _taylor_weights(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Exponents E[i, k] = max(i − k, 0) and weights C(i, k)·[i ≥ k], both (M+1, M+1)."""
    i, k = np.indices((order + 1, order + 1))
    binom = np.array([[comb(a, b) for b in range(order + 1)] for a in range(order + 1)], float)
    return np.maximum(i - k, 0), np.where(i >= k, binom, 0.0)


_TAYLOR_WEIGHTS = {m: _taylor_weights(m) for m in range(1, 9)}


def taylor_at(shape: np.ndarray, xi0: np.ndarray) -> np.ndarray:
    """Taylor coefficients T[p, k] = B_p^(k)(ξ0_p)/k!, so B_p(ξ0_p + u) = Σ_k T[p, k] u^k.

    ``shape`` (n, M+1) holds [b_0, …, b_M]; ``xi0`` (n,). Returns (n, M+1):
    T[p, k] = Σ_{i≥k} C(i, k) b_i ξ0^(i−k).
    """
    order = shape.shape[1] - 1
    exps, weights = _TAYLOR_WEIGHTS.get(order) or _taylor_weights(order)
    terms = _powers(xi0, order)[:, exps] * weights  # (n, M+1, M+1) over (i, k)
    return np.einsum("pi,pik->pk", shape, terms)


@dataclass(frozen=True, eq=False)
class Hits:
    """Per beam: the nearest admissible intersection, or ``inf`` / −1 when there is none."""

    ranges: np.ndarray  # (B,) t*, inf if no admissible root
    index: np.ndarray  # (B,) int, polynomial hit, −1 if none
    xi: np.ndarray  # (B,) ξ* of the hit (nan if none)
    slope: np.ndarray  # (B,) B'(ξ*) (nan if none)
    denom: np.ndarray  # (B,) D = dη − B'·dξ (nan if none)
    phi: np.ndarray  # (B,) beam heading θ + β
    variate: np.ndarray  # (B,) int, variate of the polynomial hit, 0 if none

    @property
    def incidence_sine(self) -> np.ndarray:  # (B,)
        """|sin| of the angle between beam and curve: |D| / √(1 + B'²) (nan if no hit)."""
        return np.abs(self.denom) / np.sqrt(1.0 + self.slope**2)


class ExpectedMeasurement(NamedTuple):
    """Predicted ranges and their Jacobian w.r.t. the state [x¹, x², θ, c0_1 … c0_n]."""

    z_hat: np.ndarray  # (B,) predicted ranges, inf where no admissible hit
    H: np.ndarray  # (B, 3+n) ∂h/∂X; rows of invalid beams are zero
    valid: np.ndarray  # (B,) bool: a hit exists and is not near-tangent
    poly_index: np.ndarray  # (B,) int, −1 if no hit


def _real_roots(coeffs: np.ndarray) -> np.ndarray:
    """Real roots of each row's polynomial Σ_k coeffs[r, k] s^k; nan where none.

    ``coeffs`` (R, M+1) → (R, M). Degrees ≤ 3 use closed forms (batched LAPACK costs
    microseconds per matrix), higher ones companion matrices. A row whose leading
    coefficient is small (< STIFF_TOL of its largest) is solved one degree lower and then
    Newton-refined on the full polynomial: the closed forms lose the small roots to
    cancellation there, while the root that goes missing lies at |s| ≳ STIFF_TOL^(−1/3) ≈ 17,
    outside (0, 1]. Below DEGREE_DROP_TOL the leading term is dropped outright. A row that is
    identically zero has no roots.
    """
    n_rows, width = coeffs.shape
    if width == 1:
        return np.empty((n_rows, 0))
    mag = np.abs(coeffs)
    ratio = mag[:, -1] / np.maximum(mag.max(axis=1), np.finfo(float).tiny)  # (R,)
    solver = _ROOT_SOLVERS.get(width - 1, _companion_roots)
    if np.all(ratio >= STIFF_TOL):  # the common case
        return solver(coeffs)
    roots = np.full((n_rows, width - 1), np.nan)  # (R, M)
    full = np.flatnonzero(ratio >= STIFF_TOL)
    if full.size:
        roots[full] = solver(coeffs[full])
    lower = np.flatnonzero(ratio < STIFF_TOL)
    roots[lower, :-1] = _real_roots(coeffs[lower, :-1])
    refine = lower[ratio[lower] >= DEGREE_DROP_TOL]
    if refine.size:
        roots[refine, :-1] = _newton(coeffs[refine], roots[refine, :-1], steps=2, max_step=1e-2)
    return roots


def _linear_roots(c: np.ndarray) -> np.ndarray:  # (r, 2) → (r, 1)
    return (-c[:, 0] / c[:, 1])[:, None]


def _quadratic_roots(c: np.ndarray) -> np.ndarray:
    """Real roots of c0 + c1 s + c2 s² (r, 3) → (r, 2), cancellation-free; nan if none.

    A slightly negative discriminant (relative to its terms) counts as a double root: a ray
    grazing a curve must be found and flagged as tangent, not missed.
    """
    a, b, c = c[:, 2], c[:, 1], c[:, 0]
    disc = b * b - 4.0 * a * c
    real = disc >= -REAL_TOL * (b * b + np.abs(4.0 * a * c))
    q = -0.5 * (b + np.copysign(np.sqrt(np.maximum(disc, 0.0)), b))
    out = np.empty((len(a), 2))
    out[:, 0] = q / a
    out[:, 1] = c / np.where(q == 0.0, 1.0, q)  # q = 0 only for the double root s = 0
    out[~real] = np.nan
    return out


def _cubic_roots(c: np.ndarray) -> np.ndarray:
    """Real roots of c0 + c1 s + c2 s² + c3 s³ (r, 4) → (r, 3), nan-padded.

    One real root comes from Cardano (one real root) or Viète's trigonometric form (three);
    the other two from the deflated quadratic. Accuracy near multiple roots is modest;
    :func:`_newton` refines afterwards.
    """
    lead = c[:, 3]
    a, b, k = c[:, 2] / lead, c[:, 1] / lead, c[:, 0] / lead
    a3 = a / 3.0
    p3 = b / 3.0 - a3 * a3  # p/3 of the depressed cubic y³ + p y + q, s = y − a/3
    h = a3 * a3 * a3 - 0.5 * a3 * b + 0.5 * k  # q/2
    h2, p3_cubed = h * h, p3 * p3 * p3
    disc = h2 + p3_cubed
    three = disc <= REAL_TOL * (h2 + np.abs(p3_cubed))  # (r,) three real roots
    neg_p3 = np.maximum(-p3, 0.0)
    root_neg_p3 = np.sqrt(neg_p3)
    # Viète: y = 2√(−p/3) cos(arccos(−(q/2)/(−p/3)^{3/2})/3), the largest of three roots.
    # Denominators below |q/2| would give |arg| > 1, i.e. ±1 after clipping: take |q/2|
    # instead, which also avoids overflow (and 0/0 when p = q = 0).
    denom = np.maximum(neg_p3 * root_neg_p3, np.abs(h))
    cos_arg = -h / np.where(denom > 0.0, denom, 1.0)  # |cos_arg| ≤ 1 exactly
    viete = 2.0 * root_neg_p3 * np.cos(np.arccos(cos_arg) / 3.0)
    # Cardano without cancellation: u = ∛(−q/2 − sign(q)√Δ), y = u − (p/3)/u.
    u = np.cbrt(-h - np.copysign(np.sqrt(np.maximum(disc, 0.0)), h))
    cardano = u - p3 / np.where(u == 0.0, np.inf, u)  # u = 0 only when y = 0 is triple
    y1 = np.where(three, viete, cardano)
    # y³ + p y + q = (y − y1)(y² + y1 y + y1² + p): the other two roots.
    half_root = 0.5 * np.sqrt(np.maximum(-3.0 * y1 * y1 - 12.0 * p3, 0.0))
    half_root[~three] = np.nan
    out = np.empty((c.shape[0], 3))
    out[:, 0] = y1 - a3
    out[:, 1] = -0.5 * y1 + half_root - a3
    out[:, 2] = -0.5 * y1 - half_root - a3
    return out


def _companion_roots(c: np.ndarray) -> np.ndarray:
    """Real roots of degree-d rows (r, d+1) → (r, d) from batched companion matrices."""
    d = c.shape[1] - 1
    companion = np.zeros((c.shape[0], d, d))  # (r, d, d), monic companion matrices
    companion[:, np.arange(1, d), np.arange(d - 1)] = 1.0
    companion[:, :, -1] = -c[:, :d] / c[:, d : d + 1]
    roots = np.linalg.eigvals(companion)
    is_real = np.abs(roots.imag) <= IMAG_TOL * np.maximum(1.0, np.abs(roots.real))
    return np.where(is_real, roots.real, np.nan)


_ROOT_SOLVERS = {1: _linear_roots, 2: _quadratic_roots, 3: _cubic_roots}


def _newton(coeffs: np.ndarray, s: np.ndarray, steps: int, max_step: float) -> np.ndarray:
    """Guarded Newton steps on roots ``s`` (r, j) of the rows of ``coeffs`` (r, M+1).

    Steps longer than ``max_step`` (near a double root Newton is unreliable, and such a hit
    is flagged tangent anyway) are not taken; nan roots stay nan.
    """
    lead, width = coeffs[:, -1:], coeffs.shape[1]
    for _ in range(steps):
        value, deriv = lead + 0.0 * s, 0.0 * s  # Horner for F and F'; nan propagates
        for k in range(width - 2, -1, -1):
            deriv = deriv * s + value
            value = value * s + coeffs[:, k : k + 1]
        step = value / np.where(deriv == 0.0, np.inf, deriv)  # exact double root: stay
        s = np.where(np.abs(step) <= max_step, s - step, s)
    return s


# -- ray casting ---------------------------------------------------------------------------------
def ray_intersections(
    pose: np.ndarray,
    beam_angles: np.ndarray,
    polys: PolynomialsLike,
    c0s: np.ndarray,
    max_range: float,
) -> Hits:
    """Nearest admissible intersection of each beam with the polynomials (module docstring).

    ``pose`` (3,) = (x, y, θ); ``beam_angles`` (B,) in rad relative to θ; ``c0s`` (n,)
    overrides the polynomials' own c0. A root counts when it is real, 0 < t ≤ max_range and
    its ξ lies in [lo, hi]; the smallest over all polynomials wins.
    """
    packed = _trim_order(pack(polys))
    c0s = np.asarray(c0s, dtype=float)
    phi = pose[2] + np.asarray(beam_angles, dtype=float)  # (B,)
    n_polys = len(packed)
    if c0s.shape != (n_polys,):
        raise ValueError(f"c0s must have shape ({n_polys},), got {c0s.shape}")
    if n_polys == 0:
        return _no_hits(phi)
    is_v1 = packed.variate == 1  # (n,)
    xi0 = np.where(is_v1, pose[0], pose[1])  # (n,)
    eta0 = np.where(is_v1, pose[1], pose[0])  # (n,)
    cos, sin = np.cos(phi)[:, None], np.sin(phi)[:, None]  # (B, 1)
    dxi = np.where(is_v1, cos, sin)  # (B, n)
    deta = np.where(is_v1, sin, cos)  # (B, n)
    taylor = taylor_at(packed.shape, xi0)  # (n, M+1)

    coeffs = _ray_polynomials(taylor, eta0 - c0s, dxi, deta, max_range)  # (B, n, M+1)
    t, index = _nearest_admissible(coeffs, xi0, dxi, packed.lo, packed.hi, max_range)
    hit = np.isfinite(t)
    return _describe_hits(t, index, hit, taylor, xi0, dxi, deta, phi, packed.variate)


def _trim_order(packed: PackedPolynomials) -> PackedPolynomials:
    """Drop leading shape columns that are zero for every polynomial (keep ≥ linear).

    A zero leading coefficient sends every row through :func:`_real_roots`' lower-degree
    path and back (e.g. straight walls padded to cubics); without the column the roots,
    the winner and its Newton polish are exactly the same, and one recursion is saved.
    """
    used = np.flatnonzero(np.any(packed.shape != 0.0, axis=0))  # columns in use
    width = max(int(used[-1]) + 1 if used.size else 0, 2)
    if width == packed.shape.shape[1]:
        return packed
    return PackedPolynomials(packed.variate, packed.shape[:, :width], packed.lo, packed.hi)


def _no_hits(phi: np.ndarray) -> Hits:
    """Every beam without a return (empty map)."""
    n = phi.size
    return Hits(
        ranges=np.full(n, np.inf),
        index=np.full(n, -1),
        xi=np.full(n, np.nan),
        slope=np.full(n, np.nan),
        denom=np.full(n, np.nan),
        phi=phi,
        variate=np.zeros(n, dtype=int),
    )


def _ray_polynomials(
    taylor: np.ndarray, offset: np.ndarray, dxi: np.ndarray, deta: np.ndarray, max_range: float
) -> np.ndarray:
    """Coefficients of F in s = t / max_range, so admissible roots have 0 < s ≤ 1.

    F(t) = (η0 − c0) + t·dη − Σ_k T_k (t·dξ)^k with T the Taylor coefficients of B at ξ0.
    ``taylor`` (n, M+1), ``offset`` = η0 − c0 (n,), ``dxi``/``deta`` (B, n) → (B, n, M+1).
    """
    coeffs = -taylor[None] * _powers(dxi * max_range, taylor.shape[1] - 1)  # (B, n, M+1)
    coeffs[..., 0] += offset
    coeffs[..., 1] += deta * max_range
    return coeffs


def _nearest_admissible(
    coeffs: np.ndarray,
    xi0: np.ndarray,
    dxi: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    max_range: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per beam, the smallest admissible root over all polynomials: (t (B,), index (B,)).

    ``coeffs`` (B, n, M+1) in s = t / max_range. Inadmissible beams get t = inf, index −1.
    Only the winning roots are Newton-polished, restoring digits the closed forms lose (a
    root within ~1e-12 of an admissibility edge may go either way; no caller can tell).
    """
    n_beams, n_polys, width = coeffs.shape
    order = width - 1
    roots = _real_roots(coeffs.reshape(-1, width)).reshape(n_beams, n_polys, order)
    xi = xi0[:, None] + roots * (max_range * dxi[..., None])  # (B, n, M)
    ok = (roots > 0.0) & (roots <= 1.0) & (xi >= lo[:, None]) & (xi <= hi[:, None])
    candidates = np.where(ok, roots, np.inf).reshape(n_beams, n_polys * order)
    flat = np.argmin(candidates, axis=1)  # (B,) over (polynomial, root) pairs
    beams = np.arange(n_beams)
    index = flat // order
    best = candidates[beams, flat]  # (B,)
    found = np.isfinite(best)
    s = _newton(coeffs[beams, index], np.where(found, best, np.nan)[:, None], 1, POLISH_MAX)
    t = np.where(found, s[:, 0] * max_range, np.inf)  # (B,)
    return t, np.where(found, index, -1)


def _describe_hits(
    t: np.ndarray,
    index: np.ndarray,
    hit: np.ndarray,
    taylor: np.ndarray,
    xi0: np.ndarray,
    dxi: np.ndarray,
    deta: np.ndarray,
    phi: np.ndarray,
    variate: np.ndarray,
) -> Hits:
    """ξ*, B'(ξ*) and D of each beam's hit, from the Taylor coefficients at the robot."""
    beams = np.arange(t.size)
    p = np.where(hit, index, 0)  # (B,) safe index for gathering
    dxi_b, deta_b = dxi[beams, p], deta[beams, p]  # (B,)
    u = np.where(hit, t, np.nan) * dxi_b  # (B,) ξ* − ξ0
    k = np.arange(1, taylor.shape[1])
    slope = (k * taylor[p, 1:] * _powers(u, k.size - 1)).sum(axis=1)  # (B,) B'(ξ0 + u)
    return Hits(
        ranges=t,
        index=index,
        xi=xi0[p] + u,
        slope=slope,
        denom=deta_b - slope * dxi_b,
        phi=phi,
        variate=np.where(hit, variate[p], 0),
    )


def expected_ranges_and_jacobian(
    mean: np.ndarray,
    polys: PolynomialsLike,
    beam_angles: np.ndarray,
    max_range: float,
    tangent_min_deg: float = 10.0,
    candidates: np.ndarray | None = None,
) -> ExpectedMeasurement:
    """h(X) for every beam and H = ∂h/∂X (SPEC §3), from the state ``mean`` (3+n,).

    A beam is valid when it has an admissible hit whose incidence |D|/√(1+B'²) is at least
    sin(tangent_min_deg); near-tangent ranges are too sensitive to linearise. Implicit
    differentiation of F(t*) = 0 gives ∂h/∂v = −(∂F/∂v)/(∂F/∂t) with ∂F/∂t = D, i.e.
    ∂h/∂ξ0 = B'/D, ∂h/∂η0 = −1/D, ∂h/∂c0 = 1/D and ∂h/∂θ = −t*(dη' − B'·dξ')/D where ' is
    d/dφ. For the x¹-variate case this is the SPEC's (B'/D, −1/D, −t*(cos φ + B' sin φ)/D,
    1/D), and for the x²-variate case (−1/D, B'/D, t*(sin φ + B' cos φ)/D, 1/D).

    ``candidates`` (ascending indices) restricts the ray casting to the polynomials a beam
    can reach (e.g. those whose bounding box lies within ``max_range``); the others must
    have no admissible root. Each beam's result is then the same as with all of them.
    """
    mean = np.asarray(mean, dtype=float)
    n_state = mean.size
    if candidates is None:
        hits = ray_intersections(mean[:3], beam_angles, polys, mean[3:], max_range)
    else:
        hits = _candidate_hits(mean, beam_angles, pack(polys), candidates, max_range)
    min_sine = np.sin(np.deg2rad(tangent_min_deg))
    valid = (hits.index >= 0) & (hits.incidence_sine >= min_sine)  # (B,)
    rows = np.flatnonzero(valid)
    H = np.zeros((hits.ranges.size, n_state))  # (B, 3+n)
    if rows.size:
        is_v1 = hits.variate[rows] == 1
        inv_d = 1.0 / hits.denom[rows]
        slope_d = hits.slope[rows] * inv_d
        cos, sin = np.cos(hits.phi[rows]), np.sin(hits.phi[rows])
        d_eta = np.where(is_v1, cos, -sin)  # d(dη)/dφ
        d_xi = np.where(is_v1, -sin, cos)  # d(dξ)/dφ
        H[rows, 0] = np.where(is_v1, slope_d, -inv_d)
        H[rows, 1] = np.where(is_v1, -inv_d, slope_d)
        H[rows, 2] = -hits.ranges[rows] * (d_eta - hits.slope[rows] * d_xi) * inv_d
        H[rows, 3 + hits.index[rows]] = inv_d
    return ExpectedMeasurement(hits.ranges, H, valid, hits.index)


def _candidate_hits(
    mean: np.ndarray,
    beam_angles: np.ndarray,
    packed: PackedPolynomials,
    candidates: np.ndarray,
    max_range: float,
) -> Hits:
    """:func:`ray_intersections` on the ``candidates`` subset, indices mapped back."""
    if candidates.size == 0:
        return _no_hits(mean[2] + np.asarray(beam_angles, dtype=float))
    sub = packed.subset(candidates)
    hits = ray_intersections(mean[:3], beam_angles, sub, mean[3 + candidates], max_range)
    index = np.where(hits.index >= 0, candidates[np.maximum(hits.index, 0)], -1)
    return Hits(hits.ranges, index, hits.xi, hits.slope, hits.denom, hits.phi, hits.variate)


# -- EKF prediction and update, dense ---------------------------------------------------------
def motion_jacobians(pose: np.ndarray, odometry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F = ∂f/∂pose and L = ∂f/∂odometry of the unicycle composition, both (3, 3).

    f(pose, u) = [x + cos θ·dx − sin θ·dy, y + sin θ·dx + cos θ·dy, θ + dθ], with the
    odometry u = (dx, dy, dθ) measured in the robot frame at the start of the step.
    """
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = odometry[0], odometry[1]
    F = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    L = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return F, L


def predict_dense(
    mean: np.ndarray, cov: np.ndarray, odometry: np.ndarray, W: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The EKF prediction as in the textbook: X⁺ = f(X, u), P⁺ = F P Fᵀ + L W Lᵀ with F and L
    (3+n)-sized (identity on the landmarks, zero rows for the noise)."""
    n_state = mean.size
    x, y, theta = mean[:3]
    c, s = np.cos(theta), np.sin(theta)
    new_mean = np.array(mean, dtype=float)
    new_mean[0] = x + c * odometry[0] - s * odometry[1]
    new_mean[1] = y + s * odometry[0] + c * odometry[1]
    new_mean[2] = wrap_angle(theta + odometry[2])
    F, L = motion_jacobians(mean, odometry)
    F_full = np.eye(n_state)
    F_full[:3, :3] = F
    L_full = np.zeros((n_state, 3))
    L_full[:3] = L
    return new_mean, F_full @ cov @ F_full.T + L_full @ W @ L_full.T


@dataclass(frozen=True, eq=False)
class UpdateResult:
    """Outcome of :func:`update`: the new estimate and which measurements were used."""

    mean: np.ndarray  # (3+n,)
    cov: np.ndarray  # (3+n, 3+n)
    accepted: np.ndarray  # (k,) bool: passed the χ² gate and went into the update
    nis: np.ndarray  # (k,) normalised innovation squared ν²/S_ii per measurement (nan if unusable)

    @property
    def mean_cov(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean, self.cov


def update(
    mean: np.ndarray,
    cov: np.ndarray,
    z: np.ndarray,
    z_hat: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    gate_prob: float = 0.99,
) -> UpdateResult:
    """Gated, batched EKF update with measurements z (k,), predictions z_hat (k,), H (k, 3+n).

    Each measurement is gated on its own normalised innovation ν_i²/S_ii against the χ²
    (1 dof) quantile ``gate_prob`` (1.0 disables the gate); non-finite z or z_hat are never
    accepted. The accepted ones update together with the Joseph form
    P⁺ = (I−KH) P (I−KH)ᵀ + K R Kᵀ, evaluated as M = P − K(PHᵀ)ᵀ, P⁺ = M − (M Hᵀ) Kᵀ + K R Kᵀ
    (the same product, without (3+n)² identities; see :func:`_joseph`), with K from a solve
    with S. H is sparse in practice (pose + one c0 per row), so P Hᵀ uses only its non-zero
    columns.
    """
    z, z_hat = np.asarray(z, dtype=float), np.asarray(z_hat, dtype=float)
    H, R = np.atleast_2d(H), np.atleast_2d(R)
    innovation = z - z_hat  # (k,)
    usable = np.isfinite(innovation)
    cols = np.flatnonzero(np.any(H[usable] != 0.0, axis=0))  # state indices H touches
    PHt = cov[:, cols] @ H[:, cols].T  # (3+n, k)
    s_diag = np.einsum("ij,ji->i", H[:, cols], PHt[cols]) + np.diag(R)  # (k,)
    nis = np.full(z.shape, np.nan)
    nis[usable] = innovation[usable] ** 2 / s_diag[usable]
    accepted = usable & (nis <= chi2_1dof_quantile(gate_prob))
    if not accepted.any():
        return UpdateResult(mean.copy(), cov.copy(), accepted, nis)
    a = np.flatnonzero(accepted)
    PHt_a, H_a, R_a = PHt[:, a], H[a][:, cols], R[a][:, a]
    S = H_a @ PHt_a[cols] + R_a  # (k_a, k_a), symmetric positive definite
    K = np.linalg.solve(S, PHt_a.T).T  # (3+n, k_a); S is tiny: LAPACK's overhead dominates
    new_mean = mean + K @ innovation[a]
    new_mean[2] = wrap_angle(new_mean[2])
    return UpdateResult(new_mean, _joseph(cov, K, PHt_a, H_a, R_a, cols), accepted, nis)


def _joseph(
    cov: np.ndarray,
    K: np.ndarray,
    PHt: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    cols: np.ndarray,
) -> np.ndarray:
    """Joseph form P⁺ = M − (M Hᵀ) Kᵀ + K R Kᵀ with M = P − K (P Hᵀ)ᵀ, symmetrised.

    ``H`` (k, c) holds only the state columns ``cols`` it touches, ``PHt`` = P Hᵀ (3+n, k).
    M Hᵀ needs only M's columns ``cols``, so M is never formed: with B = M Hᵀ − K R,
    P⁺ = P − [K  B] [PHtᵀ; Kᵀ], one rank-2k product and a handful of (3+n)² passes.
    """
    m_cols = cov[:, cols] - K @ PHt[cols].T  # (3+n, c) = M[:, cols]
    B = m_cols @ H.T - K @ R  # (3+n, k)
    new_cov = cov - np.hstack([K, B]) @ np.vstack([PHt.T, K.T])
    return _symmetrise(new_cov)


# -- approximation error, vectorised (oracle of association.nearest_by_error) ----------------
def approximation_error(
    points: np.ndarray,
    polys: PolynomialsLike,
    c0s: Sequence[float] | np.ndarray,
    squared: bool = False,
) -> np.ndarray:
    """(P, n) approximation error of each point by each polynomial (c0 taken from ``c0s``).

    Inside a polynomial's extent: the vertical (variate 1) / horizontal (variate 2) distance
    |η − p(ξ)|; outside: the distance to the nearer end point. Metres, or the paper's squared
    form with ``squared=True``. ``polys`` may be packed (the SLAM's hot path).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    packed = pack(polys)
    if len(packed) == 0:
        return np.zeros((len(pts), 0))
    coeffs = packed.shape.copy()  # (n, m+1), zero-padded
    coeffs[:, 0] = np.asarray(c0s, dtype=float)
    var1 = packed.variate == 1  # (n,)
    lo, hi = packed.lo, packed.hi
    xi = np.where(var1, pts[:, :1], pts[:, 1:])  # (P, n)
    eta = np.where(var1, pts[:, 1:], pts[:, :1])
    vertical = np.abs(eta - polyval_rows(coeffs, xi.T).T)
    ends_xi = np.stack([lo, hi], axis=0)  # (2, n)
    ends_eta = polyval_rows(coeffs, ends_xi.T).T  # (2, n)
    d_end = np.minimum(
        np.hypot(xi - ends_xi[0], eta - ends_eta[0]), np.hypot(xi - ends_xi[1], eta - ends_eta[1])
    )
    err = np.where((xi >= lo) & (xi <= hi), vertical, d_end)
    return err**2 if squared else err

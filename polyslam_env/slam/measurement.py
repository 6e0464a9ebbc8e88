"""Range measurement model h of the polynomial SLAM and its Jacobian (SPEC §3).

A beam leaves the robot at heading φ = θ + β and travels ``t`` metres. It meets a map
polynomial where F(t) = η0 + t·dη − c0 − B(ξ0 + t·dξ) = 0, with (ξ0, η0) the robot position
in the polynomial's (independent, dependent) coordinates and (dξ, dη) the beam direction in
the same order: x¹-variate gives ξ0 = x, η0 = y, dξ = cos φ, dη = sin φ; x²-variate swaps
them. ``B`` is the shape polynomial without constant term; ``c0`` comes from the EKF state.

h is the smallest real root 0 < t ≤ r_max whose ξ lies in the extent, minimised over all
polynomials. F is expanded in t from the Taylor coefficients of B at ξ0 and solved in
closed form (degree ≤ 3) or with batched companion matrices (higher), then the winning root
is Newton-polished. Everything is vectorised over beams × polynomials; the only Python loops
run over polynomial degrees. Callers on the hot path should cache a PackedPolynomials.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from math import comb
from typing import NamedTuple, Protocol

import numpy as np

from polyslam_env.slam.polynomial import Polynomial

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


@dataclass(frozen=True, eq=False)
class PackedPolynomials:
    """Shapes, variates and extents of n polynomials as arrays, for vectorised ray casting.

    Build it once per map change with :meth:`from_polynomials` and pass it instead of the
    polynomial list on the hot path; ``c0`` is not stored (it lives in the EKF state).
    """

    variate: np.ndarray  # (n,) int, 1 or 2
    shape: np.ndarray  # (n, M+1): [0, b_1, …, b_M], zero-padded to the largest order M
    lo: np.ndarray  # (n,) extent on ξ
    hi: np.ndarray  # (n,)

    @classmethod
    def from_polynomials(cls, polys: Sequence[Polynomial]) -> PackedPolynomials:
        order = max((p.order for p in polys), default=1)
        shape = np.zeros((len(polys), order + 1))  # (n, M+1)
        for i, p in enumerate(polys):
            shape[i, 1 : p.order + 1] = p.shape
        return cls(
            variate=np.array([p.variate for p in polys], dtype=int),
            shape=shape,
            lo=np.array([p.lo for p in polys], dtype=float),
            hi=np.array([p.hi for p in polys], dtype=float),
        )

    def __len__(self) -> int:
        return len(self.variate)

    @property
    def order(self) -> int:
        return self.shape.shape[1] - 1

    def subset(self, indices: np.ndarray) -> PackedPolynomials:
        """The polynomials at ``indices`` (an index array), in that order."""
        return PackedPolynomials(
            self.variate[indices], self.shape[indices], self.lo[indices], self.hi[indices]
        )


PolynomialsLike = Sequence[Polynomial] | PackedPolynomials


class ShapeRow(Protocol):
    """A landmark's shape as plain floats (e.g. a ``landmarks.LandmarkRow``), for the
    per-beam loops of ``beamcast.cast`` and ``association.nearest_by_error``."""

    @property
    def variate(self) -> int: ...
    @property
    def shape(self) -> tuple[float, ...]: ...  # (0, b_1, …, b_m), no zero tail
    @property
    def lo(self) -> float: ...
    @property
    def hi(self) -> float: ...


def pack(polys: PolynomialsLike) -> PackedPolynomials:
    """``polys`` as :class:`PackedPolynomials` (no copy when already packed)."""
    if isinstance(polys, PackedPolynomials):
        return polys
    return PackedPolynomials.from_polynomials(polys)


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


# -- polynomial algebra ------------------------------------------------------------------------
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


def _powers(x: np.ndarray, order: int) -> np.ndarray:
    """x**0 … x**order stacked on a new last axis, by products (float ** is slow)."""
    out = np.empty((*x.shape, order + 1))
    out[..., 0] = 1.0
    for k in range(1, order + 1):
        out[..., k] = out[..., k - 1] * x
    return out


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

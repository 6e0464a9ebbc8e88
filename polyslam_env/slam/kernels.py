"""Compiled kernels of the SLAM step: measurement model, association error, EKF prediction and
update, landmark boxes (STYLE habit 20).

Plain loops over flat arrays, compiled by :func:`polyslam_env.core.jit.njit` (no fastmath): each
kernel does the operations of the readable version it replaced in the same order, so results are
bit-identical to it, except where that version called BLAS or LAPACK: :func:`update_sparse` and
:func:`normalised_innovations` (plain sums instead of BLAS's products) and :func:`_companion`
(orders 4–5 only), equal to rounding. The readable versions are the test oracles in
``tests/slam/reference_floats.py``; the typed wrappers that own validation live in the modules
that use them (``measurement``, ``association``, ``ekf``, ``landmarks``, ``robot``). Kernels
write into caller buffers rather than return arrays where they run every step: numba boxes each
returned array into a new Python object.

Landmarks are passed as the :class:`~polyslam_env.slam.landmarks.LandmarkTable`'s hot-path
arrays: ``variate`` (n,), ``order`` (n,) (each shape's own order, no zero tail), ``shape``
(n, M+1) rows [0, b_1, …, b_M], ``lo``/``hi`` (n,), and the c0s (n,) from the state.

Python's scalar semantics are kept where they differ from C's: ``max(a, b)`` / ``min(a, b)``
keep the first argument unless the second is strictly larger / smaller (:func:`_max`,
:func:`_min`, which matters for nan), ``x ** i`` is libm's ``pow`` and ``math.hypot`` is
CPython's correctly rounded algorithm (:func:`hypot`), not libm's.
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import fma, njit
from polyslam_env.slam.columns import (
    CHANGED_AT,
    ETA_HI,
    ETA_LO,
    FIT_HALF,
    HI,
    LO,
    MODEL_VAR,
    ORDER,
    P_END_SIGMA,
    P_GATE,
    P_MAX_RANGE,
    P_MIN_SINE,
    P_RANGE_VAR,
    P_REACH,
    P_TURN_VAR_PER_STEP,
    PIVOT,
    S_N_FIT,
    S_REUSE_BOUND,
    S_ROTATION_STATES,
    S_SEEN_FACES,
    S_SHAPE_FOLLOWS_POSE,
    S_SHIFT_WITH_POSE,
    SHIFT_SLOPE,
    SIDE,
    USES,
    VARIATE,
    XI_VAR,
)

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
#: Slack (m) around a landmark's box when deciding whether a beam can reach it: far above the
#: error of any accepted root (the closed forms plus Newton are accurate to ~1e-9 m).
BOX_MARGIN = 1e-3
#: Largest shape order the kernels take (the SLAM's is at most 5: SlamConfig.order).
MAX_ORDER = 15

#: Rows of K that :func:`joseph_blocks` takes in one pass over P: the paper's scan's five beams.
PASS_ROWS = 5
_TINY = 2.2250738585072014e-308  # smallest normal float: np.finfo(float).tiny
_BINOM = np.array(
    [[float(math.comb(i, k)) for k in range(MAX_ORDER + 1)] for i in range(MAX_ORDER + 1)]
)  # (M+1, M+1): C(i, k)


# -- Python's scalar semantics --------------------------------------------------------------------
@njit
def _max(a: float, b: float) -> float:
    """Python's ``max(a, b)``: ``a`` unless ``b > a``."""
    return b if b > a else a


@njit
def _min(a: float, b: float) -> float:
    """Python's ``min(a, b)``: ``a`` unless ``b < a``."""
    return b if b < a else a


@njit
def _maximum(a: float, b: float) -> float:
    """numpy's ``np.maximum(a, b)``: nan if either is nan."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@njit
def _two_product(x: float, y: float) -> tuple[float, float]:
    """x·y as hi + lo, exactly (Dekker's product with Veltkamp's split)."""
    t = x * 134217729.0  # 2**27 + 1
    x_hi = t - (t - x)
    x_lo = x - x_hi
    t = y * 134217729.0
    y_hi = t - (t - y)
    y_lo = y - y_hi
    p = x_hi * y_hi
    q = x_hi * y_lo + x_lo * y_hi
    z = p + q
    zz = p - z + q + x_lo * y_lo
    return z, zz


@njit
def hypot(x: float, y: float) -> float:
    """CPython's ``math.hypot(x, y)`` (its ``vector_norm``: scaled, compensated, with a
    differential correction of the root), bit for bit; libm's hypot rounds differently."""
    a, b = abs(x), abs(y)
    if math.isinf(a) or math.isinf(b):
        return math.inf
    if math.isnan(a) or math.isnan(b):
        return math.nan
    big = b if b > a else a
    if big == 0.0:
        return big
    unscale = 1.0
    _, exponent = math.frexp(big)
    if exponent < -1023:  # subnormal: to normals first
        a, b, big = a / _TINY, b / _TINY, big / _TINY
        unscale = _TINY
        _, exponent = math.frexp(big)
    scale = math.ldexp(1.0, -exponent)
    csum, frac1, frac2 = 1.0, 0.0, 0.0
    for v in (a, b):
        v *= scale
        hi, lo = _two_product(v, v)
        total = csum + hi
        frac2 += (csum - total) + hi
        csum = total
        frac1 += lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    hi, lo = _two_product(-h, h)
    total = csum + hi
    frac2 += (csum - total) + hi
    csum = total
    frac1 += lo
    v = csum - 1.0 + (frac1 + frac2)
    h += v / (2.0 * h)
    return unscale * (h / scale)


# -- polynomials ----------------------------------------------------------------------------------
@njit
def horner(c: np.ndarray, m: int, x: float, c0: float) -> tuple[float, float]:
    """(p(x), p'(x)) of c[0..m] (m ≥ 1) with ``c0`` in place of c[0], by Horner's scheme."""
    value = c[m]
    slope = 0.0
    for i in range(m - 1, 0, -1):
        slope = slope * x + value
        value = value * x + c[i]
    slope = slope * x + value
    value = value * x + c0
    return value, slope


@njit
def taylor_shift(c: np.ndarray, m: int, x0: float, out: np.ndarray) -> None:
    """out[k] = Σ_{i≥k} C(i, k) c_i x0^(i−k), k ≤ m: p(x0 + u) = Σ_k out[k] u^k."""
    powers = np.empty(m + 1)
    powers[0] = 1.0
    for i in range(1, m + 1):
        powers[i] = powers[i - 1] * x0
    for k in range(m + 1):
        total = 0.0
        for i in range(k, m + 1):
            total += c[i] * (powers[i - k] * _BINOM[i, k])
        out[k] = total


# -- real roots of a ray polynomial (units of r_max) ----------------------------------------------
@njit
def _newton(c: np.ndarray, m: int, s: float, steps: int, max_step: float) -> float:
    """Guarded Newton steps on a root ``s`` of Σ_k c[k] s^k, k ≤ m (nan stays nan)."""
    for _ in range(steps):
        value, deriv = horner(c, m, s, c[0])
        step = value / deriv if deriv != 0.0 else 0.0
        if abs(step) <= max_step:
            s = s - step
    return s


@njit
def _quadratic(c: float, b: float, a: float, roots: np.ndarray) -> None:
    """Real roots of c + b s + a s², cancellation-free; nan if none. A slightly negative
    discriminant (relative to its terms) counts as a double root: a ray grazing a curve must
    be found and flagged as tangent, not missed."""
    disc = b * b - 4.0 * a * c
    if not disc >= -REAL_TOL * (b * b + abs(4.0 * a * c)):
        roots[0] = roots[1] = math.nan
        return
    q = -0.5 * (b + math.copysign(math.sqrt(_max(disc, 0.0)), b))
    roots[0] = q / a
    roots[1] = c / (q if q != 0.0 else 1.0)


@njit
def _cubic(k0: float, k1: float, k2: float, lead: float, roots: np.ndarray) -> None:
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
        neg_p3 = _max(-p3, 0.0)
        root_neg_p3 = math.sqrt(neg_p3)
        denom = _max(neg_p3 * root_neg_p3, abs(h))
        cos_arg = -h / (denom if denom > 0.0 else 1.0)
        y1 = 2.0 * root_neg_p3 * math.cos(math.acos(cos_arg) / 3.0)
        half_root = 0.5 * math.sqrt(_max(-3.0 * y1 * y1 - 12.0 * p3, 0.0))
        roots[0] = y1 - a3
        roots[1] = -0.5 * y1 + half_root - a3
        roots[2] = -0.5 * y1 - half_root - a3
        return
    u = np.cbrt(-h - math.copysign(math.sqrt(_max(disc, 0.0)), h))
    y1 = u - p3 / u if u != 0.0 else u
    roots[0] = y1 - a3
    roots[1] = roots[2] = math.nan


@njit
def _companion(c: np.ndarray, d: int, roots: np.ndarray) -> None:
    """Degree > 3 (orders above the paper's cubics): eigenvalues of the companion matrix.

    Complex LAPACK (zgeev): numba's real eigvals refuses complex eigenvalues. Roots differ
    from numpy's real dgeev by rounding only (~1e-16 relative), and Newton polishes the
    winner."""
    companion = np.zeros((d, d), dtype=np.complex128)
    for i in range(1, d):
        companion[i, i - 1] = 1.0
    for i in range(d):
        companion[i, d - 1] = -c[i] / c[d]
    eig = np.linalg.eigvals(companion)
    for i in range(d):
        re, im = eig[i].real, eig[i].imag
        roots[i] = re if abs(im) <= IMAG_TOL * np.maximum(1.0, abs(re)) else math.nan


@njit
def _solve(c: np.ndarray, d: int, roots: np.ndarray) -> None:
    if d == 1:
        roots[0] = -c[0] / c[1]
    elif d == 2:
        _quadratic(c[0], c[1], c[2], roots)
    elif d == 3:
        _cubic(c[0], c[1], c[2], c[3], roots)
    else:
        _companion(c, d, roots)


@njit
def real_roots(c: np.ndarray, degree: int, roots: np.ndarray) -> int:
    """Real roots of Σ_{k≤degree} c[k] s^k into ``roots`` (nan-padded); returns their count.

    A row whose leading coefficient is small (< STIFF_TOL of its largest) is solved one
    degree lower and then Newton-refined on the full polynomial: the closed forms lose the
    small roots to cancellation there, while the root that goes missing lies at
    |s| ≳ STIFF_TOL^(−1/3) ≈ 17, outside (0, 1]. Below DEGREE_DROP_TOL the leading term is
    dropped outright.
    """
    ratios = np.empty(degree + 1)
    d = degree
    while d > 0:
        largest = abs(c[0])
        for i in range(1, d + 1):
            if abs(c[i]) > largest:
                largest = abs(c[i])
        ratios[d] = abs(c[d]) / _max(largest, _TINY)
        if ratios[d] >= STIFF_TOL:
            break
        d -= 1
    if d == 0:
        return 0
    _solve(c, d, roots)
    for level in range(d + 1, degree + 1):  # innermost first, as the recursion returns
        if ratios[level] >= DEGREE_DROP_TOL:
            for i in range(d):
                roots[i] = _newton(c, level, roots[i], 2, 1e-2)
    return d


# -- casting beams against landmarks --------------------------------------------------------------
@njit
def _meets_box(x: float, y: float, dx: float, dy: float, box: np.ndarray) -> bool:
    """Whether the segment (x, y) → (x + dx, y + dy) passes within BOX_MARGIN of ``box``
    (x_min, x_max, y_min, y_max) (slab clipping: the segment's parameter interval inside each
    widened slab)."""
    t0, t1 = 0.0, 1.0
    for axis in range(2):
        start, delta = (x, dx) if axis == 0 else (y, dy)
        low, high = box[2 * axis] - BOX_MARGIN, box[2 * axis + 1] + BOX_MARGIN
        if delta == 0.0:
            if start < low or start > high:
                return False
            continue
        a, b = (low - start) / delta, (high - start) / delta
        if a > b:
            a, b = b, a
        t0, t1 = _max(t0, a), _min(t1, b)
        if t0 > t1:
            return False
    return True


@njit
def cast_scan(
    x: float,
    y: float,
    theta: float,
    angles: np.ndarray,  # (B,) beam angles in the robot frame
    candidates: np.ndarray,  # (K,) ascending landmark indices
    variate: np.ndarray,  # (n,)
    order: np.ndarray,  # (n,)
    shape: np.ndarray,  # (n, M+1)
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    c0s: np.ndarray,  # (n,)
    boxes: np.ndarray,  # (n, 4) holding each curve (inf boxes: no pruning)
    max_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cast_into` into new arrays (t, landmark, slope, D, ξ*), each (B,)."""
    n_beams = angles.size
    t_out = np.empty(n_beams)
    landmark = np.empty(n_beams, dtype=np.int64)
    slope_out, denom_out, xi_out = np.empty(n_beams), np.empty(n_beams), np.empty(n_beams)
    cast_into(
        x, y, theta, angles, candidates, variate, order, shape, lo, hi, c0s, boxes, max_range,
        t_out, landmark, slope_out, denom_out, xi_out,
    )  # fmt: skip
    return t_out, landmark, slope_out, denom_out, xi_out


@njit
def cast_into(
    x: float,
    y: float,
    theta: float,
    angles: np.ndarray,  # (B,) beam angles in the robot frame
    candidates: np.ndarray,  # (K,) ascending landmark indices
    variate: np.ndarray,  # (n,)
    order: np.ndarray,  # (n,)
    shape: np.ndarray,  # (n, M+1)
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    c0s: np.ndarray,  # (n,)
    boxes: np.ndarray,  # (n, 4) holding each curve (inf boxes: no pruning)
    max_range: float,
    t_out: np.ndarray,  # (B,) out: t* (inf: no hit)
    landmark: np.ndarray,  # (B,) out: landmark hit (−1: none)
    slope_out: np.ndarray,  # (B,) out: B'(ξ*) (nan: no hit)
    denom_out: np.ndarray,  # (B,) out: D = dη − B'·dξ
    xi_out: np.ndarray,  # (B,) out: ξ*
) -> None:
    """Per beam the nearest admissible hit on the candidates, into the ``_out`` arrays.

    Per candidate the Taylor coefficients of B at the robot, F(s) in s = t/r_max, its real
    roots (:func:`real_roots`); a root counts when 0 < s ≤ 1 and its ξ lies in [lo, hi], the
    first minimum in (candidate, root) order wins, then one guarded Newton polish. A beam
    whose segment passes farther than BOX_MARGIN from a candidate's box is not solved
    against it (it cannot hit it), and its Taylor coefficients are made only once a beam meets
    its box.
    """
    width = shape.shape[1]
    _cast_with(
        x, y, theta, angles, candidates, variate, order, shape, lo, hi, c0s, boxes, max_range,
        t_out, landmark, slope_out, denom_out, xi_out, np.empty((candidates.size, width)),
        np.empty(width), np.empty(width), np.empty(width), np.empty(candidates.size, np.bool_),
    )  # fmt: skip


@njit
def _cast_with(
    x: float,
    y: float,
    theta: float,
    angles: np.ndarray,
    candidates: np.ndarray,
    variate: np.ndarray,
    order: np.ndarray,
    shape: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    c0s: np.ndarray,
    boxes: np.ndarray,
    max_range: float,
    t_out: np.ndarray,
    landmark: np.ndarray,
    slope_out: np.ndarray,
    denom_out: np.ndarray,
    xi_out: np.ndarray,
    taylors: np.ndarray,  # (≥ K, M+1) scratch
    coeffs: np.ndarray,  # (M+1,) scratch
    best_coeffs: np.ndarray,  # (M+1,) scratch
    roots: np.ndarray,  # (M+1,) scratch
    shifted: np.ndarray,  # (≥ K,) bool scratch
) -> None:
    """:func:`cast_into` with its scratch arrays given (a caller casting many times)."""
    n_beams, n_cand = angles.size, candidates.size
    shifted[:n_cand] = False  # a candidate's Taylor coefficients, made when a beam meets its box
    t_out[:] = math.inf
    landmark[:] = -1
    slope_out[:] = math.nan
    denom_out[:] = math.nan
    xi_out[:] = math.nan
    for b in range(n_beams):
        phi = theta + angles[b]
        cos, sin = math.cos(phi), math.sin(phi)
        best = math.inf
        best_k = -1
        for k in range(n_cand):
            j = candidates[k]
            if not _meets_box(x, y, cos * max_range, sin * max_range, boxes[j]):
                continue
            if not shifted[k]:
                taylor_shift(shape[j], order[j], x if variate[j] == 1 else y, taylors[k])
                shifted[k] = True
            if variate[j] == 1:
                xi0, eta0, dxi, deta = x, y, cos, sin
            else:
                xi0, eta0, dxi, deta = y, x, sin, cos
            m = order[j]
            step = dxi * max_range  # F(s) = (η0 − c0) + s·r·dη − Σ_k T_k (s·r·dξ)^k
            power = 1.0
            for i in range(m + 1):
                coeffs[i] = -taylors[k, i] * power
                power *= step
            coeffs[0] += eta0 - c0s[j]
            coeffs[1] += deta * max_range
            step = max_range * dxi
            for r in range(real_roots(coeffs, m, roots)):
                s = roots[r]
                if s > 0.0 and s <= 1.0 and s < best:
                    xi = xi0 + s * step
                    if lo[j] <= xi and xi <= hi[j]:
                        best, best_k = s, k
                        best_coeffs[: m + 1] = coeffs[: m + 1]
        if best_k < 0:
            continue
        j = candidates[best_k]
        m = order[j]
        s = _newton(best_coeffs, m, best, 1, POLISH_MAX)
        xi0, dxi, deta = (x, cos, sin) if variate[j] == 1 else (y, sin, cos)
        t = s * max_range
        u = t * dxi
        slope, power = 0.0, 1.0
        for i in range(1, m + 1):
            slope += i * taylors[best_k, i] * power
            power *= u
        t_out[b], landmark[b], slope_out[b] = t, j, slope
        denom_out[b], xi_out[b] = deta - slope * dxi, xi0 + u


@njit
def _shape_fit_var(
    shape: np.ndarray,
    m: int,
    t: float,
    fit_inverse: np.ndarray,
    n_fit: int,
    noise_var: float,
    drop_slope: bool,
) -> float:
    """Variance of a frozen shape's η at scaled position t (see :func:`_beam_rows_of`):
    σ²·(a(t)ᵀ M⁻¹ a(t) − 1/N), a = [1, t, …, t^m], M⁻¹ = ``fit_inverse[m]``, floored at 0.
    ``drop_slope``: without the slope's own part σ²·t²·M⁻¹[1, 1] (the shape's rotation is a
    state then, ``SlamConfig.shape_rotation = "considered"``)."""
    order = m if shape[m] != 0.0 else 0
    if order == 0:
        return 0.0
    a = np.empty(order + 1)
    for i in range(order + 1):
        a[i] = 1.0 if i == 0 else math.pow(t, float(i))  # Python's t ** i: libm's pow
    inverse = fit_inverse[order]
    quad = 0.0
    for i in range(order + 1):
        inner = 0.0
        for j in range(order + 1):
            inner += inverse[i, j] * a[j]
        quad += a[i] * inner
    quad -= 1.0 / n_fit
    if drop_slope:
        quad -= t * t * inverse[1, 1]
    return noise_var * _max(quad, 0.0)


@njit
def beam_rows(
    x: float,
    y: float,
    theta: float,
    angles: np.ndarray,  # (B,) every beam's angle
    ranges: np.ndarray,  # (B,) every beam's reading
    beams: np.ndarray,  # (k,) int64: the beams wanted, in this order
    reach: float,  # landmarks whose box lies farther from the robot cannot be hit
    variate: np.ndarray,  # (n,)
    order: np.ndarray,  # (n,)
    shape: np.ndarray,  # (n, M+1)
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    c0s: np.ndarray,  # (n,)
    boxes: np.ndarray,  # (n, 4)
    max_range: float,
    min_sine: float,  # sin of the smallest incidence angle used
    range_var: float,  # σ² of the range noise
    model_var: np.ndarray,  # (n,) fit variance beyond the noise
    shape_follows_pose: bool,
    shift_with_pose: bool,  # a frozen shape's shift along ξ is predicted from the current pose
    pivot: np.ndarray,  # (n,)
    xi_var: np.ndarray,  # (n,)
    pose_var: np.ndarray,  # (2,) the current pose's variance along x and along y
    shift_slope: np.ndarray,  # (n,) ∂c0/∂(its shape's shift along ξ), negated; nan: unknown
    turn_var: np.ndarray,  # (n,) variance of the heading change since the shape was fitted
    fit_half: np.ndarray,  # (n,)
    fit_inverse: np.ndarray,  # (M+1, M+1, M+1): (AᵀA)⁻¹ of order o in [o, :o+1, :o+1]
    n_fit: int,
    alpha_base: int,  # state index of landmark 0's shape rotation; −1: not in the state
    innovation: np.ndarray,  # (≥ k,) out
    h_pose: np.ndarray,  # (≥ k, 3) out
    c0_index: np.ndarray,  # (≥ k,) int64 out
    h_c0: np.ndarray,  # (≥ k,) out
    alpha_index: np.ndarray,  # (≥ k,) int64 out: the rotation's state index, −1: none
    h_alpha: np.ndarray,  # (≥ k,) out
    variance: np.ndarray,  # (≥ k,) out
    end_room: np.ndarray,  # (≥ k,) out: how far inside its landmark's extent the hit lies (ξ)
    xi_grad: np.ndarray,  # (≥ k, 4) out: ∂ξ*/∂(x, y, θ) at fixed range, and dξ/dt
) -> int:
    """The EKF rows of the ``beams`` with a usable hit (:func:`cast_into` on the landmarks
    within ``reach``; near-tangent hits, below ``min_sine``, are skipped), written to the first
    rows of the outputs in beam order: innovation, h_pose, c0 state index, h_c0 = 1/D, the
    shape rotation's state index and Jacobian (with ``alpha_base`` ≥ 0) and the R diagonal;
    and, for :func:`ends_in_doubt`, the hit's distance from the nearer end of its landmark's
    extent and the parts of ∂ξ*/∂state that are not through the range (ξ* = ξ_robot + t·dξ:
    ∂ξ*/∂state = ``xi_grad[:3]`` on the pose + ``xi_grad[3]``·∂t/∂state).
    Returns how many. See :func:`_beam_rows_of` for the model (the Jacobian of
    SPEC §3 and the frozen shape's terms). Outputs are written, not returned: numba boxes
    every array it returns into a new Python object (~0.6 µs each)."""
    angle, t, landmark, slope, denom, xi = cast_beams(
        x, y, theta, angles, beams, reach, variate, order, shape, lo, hi, c0s, boxes, max_range
    )
    return rows_of_casts(
        theta, ranges, beams, angle, t, landmark, slope, denom, xi, variate, order, shape, lo,
        hi, min_sine, range_var, model_var, shape_follows_pose, shift_with_pose, pivot, xi_var,
        pose_var, shift_slope, turn_var, fit_half, fit_inverse, n_fit, alpha_base, innovation,
        h_pose, c0_index, h_c0, alpha_index, h_alpha, variance, end_room, xi_grad,
    )  # fmt: skip


@njit
def cast_beams(
    x: float,
    y: float,
    theta: float,
    angles: np.ndarray,  # (B,) every beam's angle
    beams: np.ndarray,  # (k,) int64: the beams cast, in this order
    reach: float,  # landmarks whose box lies farther from the robot cannot be hit
    variate: np.ndarray,
    order: np.ndarray,
    shape: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    c0s: np.ndarray,
    boxes: np.ndarray,
    max_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The ``beams`` cast from the pose (x, y, θ) on the landmarks within ``reach``
    (:func:`cast_into`): their angles, then t*, the landmark hit, B'(ξ*), D and ξ* (k,) each,
    in beam order. Each beam's cast is its own (the same beam cast alone gives the same floats),
    so a caller may cast once and use a subset: :func:`beam_rows` and :func:`steady_beams` do
    both, :func:`update_scan` shares one cast between them."""
    candidates = boxes_near(boxes, np.array([x, x, y, y]), reach)
    n_beams = beams.size
    angle = np.empty(n_beams)
    for b in range(n_beams):
        angle[b] = angles[beams[b]]
    t, landmark = np.empty(n_beams), np.empty(n_beams, dtype=np.int64)
    slope, denom, xi = np.empty(n_beams), np.empty(n_beams), np.empty(n_beams)
    cast_into(
        x, y, theta, angle, candidates, variate, order, shape, lo, hi, c0s, boxes, max_range,
        t, landmark, slope, denom, xi,
    )  # fmt: skip
    return angle, t, landmark, slope, denom, xi


@njit
def rows_of_casts(
    theta: float,
    ranges: np.ndarray,  # (B,) every beam's reading
    beams: np.ndarray,  # (k,) int64: the beams cast
    angle: np.ndarray,  # (k,) their angles
    t: np.ndarray,  # (k,) their casts (:func:`cast_beams`)
    landmark: np.ndarray,
    slope: np.ndarray,
    denom: np.ndarray,
    xi: np.ndarray,
    variate: np.ndarray,
    order: np.ndarray,
    shape: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    min_sine: float,
    range_var: float,
    model_var: np.ndarray,
    shape_follows_pose: bool,
    shift_with_pose: bool,
    pivot: np.ndarray,
    xi_var: np.ndarray,
    pose_var: np.ndarray,
    shift_slope: np.ndarray,
    turn_var: np.ndarray,
    fit_half: np.ndarray,
    fit_inverse: np.ndarray,
    n_fit: int,
    alpha_base: int,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    alpha_index: np.ndarray,
    h_alpha: np.ndarray,
    variance: np.ndarray,
    end_room: np.ndarray,
    xi_grad: np.ndarray,
) -> int:
    """:func:`beam_rows`' rows from the beams' casts at the pose of heading ``theta``
    (arguments as :func:`beam_rows`'); returns how many."""
    n_beams = beams.size
    k = 0
    for b in range(n_beams):
        j = landmark[b]
        if j < 0:
            continue
        b_slope, d = slope[b], denom[b]
        if _grazing(b_slope, d, min_sine):
            continue  # near-tangent: too sensitive to linearise
        inv_d = 1.0 / d
        slope_d = b_slope * inv_d
        phi = theta + angle[b]
        cos, sin = math.cos(phi), math.sin(phi)
        v1 = variate[j] == 1
        d_eta, d_xi = (cos, -sin) if v1 else (-sin, cos)  # d(dη)/dφ, d(dξ)/dφ
        h_theta = -t[b] * (d_eta - b_slope * d_xi) * inv_d
        var = range_var + model_var[j] * (inv_d * inv_d)
        h_rot, h_xi = 0.0, slope_d
        if shape_follows_pose:
            m = order[j]
            value, b_slope_at = horner(shape[j], m, xi[b], shape[j, 0])
            value_c, slope_c = horner(shape[j], m, pivot[j], shape[j, 0])
            carried = shift_slope[j]  # the slope c0 moves by per shift along ξ (nan: unknown)
            if shift_with_pose and not math.isnan(carried):
                # the shape was shifted along ξ by the pose's error e_f when it was fitted; c0
                # carries −carried·e_f, the rest of the curve's move at the hit is −shift·e_f,
                # predicted from the current pose's error e_n (shift_prediction)
                shift = (b_slope_at - carried) * inv_d
                gain, left = shift_prediction(xi_var[j], pose_var[0 if v1 else 1])
                h_xi -= gain * shift
                extra = shift * shift * left
            else:
                shift = (b_slope_at - slope_c) * inv_d
                extra = shift * shift * xi_var[j]
            scaled = (xi[b] - pivot[j]) / fit_half[j]
            in_state = alpha_base >= 0
            fit_var = _shape_fit_var(shape[j], m, scaled, fit_inverse, n_fit, range_var, in_state)
            extra += inv_d * inv_d * fit_var
            lever = (xi[b] - pivot[j]) + b_slope_at * (value - value_c)
            turn = (1.0 if v1 else -1.0) * lever * inv_d
            if in_state:  # the rotation is its own state: ∂h/∂α
                h_rot = turn
            else:  # the rotation is taken to be the current heading error
                h_theta += turn
                extra += turn * turn * turn_var[j]
            var += extra
        innovation[k] = ranges[beams[b]] - t[b]
        if v1:
            h_pose[k, 0], h_pose[k, 1] = h_xi, -inv_d
        else:
            h_pose[k, 0], h_pose[k, 1] = -inv_d, h_xi
        h_pose[k, 2] = h_theta
        c0_index[k] = 3 + j
        h_c0[k] = inv_d
        alpha_index[k] = alpha_base + j if h_rot != 0.0 else -1
        h_alpha[k] = h_rot
        variance[k] = var
        end_room[k] = _min(xi[b] - lo[j], hi[j] - xi[b])
        xi_grad[k, 0], xi_grad[k, 1] = (1.0, 0.0) if v1 else (0.0, 1.0)
        xi_grad[k, 2] = t[b] * d_xi
        xi_grad[k, 3] = cos if v1 else sin
        k += 1
    return k


@njit
def frozen_offset_var(
    shape: np.ndarray,  # (M+1,) the landmark's shape (c0 unused)
    m: int,  # its order
    xi: np.ndarray,  # (k,) where along ξ
    pivot: float,
    fit_half: float,
    model_var: float,
    xi_var: float,
    shift_slope: float,  # ∂c0/∂(its shape's shift along ξ), negated; nan: unknown
    turn_var: float,  # variance of the heading change since the fit (no turn state)
    fit_inverse: np.ndarray,
    n_fit: int,
    range_var: float,
    shape_follows_pose: bool,
    shift_with_pose: bool,
    in_state: bool,  # the shape's turn α is a state
    out: np.ndarray,  # (k,) out: the variance of the landmark's η error at each ξ
) -> None:
    """The variance of a landmark's frozen error along η at each ``xi``: what no state holds
    and :func:`beam_rows` adds to a beam's R there (times 1/D²), the same terms: the fit's
    misfit beyond the range noise ``model_var``; with ``shape_follows_pose`` the shape's
    higher-order fit error (:func:`_shape_fit_var`), its shift along ξ when it was fitted
    (variance ``xi_var``) beyond what c0 carries (the slope at the pivot, or with
    ``shift_with_pose`` and a known ``shift_slope`` that slope: the map, unlike a beam, does
    not predict the fit-time shift from the current pose, so all of ``xi_var`` stays), and
    without a turn state the heading change since the fit on the lever about the pivot.
    ``tests/slam/test_kernels.py`` checks it against :func:`beam_rows`' R."""
    for i in range(xi.size):
        var = model_var
        if shape_follows_pose:
            value, slope_at = horner(shape, m, xi[i], shape[0])
            value_c, slope_c = horner(shape, m, pivot, shape[0])
            ref = slope_c
            if shift_with_pose and not math.isnan(shift_slope):
                ref = shift_slope
            var += (slope_at - ref) * (slope_at - ref) * xi_var
            scaled = (xi[i] - pivot) / fit_half
            var += _shape_fit_var(shape, m, scaled, fit_inverse, n_fit, range_var, in_state)
            if not in_state:
                lever = (xi[i] - pivot) + slope_at * (value - value_c)
                var += lever * lever * turn_var
        out[i] = var


@njit
def shift_prediction(fit_var: float, now_var: float) -> tuple[float, float]:
    """The best linear prediction of the pose's error along ξ when a shape was fitted, e_f
    (variance ``fit_var``), from the current one, e_n (variance ``now_var``): (gain β, the
    variance left) with e_f = β·e_n + r, r independent of e_n (``SlamConfig.shape_shift``
    "pose"). The two errors are taken to be nested, the smaller one part of the larger: when
    the pose has grown less certain since the fit, e_n = e_f + d with the drift d independent
    of e_f, so β = var_f/var_n and var(r) = var_f·(1 − β); when it has grown more certain,
    e_f = e_n + d with d independent of e_n, so β = 1 and var(r) = var_f − var_n. Right after
    a fit (var_n = var_f) the shape moves with the pose (β = 1, nothing left); returning to a
    shape fitted near the start (var_f ≈ 0) it stays where it was (β ≈ 0): the curve's
    change of slope then tells the filter where it is along ξ, a loop closure."""
    if now_var > fit_var:
        gain = fit_var / now_var
        return gain, fit_var * (1.0 - gain)
    return 1.0, fit_var - now_var


@njit
def _grazing(slope: float, denom: float, min_sine: float) -> bool:
    """Whether a hit with B'(ξ*) = ``slope`` and D = ``denom`` meets its curve at an incidence
    whose sine is below ``min_sine`` (D / √(1 + B'²) is that sine)."""
    return abs(denom) / math.sqrt(1.0 + slope * slope) < min_sine


@njit
def _cholesky4(p: np.ndarray, out: np.ndarray) -> bool:
    """Lower-triangular ``out`` (4, 4) with out·outᵀ = ``p`` (4, 4); False when p is not
    positive definite (then ``out`` is not usable)."""
    for i in range(4):
        for j in range(4):
            out[i, j] = 0.0
    for j in range(4):
        diag = p[j, j]
        for k in range(j):
            diag -= out[j, k] * out[j, k]
        if not diag > 0.0:
            return False
        out[j, j] = math.sqrt(diag)
        for i in range(j + 1, 4):
            acc = p[i, j]
            for k in range(j):
                acc -= out[i, k] * out[j, k]
            out[i, j] = acc / out[j, j]
    return True


@njit
def steady_beams(
    mean: np.ndarray,  # (3+n,)
    cov: np.ndarray,  # (3+n, 3+n)
    angles: np.ndarray,  # (B,) every beam's angle
    beams: np.ndarray,  # (k,) int64: the beams wanted
    assigned: np.ndarray,  # (k,) int64: the landmark each was associated with (−1: any)
    reach: float,
    variate: np.ndarray,
    order: np.ndarray,
    shape: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    boxes: np.ndarray,
    max_range: float,
    min_sine: float,
    n_lm: int,
    spread: float,  # sigma points at ± spread · the columns of the Cholesky factor
    keep: np.ndarray,  # (k,) bool out
) -> int:
    """Which ``beams`` hit, at every sigma point of their landmark's joint (x, y, θ, c0)
    uncertainty, the landmark they hit at the mean: ``keep[b]`` False when the beam hits a
    landmark at the mean but, cast from one of the 8 sigma points (the mean ± ``spread``
    times each column of the Cholesky factor of that 4 × 4 covariance), misses it (past an
    end, hits another landmark first, or meets it below ``min_sine``); returns how many are
    kept. Beams with no usable hit at the mean are kept (beam_rows skips them anyway). A beam
    whose hit at the mean is on another landmark than the one its point was ``assigned`` to
    (the association's, by the point's distance to each curve) is dropped too: the map does
    not know which wall it met. A received wall's extent ran 24 cm past a corner (its end is
    only as good as the frame transform); a beam that truly hit the corner's other wall was
    cast onto that overhang and moved the wall 26 cm, to 17 cm off its true line. The
    shape's rotation, when it is a state, stays at its mean: its effect on where the beam
    meets the curve is the lever of a turn about the fit's centre, small on a short arc.

    :func:`ends_in_doubt` asks the same of a linearisation of the hit's place along the curve.
    On a short, strongly curved landmark (a round pillar's arc: 0.3 m of a circle of radius
    0.15 m covers ~110°) a few centimetres of pose or c0 move the hit nonlinearly: the beam may
    pass the arc's end, graze it, or meet another arc of the same pillar, while at the mean
    it hits well inside. Such rows came with innovations biased toward the robot (the circle
    continues where the cubic ends), small enough for the χ² gate, and made a lone robot's
    NEES 5.25 on the pillar hall (95 % band 2.02–4.16). Casting the beam itself at sigma
    points tests the measurement function, not its linearisation.
    """
    angle, _, landmark, slope, denom, _ = cast_beams(
        mean[0], mean[1], mean[2], angles, beams, reach, variate, order, shape, lo, hi,
        mean[3 : 3 + n_lm], boxes, max_range,
    )  # fmt: skip
    return steady_of_casts(
        mean, cov, assigned, reach, variate, order, shape, lo, hi, boxes, max_range, min_sine,
        n_lm, spread, angle, landmark, slope, denom, keep,
    )  # fmt: skip


@njit
def steady_of_casts(
    mean: np.ndarray,
    cov: np.ndarray,
    assigned: np.ndarray,
    reach: float,
    variate: np.ndarray,
    order: np.ndarray,
    shape: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    boxes: np.ndarray,
    max_range: float,
    min_sine: float,
    n_lm: int,
    spread: float,
    angle: np.ndarray,  # (k,) the beams' angles
    landmark: np.ndarray,  # (k,) their casts at the mean (:func:`cast_beams`)
    slope: np.ndarray,
    denom: np.ndarray,
    keep: np.ndarray,  # (k,) bool out
) -> int:
    """:func:`steady_beams` from the beams' casts at the mean (arguments as its)."""
    n_beams = angle.size
    x, y, theta = mean[0], mean[1], mean[2]
    c0s = mean[3 : 3 + n_lm].copy()
    one = np.empty(1)
    t1, landmark1 = np.empty(1), np.empty(1, dtype=np.int64)
    slope1, denom1, xi1 = np.empty(1), np.empty(1), np.empty(1)
    joint, factor = np.empty((4, 4)), np.empty((4, 4))
    index = np.empty(4, dtype=np.int64)
    moved = boxes.copy()  # a sigma point's c0 moves its landmark's curve, and its box, along η
    width = shape.shape[1]  # the casts' scratch, made once for the 8 casts of every beam
    taylors, coeffs, best_coeffs = np.empty((n_lm, width)), np.empty(width), np.empty(width)
    roots, shifted = np.empty(width), np.empty(n_lm, np.bool_)
    sigma = np.empty((8, 4))  # per sigma point: x, y, θ and the c0 shift
    near_any = np.empty(n_lm, dtype=np.int64)  # the landmarks in reach of any sigma point
    near_one = np.empty(n_lm, dtype=np.int64)  # those in reach of one
    limit = reach * reach
    kept = 0
    for b in range(n_beams):
        j = landmark[b]
        keep[b] = j < 0 or assigned[b] < 0 or j == assigned[b]
        if keep[b] and j >= 0 and not _grazing(slope[b], denom[b], min_sine):
            index[0], index[1], index[2], index[3] = 0, 1, 2, 3 + j
            for r in range(4):
                for c in range(4):
                    joint[r, c] = cov[min(index[r], index[c]), max(index[r], index[c])]
            if _cholesky4(joint, factor):
                one[0] = angle[b]
                eta = 2 if variate[j] == 1 else 0  # the box's (min, max) columns of η
                x_lo, x_hi, y_lo, y_hi = math.inf, -math.inf, math.inf, -math.inf
                eta_lo, eta_hi = math.inf, -math.inf
                for column in range(8):
                    sign = spread if column < 4 else -spread
                    a = column % 4
                    xs, ys = x + sign * factor[0, a], y + sign * factor[1, a]
                    shift = sign * factor[3, a]
                    sigma[column, 0], sigma[column, 1] = xs, ys
                    sigma[column, 2], sigma[column, 3] = theta + sign * factor[2, a], shift
                    x_lo, x_hi = _min(x_lo, xs), _max(x_hi, xs)
                    y_lo, y_hi = _min(y_lo, ys), _max(y_hi, ys)
                    eta_lo = _min(eta_lo, boxes[j, eta] + shift)
                    eta_hi = _max(eta_hi, boxes[j, eta + 1] + shift)
                # boxes_near of every sigma point looks only among the landmarks in reach of
                # their hull (j's box spanning all its shifts): a superset (rounding is
                # monotone), filtered per point by the same test, so the same ascending set
                moved[j, eta], moved[j, eta + 1] = eta_lo, eta_hi
                n_any = 0
                for i in range(n_lm):
                    if _box_within(moved, i, x_lo, x_hi, y_lo, y_hi, limit):
                        near_any[n_any] = i
                        n_any += 1
                for column in range(8):
                    xs, ys, ths, shift = (
                        sigma[column, 0],
                        sigma[column, 1],
                        sigma[column, 2],
                        sigma[column, 3],
                    )
                    c0s[j] = mean[3 + j] + shift
                    moved[j, eta] = boxes[j, eta] + shift
                    moved[j, eta + 1] = boxes[j, eta + 1] + shift
                    n_one = 0
                    for q in range(n_any):
                        if _box_within(moved, near_any[q], xs, xs, ys, ys, limit):
                            near_one[n_one] = near_any[q]
                            n_one += 1
                    _cast_with(
                        xs, ys, ths, one, near_one[:n_one], variate, order, shape, lo, hi, c0s,
                        moved, max_range, t1, landmark1, slope1, denom1, xi1, taylors, coeffs,
                        best_coeffs, roots, shifted,
                    )  # fmt: skip
                    c0s[j] = mean[3 + j]
                    moved[j, eta], moved[j, eta + 1] = boxes[j, eta], boxes[j, eta + 1]
                    if landmark1[0] != j or _grazing(slope1[0], denom1[0], min_sine):
                        keep[b] = False
                        break
        if keep[b]:
            kept += 1
    return kept


@njit
def ends_in_doubt(
    cov: np.ndarray,  # (3+n, 3+n)
    h_pose: np.ndarray,  # (k, 3)
    c0_index: np.ndarray,  # (k,)
    h_c0: np.ndarray,  # (k,)
    alpha_index: np.ndarray,  # (k,) −1: none
    h_alpha: np.ndarray,  # (k,)
    end_room: np.ndarray,  # (k,) from beam_rows
    xi_grad: np.ndarray,  # (k, 4) from beam_rows
    end_sigma: float,
    keep: np.ndarray,  # (k,) bool out
) -> int:
    """Which rows hit their landmark safely inside its extent: ``keep[i]`` when the hit's
    distance from the nearer end is at least ``end_sigma`` standard deviations of the hit's
    position along the curve, ξ*; returns how many are kept.

    A beam whose predicted intersection may lie past the end (within the state's uncertainty)
    may in truth pass the wall's end and stop on whatever lies beyond: a corner's other face,
    a shelf behind. Its range then measures something the landmark does not model, and at the
    grazing incidence such beams come in with, S is large enough for the χ² gate to let a
    10 cm innovation through (found on a warehouse shelf's corner: one beam moved the pose by
    2 cm and the NEES from 6 to 41). σ²_ξ = J P Jᵀ with J = ∂ξ*/∂state, ξ* = ξ_robot + t·dξ:
    J = ``xi_grad[:3]`` on the pose + dξ·(h_pose, h_c0, h_α)."""
    kept = 0
    idx = np.empty(5, dtype=np.int64)  # the row's state entries: pose, c0, α
    jac = np.empty(5)
    for i in range(end_room.size):
        u = xi_grad[i, 3]
        for a in range(3):
            idx[a] = a
            jac[a] = xi_grad[i, a] + u * h_pose[i, a]
        idx[3], jac[3] = c0_index[i], u * h_c0[i]
        m = 4
        if alpha_index[i] >= 0:
            idx[4], jac[4] = alpha_index[i], u * h_alpha[i]
            m = 5
        var = 0.0
        for a in range(m):
            inner = 0.0
            for b in range(m):  # P's upper triangle (joseph_blocks: the lower copy may wait)
                inner += cov[min(idx[a], idx[b]), max(idx[a], idx[b])] * jac[b]
            var += jac[a] * inner
        keep[i] = end_room[i] >= end_sigma * math.sqrt(_max(var, 0.0))
        if keep[i]:
            kept += 1
    return kept


# -- association error ----------------------------------------------------------------------------
@njit
def nearest_by_error(
    xy: np.ndarray,  # (P, 2) points
    candidates: np.ndarray,  # (K,) landmark indices
    variate: np.ndarray,  # (n,)
    order: np.ndarray,  # (n,)
    shape: np.ndarray,  # (n, M+1)
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    c0s: np.ndarray,  # (n,)
    squared: bool,
    best: np.ndarray,  # (P,) int64 out: the landmark (−1 without candidates)
    best_err: np.ndarray,  # (P,) out: its ε (inf without candidates)
) -> None:
    """Per point the landmark with the smallest approximation error ε over the candidates
    (first on ties) and that ε: |η − p(ξ)| inside the extent, else the distance to the
    nearer end point; squared with ``squared``."""
    n_cand = candidates.size
    for k in range(n_cand):
        if candidates[k] < 0 or candidates[k] >= variate.size:
            raise IndexError("nearest_by_error: a candidate does not index the landmarks")
    ends = np.empty((n_cand, 2))
    for k in range(n_cand):
        j = candidates[k]
        ends[k, 0] = horner(shape[j], order[j], lo[j], c0s[j])[0]
        ends[k, 1] = horner(shape[j], order[j], hi[j], c0s[j])[0]
    n_points = xy.shape[0]
    best[:] = -1
    best_err[:] = math.inf
    for p in range(n_points):
        for k in range(n_cand):
            j = candidates[k]
            xi, eta = (xy[p, 0], xy[p, 1]) if variate[j] == 1 else (xy[p, 1], xy[p, 0])
            if lo[j] <= xi and xi <= hi[j]:
                err = abs(eta - horner(shape[j], order[j], xi, c0s[j])[0])
            else:
                err = _min(hypot(xi - lo[j], eta - ends[k, 0]), hypot(xi - hi[j], eta - ends[k, 1]))
            if squared:
                err = err * err
            if err < best_err[p]:
                best[p], best_err[p] = j, err


# -- landmark boxes -------------------------------------------------------------------------------
@njit
def boxes(
    c0s: np.ndarray, variate: np.ndarray, lo: np.ndarray, hi: np.ndarray, eta_range: np.ndarray
) -> np.ndarray:
    """(n, 4) = (x_min, x_max, y_min, y_max) holding each curve: the extent on ξ and
    c0 + the bounds of B over it (``eta_range`` (n, 2)) on η."""
    n = c0s.size
    out = np.empty((n, 4))
    for i in range(n):
        eta_lo, eta_hi = c0s[i] + eta_range[i, 0], c0s[i] + eta_range[i, 1]
        if variate[i] == 1:
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = lo[i], hi[i], eta_lo, eta_hi
        else:
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = eta_lo, eta_hi, lo[i], hi[i]
    return out


@njit
def boxes_near(boxes: np.ndarray, box: np.ndarray, distance: float) -> np.ndarray:
    """Indices (ascending) of ``boxes`` (n, 4) within ``distance`` of ``box`` (4,)."""
    n = boxes.shape[0]
    out = np.empty(n, dtype=np.int64)
    count = 0
    limit = distance * distance
    for i in range(n):
        if _box_within(boxes, i, box[0], box[1], box[2], box[3], limit):
            out[count] = i
            count += 1
    return out[:count]


@njit
def _box_within(
    boxes: np.ndarray, i: int, x_lo: float, x_hi: float, y_lo: float, y_hi: float, limit: float
) -> bool:
    """Whether ``boxes[i]`` lies within √``limit`` of the box (x_lo, x_hi, y_lo, y_hi)."""
    gap_x = _maximum(_maximum(boxes[i, 0] - x_hi, x_lo - boxes[i, 1]), 0.0)
    gap_y = _maximum(_maximum(boxes[i, 2] - y_hi, y_lo - boxes[i, 3]), 0.0)
    return gap_x * gap_x + gap_y * gap_y <= limit


# -- EKF ------------------------------------------------------------------------------------------
@njit
def wrap(angle: float) -> float:
    """π − (π − angle) mod 2π with Python's float modulo (``geometry.wrap_scalar``)."""
    return math.pi - (math.pi - angle) % (2.0 * math.pi)


@njit
def predict(
    mean: np.ndarray,  # (3+n,) written in place
    cov: np.ndarray,  # (3+n, 3+n) written in place
    odometry: np.ndarray,  # (3,) (dx, dy, dθ) in the robot frame
    w: np.ndarray,  # (3, 3) its noise covariance
    first_x: float,  # position of the pose's first estimate (FEJ), nan: the standard F
    first_y: float,
) -> None:
    """EKF prediction through the unicycle composition (see ``ekf.predict_inplace``): the
    pose–landmark rows gain a and b times the heading row, the pose block is F P Fᵀ + L W Lᵀ
    written out from its upper triangle."""
    x, y, theta = mean[0], mean[1], mean[2]
    dx, dy, dtheta = odometry[0], odometry[1], odometry[2]
    c, s = math.cos(theta), math.sin(theta)
    mean[0] = x + c * dx - s * dy
    mean[1] = y + s * dx + c * dy
    mean[2] = wrap(theta + dtheta)
    if math.isnan(first_x):
        a, b = -s * dx - c * dy, c * dx - s * dy  # F[0, 2], F[1, 2]
    else:
        a, b = -(mean[1] - first_y), mean[0] - first_x
    for i in range(3, mean.size):
        heading = cov[2, i]
        cov[0, i] = cov[0, i] + a * heading
        cov[1, i] = cov[1, i] + b * heading
        cov[i, 0] = cov[0, i]
        cov[i, 1] = cov[1, i]
    p00, p01, p02 = cov[0, 0], cov[0, 1], cov[0, 2]
    p11, p12, p22 = cov[1, 1], cov[1, 2], cov[2, 2]
    # F P Fᵀ, F = I + a·e₀e₂ᵀ + b·e₁e₂ᵀ
    f02, f12 = p02 + a * p22, p12 + b * p22
    f00 = p00 + a * p02 + a * f02
    f01 = p01 + a * p12 + b * f02
    f11 = p11 + b * p12 + b * f12
    # L W Lᵀ, L = rotation by θ on (x, y), 1 on θ
    r00, r01 = c * w[0, 0] - s * w[1, 0], c * w[0, 1] - s * w[1, 1]  # rows of L W
    r10, r11 = s * w[0, 0] + c * w[1, 0], s * w[0, 1] + c * w[1, 1]
    q00, q01 = r00 * c - r01 * s, r00 * s + r01 * c
    q11 = r10 * s + r11 * c
    q02, q12 = c * w[0, 2] - s * w[1, 2], s * w[0, 2] + c * w[1, 2]
    cov[0, 0], cov[0, 1], cov[0, 2] = f00 + q00, f01 + q01, f02 + q02
    cov[1, 0], cov[1, 1], cov[1, 2] = f01 + q01, f11 + q11, f12 + q12
    cov[2, 0], cov[2, 1], cov[2, 2] = f02 + q02, f12 + q12, p22 + w[2, 2]


@njit
def normalised_innovations(
    cov: np.ndarray,  # (3+n, 3+n)
    innovation: np.ndarray,  # (k,)
    h_pose: np.ndarray,  # (k, 3)
    c0_index: np.ndarray,  # (k,)
    h_c0: np.ndarray,  # (k,)
    alpha_index: np.ndarray,  # (k,) −1: the row has no rotation term
    h_alpha: np.ndarray,  # (k,)
    r: np.ndarray,  # (k,)
    out: np.ndarray,  # (k,) out
) -> None:
    """ν_i² / S_ii for rows on the pose, one c0 and at most one shape rotation α:
    S_ii = h P_pp hᵀ + 2 h_c h P_pc + h_c² P_cc (+ 2 h_α h P_pα + 2 h_c h_α P_cα + h_α² P_αα)
    + r_i."""
    k = r.size
    for i in range(k):
        c, hc = c0_index[i], h_c0[i]
        quad = 0.0
        for a in range(3):
            row = h_pose[i, 0] * cov[0, a] + h_pose[i, 1] * cov[1, a] + h_pose[i, 2] * cov[2, a]
            quad += row * h_pose[i, a]
        cross = h_pose[i, 0] * cov[0, c] + h_pose[i, 1] * cov[1, c] + h_pose[i, 2] * cov[2, c]
        s = quad + (2.0 * hc * cross + hc * hc * cov[c, c] + r[i])
        g = alpha_index[i]
        if g >= 0:
            ha = h_alpha[i]
            cross_a = h_pose[i, 0] * cov[0, g] + h_pose[i, 1] * cov[1, g] + h_pose[i, 2] * cov[2, g]
            s += ha * (2.0 * cross_a + 2.0 * hc * cov[c, g] + ha * cov[g, g])
        out[i] = innovation[i] * innovation[i] / s


@njit
def joseph_blocks(cov: np.ndarray, kt: np.ndarray, wt: np.ndarray, consider_from: int) -> None:
    """P⁺ = P − (K Wᵀ + W Kᵀ) in place, ``kt`` = Kᵀ and ``wt`` = Wᵀ (k, n), whose columns
    from ``consider_from`` on are K's considered rows: zero (:func:`update_sparse`).

    Written: the upper triangle of the estimated rows i < c (the pose block whole), and the
    cross block's upper copy (i < c ≤ j), which takes K_i·W_j alone. Not written: the
    considered block (i, j ≥ c), which does not change at all (each entry would subtract an
    exact zero: a running sum that starts at +0 and adds ±0 stays +0), and the lower copies
    of the rest (j < min(i, c) but in the pose block), left as they were: their mirror is a
    strided copy of half of what changed, and :func:`mirror_lower` does it when a reader
    needs all of P.
    What is written is the same bits as the full update's (tested against it).

    Each entry's sum runs over K's rows in order from +0 and is then subtracted from P
    (``tests/slam/reference_floats.joseph_full``); the rows of K are taken four (then two)
    per pass over P's row, summed in that order inside one loop, the last pass subtracting:
    fewer passes over the row than one per row of K, the same operations in the same order.
    The cross block goes separately (:func:`_cross_block`), two rows of P at a time.

    Up to :data:`PASS_ROWS` rows of K (the paper's scan: five beams) take one pass over P,
    two rows of P at a time, subtracting as it sums (:func:`_estimated_one_pass`,
    :func:`_cross_one_pass`): K and W padded to :data:`PASS_ROWS` rows with zero rows, whose
    terms are +0 (0·0, or 0·0 + 0·0); a sum that starts at +0 is never −0 (x + y is −0 only
    when both are), so adding +0 to it changes no bit.
    """
    count, n = kt.shape
    c = min(max(consider_from, 0), n)
    if 0 < count <= PASS_ROWS:
        if count < PASS_ROWS:
            padded_k, padded_w = np.zeros((PASS_ROWS, n)), np.zeros((PASS_ROWS, n))
            padded_k[:count] = kt
            padded_w[:count] = wt
            kt, wt = padded_k, padded_w
        _estimated_one_pass(cov, kt, wt, c)
        _cross_one_pass(cov, kt, wt, c)
    else:
        _estimated_passes(cov, kt, wt, c)
        _cross_block(cov, kt, wt, c)
    for i in range(min(3, c)):  # the pose block whole (its readers take it as a matrix)
        for j in range(i):
            cov[i, j] = cov[j, i]


@njit
def _estimated_passes(cov: np.ndarray, kt: np.ndarray, wt: np.ndarray, c: int) -> None:
    """:func:`joseph_blocks`' estimated block (upper triangle, i ≤ j < c) with any number of
    rows of K: four rows per pass over P's row into a scratch row, then two (or the last one
    or two) subtracting."""
    count = kt.shape[0]
    acc = np.zeros(c)  # row i of K Wᵀ + W Kᵀ from the diagonal to column c, over K's rows
    for i in range(c):
        inner = c - i
        estimated = acc[:inner]
        row_estimated = cov[i, i:c]
        estimated[:] = 0.0
        q = 0
        while q + 4 < count:  # four rows of K into the sums
            k0, k1, k2, k3 = kt[q, i], kt[q + 1, i], kt[q + 2, i], kt[q + 3, i]
            w0, w1, w2, w3 = wt[q, i], wt[q + 1, i], wt[q + 2, i], wt[q + 3, i]
            kr0, kr1, kr2, kr3 = kt[q, i:c], kt[q + 1, i:c], kt[q + 2, i:c], kt[q + 3, i:c]
            wr0, wr1, wr2, wr3 = wt[q, i:c], wt[q + 1, i:c], wt[q + 2, i:c], wt[q + 3, i:c]
            for j in range(inner):
                s = estimated[j] + (k0 * wr0[j] + w0 * kr0[j])
                s = s + (k1 * wr1[j] + w1 * kr1[j])
                s = s + (k2 * wr2[j] + w2 * kr2[j])
                estimated[j] = s + (k3 * wr3[j] + w3 * kr3[j])
            q += 4
        while q < count:  # two rows into the sums, or the last one or two, subtracting
            k0, w0, kr0, wr0 = kt[q, i], wt[q, i], kt[q, i:c], wt[q, i:c]
            if q + 1 == count:
                for j in range(inner):
                    row_estimated[j] -= estimated[j] + (k0 * wr0[j] + w0 * kr0[j])
                q += 1
                continue
            k1, w1, kr1, wr1 = kt[q + 1, i], wt[q + 1, i], kt[q + 1, i:c], wt[q + 1, i:c]
            if q + 2 == count:
                for j in range(inner):
                    s = estimated[j] + (k0 * wr0[j] + w0 * kr0[j])
                    row_estimated[j] -= s + (k1 * wr1[j] + w1 * kr1[j])
            else:
                for j in range(inner):
                    s = estimated[j] + (k0 * wr0[j] + w0 * kr0[j])
                    estimated[j] = s + (k1 * wr1[j] + w1 * kr1[j])
            q += 2


@njit
def _cross_block(cov: np.ndarray, kt: np.ndarray, wt: np.ndarray, c: int) -> None:
    """:func:`joseph_blocks`' cross block, rows i < c, columns j ≥ c: P_ij −= Σ_q K_qi W_qj, each
    sum over q in order from +0, then subtracted. Two rows of P at a time and four rows of K per
    pass over them: each W row slice is loaded once for both rows (the same operations in the
    same order as one row at a time)."""
    count, n = kt.shape
    m = n - c
    if count == 0 or m == 0:
        return
    a0, a1 = np.zeros(m), np.zeros(m)
    for i in range(0, c - 1, 2):
        a0[:] = 0.0
        a1[:] = 0.0
        q = 0
        while q + 4 <= count:
            p0, p1, p2, p3 = kt[q, i], kt[q + 1, i], kt[q + 2, i], kt[q + 3, i]
            r0, r1, r2, r3 = kt[q, i + 1], kt[q + 1, i + 1], kt[q + 2, i + 1], kt[q + 3, i + 1]
            wc0, wc1, wc2, wc3 = wt[q, c:], wt[q + 1, c:], wt[q + 2, c:], wt[q + 3, c:]
            for j in range(m):
                x0, x1, x2, x3 = wc0[j], wc1[j], wc2[j], wc3[j]
                a0[j] = (((a0[j] + p0 * x0) + p1 * x1) + p2 * x2) + p3 * x3
                a1[j] = (((a1[j] + r0 * x0) + r1 * x1) + r2 * x2) + r3 * x3
            q += 4
        while q < count:
            p0, r0, wc0 = kt[q, i], kt[q, i + 1], wt[q, c:]
            for j in range(m):
                a0[j] = a0[j] + p0 * wc0[j]
                a1[j] = a1[j] + r0 * wc0[j]
            q += 1
        row0, row1 = cov[i, c:], cov[i + 1, c:]
        for j in range(m):
            row0[j] -= a0[j]
            row1[j] -= a1[j]
    if c % 2 == 1:  # the last row alone
        i = c - 1
        a0[:] = 0.0
        for q in range(count):
            p0, wc0 = kt[q, i], wt[q, c:]
            for j in range(m):
                a0[j] = a0[j] + p0 * wc0[j]
        row0 = cov[i, c:]
        for j in range(m):
            row0[j] -= a0[j]


@njit
def _estimated_one_pass(cov: np.ndarray, kt: np.ndarray, wt: np.ndarray, c: int) -> None:
    """:func:`joseph_blocks`' estimated block (upper triangle, i ≤ j < c) with
    :data:`PASS_ROWS` rows of K: P_ij −= Σ_q (K_qi W_qj + W_qi K_qj), the sum over q in order
    from +0, in one pass that subtracts as it sums. Rows i and i + 1 at a time from column
    i + 1 (each slice of K's and W's rows is loaded once for both), entry (i, i) alone."""
    for i in range(0, c, 2):
        k0, k1, k2, k3, k4 = kt[0, i], kt[1, i], kt[2, i], kt[3, i], kt[4, i]
        w0, w1, w2, w3, w4 = wt[0, i], wt[1, i], wt[2, i], wt[3, i], wt[4, i]
        s = 0.0 + (k0 * w0 + w0 * k0)
        s = s + (k1 * w1 + w1 * k1)
        s = s + (k2 * w2 + w2 * k2)
        s = s + (k3 * w3 + w3 * k3)
        cov[i, i] -= s + (k4 * w4 + w4 * k4)
        lo = i + 1
        if lo == c:
            break
        l0, l1, l2, l3, l4 = kt[0, lo], kt[1, lo], kt[2, lo], kt[3, lo], kt[4, lo]
        v0, v1, v2, v3, v4 = wt[0, lo], wt[1, lo], wt[2, lo], wt[3, lo], wt[4, lo]
        kr0, kr1, kr2, kr3, kr4 = kt[0, lo:c], kt[1, lo:c], kt[2, lo:c], kt[3, lo:c], kt[4, lo:c]
        wr0, wr1, wr2, wr3, wr4 = wt[0, lo:c], wt[1, lo:c], wt[2, lo:c], wt[3, lo:c], wt[4, lo:c]
        row0, row1 = cov[i, lo:c], cov[lo, lo:c]
        for j in range(c - lo):
            x0, x1, x2, x3, x4 = wr0[j], wr1[j], wr2[j], wr3[j], wr4[j]
            y0, y1, y2, y3, y4 = kr0[j], kr1[j], kr2[j], kr3[j], kr4[j]
            s = 0.0 + (k0 * x0 + w0 * y0)
            s = s + (k1 * x1 + w1 * y1)
            s = s + (k2 * x2 + w2 * y2)
            s = s + (k3 * x3 + w3 * y3)
            row0[j] -= s + (k4 * x4 + w4 * y4)
            t = 0.0 + (l0 * x0 + v0 * y0)
            t = t + (l1 * x1 + v1 * y1)
            t = t + (l2 * x2 + v2 * y2)
            t = t + (l3 * x3 + v3 * y3)
            row1[j] -= t + (l4 * x4 + v4 * y4)


@njit
def _cross_one_pass(cov: np.ndarray, kt: np.ndarray, wt: np.ndarray, c: int) -> None:
    """:func:`joseph_blocks`' cross block (i < c ≤ j) with :data:`PASS_ROWS` rows of K:
    P_ij −= Σ_q K_qi W_qj, the sum over q in order from +0, in one pass that subtracts as it
    sums. Rows i and i + 1 at a time (each slice of W's rows is loaded once for both); an odd
    last row with itself as its partner, written once."""
    n = kt.shape[1]
    x0s, x1s, x2s, x3s, x4s = wt[0, c:], wt[1, c:], wt[2, c:], wt[3, c:], wt[4, c:]
    for i in range(0, c, 2):
        lo = min(i + 1, c - 1)
        p0, p1, p2, p3, p4 = kt[0, i], kt[1, i], kt[2, i], kt[3, i], kt[4, i]
        r0, r1, r2, r3, r4 = kt[0, lo], kt[1, lo], kt[2, lo], kt[3, lo], kt[4, lo]
        row0, row1 = cov[i, c:], cov[lo, c:]
        if lo == i:
            for j in range(n - c):
                x0, x1, x2, x3, x4 = x0s[j], x1s[j], x2s[j], x3s[j], x4s[j]
                row0[j] -= ((((0.0 + p0 * x0) + p1 * x1) + p2 * x2) + p3 * x3) + p4 * x4
            break
        for j in range(n - c):
            x0, x1, x2, x3, x4 = x0s[j], x1s[j], x2s[j], x3s[j], x4s[j]
            row0[j] -= ((((0.0 + p0 * x0) + p1 * x1) + p2 * x2) + p3 * x3) + p4 * x4
            row1[j] -= ((((0.0 + r0 * x0) + r1 * x1) + r2 * x2) + r3 * x3) + r4 * x4


@njit
def mirror_lower(cov: np.ndarray, consider_from: int) -> None:
    """P's lower triangle below the estimated rows' and the cross block's upper copy (rows
    i, columns j < min(i, ``consider_from``)): what :func:`joseph_blocks` leaves for the
    reader that needs all of P."""
    n = cov.shape[0]
    for i in range(n):
        for j in range(min(i, consider_from)):
            cov[i, j] = cov[j, i]


@njit
def update_sparse(
    mean: np.ndarray,  # (3+n,) written in place
    cov: np.ndarray,  # (3+n, 3+n) its upper triangle and pose block, written in place
    innovation: np.ndarray,  # (k,)
    h_pose: np.ndarray,  # (k, 3)
    c0_index: np.ndarray,  # (k,) state index of each row's c0
    h_c0: np.ndarray,  # (k,)
    alpha_index: np.ndarray,  # (k,) state index of each row's shape rotation, −1: none
    h_alpha: np.ndarray,  # (k,)
    r: np.ndarray,  # (k,) R diagonal
    gate: float,  # χ²(1) quantile: rows with ν²/S_ii above it are rejected
    consider_from: int,  # state entries from this index on get no gain (Schmidt); n: none
    accepted: np.ndarray,  # (k,) bool out: passed the gate
    nis: np.ndarray,  # (k,) out: ν²/S_ii
) -> int:
    """Gated EKF update with rows on the pose and one c0 each, Joseph form, in place; returns
    how many rows passed the gate. See ``ekf.update_sparse_inplace`` for the arrangement:

    * P Hᵀ from P's rows 0–2 and c0 (P is symmetric: rows are contiguous, columns are not);
    * K = P Hᵀ S⁻¹ by a solve with S = H P Hᵀ + R (symmetrised before R is added);
    * P⁺ = P − (K Wᵀ + W Kᵀ) with W = P Hᵀ − ½ K S, which is the Joseph form for any gain.
      Each entry is P_ij − Σ_l (K_il W_jl + W_il K_jl), symmetric in (i, j): the upper
      triangle is computed and mirrored, so P⁺ is exactly symmetric, in one pass over P.
    * The entries from ``consider_from`` on are *considered* (Schmidt–Kalman): their rows of K
      are zero, so their estimates and their own covariance stay, while their
      cross-covariances with the rest follow the update; the Joseph form keeps P⁺ right for
      that gain. The covariance update goes in blocks (the considered block is left alone,
      the cross block takes one product instead of two): with the n turns of n landmarks
      considered it does about half the work of the full (3 + 2n)² update, and the result
      is the same bits as the full one (tested).
    * Only P's upper triangle (and its pose block whole) is read and written
      (:func:`joseph_blocks`): the lower copy's mirror, a strided copy of half of what
      changed, waits for a reader that needs all of P (:func:`mirror_lower`;
      ``ekf.update_sparse_inplace`` and ``PolySlam.cov`` call it).

    Not bit-identical to the numpy version it replaced (BLAS's fused products and the
    Z₊Z₊ᵀ − Z₋Z₋ᵀ split of its syrk): equal to rounding, checked against it in the tests.
    """
    n, k = mean.size, r.size
    pht = np.empty((k, n))  # row i: column i of P Hᵀ
    for i in range(k):
        c, h0, h1, h2, hc = c0_index[i], h_pose[i, 0], h_pose[i, 1], h_pose[i, 2], h_c0[i]
        for a in range(c):  # P's row c from its upper triangle (the lower copy may wait)
            pht[i, a] = cov[0, a] * h0 + cov[1, a] * h1 + cov[2, a] * h2 + cov[a, c] * hc
        for a in range(c, n):
            pht[i, a] = cov[0, a] * h0 + cov[1, a] * h1 + cov[2, a] * h2 + cov[c, a] * hc
        g = alpha_index[i]
        if g >= 0:  # P's row g from its upper triangle (the lower copy may wait)
            ha = h_alpha[i]
            for a in range(min(g, consider_from)):
                pht[i, a] += cov[a, g] * ha
            for a in range(min(g, consider_from), n):
                pht[i, a] += cov[g, a] * ha
    accepted[:] = False
    count = 0
    for i in range(k):
        c = c0_index[i]
        s_ii = h_pose[i, 0] * pht[i, 0] + h_pose[i, 1] * pht[i, 1] + h_pose[i, 2] * pht[i, 2]
        s_ii += h_c0[i] * pht[i, c]
        if alpha_index[i] >= 0:
            s_ii += h_alpha[i] * pht[i, alpha_index[i]]
        nis[i] = innovation[i] * innovation[i] / (s_ii + r[i])
        if nis[i] <= gate:
            accepted[i] = True
            count += 1
    if count == 0:
        return 0
    rows = np.flatnonzero(accepted)
    pht = pht[rows]  # (k_a, n)
    s_mat = np.empty((count, count))  # H P Hᵀ on the accepted rows
    for i in range(count):
        hi_, c, g = rows[i], c0_index[rows[i]], alpha_index[rows[i]]
        for j in range(count):
            s_mat[i, j] = (
                h_pose[hi_, 0] * pht[j, 0]
                + h_pose[hi_, 1] * pht[j, 1]
                + h_pose[hi_, 2] * pht[j, 2]
                + h_c0[hi_] * pht[j, c]
            )
            if g >= 0:
                s_mat[i, j] += h_alpha[hi_] * pht[j, g]
    s_sym = np.empty((count, count))
    for i in range(count):
        for j in range(count):
            s_sym[i, j] = 0.5 * (s_mat[i, j] + s_mat[j, i])
        s_sym[i, i] += r[rows[i]]
    kt = np.ascontiguousarray(np.linalg.solve(s_sym, pht))  # (k_a, n) = (P Hᵀ S⁻¹)ᵀ
    for q in range(count):  # considered entries: no gain
        for a in range(consider_from, n):
            kt[q, a] = 0.0
    for a in range(n):
        step = 0.0
        for q in range(count):
            step += kt[q, a] * innovation[rows[q]]
        mean[a] += step
    mean[2] = wrap(mean[2])
    wt = np.empty((count, n))  # (P Hᵀ − ½ K S)ᵀ
    for q in range(count):
        for a in range(n):
            ks = 0.0
            for m in range(count):
                ks += s_sym[q, m] * kt[m, a]
            wt[q, a] = pht[q, a] - 0.5 * ks
    joseph_blocks(cov, kt, wt, consider_from)
    return count


# -- the state's size changes --------------------------------------------------------------------
@njit
def grown(
    mean: np.ndarray,  # (N,)
    cov: np.ndarray,  # (N, N)
    value: float,
    cross: np.ndarray,  # (N,) the new entry's covariance with the state
    var: float,
    order: np.ndarray,  # (N+1,) int64: the grown state's entries in their new order
) -> tuple[np.ndarray, np.ndarray]:
    """The state with one entry appended (mean ``value``, covariance row ``cross``, variance
    ``var``: ``ekf.augment``'s [P, P Gxᵀ; Gx P, …]) and taken in ``order`` (index N is the new
    entry), in one pass: copies only, each float moved as it is."""
    n = mean.size
    size = n + 1
    out_mean, out_cov = np.empty(size), np.empty((size, size))
    for i in range(size):
        a = order[i]
        out_mean[i] = value if a == n else mean[a]
        for j in range(size):
            b = order[j]
            if a == n:
                out_cov[i, j] = var if b == n else cross[b]
            elif b == n:
                out_cov[i, j] = cross[a]
            else:
                out_cov[i, j] = cov[a, b]
    return out_mean, out_cov


@njit
def augmented(
    mean: np.ndarray,  # (N,)
    cov: np.ndarray,  # (N, N)
    value: float,
    gx: np.ndarray,  # (N,) ∂g/∂X
    gy: np.ndarray,  # (K,) ∂g/∂y
    v: np.ndarray,  # (K, K) the covariance of y
    order: np.ndarray,  # (N+1,) int64, as grown's
) -> tuple[np.ndarray, np.ndarray]:
    """``ekf.augment`` in one call: the new entry's covariance row P Gxᵀ and its variance
    Gx P Gxᵀ + Gy V Gyᵀ by the same BLAS products numpy's matmul calls (gemv, dot: the same
    floats, checked against numpy's in ``tests/slam/test_ekf.py``), then :func:`grown`."""
    cross = cov @ gx
    var = gx @ cross + gy @ v @ gy
    return grown(mean, cov, value, cross, var, order)


@njit
def augmented_pair(
    mean: np.ndarray,
    cov: np.ndarray,
    value: float,
    gx: np.ndarray,
    gy: np.ndarray,
    v: np.ndarray,
    turn_gx: np.ndarray,  # (N+1,) the second entry's ∂/∂X over the state grown by the first
    turn_var: float,  # its variance beyond what the state holds
    order: np.ndarray,  # (N+2,) int64: the twice-grown state's order
) -> tuple[np.ndarray, np.ndarray]:
    """Two :func:`augmented` in one call, as ``StateLayout.add`` makes a landmark's c0 and
    then its turn α: the first appended in place, the second (G_y = [1], V = [[turn_var]])
    then taken in ``order``."""
    first_mean, first_cov = augmented(mean, cov, value, gx, gy, v, np.arange(mean.size + 1))
    one = np.ones(1)
    return augmented(first_mean, first_cov, 0.0, turn_gx, one, np.full((1, 1), turn_var), order)


@njit
def shrunk(mean: np.ndarray, cov: np.ndarray, drop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state without the entries ``drop`` (int64, any order, in range): ``ekf.remove``'s
    marginalisation, the rest in their order, each float copied as it is, in one pass."""
    n = mean.size
    keep = np.ones(n, dtype=np.bool_)
    for a in drop:
        keep[a] = False
    rows = np.flatnonzero(keep)
    size = rows.size
    out_mean, out_cov = np.empty(size), np.empty((size, size))
    for i in range(size):
        out_mean[i] = mean[rows[i]]
        for j in range(size):
            out_cov[i, j] = cov[rows[i], rows[j]]
    return out_mean, out_cov


# -- the SLAM step's two scans --------------------------------------------------------------------
@njit
def _scan_model(
    mean: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    step: int,
) -> tuple[np.ndarray, np.ndarray, int]:
    """The landmarks' boxes (n, 4) at the state's c0s, each landmark's heading drift since
    its shape was fitted (n,) (``PolySlam._turn_var``: steps since times the odometry's
    heading variance per step) and α_1's state index (−1: no turns in the state)."""
    c0s = mean[3 : 3 + n]
    near = boxes(
        c0s, index[VARIATE, :n], real[LO, :n], real[HI, :n], real[ETA_LO : ETA_HI + 1, :n].T
    )
    turn_var = np.empty(n)
    for j in range(n):
        turn_var[j] = (float(step) - float(index[CHANGED_AT, j])) * params[P_TURN_VAR_PER_STEP]
    alpha_base = 3 + n if switches[S_ROTATION_STATES] else -1
    return near, turn_var, alpha_base


@njit
def _beam_rows_of(
    mean: np.ndarray,
    cov: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    beams: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    alpha_index: np.ndarray,
    h_alpha: np.ndarray,
    variance: np.ndarray,
    end_room: np.ndarray,
    xi_grad: np.ndarray,
) -> int:
    """:func:`beam_rows` at the state ``mean`` with the table's landmarks and the filter's
    model: the landmarks within range at the current mean, the model constants.

    Each beam's hit (:func:`~polyslam_env.slam.kernels.beam_rows`, a whole scan per call,
    on the landmarks within range) gives one row of H: the pose part and 1/D on the c0
    hit (SPEC §3, :mod:`~polyslam_env.slam.measurement`). Near-tangent hits are skipped.
    R adds to the range noise the landmark's fit variance beyond the noise, and with
    ``shape_follows_pose`` the frozen shape's own errors:

    A shape was fitted to points placed with the pose estimate of its time, so that
    pose's error moves the whole shape rigidly. ``c0``'s Jacobian G_x carries the part of
    that motion a constant offset can: the shift of the curve at its centroid ξ_c. What
    it cannot carry (the shape is outside the state, as in the paper) is

    * the rotation by δα about the centroid (ξ_c, η_c), which changes η at ξ* by
      ±[(ξ* − ξ_c) + B'(ξ*)(η* − η_c)]·δα (+ for x¹-variate, − for x²-variate), and
    * the translation along ξ by δξ, which changes η at ξ* by −(B'(ξ*) − B'(ξ_c))·δξ.

    The heading error changes little after a landmark is made (odometry turns it by
    little and a wall hardly corrects absolute heading), so the shape's rotation is taken
    equal to the robot's current heading error: ±lever/D is added to ∂h/∂θ
    (∂h/∂η = ∂h/∂c0 = 1/D). Without it a frozen slope makes the absolute heading look
    observable: P_θθ shrinks while the error stays. The position error, in contrast, is
    corrected by the update, so the translation term is treated as noise: its variance
    ((B'(ξ*) − B'(ξ_c))/D)²·σ²_ξ, with σ²_ξ the pose variance along ξ when the landmark was
    made, goes into R together with the shape's own fit error: the shape was fitted to
    noisy points, so its estimation error is a bias every later beam on it shares. For N
    points equally spaced over the fitted extent, the fit's η at t = (ξ* − ξ_c)/half-extent
    has variance σ² a(t)ᵀM⁻¹a(t) (a = [1, t, …, t^m]); the constant part σ²/N is c0's and
    already in the state, the rest goes into R. It is small inside the fitted extent
    (~σ²·m/N) and grows fast where the curve is extrapolated. N = ε_Z + 1, the size of the
    cluster a landmark is born from. And the rotation the shape is taken to share is the
    heading error *when it was fitted*, which the current one has drifted from since: that
    drift's variance (``turn_var``: steps since the fit times the odometry's heading variance
    per step) times (lever/D)² goes into R as well.

    With rotation states (``shape_rotation="considered"``) the rotation is instead the
    landmark's own α: ±lever/D goes to ∂h/∂α, and neither the heading drift nor the
    slope's part of the fit variance (σ²·t²·M⁻¹[1, 1], which α's variance holds) enters R.

    With ``shape_shift="pose"`` the translation is not noise independent of the pose: the
    fit-time error along ξ is predicted from the current one (:func:`shift_prediction`, from
    σ²_ξ and the current pose variance along ξ), the predicted part of the curve's move at the
    hit, −β·(B'(ξ*) − s̄)/D (s̄ the slope c0 moves by, ``SHIFT_SLOPE``), goes to ∂h/∂ξ and only
    what the prediction leaves goes into R (docs/notes/floors.md, Round 5).
    """
    near, turn_var, alpha_base = _scan_model(mean, real, index, n, params, switches, step)
    pose_var = np.array([cov[0, 0], cov[1, 1]])
    return beam_rows(
        mean[0], mean[1], mean[2], angles, ranges, beams, params[P_REACH], index[VARIATE, :n],
        index[ORDER, :n], shape[:n], real[LO, :n], real[HI, :n], mean[3 : 3 + n], near,
        params[P_MAX_RANGE], params[P_MIN_SINE], params[P_RANGE_VAR], real[MODEL_VAR, :n],
        switches[S_SHAPE_FOLLOWS_POSE] != 0, switches[S_SHIFT_WITH_POSE] != 0, real[PIVOT, :n],
        real[XI_VAR, :n], pose_var, real[SHIFT_SLOPE, :n], turn_var, real[FIT_HALF, :n],
        fit_inverse, switches[S_N_FIT], alpha_base, innovation, h_pose, c0_index, h_c0,
        alpha_index, h_alpha, variance, end_room, xi_grad,
    )  # fmt: skip


@njit
def screen_scan(
    mean: np.ndarray,  # (3+n(+n),) the predicted state
    cov: np.ndarray,
    angles: np.ndarray,  # (S,) the screened beams' angles
    ranges: np.ndarray,  # (S,) their readings (inf or nan: no return)
    outlier: np.ndarray,  # (S,) bool out: NIS above the gate, per row
    real: np.ndarray,  # the landmark table (n landmarks)
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,  # the filter's model (``columns``: P_*, S_*)
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
) -> int:
    """Every beam's row (:func:`beam_rows`, a missing return counting as r_max) and whether
    its NIS (:func:`normalised_innovations`) exceeds the gate, into the first rows of
    ``outlier``; returns how many rows (the divergence screen of ``PolySlam``)."""
    n_beams = angles.size
    seen = np.empty(n_beams)
    for b in range(n_beams):
        seen[b] = ranges[b] if math.isfinite(ranges[b]) else params[P_MAX_RANGE]
    innovation, h_pose = np.empty(n_beams), np.empty((n_beams, 3))
    c0_index, h_c0, variance = np.empty(n_beams, np.int64), np.empty(n_beams), np.empty(n_beams)
    alpha_index, h_alpha = np.empty(n_beams, np.int64), np.empty(n_beams)
    end_room, xi_grad = np.empty(n_beams), np.empty((n_beams, 4))
    k = _beam_rows_of(
        mean, cov, angles, seen, np.arange(n_beams), real, index, shape, n, params, switches,
        fit_inverse, step, innovation, h_pose, c0_index, h_c0, alpha_index, h_alpha, variance,
        end_room, xi_grad,
    )  # fmt: skip
    nis = np.empty(k)
    normalised_innovations(
        cov, innovation[:k], h_pose[:k], c0_index[:k], h_c0[:k], alpha_index[:k], h_alpha[:k],
        variance[:k], nis,
    )  # fmt: skip
    for i in range(k):
        outlier[i] = nis[i] > params[P_GATE]
    return k


@njit
def share_landmark_error(
    c0_index: np.ndarray,  # (k,) int64: each row's c0 state index
    variance: np.ndarray,  # (k,) each row's own R diagonal, written in place
    range_var: float,  # σ² of the range noise, the part no two beams share
    reuse: np.ndarray,  # (n,) per landmark row: its shared part's weight (reuse_factors)
) -> None:
    """Make the R diagonal of one update's rows bound their joint errors.

    A row's variance is σ_r² + s_i²; the s_i² part (the landmark's fit residual and frozen
    shape) is one error seen by every beam on that landmark, so rows on one landmark are
    correlated: σ_r² I + s sᵀ. For n rows with shared errors s_i·z, Cauchy–Schwarz gives
    (Σ s_i x_i)² ≤ n Σ s_i² x_i², so the diagonal σ_r² + n s_i² bounds that covariance from
    above, and the diagonal update stays conservative however many beams hit one landmark.
    Rows on different landmarks are independent and keep their own n. The same error comes
    back in every later update on that landmark: ``reuse`` (1: none) multiplies the shared
    part further, so that it is bounded over the updates too (:func:`reuse_factors`)."""
    k = c0_index.size
    if k == 0:
        return
    top = 0
    for i in range(k):
        top = max(top, c0_index[i])
    count = np.zeros(top + 1, dtype=np.int64)
    for i in range(k):
        count[c0_index[i]] += 1
    for i in range(k):
        n = count[c0_index[i]]
        weight = reuse[c0_index[i] - 3]
        if n > 1 or weight != 1.0:
            variance[i] = range_var + (n * weight) * (variance[i] - range_var)


@njit
def reuse_factors(index: np.ndarray, n: int, mode: int, out: np.ndarray) -> None:
    """Per landmark row, the weight of its own error's share in this update (``out`` (n,)):
    u(u + 1) for the u-th update its beams enter since its shape was fitted (``index[USES]``
    counts the earlier ones), 1 where ``mode`` leaves it out (``SlamConfig.reuse_bound``: 0
    "none" every landmark, 1 "curved" the lines, 2 "all" none).

    A landmark's misfit and frozen shape are one error e(ξ) every beam on it sees, in every
    update until it is refitted. For weights λ_u > 0 with Σ_u λ_u ≤ 1, Cauchy–Schwarz gives
    (Σ_u x_u e_u)² ≤ Σ_u x_u² e_u² / λ_u, so rows whose shared variance is s²/λ_u in the
    u-th update bound that error's covariance over *all* of them, however many there will
    be. λ_u = 1/(u(u + 1)) sums to exactly 1. Counting each step as fresh noise (1 each
    time) let a curved cave wall's frozen curvature feed the heading step after step: the
    heading error grew to 4–5 σ while σ shrank (docs/notes/floors.md, Round 3). Within one
    update the n rows on a landmark share it as well (:func:`share_landmark_error`)."""
    for j in range(n):
        weight = 1.0
        if mode == 2 or (mode == 1 and index[ORDER, j] >= 2):
            u = float(index[USES, j] + 1)
            weight = u * (u + 1.0)
        out[j] = weight


@njit
def count_uses(index: np.ndarray, n: int, c0_index: np.ndarray, accepted: np.ndarray) -> None:
    """Add one to ``index[USES]`` of each landmark with a row among the ``accepted`` ones."""
    counted = np.zeros(n, np.bool_)
    for i in range(c0_index.size):
        j = c0_index[i] - 3
        if accepted[i] and not counted[j]:
            counted[j] = True
            index[USES, j] += 1


@njit
def on_seen_face(
    landmark: np.ndarray,  # (k,) int64: the landmark each beam's cast hit (−1: none)
    denom: np.ndarray,  # (k,) the cast's D = dη − B'·dξ at the hit
    sides: np.ndarray,  # (n,) each landmark's seen face (``SIDE``: +1 from +η, −1 from −η, 0)
    out: np.ndarray,  # (k,) bool out
) -> None:
    """Whether each cast meets its landmark on a face the landmark's beams saw
    (``SlamConfig.seen_faces``): a ray with D > 0 crosses the curve towards +η, so it comes
    from the −η side, and one with D < 0 from the +η side; it meets a landmark seen only
    from the other side (SIDE·D > 0) from behind, and is out. A cast that hit nothing, or a
    landmark of both faces or of no known face (SIDE 0), is in."""
    for i in range(landmark.size):
        j = landmark[i]
        out[i] = j < 0 or sides[j] * denom[i] <= 0.0


@njit
def update_scan(
    mean: np.ndarray,  # (3+n(+n),) written in place
    cov: np.ndarray,  # written in place
    angles: np.ndarray,  # (B,) every beam's angle
    ranges: np.ndarray,  # (B,) every beam's reading
    beams: np.ndarray,  # (k,) int64: the beams to update with, in this order
    assigned: np.ndarray,  # (k,) int64: the landmark each was associated with (−1: any)
    real: np.ndarray,  # the landmark table (n landmarks)
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,  # the filter's model (``columns``: P_*, S_*)
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
) -> int:
    """The rows of ``beams`` (:func:`beam_rows`) but, with ``end_sigma`` > 0, those cast at
    the mean onto another landmark than the one ``assigned``, those that miss their landmark
    from one of its sigma points at ``end_sigma`` (:func:`steady_beams`) and
    those whose hit may lie past its end (:func:`ends_in_doubt`), their R made a joint
    bound (:func:`share_landmark_error`), and the gated update with them
    (:func:`update_sparse`; the turns α are considered, not estimated); returns how many rows
    passed the gate, or −1 when no beam had a usable row (then nothing ran)."""
    n_beams = beams.size
    end_sigma = params[P_END_SIGMA]
    innovation, h_pose = np.empty(n_beams), np.empty((n_beams, 3))
    c0_index, h_c0, variance = np.empty(n_beams, np.int64), np.empty(n_beams), np.empty(n_beams)
    alpha_index, h_alpha = np.empty(n_beams, np.int64), np.empty(n_beams)
    end_room, xi_grad = np.empty(n_beams), np.empty((n_beams, 4))
    # one scan model and one cast at the mean serve the sigma-point test and the rows
    near, turn_var, alpha_base = _scan_model(mean, real, index, n, params, switches, step)
    variate, order, lo, hi = index[VARIATE, :n], index[ORDER, :n], real[LO, :n], real[HI, :n]
    angle, t, landmark, slope, denom, xi = cast_beams(
        mean[0], mean[1], mean[2], angles, beams, params[P_REACH], variate, order, shape[:n],
        lo, hi, mean[3 : 3 + n], near, params[P_MAX_RANGE],
    )  # fmt: skip
    if switches[S_SEEN_FACES]:
        seen = np.empty(beams.size, np.bool_)
        on_seen_face(landmark, denom, index[SIDE, :n], seen)
        beams, angle, t, landmark = beams[seen], angle[seen], t[seen], landmark[seen]
        slope, denom, xi = slope[seen], denom[seen], xi[seen]
        assigned = assigned[seen]
    if end_sigma > 0.0:
        steady = np.empty(beams.size, np.bool_)
        steady_of_casts(
            mean, cov, assigned, params[P_REACH], variate, order, shape[:n], lo, hi, near,
            params[P_MAX_RANGE], params[P_MIN_SINE], n, end_sigma, angle, landmark, slope,
            denom, steady,
        )  # fmt: skip
        beams, angle, t, landmark = beams[steady], angle[steady], t[steady], landmark[steady]
        slope, denom, xi = slope[steady], denom[steady], xi[steady]
    k = rows_of_casts(
        mean[2], ranges, beams, angle, t, landmark, slope, denom, xi, variate, order, shape[:n],
        lo, hi, params[P_MIN_SINE], params[P_RANGE_VAR], real[MODEL_VAR, :n],
        switches[S_SHAPE_FOLLOWS_POSE] != 0, switches[S_SHIFT_WITH_POSE] != 0, real[PIVOT, :n],
        real[XI_VAR, :n], np.array([cov[0, 0], cov[1, 1]]), real[SHIFT_SLOPE, :n], turn_var,
        real[FIT_HALF, :n], fit_inverse, switches[S_N_FIT], alpha_base, innovation, h_pose,
        c0_index, h_c0, alpha_index, h_alpha, variance, end_room, xi_grad,
    )  # fmt: skip
    if k > 0 and end_sigma > 0.0:
        keep = np.empty(k, np.bool_)
        ends_in_doubt(
            cov, h_pose[:k], c0_index[:k], h_c0[:k], alpha_index[:k], h_alpha[:k],
            end_room[:k], xi_grad[:k], end_sigma, keep,
        )  # fmt: skip
        w = 0
        for i in range(k):  # compact the kept rows, in order
            if keep[i]:
                innovation[w], h_pose[w], c0_index[w] = innovation[i], h_pose[i], c0_index[i]
                h_c0[w], alpha_index[w], h_alpha[w] = h_c0[i], alpha_index[i], h_alpha[i]
                variance[w] = variance[i]
                w += 1
        k = w
    if k == 0:
        return -1
    reuse = np.empty(n)
    reuse_factors(index, n, switches[S_REUSE_BOUND], reuse)
    share_landmark_error(c0_index[:k], variance[:k], params[P_RANGE_VAR], reuse)
    accepted, nis = np.empty(k, np.bool_), np.empty(k)
    consider_from = 3 + n if switches[S_ROTATION_STATES] else mean.size
    used = update_sparse(
        mean, cov, innovation[:k], h_pose[:k], c0_index[:k], h_c0[:k], alpha_index[:k],
        h_alpha[:k], variance[:k], params[P_GATE], consider_from, accepted, nis,
    )  # fmt: skip
    count_uses(index, n, c0_index[:k], accepted)
    return used


@njit
def fma_product3(a: np.ndarray, b: np.ndarray, transposed: bool, out: np.ndarray) -> None:
    """``out`` = a b (or a bᵀ when ``transposed``) of 3 × 3 matrices, each entry a chain of
    fused multiply-adds along the inner index from 0, as OpenBLAS's FMA gemm kernels run it."""
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for k in range(3):
                acc = fma(a[r, k], b[c, k] if transposed else b[k, c], acc)
            out[r, c] = acc


@njit
def start_error_covs(poses: np.ndarray, p0: np.ndarray, out: np.ndarray) -> None:
    """J P0 Jᵀ of each pose (K, ≥2) into ``out`` (K, 3, 3), symmetrised as ½(C + Cᵀ), with
    J = [[1, 0, −y], [0, 1, x], [0, 0, 1]] (:func:`~polyslam_env.slam.ekf.start_error_covs`).
    The two products as numpy's stacked matmul ran them on OpenBLAS's FMA gemm kernels: each
    entry a chain of fused multiply-adds along the inner index from 0, J's zeros included."""
    jac = np.zeros((3, 3))
    left = np.empty((3, 3))
    both = np.empty((3, 3))
    for i in range(poses.shape[0]):
        jac[0, 0] = jac[1, 1] = jac[2, 2] = 1.0
        jac[0, 2] = -poses[i, 1]
        jac[1, 2] = poses[i, 0]
        fma_product3(jac, p0, False, left)
        fma_product3(left, jac, True, both)
        for r in range(3):
            for c in range(3):
                out[i, r, c] = 0.5 * (both[r, c] + both[c, r])

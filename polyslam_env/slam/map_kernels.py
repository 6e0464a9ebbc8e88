"""Compiled kernels of the map's bookkeeping in one SLAM step: this step's beam points, their
association with the landmarks, the clusters and Q_bad sets they join, the extents they stretch
(STYLE habits 20, 21).

They read and write the landmark table's and the stored points' field-major buffers
(:mod:`~polyslam_env.slam.columns`): ``real``/``index`` (fields × capacity, the first ``n``
columns in use) and ``shape`` (capacity × (M+1)) of the table, ``preal``/``pindex`` and their
``counters`` of the stored points. Each kernel does the operations of the Python it replaced
in the same order, so results are bit for bit the same; the readable list-of-objects version
(``MapBook`` with its points as Python tuples) is the test oracle in
``tests/slam/reference_association.py``.

Python's scalar semantics are kept: ``min``/``max`` (:func:`~polyslam_env.slam.kernels._min`),
``math.hypot`` (:func:`~polyslam_env.slam.kernels.hypot`) and ``x ** 2``, which is libm's
``pow`` (:func:`rotation_fit_var` takes its exponent as an argument: LLVM turns a literal
``pow(x, 2.0)`` into ``x * x``, which rounds differently in ~0.1 % of cases).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.geometry import symmetric_eigvals3
from polyslam_env.core.jit import fma, njit, sum_like_numpy
from polyslam_env.slam.columns import (
    BEAM,
    CHANGED_AT,
    CLUSTER,
    ETA_HI,
    ETA_LO,
    EV_HI,
    EV_LO,
    FIT_HALF,
    HI,
    ID,
    KIND,
    LO,
    MODEL_VAR,
    N_NEW,
    N_REFIT,
    NEW,
    NEXT_CLUSTER,
    NEXT_RANK,
    ORDER,
    OWNER,
    P_CLUSTER_RADIUS,
    P_RANGE_SIGMA,
    P_RANGE_VAR,
    P_SQUARE,
    P_TURN_VAR_PER_STEP,
    PIVOT,
    PTH,
    PX,
    PY,
    QBAD,
    RANK,
    RECEIVED,
    REFIT,
    S_EPS_M,
    S_EPS_Z,
    S_LINK_CLUSTERS,
    S_ROTATION_STATES,
    S_SEEN_FACES,
    S_SQUARED,
    S_STRETCH_ENDS,
    SHIFT_SLOPE,
    SIDE,
    SIGMA,
    SIZE,
    STAMP,
    STEP,
    USES,
    UX,
    UY,
    VARIATE,
    WEIGHT,
    XI_VAR,
    X,
    Y,
)
from polyslam_env.slam.kernels import (
    _max,
    _min,
    boxes,
    boxes_near,
    horner,
    hypot,
    nearest_by_error,
    taylor_shift,
)

#: m, widest gap between neighbouring points (along the wall) that one landmark may span. The
#: smallest doorway a robot can pass is its diameter 0.13 m; consecutive hits of one beam
#: along a wall it drives past are at most v_max·T = 0.3 m apart (the default speed limit and
#: period) and the beams' hits interleave, so 0.3 m — the widest sampling gap, half the
#: narrowest door of the generators (0.6 m) — separates a gap from sparse sampling
#: (``association.GAP_SPLIT``: a cluster fit is cut there, an extent never stretched across).
GAP_SPLIT = 0.3
#: m², the smallest pose uncertainty a point's LMS weight divides by: a pose known exactly (the
#: start, without odometry noise) weighs as one known to a micrometre, not infinitely.
POSE_VAR_FLOOR = 1e-12


# -- small pieces ---------------------------------------------------------------------------------
@njit
def carry_points(
    real: np.ndarray, n: int, before: np.ndarray, after: np.ndarray, c: float, s: float
) -> None:
    """Move the first ``n`` stored points of ``real`` (the stored points' float buffer)
    rigidly from pose ``before`` (3,) to ``after`` (3,) (:meth:`~polyslam_env.slam.stored.
    StoredPoints.carry`; ``c``, ``s`` the cosine and sine of the heading's change dθ):
    position and pose position ``(p − b) Rᵀ + a``, direction ``u Rᵀ``, pose heading ``+ dθ``.

    Each row times Rᵀ is computed as the BLAS product it replaced computed it (a (n, 7) ×
    (7, 7) gemm of OpenBLAS's FMA kernels, the goldens' pinned Haswell): per output, a chain
    of fused multiply-adds along the seven inputs from 0, the motion's zeros included (they
    settle the sign of an exact zero)."""
    dtheta = after[2] - before[2]
    motion = np.zeros((7, 7))
    motion[0, 0] = motion[2, 2] = motion[4, 4] = c
    motion[0, 1] = motion[2, 3] = motion[4, 5] = s
    motion[1, 0] = motion[3, 2] = motion[5, 4] = -s
    motion[1, 1] = motion[3, 3] = motion[5, 5] = c
    motion[6, 6] = 1.0
    shift_in = (before[0], before[1], 0.0, 0.0, before[0], before[1], 0.0)
    shift_out = (after[0], after[1], 0.0, 0.0, after[0], after[1], dtheta)
    row = np.empty(7)
    for i in range(n):
        for k in range(7):
            row[k] = real[X + k, i] - shift_in[k]
        for j in range(7):
            acc = 0.0
            for k in range(7):
                acc = fma(row[k], motion[k, j], acc)
            real[X + j, i] = acc + shift_out[j]


@njit
def spectral_norm3(p: np.ndarray) -> float:
    """‖P‖₂ of the symmetric 3×3 block at the top left of ``p``: its largest |eigenvalue|
    (``ekf.spectral_norm_sym``'s 3×3 case)."""
    e0, _, e2 = symmetric_eigvals3(p)
    return _max(-e0, e2)


@njit
def prediction_weight(cov: np.ndarray) -> float:
    """LMS weight 1/‖P_{k|k−1}‖ of this step's points (the pose block of ``cov``), the norm
    floored at :data:`POSE_VAR_FLOOR` (``fitting.prediction_weight``)."""
    norm = spectral_norm3(cov)
    if not norm >= 0:
        raise ValueError("pose covariance has no finite norm; cannot weight its points")
    return 1.0 / _max(norm, POSE_VAR_FLOOR)


@njit
def slope_at(shape: np.ndarray, m: int, x: float) -> float:
    """B'(x) of the shape row [0, b_1, …, b_m]: numpy's ``polyval(x, polyder(coeffs))``, the
    derivative's coefficients k·b_k evaluated by Horner's scheme (``Polynomial.slope``; not
    :func:`~polyslam_env.slam.kernels.horner`'s running derivative, which rounds otherwise)."""
    value = m * shape[m]
    for k in range(m - 1, 0, -1):
        value = k * shape[k] + value * x
    return value


@njit
def rotation_fit_var(
    shape: np.ndarray,  # (M+1,) [0, b_1, …, b_M]
    m: int,  # its own order
    lo: float,
    hi: float,
    fit_inverse: np.ndarray,  # (K+1, K+1, K+1): (AᵀA)⁻¹ of order o at [o]
    range_var: float,
    square: float,  # 2.0 (the module docstring says why it is an argument)
) -> float:
    """Variance of a fitted shape's turn from its slope's fit error: σ²·M⁻¹[1, 1]/h² (N = ε_Z
    + 1 equally spaced points over the half-extent h ≥ 5 cm, ``PolySlam``'s model) over
    (1 + b'²)², the slope-to-angle factor at the middle of the extent."""
    half = _max(0.5 * (hi - lo), 0.05)
    slope = slope_at(shape, m, 0.5 * (lo + hi))
    return range_var * fit_inverse[m, 1, 1] / (half * half) / math.pow(1.0 + slope * slope, square)


@njit
def eta_range(shape: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    """Bounds on B(ξ) over ξ ∈ [lo, hi] for one shape row [0, b_1, …, b_M] (all M+1
    coefficients, zero tail included): interval arithmetic on the Taylor expansion about the
    middle of the extent (``landmarks.shape_range``, whose docstring has the argument)."""
    width = shape.size
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    taylor = np.empty(width)
    taylor_shift(shape, width - 1, mid, taylor)
    terms = np.empty(width - 1)
    for k in range(1, width):
        terms[k - 1] = abs(taylor[k]) * math.pow(half, float(k))
    spread = sum_like_numpy(terms, 0, terms.size)
    # a relative pad absorbs the rounding of T_0 and of the exact values this bounds
    pad = spread * 1e-9 + 1e-9 * (1.0 + abs(taylor[0]))
    return taylor[0] - spread - pad, taylor[0] + spread + pad


@njit
def turned_line(
    c0: float, slope: float, variate: int, pivot: float, angle: float
) -> tuple[float, float]:
    """(c0, slope) of the line η = c0 + slope·ξ (``variate``) turned by ``angle`` about its
    point at ξ = ``pivot`` (:func:`~polyslam_env.slam.links.turned_line`'s model): its
    direction (1, slope) on (ξ, η) turned by R(angle) in (x¹, x²), the offset at the pivot
    kept. The floats of its numpy form (``tests/slam/reference_links.py``): R's entries are
    libm's ``cos``/``sin`` as numpy's, and ``R @ d`` is BLAS's gemv of two columns, the
    second column's product rounded, the first's fused onto it."""
    eta_c = c0 + slope * pivot
    c, s = math.cos(angle), math.sin(angle)
    dx, dy = (1.0, slope) if variate == 1 else (slope, 1.0)
    tx = fma(c, dx, -s * dy)  # R = [[c, −s], [s, c]]
    ty = fma(s, dx, c * dy)
    turned = ty / tx if variate == 1 else tx / ty
    return eta_c - turned * pivot, turned


# -- the merge test of two polynomials ------------------------------------------------------------
#: samples of the other polynomial projected on p's axis (``merging`` module: overlap and γ)
MERGE_SAMPLES = 64
#: :func:`merge_test`'s answers
DISJOINT, SHORT_OVERLAP, MEASURED = 0, 1, 2


@njit
def _linspace(start: float, stop: float, num: int, out: np.ndarray) -> None:
    """``np.linspace(start, stop, num)`` (num ≥ 2) into ``out``: the same floats (i·step +
    start, i/div·delta + start when the step underflows to 0, the end point exactly)."""
    div = num - 1
    delta = stop - start
    step = delta / div
    for i in range(num):
        out[i] = (i / div) * delta + start if step == 0.0 else i * step + start
    out[num - 1] = stop


@njit
def equally_spaced(c: np.ndarray, variate: int, lo: float, hi: float, n: int) -> np.ndarray:
    """``n`` points (n, 2) of the curve with coefficients ``c`` equally spaced in ξ over
    [lo, hi]: ``Polynomial.points_at(np.linspace(lo, hi, n))``, the same floats, in one call
    (the SLAM samples landmarks so for every merge and link)."""
    xi = np.empty(n)
    if n == 1:
        xi[0] = lo
    elif n > 1:
        _linspace(lo, hi, n, xi)
    out = np.empty((n, 2))
    _on_curve(c, variate, xi, out)
    return out


@njit
def _on_curve(c: np.ndarray, variate: int, xi: np.ndarray, out: np.ndarray) -> None:
    """Points (n, 2) of the curve with coefficients ``c`` at ``xi`` (``Polynomial.points_at``;
    Horner in polyval's order: the same floats)."""
    m = c.size - 1
    for i in range(xi.size):
        eta = horner(c, m, xi[i], c[0])[0]
        out[i, 0], out[i, 1] = (xi[i], eta) if variate == 1 else (eta, xi[i])


@njit
def _rms_error(xy: np.ndarray, variate: int, c: np.ndarray, lo: float, hi: float) -> float:
    """RMS approximation error of the points ``xy`` by one polynomial: each point's
    ``kernels.nearest_by_error`` with it the only candidate (|η − p(ξ)| inside the extent,
    else the distance to the nearer end point; no finite error: inf), in its operations
    without its candidate arrays, and their mean square summed as numpy sums."""
    m = c.size - 1
    order = 1
    for k in range(m, 0, -1):  # the shape's own order (its last non-zero power, ≥ 1)
        if c[k] != 0.0:
            order = max(k, 1)
            break
    c0 = c[0]
    end_lo, end_hi = horner(c, order, lo, c0)[0], horner(c, order, hi, c0)[0]
    n = xy.shape[0]
    squares = np.empty(n)
    for p in range(n):
        xi, eta = (xy[p, 0], xy[p, 1]) if variate == 1 else (xy[p, 1], xy[p, 0])
        if lo <= xi and xi <= hi:
            err = abs(eta - horner(c, order, xi, c0)[0])
        else:
            err = _min(hypot(xi - lo, eta - end_lo), hypot(xi - hi, eta - end_hi))
        err = err if err < math.inf else math.inf  # nearest_by_error keeps inf past a nan
        squares[p] = err * err
    return math.sqrt(sum_like_numpy(squares, 0, n) / n)


@njit
def _unique_rounded(spots: np.ndarray) -> np.ndarray:
    """``np.unique(np.rint(spots).astype(np.int64))`` of non-decreasing ``spots`` (a
    linspace): rint (numpy's round, half to even) keeps their order, so the unique values are
    the first of each run of equal ones."""
    out = np.empty(spots.size, dtype=np.int64)
    count = 0
    for i in range(spots.size):
        value = np.int64(np.rint(spots[i]))
        if count == 0 or value != out[count - 1]:
            out[count] = value
            count += 1
    return out[:count]


@njit
def merge_test(
    p_variate: int, p_coeffs: np.ndarray, p_lo: float, p_hi: float,
    o_variate: int, o_coeffs: np.ndarray, o_lo: float, o_hi: float,
    min_overlap: float,
    out: np.ndarray,  # (4,) out: a, b, γ, the ξ on the other polynomial of its tangent
) -> int:  # fmt: skip
    """The merge test's geometry of p (coefficients with its c0, extent) against another
    polynomial (see ``merging``): the other's :data:`MERGE_SAMPLES` samples projected on p's
    axis give the overlap [a, b]; :data:`DISJOINT` when there is none, :data:`SHORT_OVERLAP`
    when neither includes the other and it is shorter than ``min_overlap``; else
    :data:`MEASURED` with γ = max(RMS error of the other on p's m+1 equally spaced points of
    [a, b], RMS error of p on up to m+1 of the other's samples projecting there) and where the
    other's tangent is to be taken (the middle of those samples). The same floats as the
    readable version in ``tests/slam/reference_merging.py`` (tested)."""
    xi_o = np.empty(MERGE_SAMPLES)
    _linspace(o_lo, o_hi, MERGE_SAMPLES, xi_o)
    samples = np.empty((MERGE_SAMPLES, 2))
    _on_curve(o_coeffs, o_variate, xi_o, samples)
    axis = 0 if p_variate == 1 else 1
    xi_s = samples[:, axis]
    lo2, hi2 = xi_s.min(), xi_s.max()
    a = lo2 if lo2 > p_lo else p_lo  # Python's max(p_lo, lo2), min(p_hi, hi2)
    b = hi2 if hi2 < p_hi else p_hi
    if b < a:
        return DISJOINT
    included = (p_lo <= lo2 and hi2 <= p_hi) or (lo2 <= p_lo and p_hi <= hi2)
    if not (included or b - a >= min_overlap):
        return SHORT_OVERLAP
    m = p_coeffs.size - 1
    xi_p = np.empty(m + 1)
    _linspace(a, b, m + 1, xi_p)
    on_p = np.empty((m + 1, 2))
    _on_curve(p_coeffs, p_variate, xi_p, on_p)
    gamma_p = _rms_error(on_p, o_variate, o_coeffs, o_lo, o_hi)
    inside = np.flatnonzero((xi_s >= a) & (xi_s <= b))
    if inside.size == 0:
        inside = np.arange(MERGE_SAMPLES)
    spots = np.empty(m + 1)
    _linspace(0.0, float(inside.size - 1), m + 1, spots)
    pick = _unique_rounded(spots)
    gamma_o = _rms_error(samples[inside[pick]], p_variate, p_coeffs, p_lo, p_hi)
    out[0], out[1] = a, b
    out[2] = gamma_o if gamma_o > gamma_p else gamma_p  # Python's max(gamma_p, gamma_o)
    out[3] = xi_o[inside[inside.size // 2]]
    return MEASURED


@njit
def _unit_tangent(variate: int, c: np.ndarray, xi: float) -> tuple[float, float]:
    """``merging.unit_tangent``: (1, B') or (B', 1) over its norm, the same floats."""
    slope = slope_at(c, c.size - 1, xi)
    t0, t1 = (1.0, slope) if variate == 1 else (slope, 1.0)
    norm = math.sqrt(t0 * t0 + t1 * t1)
    return t0 / norm, t1 / norm


@njit
def join_offset(
    p_variate: int, p_coeffs: np.ndarray, p_lo: float, p_hi: float,
    o_variate: int, o_coeffs: np.ndarray, o_lo: float, o_hi: float,
    max_gap: float, max_angle_deg: float, thin_wall: float,
) -> float:  # fmt: skip
    """``merging.join_gamma`` of p against another polynomial (coefficients with their c0,
    extents): the lateral offset of the two pieces meeting end to end, nan when they cannot
    be joined (nearer ends farther than ``max_gap``, tangents there beyond ``max_angle_deg``,
    offset above ``thin_wall``). The same floats as the readable version in
    ``tests/slam/reference_merging.py`` (tested)."""
    ends = np.empty(2)
    ends_p, ends_o = np.empty((2, 2)), np.empty((2, 2))
    ends[0], ends[1] = p_lo, p_hi
    _on_curve(p_coeffs, p_variate, ends, ends_p)
    ends[0], ends[1] = o_lo, o_hi
    _on_curve(o_coeffs, o_variate, ends, ends_o)
    best_i, best_k, best = 0, 0, np.inf
    for i in range(2):
        for k in range(2):
            dx, dy = ends_p[i, 0] - ends_o[k, 0], ends_p[i, 1] - ends_o[k, 1]
            gap = math.sqrt(dx * dx + dy * dy)
            if gap < best or (i == 0 and k == 0):  # numpy's argmin: the first smallest
                best_i, best_k, best = i, k, gap
    if best > max_gap:
        return np.nan
    tp0, tp1 = _unit_tangent(p_variate, p_coeffs, p_lo if best_i == 0 else p_hi)
    to0, to1 = _unit_tangent(o_variate, o_coeffs, o_lo if best_k == 0 else o_hi)
    cosine = min(abs(tp0 * to0 + tp1 * to1), 1.0)
    if math.acos(cosine) * (180.0 / math.pi) > max_angle_deg:  # np.degrees' factor
        return np.nan
    d0 = ends_o[best_k, 0] - ends_p[best_i, 0]
    d1 = ends_o[best_k, 1] - ends_p[best_i, 1]
    across_p, across_o = abs(tp0 * d1 - tp1 * d0), abs(to0 * d1 - to1 * d0)
    offset = across_o if across_o > across_p else across_p  # Python's max(across_p, across_o)
    return offset if offset <= thin_wall else np.nan


@njit
def merge_cosine(
    p_variate: int, p_coeffs: np.ndarray, xi_p: float,
    o_variate: int, o_coeffs: np.ndarray, xi_o: float,
) -> float:  # fmt: skip
    """|cos| of the angle between p's tangent at ``xi_p`` and the other's at ``xi_o``, at most
    1 (``merging.merge_angle`` takes its arccos): the same floats as numpy's (the 2-vectors'
    dot products are BLAS's plain sums of two products)."""
    tp0, tp1 = _unit_tangent(p_variate, p_coeffs, xi_p)
    to0, to1 = _unit_tangent(o_variate, o_coeffs, xi_o)
    return min(abs(tp0 * to0 + tp1 * to1), 1.0)


@njit
def merge_candidates(
    p_variate: int, p_coeffs: np.ndarray, p_lo: float, p_hi: float,
    rows: np.ndarray,  # (k,) int64: the candidates' rows of the columns below
    variates: np.ndarray,  # (n,) int64: the candidates' columns, as the landmark table holds them
    shapes: np.ndarray,  # (n, W) rows [·, b_1, …]: coefficient 0 is replaced by the c0
    sizes: np.ndarray,  # (n,) int64: each one's number of coefficients (≤ W)
    c0s: np.ndarray,  # (n,)
    los: np.ndarray,  # (n,)
    his: np.ndarray,  # (n,)
    min_overlap: float, max_angle_deg: float,
    join_gap: float, join_angle_deg: float, thin_wall: float,  # join_gap nan: no joins
    gammas: np.ndarray,  # (k,) out: γ, nan when it does not count
    joined: np.ndarray,  # (k,) bool out: γ is a join's offset
) -> None:  # fmt: skip
    """The merge test of p against every candidate in one call (``merging.merge_gammas``):
    γ where :func:`merge_test` measures it and the tangents there agree within
    ``max_angle_deg``; else, with ``join_gap``, :func:`join_offset` (nan when no join)."""
    found = np.empty(4)
    for i in range(rows.size):
        j = rows[i]
        c = shapes[j, : sizes[j]].copy()
        c[0] = c0s[j]
        gammas[i], joined[i] = np.nan, False
        measured = merge_test(
            p_variate, p_coeffs, p_lo, p_hi, variates[j], c, los[j], his[j], min_overlap, found
        )
        if measured == MEASURED:
            cosine = merge_cosine(
                p_variate, p_coeffs, 0.5 * (found[0] + found[1]), variates[j], c, found[3]
            )
            if math.acos(cosine) * (180.0 / math.pi) <= max_angle_deg:  # np.degrees' factor
                gammas[i] = found[2]
                continue
        if not math.isnan(join_gap):
            gammas[i] = join_offset(
                p_variate, p_coeffs, p_lo, p_hi, variates[j], c, los[j], his[j], join_gap,
                join_angle_deg, thin_wall,
            )  # fmt: skip
            joined[i] = True


@njit
def near_merge_candidates(
    p_variate: int, p_coeffs: np.ndarray, p_lo: float, p_hi: float,
    boxes: np.ndarray,  # (n, 4) the candidates' boxes (x_min, x_max, y_min, y_max)
    box: np.ndarray,  # (4,) p's
    distance: float,
    exclude: int,  # a row left out (p's own), −1: none
    variates: np.ndarray, shapes: np.ndarray, sizes: np.ndarray, c0s: np.ndarray,
    los: np.ndarray, his: np.ndarray,
    min_overlap: float, max_angle_deg: float,
    join_gap: float, join_angle_deg: float, thin_wall: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The rows whose boxes lie within ``distance`` of ``box`` (``kernels.boxes_near``,
    ascending, without ``exclude``) and :func:`merge_candidates`' (γ, joined) for them, in one
    call (``merging.near_merge_gammas``)."""
    near = boxes_near(boxes, box, distance)
    if exclude >= 0:
        near = near[near != exclude]
    gammas, joined = np.empty(near.size), np.empty(near.size, dtype=np.bool_)
    merge_candidates(
        p_variate, p_coeffs, p_lo, p_hi, near, variates, shapes, sizes, c0s, los, his,
        min_overlap, max_angle_deg, join_gap, join_angle_deg, thin_wall, gammas, joined,
    )  # fmt: skip
    return near, gammas, joined


@njit
def curve_box(c: np.ndarray, variate: int, lo: float, hi: float, n: int) -> np.ndarray:
    """(4,) box (x_min, x_max, y_min, y_max) of :func:`equally_spaced`'s ``n`` points (the
    exchange's same-wall test looks for the landmarks near it)."""
    xy = equally_spaced(c, variate, lo, hi, n)
    box = np.empty(4)
    box[0], box[1] = xy[:, 0].min(), xy[:, 0].max()
    box[2], box[3] = xy[:, 1].min(), xy[:, 1].max()
    return box


# -- stored points --------------------------------------------------------------------------------
@njit
def _append_point(
    preal: np.ndarray,
    pindex: np.ndarray,
    counters: np.ndarray,
    source: np.ndarray,  # (N_POINT_REAL,) the point's real fields
    beam: int,
    step: int,
    kind: int,
    owner: int,
) -> None:
    """A new stored point (the next rank) in the first free row."""
    row = counters[SIZE]
    for f in range(source.size):
        preal[f, row] = source[f]
    pindex[BEAM, row], pindex[STEP, row] = beam, step
    pindex[KIND, row], pindex[OWNER, row] = kind, owner
    pindex[RANK, row] = counters[NEXT_RANK]
    counters[NEXT_RANK] += 1
    counters[SIZE] += 1


@njit
def _members(pindex: np.ndarray, size: int, kind: int, owner: int) -> np.ndarray:
    """Rows of the points of one holder, in rank order."""
    rows = np.empty(size, dtype=np.int64)
    count = 0
    for row in range(size):
        if pindex[KIND, row] == kind and pindex[OWNER, row] == owner:
            rows[count] = row
            count += 1
    rows = rows[:count]
    return rows[np.argsort(pindex[RANK, rows], kind="mergesort")]


@njit
def _count_of(pindex: np.ndarray, size: int, kind: int, owner: int) -> int:
    count = 0
    for row in range(size):
        if pindex[KIND, row] == kind and pindex[OWNER, row] == owner:
            count += 1
    return count


@njit
def _hand_over(
    pindex: np.ndarray, size: int, kind: int, owner: int, new_kind: int, new_owner: int
) -> None:
    """Every point of one holder (``kind``, ``owner``) goes to another, ranks kept."""
    for row in range(size):
        if pindex[KIND, row] == kind and pindex[OWNER, row] == owner:
            pindex[KIND, row], pindex[OWNER, row] = new_kind, new_owner


@njit
def _cluster_keys(pindex: np.ndarray, size: int) -> np.ndarray:
    """The clusters' keys in cluster order (oldest first)."""
    keys = np.empty(size, dtype=np.int64)
    count = 0
    for row in range(size):
        if pindex[KIND, row] == CLUSTER:
            keys[count] = pindex[OWNER, row]
            count += 1
    return np.unique(keys[:count])


@njit
def _add_bad(
    preal: np.ndarray,
    pindex: np.ndarray,
    counters: np.ndarray,
    requests: np.ndarray,  # (B,) out: landmark id of each refit request
    point: np.ndarray,
    beam: int,
    step: int,
    landmark_id: int,
    eps_m: int,
) -> None:
    """Add the point to the landmark's Q_bad; past ε_M points, the set becomes a refit request
    (joining this step's request for that landmark, if any) and Q_bad starts empty."""
    _append_point(preal, pindex, counters, point, beam, step, QBAD, landmark_id)
    size = counters[SIZE]
    if _count_of(pindex, size, QBAD, landmark_id) <= eps_m:
        return
    request = -1
    for r in range(counters[N_REFIT]):
        if requests[r] == landmark_id:
            request = r
            break
    if request < 0:
        request = counters[N_REFIT]
        requests[request] = landmark_id
        counters[N_REFIT] += 1
    _hand_over(pindex, size, QBAD, landmark_id, REFIT, request)


@njit
def _add_to_cluster(
    preal: np.ndarray,
    pindex: np.ndarray,
    counters: np.ndarray,
    point: np.ndarray,
    beam: int,
    step: int,
    radius: float,
    link: bool,
    eps_z: int,
) -> None:
    """Put the point in the cluster with most neighbours within R (first on ties), or a new
    cluster; with ``link`` every other cluster with a neighbour joins that one (single
    linkage: its points follow, cluster by cluster in order). A cluster past ε_Z becomes a
    new-landmark request (``MapBook.add_to_cluster``)."""
    size = counters[SIZE]
    keys = _cluster_keys(pindex, size)
    counts = np.zeros(keys.size, dtype=np.int64)
    x, y = point[X], point[Y]
    for row in range(size):
        if pindex[KIND, row] == CLUSTER:
            if hypot(preal[X, row] - x, preal[Y, row] - y) <= radius:
                counts[np.searchsorted(keys, pindex[OWNER, row])] += 1
    best = -1
    for k in range(keys.size):
        if counts[k] > 0 and (best < 0 or counts[k] > counts[best]):
            best = k
    if best < 0:
        key = counters[NEXT_CLUSTER]
        counters[NEXT_CLUSTER] += 1
        _append_point(preal, pindex, counters, point, beam, step, CLUSTER, key)
    else:
        key = keys[best]
        _append_point(preal, pindex, counters, point, beam, step, CLUSTER, key)
        if link:
            for k in range(keys.size):
                if counts[k] > 0 and k != best:
                    for row in _members(pindex, counters[SIZE], CLUSTER, keys[k]):
                        pindex[OWNER, row] = key
                        pindex[RANK, row] = counters[NEXT_RANK]
                        counters[NEXT_RANK] += 1
    size = counters[SIZE]
    if _count_of(pindex, size, CLUSTER, key) > eps_z:
        request = counters[N_NEW]
        counters[N_NEW] += 1
        _hand_over(pindex, size, CLUSTER, key, NEW, request)


# -- the association step -------------------------------------------------------------------------
@njit
def beam_returns(
    mean: np.ndarray,  # (3…,) the predicted pose first
    cov: np.ndarray,  # its covariance (the pose block at the top left)
    ranges: np.ndarray,  # (B,) readings (inf/nan: no return)
    angles: np.ndarray,  # (B,) beam angles
    range_sigma: float,
    points: np.ndarray,  # (≥ B, N_POINT_REAL) out: each return's real fields
    beams: np.ndarray,  # (≥ B,) int64 out: its beam
) -> int:
    """This step's returns as stored points (paper eq. 3: π = p + r (cos φ, sin φ), φ = θ + β,
    the direction, σ, the LMS weight 1/‖P_{k|k−1}‖ and the pose), in beam order; returns how
    many."""
    x, y, theta = mean[0], mean[1], mean[2]
    weight = prediction_weight(cov)
    count = 0
    for b in range(ranges.size):
        r = ranges[b]
        if not math.isfinite(r):
            continue
        phi = theta + angles[b]
        c, s = math.cos(phi), math.sin(phi)
        p = points[count]
        p[X], p[Y], p[UX], p[UY] = x + r * c, y + r * s, c, s
        p[PX], p[PY], p[PTH] = x, y, theta
        p[SIGMA], p[WEIGHT] = range_sigma, weight
        beams[count] = b
        count += 1
    return count


@njit
def _continued_xi(
    x: float, y: float, j: int, real: np.ndarray, index: np.ndarray, shape: np.ndarray,
    c0: float, range_sigma: float,
) -> float:  # fmt: skip
    """ξ of a point (x, y) past landmark j's extent when its curve continued there explains
    it within 2σ of the range noise (|η − p(ξ)|); nan otherwise (``PolySlam._continued_xi``)."""
    v1 = index[VARIATE, j] == 1
    xi, eta = (x, y) if v1 else (y, x)
    m = index[ORDER, j]
    value = shape[j, m]
    for i in range(m - 1, 0, -1):
        value = value * xi + shape[j, i]
    curve = (value * xi + 0.0) + c0  # the shape with c0 = 0 at ξ, then the state's c0
    if abs(eta - curve) <= 2.0 * range_sigma:
        return xi
    return math.nan


@njit
def _within_extent(x: float, y: float, j: int, real: np.ndarray, index: np.ndarray) -> bool:
    xi = x if index[VARIATE, j] == 1 else y
    return real[LO, j] <= xi and xi <= real[HI, j]


@njit
def _continues_past_end(
    x: float,
    y: float,
    j: int,
    n: int,
    mean: np.ndarray,
    cov: np.ndarray,
    step: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
) -> bool:
    """The ``stretch_ends`` test (``PolySlam._continues_past_end``): the point lies at most
    GAP_SPLIT past landmark j's end, on its continued curve, where that curve is known to the
    range noise relative to the robot (lever² · var(α − θ) ≤ σ²)."""
    if _within_extent(x, y, j, real, index):
        return False
    xi = _continued_xi(x, y, j, real, index, shape, mean[3 + j], params[P_RANGE_SIGMA])
    if math.isnan(xi):
        return False
    if _min(abs(xi - real[LO, j]), abs(xi - real[HI, j])) > GAP_SPLIT:
        return False
    lever = xi - real[PIVOT, j]
    if switches[S_ROTATION_STATES]:
        a = 3 + n + j
        turn_var = cov[a, a] + cov[2, 2] - 2.0 * cov[2, a]  # P's upper copy
    else:  # the frozen-shape model: the fit's slope error and the heading's walk since the fit
        age = float(step) - float(index[CHANGED_AT, j])
        turn_var = rotation_fit_var(
            shape[j], index[ORDER, j], real[LO, j], real[HI, j], fit_inverse,
            params[P_RANGE_VAR], params[P_SQUARE],
        ) + age * params[P_TURN_VAR_PER_STEP]  # fmt: skip
    return lever * lever * turn_var <= params[P_RANGE_VAR]


@njit
def extend_to_hit(
    real: np.ndarray, index: np.ndarray, shape: np.ndarray, j: int, xi: float
) -> None:
    """Stretch landmark j's extent and evidence to a supporting hit at ``xi``; its η range
    follows and its stamp moves (``LandmarkTable.extend_to_hit``)."""
    real[EV_LO, j], real[EV_HI, j] = _min(real[EV_LO, j], xi), _max(real[EV_HI, j], xi)
    set_extent(real, index, shape, j, _min(real[LO, j], xi), _max(real[HI, j], xi))


@njit
def own_order(shape: np.ndarray) -> int:
    """A zero-padded shape row's own order: its last nonzero coefficient's index (a NaN is
    nonzero), at least 1 (``landmarks._own_order``'s row length minus one)."""
    last = -1
    for k in range(shape.size):
        if shape[k] != 0.0:
            last = k
    return last if last > 1 else 1


@njit
def write_row(
    real: np.ndarray, index: np.ndarray, shape: np.ndarray, i: int,
    coeffs: np.ndarray,  # (m+1,) [c0, b_1, …, b_m]: the shape row gets b_1 … b_m
    variate: int, lo: float, hi: float, evidence: tuple[float, float],
    pivot: float, xi_var: float, model_var: float, fit_half: float, shift_slope: float,
    landmark_id: int, side: int, step: int, received: int,
) -> None:  # fmt: skip
    """Row ``i`` of a landmark table's buffers (room made) for a new landmark
    (``LandmarkTable.append``): its zero-padded shape, extent, η range, evidence and
    scalars, its id, variate, own order, face, step and received flag; stamp and uses 0."""
    row = shape[i]
    row[:] = 0.0
    row[1 : coeffs.size] = coeffs[1:]
    real[LO, i], real[HI, i] = lo, hi
    real[ETA_LO, i], real[ETA_HI, i] = eta_range(row, lo, hi)
    real[EV_LO, i], real[EV_HI, i] = evidence
    real[PIVOT, i], real[XI_VAR, i] = pivot, xi_var
    real[MODEL_VAR, i], real[FIT_HALF, i] = model_var, fit_half
    real[SHIFT_SLOPE, i] = shift_slope
    index[ID, i], index[VARIATE, i] = landmark_id, variate
    index[ORDER, i] = own_order(row)
    index[SIDE, i], index[CHANGED_AT, i], index[STAMP, i] = side, step, 0
    index[RECEIVED, i], index[USES, i] = received, 0


@njit
def set_extent(
    real: np.ndarray, index: np.ndarray, shape: np.ndarray, j: int, lo: float, hi: float
) -> None:
    """New extent [lo, hi] of landmark j (same shape): its η range follows, its stamp moves."""
    real[LO, j], real[HI, j] = lo, hi
    real[ETA_LO, j], real[ETA_HI, j] = eta_range(shape[j], lo, hi)
    index[STAMP, j] += 1


@njit
def facing_candidates(
    candidates: np.ndarray,  # (K,) landmark rows
    sides: np.ndarray,  # (n,) each landmark's seen face: +1 from +η, −1 from −η, 0 both/unknown
    variate: np.ndarray,  # (n,)
    ux: float,  # the beam's unit direction (frame 0)
    uy: float,
    out: np.ndarray,  # (≥ K,) int64 out: the rows kept, in order
) -> int:
    """The candidates a beam travelling along (ux, uy) can hit on their seen face, into
    ``out``; returns how many (``maintenance.observed_side``'s rule: a beam travelling
    towards +η comes from the −η side)."""
    k = 0
    for c in range(candidates.size):
        j = candidates[c]
        u_eta = uy if variate[j] == 1 else ux
        beam_side = -1 if u_eta > 0.0 else (1 if u_eta < 0.0 else 0)
        if sides[j] * beam_side < 0:
            continue
        out[k] = j
        k += 1
    return k


@njit
def associate_scan(
    mean: np.ndarray,  # (3+n(+n),) the predicted state
    cov: np.ndarray,
    ranges: np.ndarray,  # (B,) this step's readings (inf/nan: no return)
    angles: np.ndarray,  # (B,) beam angles
    step: int,  # this step's number (the points' stamp)
    rho: float,  # this step's thresholds ρ_k and σ_k
    sigma: float,
    params: np.ndarray,  # (N_PARAMS,)
    switches: np.ndarray,  # (N_SWITCHES,)
    fit_inverse: np.ndarray,  # (K+1, K+1, K+1)
    real: np.ndarray,  # the landmark table (n landmarks)
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    preal: np.ndarray,  # the stored points: room for B more
    pindex: np.ndarray,
    counters: np.ndarray,
    requests: np.ndarray,  # (B,) out: landmark id of each refit request
    good: np.ndarray,  # (B,) out: id of the landmark each beam updates, −1: none
) -> int:
    """One step's map association (``PolySlam``'s association stage), into the buffers:

    1. each beam with a return becomes a point (frame-0 position, direction, σ, weight
       1/‖P_{k|k−1}‖, the pose; ``fitting.store_beams``);
    2. candidates: the landmarks whose box lies within σ_k (with ``stretch_ends``, GAP_SPLIT
       when wider) of the points' box; per point the nearest by approximation error ε
       (``kernels.nearest_by_error``);
    3. per point, in beam order: ε ≤ ρ_k good; else, with ``stretch_ends``, a point continuing
       its nearest landmark past its end is *extended*; else ε ≤ σ_k joins that landmark's
       Q_bad (:func:`_add_bad`), else a cluster (:func:`_add_to_cluster`);
    4. each good or extended point past its landmark's extent that the continued curve explains
       stretches the extent (:func:`extend_to_hit`); with ``stretch_ends`` a good one it does
       not explain updates nothing.

    ``counters`` gets this step's refit and new-landmark requests (their points are held as
    ``REFIT``/``NEW``); returns how many extents changed."""
    n_beams = ranges.size
    good[:] = -1
    counters[N_REFIT] = 0
    counters[N_NEW] = 0
    points = np.empty((n_beams, preal.shape[0]))  # this step's points, real fields
    beam_of = np.empty(n_beams, dtype=np.int64)
    count = beam_returns(mean, cov, ranges, angles, params[P_RANGE_SIGMA], points, beam_of)
    if count == 0:
        return 0
    # candidates (PolySlam._association_candidates)
    box = np.empty(4)
    box[0], box[1], box[2], box[3] = points[0, X], points[0, X], points[0, Y], points[0, Y]
    for i in range(1, count):
        box[0], box[1] = _min(box[0], points[i, X]), _max(box[1], points[i, X])
        box[2], box[3] = _min(box[2], points[i, Y]), _max(box[3], points[i, Y])
    reach = math.sqrt(sigma) if switches[S_SQUARED] else sigma  # ε² ≤ σ_k there
    stretch = switches[S_STRETCH_ENDS] != 0
    if stretch:
        reach = _max(reach, GAP_SPLIT)
    reach = reach * (1.0 + 1e-9) + 1e-12  # ≥ the threshold despite rounding
    c0s = mean[3 : 3 + n]
    variate, order = index[VARIATE, :n], index[ORDER, :n]
    lo, hi = real[LO, :n], real[HI, :n]
    near = boxes(c0s, variate, lo, hi, real[ETA_LO : ETA_HI + 1, :n].T)
    candidates = boxes_near(near, box, reach)
    nearest, error = np.empty(count, dtype=np.int64), np.empty(count)
    xy = np.ascontiguousarray(points[:count, X : Y + 1])
    if switches[S_SEEN_FACES]:
        facing = np.empty(candidates.size, dtype=np.int64)
        sides = index[SIDE, :n]
        for i in range(count):  # per point, the landmarks whose seen face it can hit
            k = facing_candidates(candidates, sides, variate, points[i, UX], points[i, UY], facing)
            nearest_by_error(
                xy[i : i + 1], facing[:k], variate, order, shape[:n], lo, hi, c0s,
                switches[S_SQUARED] != 0, nearest[i : i + 1], error[i : i + 1],
            )  # fmt: skip
    else:
        nearest_by_error(
            xy, candidates, variate, order, shape[:n], lo, hi, c0s, switches[S_SQUARED] != 0,
            nearest, error,
        )  # fmt: skip
    row_of = np.full(count, -1, dtype=np.int64)  # landmark row of a good or extended point
    for i in range(count):
        j, eps, b = nearest[i], error[i], beam_of[i]
        p = points[i]
        if eps <= rho:
            good[b] = index[ID, j]
            row_of[i] = j
        elif (
            stretch
            and j >= 0
            and _continues_past_end(
                p[X], p[Y], j, n, mean, cov, step, params, switches, fit_inverse, real, index, shape
            )
        ):
            row_of[i] = j
        elif eps <= sigma:
            _add_bad(preal, pindex, counters, requests, p, b, step, index[ID, j],
                     switches[S_EPS_M])  # fmt: skip
        else:
            _add_to_cluster(
                preal, pindex, counters, p, b, step, params[P_CLUSTER_RADIUS],
                switches[S_LINK_CLUSTERS] != 0, switches[S_EPS_Z],
            )  # fmt: skip
    # extents (PolySlam._extend_extents)
    changed = 0
    for i in range(count):
        j = row_of[i]
        if j < 0 or _within_extent(points[i, X], points[i, Y], j, real, index):
            continue
        xi = _continued_xi(points[i, X], points[i, Y], j, real, index, shape, mean[3 + j],
                           params[P_RANGE_SIGMA])  # fmt: skip
        if not math.isnan(xi):
            extend_to_hit(real, index, shape, j, xi)
            changed += 1
        elif stretch:
            good[beam_of[i]] = -1  # its hit is not on the landmark
    return changed

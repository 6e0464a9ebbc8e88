"""Compiled kernels of the map exchange (:mod:`~polyslam_env.comms.alignment`).

:func:`match_walls` is the point-to-wall pairing of the transform refinement, point by point
in the numpy version's operations (``tests/comms/test_alignment.py`` holds that version as the
oracle and checks the two bit for bit); :func:`gauss_newton_terms` is one whole iteration of
the refinement up to its matrix products and solve, on :func:`near_chains` (the chains within
each wall's reach) and :func:`match_walls` (its numpy form is the oracle in the same tests);
:func:`gauss_newton` is all the iterations, with the products and the 3 × 3 solve in the
operations of the OpenBLAS kernels numpy called (:func:`transposed_product`,
:func:`transposed_times`, :func:`times3`, :func:`solve3`; checked against numpy's in the same
tests); :func:`reach_boxes` and :func:`normal_variances` are
the refinement's per-wall bounds and weights, in the operations of ``Polynomial.max_slope``,
``map_kernels.eta_range`` and ``exchange.normal_variance`` (oracles in the same tests).
:func:`unit_tangents`, :func:`frame_chain`, :func:`received_geometry` and
:func:`variance_floor` are a received chain's geometry in the receiver's frame, in the floats
of the numpy they replaced (``np.gradient``, BLAS's products, ``np.einsum``; the numpy
versions are the oracles in ``tests/comms/reference_geometry.py``).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import fma, njit, sum_like_numpy
from polyslam_env.slam.fit_kernels import fit_points
from polyslam_env.slam.fitting import J_ROT
from polyslam_env.slam.kernels import boxes_near, horner
from polyslam_env.slam.map_kernels import eta_range


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
    (``alignment._refine_from``'s pairing, through :func:`gauss_newton_terms`)."""
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
                if not abs(n0 * tangents[i, 0] + n1 * tangents[i, 1]) <= sin_max:
                    continue  # not the same direction (tested first: nothing below is needed)
                r = (eta - _horner(c, xi)) / math.sqrt(1.0 + slope * slope)
                for j in range(3):
                    g[j] = n0 * dp_dt[i, 0, j] + n1 * dp_dt[i, 1, j]
                quad = 0.0
                for u in range(3):
                    for v in range(3):
                        quad += g[u] * cov_t[u, v] * g[v]
                pred = math.sqrt(quad + point_var[i] + wall_var[w])
                score = abs(r) / pred
                if score <= gate and score < best[i]:
                    best[i], residual[i], wall_of[i] = score, r, w
                    grad[i, 0], grad[i, 1], grad[i, 2] = g[0], g[1], g[2]
    return best, residual, grad, wall_of


@njit
def near_chains(reach: np.ndarray, p: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(W, K) whether chain k of ``p`` (N, 2) (rows ``starts[k]:starts[k+1]``, each at least one)
    has a bounding box that meets wall w's ``reach`` box [x_lo, x_hi, y_lo, y_hi] (W, 4)
    (:func:`reach_boxes`): only those chains can pair with it (``alignment._refine_from``, through
    :func:`gauss_newton_terms`; comparisons only, the answers of its numpy form, the oracle in
    ``tests/comms/test_alignment.py``)."""
    n_chains = starts.size - 1
    box = np.empty((n_chains, 4))
    for k in range(n_chains):
        box[k] = bounding_box(p, starts[k], starts[k + 1])
    meets = np.empty((reach.shape[0], n_chains), dtype=np.bool_)
    for w in range(reach.shape[0]):
        for k in range(n_chains):
            meets[w, k] = (
                box[k, 0] <= reach[w, 1] and box[k, 1] >= reach[w, 0]
                and box[k, 2] <= reach[w, 3] and box[k, 3] >= reach[w, 2]
            )  # fmt: skip
    return meets


@njit
def bounding_box(p: np.ndarray, first: int, end: int) -> np.ndarray:
    """[x_min, x_max, y_min, y_max] of rows ``first:end`` (at least one) of ``p`` (N, 2), NaN
    where a coordinate is (as numpy's ``min`` and ``max``)."""
    out = np.empty(4)
    for axis in range(2):
        low = high = p[first, axis]
        for i in range(first + 1, end):
            value = p[i, axis]
            if low == low and not value >= low:  # smaller, or NaN (numpy's min keeps it)
                low = value
            if high == high and not value <= high:
                high = value
        out[2 * axis], out[2 * axis + 1] = low, high
    return out


@njit
def gauss_newton_terms(
    q: np.ndarray,  # (N, 2) the received chains' points, sender frame, one after another
    tangents_q: np.ndarray,  # (N, 2) their unit tangents (:func:`chain_tangents`)
    starts: np.ndarray,  # (K+1,) int64: chain k is rows starts[k]:starts[k+1]
    chain_of: np.ndarray,  # (N,) int64: each point's chain
    t: np.ndarray,  # (3,) the current transform
    rot: np.ndarray,  # (2, 2) R(t[2])
    reach: np.ndarray,  # (W, 4) the walls' reach boxes (:func:`reach_boxes`)
    variate: np.ndarray,  # (W,) int64, 1 or 2
    coeffs: np.ndarray,  # (W, M+1) zero-padded, current c0 first
    extent: np.ndarray,  # (W, 2) lo, hi
    cov_t: np.ndarray,  # (3, 3)
    point_var: np.ndarray,  # (N,)
    wall_var: np.ndarray,  # (W,)
    gate: float,  # GATE_SIGMAS
    sin_max: float,  # √(1 − cos²(MAX_ANGLE))
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """One Gauss–Newton iteration of ``alignment._refine_from`` up to its products: the
    points under T (:func:`frame_chain`), their tangents turned by R (as numpy's matmul),
    the chains near each wall (:func:`near_chains`), the pairing (:func:`match_walls`), and
    for the M points that pair their residuals (M,), gradients (M, 3), those times the
    weights, the weights (M,) 1 / ((point_var + wall_var) · n), n the points of the same
    (chain, wall) pair (each pair counts once), and the number of pairs; M = 0: none."""
    n = q.shape[0]
    p, dp_dt = frame_chain(q, t, rot)
    tangents = np.empty((n, 2))
    _times_transposed(tangents_q, rot, tangents)
    meets = near_chains(reach, p, starts)
    _, residual_all, grad_all, wall_of = match_walls(
        p, dp_dt, tangents, variate, coeffs, extent, cov_t, point_var, wall_var, meets, starts,
        gate, sin_max,
    )  # fmt: skip
    n_walls = coeffs.shape[0]
    m = 0
    for i in range(n):
        if wall_of[i] >= 0:
            m += 1
    residual, grad, pair = np.empty(m), np.empty((m, 3)), np.empty(m, dtype=np.int64)
    k = 0
    n_keys = 0
    for i in range(n):
        if wall_of[i] >= 0:
            residual[k] = residual_all[i]
            grad[k, 0], grad[k, 1], grad[k, 2] = grad_all[i, 0], grad_all[i, 1], grad_all[i, 2]
            pair[k] = chain_of[i] * n_walls + wall_of[i]
            n_keys = max(n_keys, pair[k] + 1)
            k += 1
    counts = np.zeros(n_keys, dtype=np.int64)  # np.bincount
    for k in range(m):
        counts[pair[k]] += 1
    n_pairs = 0
    for key in range(n_keys):
        if counts[key] > 0:
            n_pairs += 1
    weight, weighted = np.empty(m), np.empty((m, 3))
    k = 0
    for i in range(n):
        if wall_of[i] >= 0:
            pair_var = point_var[i] + wall_var[wall_of[i]]
            weight[k] = 1.0 / (pair_var * float(counts[pair[k]]))
            for j in range(3):
                weighted[k, j] = grad[k, j] * weight[k]
            k += 1
    return residual, grad, weighted, weight, n_pairs


@njit
def gauss_newton(
    q: np.ndarray,  # (N, 2) the received chains' points, sender frame, one after another
    tangents_q: np.ndarray,  # (N, 2) their unit tangents (:func:`chain_tangents`)
    starts: np.ndarray,  # (K+1,) int64: chain k is rows starts[k]:starts[k+1]
    chain_of: np.ndarray,  # (N,) int64: each point's chain
    start: np.ndarray,  # (3,) the transform the iteration starts from
    t0: np.ndarray,  # (3,) the prior's mean
    info_prior: np.ndarray,  # (3, 3) the prior's information Σ_T⁻¹
    reach: np.ndarray,  # (W, 4) the walls' reach boxes (:func:`reach_boxes`)
    variate: np.ndarray,  # (W,) int64, 1 or 2
    coeffs: np.ndarray,  # (W, M+1) zero-padded, current c0 first
    extent: np.ndarray,  # (W, 2) lo, hi
    cov_t: np.ndarray,  # (3, 3) the prior's covariance Σ_T
    point_var: np.ndarray,  # (N,)
    wall_var: np.ndarray,  # (W,)
    gate: float,  # GATE_SIGMAS
    sin_max: float,  # √(1 − cos²(MAX_ANGLE))
    iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, bool]:
    """``alignment._refine_from``'s Gauss–Newton iterations from ``start``: each
    :func:`gauss_newton_terms`, then info = Σ_T⁻¹ + (wg)ᵀ g, rhs = (−wg)ᵀ r − Σ_T⁻¹ (t − t0)
    and t += info⁻¹ rhs, stopping once every |step| < 1e-9, in the floats numpy computed them
    with (OpenBLAS's gemm, gemv and gesv: :func:`transposed_product`,
    :func:`transposed_times`, :func:`times3`, :func:`solve3`; R(θ) from libm's cos and sin, as
    numpy's). Returns t, the last info, the last iteration's residuals and weights, its
    number of pairs, and False when that matrix was singular (numpy's solve raised); no
    residuals: an iteration paired nothing."""
    t = start.copy()
    info = info_prior.copy()
    residual, weight = np.empty(0), np.empty(0)
    n_pairs = 0
    d = np.empty(3)
    rot = np.empty((2, 2))
    for _ in range(iterations):
        c, s = math.cos(t[2]), math.sin(t[2])
        rot[0, 0], rot[0, 1], rot[1, 0], rot[1, 1] = c, -s, s, c
        residual, grad, weighted, weight, n_pairs = gauss_newton_terms(
            q, tangents_q, starts, chain_of, t, rot, reach, variate, coeffs, extent, cov_t,
            point_var, wall_var, gate, sin_max,
        )  # fmt: skip
        if residual.size == 0:
            break
        info = info_prior + transposed_product(weighted, grad)
        for j in range(3):
            d[j] = t[j] - t0[j]
        rhs = transposed_times(-weighted, residual) - times3(info_prior, d)
        step, regular = solve3(info, rhs)
        if not regular:
            return t, info, residual, weight, n_pairs, False
        t = t + step
        if abs(step[0]) < 1e-9 and abs(step[1]) < 1e-9 and abs(step[2]) < 1e-9:
            break
    return t, info, residual, weight, n_pairs, True


@njit
def transposed_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a.T @ b`` (3, 3) of ``a`` and ``b`` (M, 3) as numpy's matmul computes it through
    OpenBLAS's gemm (Haswell kernels): per output a chain of fused multiply-adds along M from
    0, M split as the gemm driver splits it (blocks of 256; a rest between 256 and 512 in two
    halves rounded up to 4), the blocks' sums added in order."""
    out = np.empty((3, 3))
    m = a.shape[0]
    for i in range(3):
        for j in range(3):
            total = 0.0
            first = 0
            while first < m:
                size = m - first
                if size >= 512:
                    size = 256
                elif size > 256:
                    size = ((size // 2 + 3) // 4) * 4
                acc = 0.0
                for k in range(first, first + size):
                    acc = fma(a[k, i], b[k, j], acc)
                total = acc if first == 0 else total + acc
                first += size
            out[i, j] = total
    return out


@njit
def transposed_times(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``a.T @ v`` (3,) of ``a`` (M, 3) and ``v`` (M,) as numpy's matmul computes it through
    OpenBLAS's gemv (a 3-row matrix: per output the products rounded, added two by two onto
    a running sum from 0 over each four, the rest one by one)."""
    out = np.empty(3)
    m = v.size
    for i in range(3):
        acc = 0.0
        k = 0
        while k < m - m % 4:
            acc = acc + (a[k, i] * v[k] + a[k + 1, i] * v[k + 1])
            acc = acc + (a[k + 2, i] * v[k + 2] + a[k + 3, i] * v[k + 3])
            k += 4
        while k < m:
            acc = acc + a[k, i] * v[k]
            k += 1
        out[i] = 0.0 + acc
    return out


@njit
def times3(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``m @ v`` (3,) of ``m`` (3, 3) and ``v`` (3,) as numpy's matmul computes it through
    OpenBLAS's gemv: per output the second product rounded, the first and then the third
    fused onto it (found by testing every order and fusion)."""
    out = np.empty(3)
    for j in range(3):
        out[j] = 0.0 + fma(m[j, 2], v[2], fma(m[j, 0], v[0], m[j, 1] * v[1]))
    return out


@njit
def solve3(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """``np.linalg.solve(a, b)`` of ``a`` (3, 3) and ``b`` (3,) in the operations of
    OpenBLAS's gesv: :func:`_lu3`, then the row swaps, the unit-lower and the upper
    triangular solves (trsv: column by column, the diagonal divided). False (and no answer)
    when a pivot is zero: numpy raises."""
    lu, pivots, regular = _lu3(a)
    x = b.copy()
    if not regular:
        return x, False
    for i in range(3):
        p = pivots[i]
        if p != i:
            x[i], x[p] = x[p], x[i]
    for i in range(3):
        for k in range(i + 1, 3):
            x[k] = x[k] + (-x[i]) * lu[k, i]
    for i in range(2, -1, -1):
        x[i] /= lu[i, i]
        for k in range(i):
            x[k] = x[k] + (-x[i]) * lu[k, i]
    return x, True


@njit
def inverse3(a: np.ndarray) -> tuple[np.ndarray, bool]:
    """``np.linalg.inv(a)`` of ``a`` (3, 3) in the operations of OpenBLAS's gesv on the
    identity: :func:`_lu3`, the row swaps, then column by column the unit-lower solve (trsm:
    fused multiply-adds) and the upper one (the diagonal's reciprocal multiplied). False
    (and no answer) when a pivot is zero: numpy raises."""
    lu, pivots, regular = _lu3(a)
    x = np.eye(3)
    if not regular:
        return x, False
    for i in range(3):
        p = pivots[i]
        if p != i:
            for c in range(3):
                x[i, c], x[p, c] = x[p, c], x[i, c]
    for c in range(3):
        for i in range(3):
            for k in range(i + 1, 3):
                x[k, c] = fma(-x[i, c], lu[k, i], x[k, c])
        for i in range(2, -1, -1):
            x[i, c] = x[i, c] * (1.0 / lu[i, i])
            for k in range(i):
                x[k, c] = x[k, c] + (-x[i, c]) * lu[k, i]
    return x, True


@njit
def _lu3(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """OpenBLAS's getf2 on ``a`` (3, 3): LU with partial pivoting column by column (the
    earlier pivots and unit-lower columns applied to column j as dot products, the largest
    |entry| from j down as the pivot, the first of ties, the column below it times the
    pivot's reciprocal). The factors (unit lower below the diagonal), the pivot rows, and
    False when a pivot is zero."""
    lu = a.copy()
    pivots = np.empty(3, dtype=np.int64)
    for j in range(3):
        for i in range(j):
            p = pivots[i]
            if p != i:
                lu[i, j], lu[p, j] = lu[p, j], lu[i, j]
        for i in range(1, j):
            dot = 0.0
            for k in range(i):
                dot = dot + lu[i, k] * lu[k, j]
            lu[i, j] -= dot
        if j > 0:
            for i in range(j, 3):
                dot = 0.0
                for k in range(j):
                    dot = dot + lu[i, k] * lu[k, j]
                lu[i, j] = lu[i, j] + (-1.0) * dot
        p = j
        largest = abs(lu[j, j])
        for i in range(j + 1, 3):
            if abs(lu[i, j]) > largest:
                largest, p = abs(lu[i, j]), i
        pivots[j] = p
        pivot = lu[p, j]
        if pivot == 0.0:
            return lu, pivots, False
        if p != j:
            for k in range(j + 1):
                lu[j, k], lu[p, k] = lu[p, k], lu[j, k]
        reciprocal = 1.0 / pivot
        for i in range(j + 1, 3):
            lu[i, j] *= reciprocal
    return lu, pivots, True


@njit
def prior_information(cov: np.ndarray) -> tuple[np.ndarray, bool]:
    """Σ⁻¹ (3, 3) of ``cov`` (3, 3) as ``alignment._refine_from`` had numpy compute it:
    L⁻ᵀ L⁻¹ with L its Cholesky factor (OpenBLAS's potf2: per column the squares of the row
    so far summed, the root, the column below it less its rows' products and times the
    root's reciprocal), L⁻¹ by :func:`inverse3`, the product by :func:`transposed_product`.
    False when Σ is not positive definite (numpy raises)."""
    lower = np.zeros((3, 3))
    for j in range(3):
        dot = 0.0
        for k in range(j):
            dot = dot + lower[j, k] * lower[j, k]
        diagonal = cov[j, j] - dot
        if diagonal <= 0.0:
            return lower, False
        diagonal = math.sqrt(diagonal)
        lower[j, j] = diagonal
        reciprocal = 1.0 / diagonal
        for i in range(j + 1, 3):
            below = cov[i, j]
            if j > 0:
                dot = 0.0
                for k in range(j):
                    dot = dot + lower[i, k] * lower[j, k]
                below = below + (-1.0) * dot
            lower[i, j] = below * reciprocal
    lower_inv, regular = inverse3(lower)
    if not regular:
        return lower, False
    return transposed_product(lower_inv, lower_inv), True


@njit
def max_slope(coeffs: np.ndarray, lo: float, hi: float) -> float:
    """max |dη/dξ| over [lo, hi] of a polynomial of at most 4 coefficients, in the operations
    of ``Polynomial.max_slope`` (the ends, and a cubic's one turn of the slope inside)."""
    at = np.empty(3)
    at[0], at[1] = lo, hi
    n = 2
    if coeffs.size == 4:
        rate = 2.0 * (3.0 * coeffs[3])  # p'' = 2b₂ + rate·ξ
        if rate != 0.0:
            turn = -(2.0 * coeffs[2]) / rate
            if lo < turn < hi:
                at[2] = turn
                n = 3
    deriv = _derivative(coeffs, 1)
    out = abs(_horner(deriv, at[0]))
    for k in range(1, n):
        value = abs(_horner(deriv, at[k]))
        if value > out or value != value:  # np.max: the largest, nan if any is
            out = value
    return out


@njit
def reach_boxes(
    order: np.ndarray,  # (W,) int64: wall w's coefficients are coeffs[w, : order[w] + 1]
    variate: np.ndarray,  # (W,) int64, 1 or 2
    coeffs: np.ndarray,  # (W, M+1) zero-padded, current c0 first
    extent: np.ndarray,  # (W, 2) lo, hi
    slopes: np.ndarray,  # (W,) max |B'| where known (orders ≥ 4), −1: computed here
    wall_var: np.ndarray,  # (W,)
    cov_t: np.ndarray,  # (3, 3) Σ_T
    q: np.ndarray,  # (N, 2) the received points, sender frame
    point_var: np.ndarray,  # (N,)
    gate: float,  # GATE_SIGMAS
) -> np.ndarray:
    """``alignment.wall_reach``'s boxes (W, 4), wall by wall in its operations, after its
    bound of gᵀΣ_T g + point_var: tr(Σ_T)(1 + max |q|²) + max point_var (numpy's floats:
    the trace summed in order, each |q|² as its two squares added, the maxima from 0 and NaN
    if any is)."""
    largest_q = 0.0
    for i in range(q.shape[0]):
        value = q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1]
        if value > largest_q or value != value:
            largest_q = value
    largest_var = 0.0
    for i in range(point_var.size):
        if point_var[i] > largest_var or point_var[i] != point_var[i]:
            largest_var = point_var[i]
    worst = (cov_t[0, 0] + cov_t[1, 1] + cov_t[2, 2]) * (1.0 + largest_q) + largest_var
    out = np.empty((coeffs.shape[0], 4))
    for w in range(coeffs.shape[0]):
        c = coeffs[w, : order[w] + 1]
        shape = c.copy()
        shape[0] = 0.0
        lo, hi = extent[w, 0], extent[w, 1]
        b_lo, b_hi = eta_range(shape, lo, hi)
        slope = slopes[w] if slopes[w] >= 0.0 else max_slope(c, lo, hi)
        reach = gate * math.sqrt((worst + wall_var[w]) * (1.0 + slope * slope)) + 1e-9
        eta_lo, eta_hi = c[0] + b_lo - reach, c[0] + b_hi + reach
        if variate[w] == 1:
            out[w, 0], out[w, 1], out[w, 2], out[w, 3] = lo, hi, eta_lo, eta_hi
        else:
            out[w, 0], out[w, 1], out[w, 2], out[w, 3] = eta_lo, eta_hi, lo, hi
    return out


@njit
def normal_variances(
    order: np.ndarray,  # (W,) int64
    coeffs: np.ndarray,  # (W, M+1) zero-padded
    extent: np.ndarray,  # (W, 2) lo, hi
    c0_var: np.ndarray,  # (W,)
) -> np.ndarray:
    """``exchange.normal_variance`` of each wall (W,): var(c0) / (1 + B'²) at the middle of
    the extent, in its operations."""
    out = np.empty(coeffs.shape[0])
    for w in range(coeffs.shape[0]):
        out[w] = _normal_variance(coeffs[w, : order[w] + 1], extent[w, 0], extent[w, 1], c0_var[w])
    return out


@njit
def _normal_variance(coeffs: np.ndarray, lo: float, hi: float, c0_var: float) -> float:
    """``exchange.normal_variance`` of one wall: var(c0) / (1 + B'²), B' at the middle of
    [lo, hi], in its operations."""
    slope = _horner(_derivative(coeffs, 1), 0.5 * (lo + hi))
    return c0_var / (1.0 + slope * slope)


@njit
def better_cover(
    xy: np.ndarray,  # (N, 2) a received piece's points in the receiver's frame
    rows: np.ndarray,  # (k,) int64: the receiver's landmarks of the same wall
    limit: float,  # the piece's normal variance, with the round-off margin
    variate: np.ndarray,  # (n,) int64: the receiver's table's columns …
    shape: np.ndarray,  # (n, M+1)
    order: np.ndarray,  # (n,) int64 each shape's own order
    size: np.ndarray,  # (n,) int64 each polynomial's number of coefficients
    c0: np.ndarray,  # (n,) the current c0s
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    cov: np.ndarray,  # (S, S) the receiver's covariance (c0 of row j at 3 + j)
    reach: float,
) -> tuple[int, np.ndarray]:
    """Rule 1 of a received piece's fusion (``RendezvousExchange._fuse``) in one call: how
    many of the landmarks ``rows`` are *better* (their normal-offset variance,
    ``exchange.normal_variance`` of their shape and var(c0), at most ``limit``), and (N,)
    which points those cover: within a landmark's extent (its ξ) and within ``reach`` of its
    curve along η (the readable form is ``covered_points`` in ``tests/comms/
    reference_geometry.py``, its value in ``polyval``'s operations)."""
    covered = np.zeros(xy.shape[0], dtype=np.bool_)
    better = 0
    for r in rows:
        k = 3 + r
        if not _normal_variance(shape[r, : order[r] + 1], lo[r], hi[r], cov[k, k]) <= limit:
            continue
        better += 1
        c = shape[r, : size[r]].copy()
        c[0] = c0[r]
        for i in range(xy.shape[0]):
            xi, eta = (xy[i, 0], xy[i, 1]) if variate[r] == 1 else (xy[i, 1], xy[i, 0])
            if xi >= lo[r] and xi <= hi[r] and abs(eta - _horner(c, xi)) <= reach:
                covered[i] = True
    return better, covered


@njit
def table_walls(
    rows: np.ndarray,  # (W,) int64: the table's rows to take, in order
    order: np.ndarray,  # (n,) int64: each row's own order
    variate: np.ndarray,  # (n,) int64
    shape: np.ndarray,  # (n, M+1) [0, b_1, …, b_M]
    c0s: np.ndarray,  # (n,) current c0s
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    cov: np.ndarray,  # (3+…, 3+…) the state's covariance: row r's c0 at 3 + r
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``rows`` of a landmark table as ``alignment.WallArrays`` (order, variate,
    coefficients at the widest order among them (at least 2 columns) with the current c0
    first, extent (W, 2)) and their normal variances (:func:`normal_variances` of their c0
    variances): ``exchange._table_walls`` and its walls' variances in one call, copies only."""
    n_rows = rows.size
    width = 2
    for k in range(n_rows):
        width = max(width, order[rows[k]] + 1)
    out_order = np.empty(n_rows, dtype=np.int64)
    out_variate = np.empty(n_rows, dtype=np.int64)
    coeffs = np.empty((n_rows, width))
    extent = np.empty((n_rows, 2))
    c0_var = np.empty(n_rows)
    for k in range(n_rows):
        r = rows[k]
        out_order[k], out_variate[k] = order[r], variate[r]
        coeffs[k, 0] = c0s[r]
        for j in range(1, width):
            coeffs[k, j] = shape[r, j]
        extent[k, 0], extent[k, 1] = lo[r], hi[r]
        c0_var[k] = cov[3 + r, 3 + r]
    wall_var = normal_variances(out_order, coeffs, extent, c0_var)
    return out_order, out_variate, coeffs, extent, wall_var


@njit
def _no_curvature(coeffs: np.ndarray) -> bool:
    """Whether no coefficient past the slope of ``coeffs`` [c0, b_1, …] is nonzero (a NaN
    is): a line (``alignment.is_straight_wall``'s shape test)."""
    for j in range(2, coeffs.size):
        if coeffs[j] != 0.0:
            return False
    return True


@njit
def longest_straight(shape: np.ndarray, lo: np.ndarray, hi: np.ndarray, min_length: float) -> int:
    """The row of the longest straight landmark of a table's columns ``shape`` (n, M+1), ``lo``
    and ``hi`` (n,): no coefficient past the slope nonzero (NaN counts, as numpy's ``any``)
    and at least ``min_length`` long; the first of ties, −1 for none
    (``exchange.RendezvousExchange._off_square``'s reference wall, numpy's argmax over those
    lengths in one pass)."""
    best, best_length = -1, 0.0
    for k in range(lo.size):
        length = hi[k] - lo[k]
        if not length >= min_length:
            continue
        if _no_curvature(shape[k]) and (best < 0 or length > best_length):
            best, best_length = k, length
    return best


@njit
def kept_runs(keep: np.ndarray, xy: np.ndarray, min_length: float) -> np.ndarray:
    """(K, 2) [first, end) rows of the maximal runs of ``keep`` (N,) bool along a chain
    ``xy`` (N, 2) whose length (the sum of the run's own steps ‖p_{i+1} − p_i‖, in numpy's
    summation order) is at least ``min_length`` (``exchange.uncovered_runs``)."""
    n = keep.size
    step = np.empty(max(n - 1, 0))
    for i in range(n - 1):
        dx, dy = xy[i + 1, 0] - xy[i, 0], xy[i + 1, 1] - xy[i, 1]
        step[i] = math.sqrt(dx * dx + dy * dy)
    out = np.empty((n // 2 + 1, 2), dtype=np.int64)
    k = 0
    i = 0
    while i < n:
        if not keep[i]:
            i += 1
            continue
        first = i
        while i < n and keep[i]:
            i += 1
        if sum_like_numpy(step, first, i - 1 - first) >= min_length:
            out[k, 0], out[k, 1] = first, i
            k += 1
    return out[:k]


# -- the chain of a received polynomial (comms/polyline.py, orders ≤ 3) -------------------------
@njit
def _derivative(coeffs: np.ndarray, derivative: int) -> np.ndarray:
    """The coefficients ``slam.polynomial.polyval`` evaluates for a ``derivative``: j·c_j
    that many times (``c[:1]·0`` past the order), for :func:`_horner`."""
    c = coeffs.copy()
    if derivative >= c.size:
        return c[:1] * 0.0
    for _ in range(derivative):
        c = c[1:] * np.arange(1, c.size).astype(np.float64)
    return c


@njit
def _linspace(start: float, stop: float, num: int) -> np.ndarray:
    """``np.linspace(start, stop, num)`` in its operations (i·step + start, the last = stop;
    a zero step as (i/div)·delta + start)."""
    out = np.empty(num)
    div = num - 1
    delta = stop - start
    if div > 0:
        step = delta / div
        for i in range(num):
            out[i] = (float(i) / div * delta if step == 0.0 else float(i) * step) + start
        out[num - 1] = stop
    else:
        for i in range(num):
            out[i] = float(i) * delta + start
    return out


@njit
def _point(variate: int, xi: float, eta: float) -> tuple[float, float]:
    return (xi, eta) if variate == 1 else (eta, xi)


@njit
def _initial_knots(variate: int, coeffs: np.ndarray, lo: float, hi: float, sagitta: float,
                   dense: int) -> np.ndarray:  # fmt: skip
    """``polyline._initial_knots``: ξ knots spaced so each chord's sagitta κL²/8 is about
    ``sagitta``.

    A line (no coefficient past the slope, and 1 + slope² finite) has no curvature anywhere:
    its curvature grid would give κ = 0 at every point (p'' is +0 in Horner's scheme), a zero
    integral and the two ends as knots, which are returned without it (most received walls
    are straight, and the grid was most of their chain's time)."""
    if _no_curvature(coeffs) and coeffs.size > 1 and math.isfinite(1.0 + coeffs[1] * coeffs[1]):
        out = np.empty(2)
        out[0], out[1] = lo, hi
        return out
    xi = _linspace(lo, hi, dense)
    density = np.empty(dense)
    first, second = _derivative(coeffs, 1), _derivative(coeffs, 2)
    for i in range(dense):
        d1 = _horner(first, xi[i])
        d2 = _horner(second, xi[i])
        speed = math.sqrt(1.0 + d1 * d1)
        kappa = abs(d2) / math.pow(speed, 3.0)  # as numpy's speed**3
        density[i] = math.sqrt(kappa / (8.0 * sagitta)) * speed
    cum = np.zeros(dense)
    for i in range(1, dense):
        cum[i] = cum[i - 1] + 0.5 * (density[i] + density[i - 1]) * (xi[i] - xi[i - 1])
    total = cum[dense - 1]
    n = max(math.ceil(total), 1)
    if total <= 0:
        out = np.empty(2)
        out[0], out[1] = lo, hi
        return out
    knots = np.interp(_linspace(0.0, total, n + 1), cum, xi)
    knots[0], knots[-1] = lo, hi
    return knots


@njit
def _chord_error(variate: int, coeffs: np.ndarray, c: np.ndarray, a: float, b: float,
                 samples: np.ndarray) -> float:  # fmt: skip
    """Largest distance from the curve on [a, b] to its chord: ``_max_perpendicular_cubic``
    (the critical points of the vertical error, closed form) against ``_sampled_segment_
    distance`` (``samples``: the interior fractions of the chord, end effects); ``c`` is
    ``coeffs`` zero-padded to a cubic's four."""
    ya, yb = _horner(coeffs, a), _horner(coeffs, b)
    s = (yb - ya) / (b - a)
    d0, d1, d2 = c[1] - s, 2.0 * c[2], 3.0 * c[3]
    big = 1e-12 * max(max(abs(d0), abs(d1)), abs(d2))
    quad = abs(d2) > big
    line = not quad and abs(d1) > big
    r0, r1 = np.nan, np.nan
    if quad:
        disc = d1 * d1 - 4.0 * d2 * d0
        if disc >= 0.0:
            q = -0.5 * (d1 + math.copysign(math.sqrt(disc), d1))
            r0 = q / d2
            r1 = d0 / q if q != 0.0 else r0
    elif line:
        r0 = -d0 / d1
    worst = 0.0
    for k in range(2):
        root = r0 if k == 0 else r1
        crit = root if (root > a and root < b) else a  # a: zero error, as no critical point
        err = abs(_horner(coeffs, crit) - (ya + s * (crit - a)))
        worst = err if k == 0 else max(worst, err)
    perp = worst / math.hypot(1.0, s)
    # the sampled check: curve points against the chord segment
    sx, sy = _point(variate, a, ya)
    ex, ey = _point(variate, b, yb)
    abx, aby = ex - sx, ey - sy
    denom = max(abx * abx + aby * aby, 1e-300)
    far = 0.0
    for k in range(samples.size):
        xi = a + (b - a) * samples[k]
        px, py = _point(variate, xi, _horner(coeffs, xi))
        u = min(max(((px - sx) * abx + (py - sy) * aby) / denom, 0.0), 1.0)
        dx, dy = px - (sx + u * abx), py - (sy + u * aby)
        dist = math.sqrt(dx * dx + dy * dy)
        far = dist if k == 0 else max(far, dist)
    return max(perp, far)


@njit
def chain(variate: int, coeffs: np.ndarray, lo: float, hi: float, chord_tol: float,
          sagitta: float, dense: int, check_samples: int, spacing: float,
          max_vertices: int) -> np.ndarray:  # fmt: skip
    """``polyline_points(piecewise_linear(poly, chord_tol), spacing)`` for orders ≤ 3 in one
    call: the chain's points (N, 2) every ``spacing`` or less, bit for bit (the numpy version
    is the oracle in ``tests/comms/test_polyline.py``). ``sagitta``, ``dense`` and
    ``check_samples`` are ``polyline``'s aim × tolerance, curvature grid and chord samples."""
    if hi == lo:
        xi = np.empty(2)
        xi[0], xi[1] = lo, hi
    else:
        xi = _initial_knots(variate, coeffs, lo, hi, sagitta, dense)
        samples = _linspace(0.0, 1.0, check_samples)[1:-1]
        padded = np.zeros(4)
        padded[: coeffs.size] = coeffs
        while True:
            bad = np.zeros(xi.size - 1, dtype=np.bool_)
            n_bad = 0
            for i in range(xi.size - 1):
                bad[i] = (
                    _chord_error(variate, coeffs, padded, xi[i], xi[i + 1], samples) > chord_tol
                )
                n_bad += bad[i]
            if n_bad == 0:
                break
            finer = np.empty(xi.size + n_bad)
            k = 0
            for i in range(xi.size):
                finer[k] = xi[i]
                k += 1
                if i < xi.size - 1 and bad[i]:
                    finer[k] = 0.5 * (xi[i] + xi[i + 1])
                    k += 1
            xi = finer
            if xi.size > max_vertices:
                raise RuntimeError("piecewise_linear: more vertices needed than allowed")
    # polyline_points: the vertices, those after a zero-length chord dropped, by arc length
    n_v = xi.size
    vx, vy = np.empty(n_v), np.empty(n_v)
    arc = np.empty(n_v)
    vx[0], vy[0] = _point(variate, xi[0], _horner(coeffs, xi[0]))
    arc[0] = 0.0
    kept = 1
    last_x, last_y = vx[0], vy[0]  # the previous vertex, kept or not
    for i in range(1, n_v):
        px, py = _point(variate, xi[i], _horner(coeffs, xi[i]))
        dx, dy = px - last_x, py - last_y
        seg = math.sqrt(dx * dx + dy * dy)
        last_x, last_y = px, py
        if seg > 0:
            vx[kept], vy[kept] = px, py
            arc[kept] = arc[kept - 1] + seg
            kept += 1
    if arc[kept - 1] == 0:
        out = np.empty((1, 2))
        out[0, 0], out[0, 1] = vx[0], vy[0]
        return out
    total = arc[kept - 1]
    n = math.ceil(total / spacing) + 1
    targets = _linspace(0.0, total, n)
    out = np.empty((n, 2))
    out[:, 0] = np.interp(targets, arc[:kept], vx[:kept])
    out[:, 1] = np.interp(targets, arc[:kept], vy[:kept])
    return out


@njit
def covered_by_walls(
    xy: np.ndarray,  # (N, 2) a received chain in the receiver's frame
    normals: np.ndarray,  # (N, 2) its unit normals
    rows: np.ndarray,  # (W,) int64: the walls to test, rows of the arrays below
    variate: np.ndarray,  # (n,) int64, 1 or 2
    shape: np.ndarray,  # (n, M+1) zero-padded coefficients (c0 from c0s)
    c0s: np.ndarray,  # (n,) each wall's current c0
    lo: np.ndarray,  # (n,) extents
    hi: np.ndarray,
    cov: np.ndarray,  # (3+n, 3+n) the state's covariance: var(c0) of row w at [3+w, 3+w]
    max_var: float,  # a wall counts only if its normal variance is at most this
    reach: float,  # m, γ_M
    cos_max: float,  # cos of the merge test's angle
    min_overlap: float,  # m, merge_min_overlap
) -> np.ndarray:
    """(N,) True where a chain point lies on one of the walls ``rows`` whose normal variance
    var(c0)/(1 + B'²) (B' at the middle of its extent) is at most ``max_var``: inside the
    wall's extent, within ``reach`` of it along η, the two normals within the merge test's
    angle, on a run of such points at least ``min_overlap`` long (the sum of the steps between
    its points) (:func:`received_cover`, reading a landmark table's columns; the
    oracle is in ``tests/comms/test_exchange.py``)."""
    n_pts = xy.shape[0]
    out = np.zeros(n_pts, dtype=np.bool_)
    on = np.zeros(n_pts, dtype=np.bool_)
    step = np.zeros(max(n_pts - 1, 0))
    for i in range(n_pts - 1):
        dx, dy = xy[i + 1, 0] - xy[i, 0], xy[i + 1, 1] - xy[i, 1]
        step[i] = math.sqrt(dx * dx + dy * dy)
    width = shape.shape[1]
    deriv = np.zeros(max(width - 1, 1))
    c = np.empty(width)
    for w in rows:
        c[:] = shape[w]
        c[0] = c0s[w]
        for j in range(1, width):
            deriv[j - 1] = c[j] * float(j)
        w_lo, w_hi = lo[w], hi[w]
        mid_slope = _horner(deriv[: max(width - 1, 1)], 0.5 * (w_lo + w_hi))
        if cov[3 + w, 3 + w] / (1.0 + mid_slope * mid_slope) > max_var:
            continue
        for i in range(n_pts):
            xi, eta = (xy[i, 0], xy[i, 1]) if variate[w] == 1 else (xy[i, 1], xy[i, 0])
            n_xi, n_eta = (normals[i, 0], normals[i, 1]) if variate[w] == 1 else (
                normals[i, 1], normals[i, 0])  # fmt: skip
            on[i] = False
            if w_lo <= xi <= w_hi and abs(eta - _horner(c, xi)) <= reach:
                s = _horner(deriv[: max(width - 1, 1)], xi)
                on[i] = abs(n_eta - s * n_xi) >= cos_max * math.sqrt(1.0 + s * s)
        i = 0
        while i < n_pts:  # keep the runs at least min_overlap long
            if not on[i]:
                i += 1
                continue
            j, length = i, 0.0
            while j + 1 < n_pts and on[j + 1]:
                length += step[j]
                j += 1
            if length >= min_overlap:
                out[i : j + 1] = True
            i = j + 1
    return out


@njit
def received_cover(
    xy: np.ndarray,  # (N, 2) a received chain in the receiver's frame
    normals: np.ndarray,  # (N, 2) its unit normals
    sigma: np.ndarray,  # (N,) each point's σ along its normal from the transform
    limit: float,  # a point is kept where σ ≤ this
    cov_t: np.ndarray,  # (3, 3) the transform's covariance as a refit carries it
    shift: np.ndarray,  # (2,) the direction the sender's c0 moves every point
    shift_var: float,  # that c0's variance as fused
    boxes: np.ndarray,  # (n, 4) the receiver's landmarks' bounding boxes
    variate: np.ndarray,  # (n,) int64, 1 or 2: the landmark table's columns
    shape: np.ndarray,  # (n, M+1)
    c0s: np.ndarray,  # (n,)
    lo: np.ndarray,  # (n,)
    hi: np.ndarray,  # (n,)
    cov: np.ndarray,  # (3+n, 3+n) the receiver's state covariance
    roundoff: float,  # the floor's relative margin (exchange._ROUNDOFF)
    reach: float,  # m, γ_M
    cos_max: float,  # cos of the merge test's angle
    min_overlap: float,  # m, merge_min_overlap
) -> tuple[np.ndarray, int, bool]:
    """``exchange.RendezvousExchange._integrate``'s tests of one received chain before its
    refit, in one call: the points kept (σ ≤ ``limit``), their runs at least ``min_overlap``
    long (:func:`kept_runs`, (K, 2) [first, end) rows), the number of points dropped, and
    whether held walls better than any refit of the chain could be (:func:`variance_floor` of
    the kept normals; :func:`covered_by_walls` on the landmarks whose boxes lie within γ_M of
    the chain's, ``slam.kernels.boxes_near``) cover every such run
    (rule 1's "better"); not covered when no run is kept. The oracle, the exchange's calls
    it replaced, is in ``tests/comms/test_exchange.py``."""
    n = xy.shape[0]
    sure = np.empty(n, dtype=np.bool_)
    n_sure = 0
    for i in range(n):
        sure[i] = sigma[i] <= limit
        n_sure += sure[i]
    runs = kept_runs(sure, xy, min_overlap)
    if runs.shape[0] == 0:
        return runs, n - n_sure, False
    kept = np.empty((n_sure, 2))
    k = 0
    for i in range(n):
        if sure[i]:
            kept[k, 0], kept[k, 1] = normals[i, 0], normals[i, 1]
            k += 1
    floor = variance_floor(kept, cov_t, shift, shift_var)
    near = boxes_near(boxes, bounding_box(xy, 0, n), reach)
    if near.size:
        covered = covered_by_walls(
            xy, normals, near, variate, shape, c0s, lo, hi, cov, floor * roundoff, reach,
            cos_max, min_overlap,
        )  # fmt: skip
        for i in range(n):
            sure[i] = sure[i] and not covered[i]
    return runs, n - n_sure, kept_runs(sure, xy, min_overlap).shape[0] == 0


# -- a received chain's geometry in the receiver's frame (comms/alignment.py, exchange.py) -------
@njit
def unit_tangents(q: np.ndarray) -> np.ndarray:
    """(N, 2) unit tangents of a chain of points ``q`` (N, 2): ``np.gradient(q, axis=0)``
    (central differences / 2 inside, one-sided at the ends) over its row norms floored at
    1e-12 (NaN kept, as ``np.maximum``); (1, 0) for a single point."""
    n = q.shape[0]
    out = np.empty((n, 2))
    if n < 2:
        for i in range(n):
            out[i, 0], out[i, 1] = 1.0, 0.0
        return out
    for i in range(n):
        if i == 0:
            dx, dy = q[1, 0] - q[0, 0], q[1, 1] - q[0, 1]
        elif i == n - 1:
            dx, dy = q[i, 0] - q[i - 1, 0], q[i, 1] - q[i - 1, 1]
        else:
            dx, dy = (q[i + 1, 0] - q[i - 1, 0]) / 2.0, (q[i + 1, 1] - q[i - 1, 1]) / 2.0
        norm = math.sqrt(dx * dx + dy * dy)
        if norm < 1e-12:  # np.maximum(norm, 1e-12): a NaN norm stays NaN
            norm = 1e-12
        out[i, 0], out[i, 1] = dx / norm, dy / norm
    return out


@njit
def chain_tangents(q: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(N, 2) :func:`unit_tangents` of each chain of ``q`` (N, 2), chain k rows
    ``starts[k]:starts[k+1]``."""
    out = np.empty((q.shape[0], 2))
    for k in range(starts.size - 1):
        out[starts[k] : starts[k + 1]] = unit_tangents(q[starts[k] : starts[k + 1]])
    return out


@njit
def _times_transposed(a: np.ndarray, m: np.ndarray, out: np.ndarray) -> None:
    """``out`` = ``a`` (N, 2) @ ``m``ᵀ (m (2, 2)) as numpy's matmul computes it through BLAS:
    a gemm for N ≥ 2 (per output a chain of fused multiply-adds along the row from 0), a gemv
    for N = 1 (the second product rounded, the first fused onto it)."""
    n = a.shape[0]
    for i in range(n):
        for j in range(2):
            if n == 1:
                out[i, j] = fma(a[i, 0], m[j, 0], a[i, 1] * m[j, 1])
            else:
                out[i, j] = fma(a[i, 1], m[j, 1], fma(a[i, 0], m[j, 0], 0.0))


@njit
def frame_chain(q: np.ndarray, t: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``q`` (N, 2) of the sender's frame in the receiver's, p = R q + t, and ∂p/∂T
    (N, 2, 3) w.r.t. T = (t_x, t_y, θ); ``rot`` = R(θ) (2, 2) (``alignment.frame_points``)."""
    n = q.shape[0]
    rq = np.empty((n, 2))
    _times_transposed(q, rot, rq)
    turn = np.empty((n, 2))
    _times_transposed(rq, J_ROT, turn)  # ∂(R q)/∂θ = J R q
    p = np.empty((n, 2))
    dp_dt = np.zeros((n, 2, 3))
    for i in range(n):
        p[i, 0], p[i, 1] = t[0] + rq[i, 0], t[1] + rq[i, 1]
        dp_dt[i, 0, 0] = dp_dt[i, 1, 1] = 1.0
        dp_dt[i, 0, 2], dp_dt[i, 1, 2] = turn[i, 0], turn[i, 1]
    return p, dp_dt


@njit
def received_geometry(
    q: np.ndarray, t: np.ndarray, rot: np.ndarray, cov_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A received chain ``q`` (N, 2, sender frame) in the receiver's frame under T = ``t``
    (rot = R(θ)): its points (N, 2), ∂p/∂T (N, 2, 3), unit normals (N, 2; the tangents of
    :func:`unit_tangents` turned by +90° and by R) and each point's standard deviation along
    its normal from T's covariance ``cov_t`` (3, 3): √(gᵀ Σ_T g), g = nᵀ ∂p/∂T (einsum's
    floats: g's two products added, then the nine products (g_i Σ_ij) g_j summed from 0, i
    outer) (``exchange.transform_normal_sigma``)."""
    n = q.shape[0]
    p, dp_dt = frame_chain(q, t, rot)
    tangent = unit_tangents(q)
    left = np.empty((n, 2))
    for i in range(n):
        left[i, 0], left[i, 1] = -tangent[i, 1], tangent[i, 0]
    normals = np.empty((n, 2))
    _times_transposed(left, rot, normals)
    sigma = np.empty(n)
    g = np.empty(3)
    for i in range(n):
        for j in range(3):
            g[j] = normals[i, 0] * dp_dt[i, 0, j] + normals[i, 1] * dp_dt[i, 1, j]
        v = 0.0
        for a in range(3):
            for b in range(3):
                v += (g[a] * cov_t[a, b]) * g[b]
        sigma[i] = math.sqrt(v) if v > 0.0 or v != v else 0.0  # √max(v, 0), NaN kept
    return p, dp_dt, normals, sigma


@njit
def variance_floor(
    normals: np.ndarray, cov_t: np.ndarray, shift: np.ndarray, shift_var: float
) -> float:
    """The least nᵀ Q n over the unit ``normals`` (N, 2) (0.0 for none; NaN if any is), Q the
    translation's covariance given the turn, Σ_tt − Σ_tθ Σ_θθ⁻¹ Σ_θt (Σ = ``cov_t`` (3, 3); no
    correction when Σ_θθ ≤ 0), plus ``shift_var`` · shift shiftᵀ, in numpy's floats
    (``exchange.refit_variance_floor``): ``np.einsum("ni,ij,nj->n", …)`` sums the four
    products (n_a Q_ab) n_b from 0 in order (a outer), but on one or two normals sums each a's
    pair apart and then those (numpy 2.4's loop order, found by testing every order)."""
    n = normals.shape[0]
    if n == 0:
        return 0.0
    q = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            q[a, b] = cov_t[a, b]
            if cov_t[2, 2] > 0.0:
                q[a, b] -= (cov_t[a, 2] * cov_t[2, b]) / cov_t[2, 2]
            q[a, b] += shift_var * (shift[a] * shift[b])
    least = np.inf
    for i in range(n):
        v = 0.0
        for a in range(2):
            row = 0.0
            for b in range(2):
                term = (normals[i, a] * q[a, b]) * normals[i, b]
                if n <= 2:  # einsum sums each row of Q apart first on one or two normals
                    row += term
                else:
                    v += term
            v += row
        if v != v:
            return v
        least = min(least, v)
    return least


@njit
def point_jacobians(
    dp_dt: np.ndarray, d_state: np.ndarray, d_noise: np.ndarray, shift: np.ndarray, n_state: int
) -> tuple[np.ndarray, np.ndarray]:
    """A received chain's point Jacobians from their ∂p/∂T ``dp_dt`` (N, 2, 3): w.r.t. the
    receiver's state (N, 2, ``n_state``), ∂p/∂T ∂T/∂pose (``d_state`` (3, 3)) in the pose's
    three columns and zeros after; w.r.t. the noise (N, 2, 1 + K), ``shift`` (2,) (the
    sender's c0 moves every point along its turned η axis) then ∂p/∂T ∂T/∂noise (``d_noise``
    (3, K)). The products as numpy's batched matmul computes them through BLAS (per output
    a chain of fused multiply-adds from 0) (``exchange._point_set``)."""
    n = dp_dt.shape[0]
    k = d_noise.shape[1]
    out_state = np.zeros((n, 2, n_state))
    out_noise = np.empty((n, 2, 1 + k))
    for i in range(n):
        for r in range(2):
            for c in range(3):
                acc = 0.0
                for m in range(3):
                    acc = fma(dp_dt[i, r, m], d_state[m, c], acc)
                out_state[i, r, c] = acc
            out_noise[i, r, 0] = shift[r]
            for c in range(k):
                acc = 0.0
                for m in range(3):
                    acc = fma(dp_dt[i, r, m], d_noise[m, c], acc)
                out_noise[i, r, 1 + c] = acc
    return out_state, out_noise


@njit
def largest_residual(xy: np.ndarray, variate: int, coeffs: np.ndarray) -> float:
    """max |η − p(ξ)| over the points ``xy`` (N ≥ 1, 2) of the polynomial with ``coeffs``
    (c0 first, at least two) on axis ``variate``: ``np.max(np.abs(eta − poly.value(xi)))``,
    the same float (Horner in polyval's order; a nan residual is the answer, as numpy's)."""
    m = coeffs.size - 1
    worst = 0.0
    for i in range(xy.shape[0]):
        xi, eta = (xy[i, 0], xy[i, 1]) if variate == 1 else (xy[i, 1], xy[i, 0])
        residual = abs(eta - horner(coeffs, m, xi, coeffs[0])[0])
        if residual != residual:
            return residual
        if i == 0 or residual > worst:
            worst = residual
    return worst


@njit
def chain_fit(
    xy: np.ndarray,
    weights: np.ndarray,
    d_state: np.ndarray,
    d_noise: np.ndarray,
    max_order: int,
    auto_order: bool,
    tol: float,
) -> tuple[bool, int, int, np.ndarray, float, float, float, np.ndarray, np.ndarray, float, bool]:
    """A received chain's refit in one call (``exchange._fit_chain``): the shape-fixed fit
    (:func:`~polyslam_env.slam.fit_kernels.fit_points`) of order 1, 2, … ``max_order`` with
    ``auto_order`` (else ``max_order`` alone), the first whose :func:`largest_residual` is
    within ``tol``, or the last tried.

    Returns (valid, variate, m, coeffs, lo, hi, rms, G_x, G_y, worst, finite): ``coeffs``
    padded with zeros to ``max_order + 1``; ``valid`` False when a tried fit has no variate or
    a non-finite coefficient or extent (its values are returned, and the loop stops there: the
    caller builds the checked polynomial, whose error it then raises as the fit-by-fit loop
    did); ``finite``: whether G_x and G_y are finite too (a refit the exchange keeps)."""
    no_limits = np.zeros((0, 0))
    first = 1 if auto_order else max_order
    for order in range(first, max_order + 1):
        var, m, coeffs, lo, hi, rms, gx, gy, _, _ = fit_points(
            xy, weights, d_state, d_noise, order, 0, True, False, no_limits
        )
        valid = (var == 1 or var == 2) and math.isfinite(lo) and math.isfinite(hi)
        for c in coeffs:
            valid = valid and math.isfinite(c)
        padded = np.zeros(max_order + 1)
        padded[: coeffs.size] = coeffs
        if not valid:
            return False, var, m, padded, lo, hi, rms, gx, gy, 0.0, False
        worst = largest_residual(xy, var, coeffs)
        if worst <= tol or order == max_order:
            finite = True
            for g in gx:
                finite = finite and math.isfinite(g)
            for g in gy:
                finite = finite and math.isfinite(g)
            return True, var, m, padded, lo, hi, rms, gx, gy, worst, finite
    raise ValueError("chain_fit: max_order must be at least 1")

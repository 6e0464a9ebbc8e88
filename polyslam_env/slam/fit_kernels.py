"""Compiled weighted LMS polynomial fits: the numerics of
:func:`~polyslam_env.slam.fitting.fit_polynomial` in one call (STYLE habit 20).

Every landmark the SLAM creates, refits or merges is one such fit; in Python (numpy's small
QR, triangular solves through LAPACK, einsum) each cost ~400 interpreter calls, most of a map
change's. Here the whole fit is one kernel over plain arrays: the variate from the points'
principal direction, the distinct abscissae, the order selection by the χ² test, the QR of
√W A on scaled abscissae (lowering the order until it has full rank), the coefficients by
back substitution, the gradient of c0 and its contraction with the points' derivatives.

The readable numpy version (LAPACK's QR and ``dtrtrs``, ``np.einsum``) is the oracle in
``tests/slam/reference_fitting.py``. numba's QR goes through scipy's LAPACK and the triangular
solves are plain loops, so the last bits differ from it: the tests compare within a bound
from the design's conditioning (``tests/slam/test_fit_kernels.py``).

Conventions: ξ is the independent coordinate (x¹ for variate 1, x² for variate 2), η the
other; the design A has columns (ξ/s)^j, j = 0 … m, with s = max(max|ξ|, 1e-9); the weights
are w/max(w) (a fit is invariant to a common factor). R is the upper-triangular factor of
√W A, so AᵀWA = RᵀR on the scaled coefficients a_s (a_j = a_s,j / s^j).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import fma, njit, sum_like_numpy
from polyslam_env.slam.map_kernels import equally_spaced

__all__ = [
    "coefficient_gradient",
    "fit_points",
    "principal_variate",
    "sample_into",
    "stored_point_arrays",
    "turn_gradient",
    "wall_mask",
    "weighted_qr",
]


@njit
def principal_variate(xy: np.ndarray, w: np.ndarray) -> int:
    """1 if the weighted principal direction of ``xy`` (N, 2) is closer to x¹ (|dx| ≥ |dy|),
    else 2."""
    total = w.sum()
    mx = (w * xy[:, 0]).sum() / total
    my = (w * xy[:, 1]).sum() / total
    cov = np.zeros((2, 2))
    for i in range(xy.shape[0]):
        dx, dy = xy[i, 0] - mx, xy[i, 1] - my
        cov[0, 0] += w[i] * dx * dx
        cov[0, 1] += w[i] * dx * dy
        cov[1, 1] += w[i] * dy * dy
    cov[1, 0] = cov[0, 1]
    vectors = np.linalg.eigh(cov)[1]
    return 1 if abs(vectors[0, 1]) >= abs(vectors[1, 1]) else 2


@njit
def _distinct_count(xi: np.ndarray, scale: float) -> int:
    """Number of distinct abscissae, up to a relative tolerance of 1e-9."""
    ordered = np.sort(xi)
    count = 1
    for i in range(1, ordered.size):
        if ordered[i] - ordered[i - 1] > 1e-9 * scale:
            count += 1
    return count


@njit
def weighted_qr(
    xi_s: np.ndarray, sqrt_w: np.ndarray, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(A (N, m+1), Q (N, m+1), R (m+1, m+1), m): the reduced QR of √W A on the scaled
    abscissae ``xi_s``, lowering the order m from ``order`` until R has full rank (its
    smallest |diagonal| above 1e-10 of its largest)."""
    n = xi_s.size
    while True:
        a_mat = np.empty((n, order + 1))
        for i in range(n):
            power = 1.0
            for j in range(order + 1):
                a_mat[i, j] = power
                power *= xi_s[i]
        weighted = np.empty((n, order + 1))
        for i in range(n):
            for j in range(order + 1):
                weighted[i, j] = sqrt_w[i] * a_mat[i, j]
        q, r = np.linalg.qr(weighted)
        low, high = np.inf, 0.0
        for j in range(r.shape[0]):
            d = abs(r[j, j])
            low, high = min(low, d), max(high, d)
        if order == 0 or low > 1e-10 * high:
            return a_mat, q, r, order
        order -= 1


@njit
def _solve_upper(r: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with R x = rhs, R upper triangular (back substitution)."""
    n = rhs.size
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        acc = rhs[i]
        for j in range(i + 1, n):
            acc -= r[i, j] * x[j]
        x[i] = acc / r[i, i]
    return x


@njit
def _solve_upper_transposed(r: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with Rᵀ x = rhs, R upper triangular (forward substitution on Rᵀ)."""
    n = rhs.size
    x = np.empty(n)
    for i in range(n):
        acc = rhs[i]
        for j in range(i):
            acc -= r[j, i] * x[j]
        x[i] = acc / r[i, i]
    return x


@njit
def _least_squares(q: np.ndarray, r: np.ndarray, sqrt_w: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """The scaled coefficients a_s = R⁻¹ Qᵀ √W η."""
    n, width = q.shape
    rhs = np.zeros(width)
    for i in range(n):
        weighted = sqrt_w[i] * eta[i]
        for j in range(width):
            rhs[j] += q[i, j] * weighted
    return _solve_upper(r, rhs)


@njit
def coefficient_gradient(
    e: np.ndarray,
    scale: float,
    w: np.ndarray,
    a_mat: np.ndarray,
    r: np.ndarray,
    a_s: np.ndarray,
    resid: np.ndarray,
) -> np.ndarray:
    """(N, 2): ∂(eᵀa_s)/∂ξ_i and ∂(eᵀa_s)/∂η_i of a linear function e (m+1,) of the scaled
    coefficients, from the normal equations (M = AᵀWA = RᵀR, A_i' = d/dξ of row A_i):
    ∂/∂η_i = eᵀM⁻¹A_iᵀ w_i, ∂/∂ξ_i = eᵀM⁻¹[w_i A_i'ᵀ r_i − w_i A_iᵀ (A_i' a_s)]."""
    row = _solve_upper(r, _solve_upper_transposed(r, e))  # M⁻¹ e
    n, width = a_mat.shape
    out = np.empty((n, 2))
    for i in range(n):
        slope = q_da = q_a = 0.0
        for j in range(width):
            q_a += a_mat[i, j] * row[j]
            if j > 0:
                d = j * a_mat[i, j - 1] / scale  # d/dξ of (ξ/s)^j
                slope += d * a_s[j]
                q_da += d * row[j]
        out[i, 0] = w[i] * (q_da * resid[i] - q_a * slope)
        out[i, 1] = w[i] * q_a
    return out


@njit
def _residuals(a_mat: np.ndarray, a_s: np.ndarray, eta: np.ndarray) -> np.ndarray:
    return eta - a_mat @ a_s


@njit
def _select_order(
    xi_s: np.ndarray, eta: np.ndarray, sqrt_w: np.ndarray, max_order: int, limits: np.ndarray
) -> int:
    """The lowest order in 1..max_order whose residual sum of squares is within
    ``limits[0, m − 1]`` (the caller's χ² bound, :func:`~polyslam_env.slam.fitting.
    order_limits`) and, when ``limits`` has a second row, whose sum drops by no more than
    ``limits[1, m − 1]`` at order m + 1 (:func:`~polyslam_env.slam.fitting.
    next_term_limits`); a rank-deficient design or too few points stop the search."""
    n = xi_s.size
    for m in range(1, max_order + 1):
        a_mat, q, r, m_eff = weighted_qr(xi_s, sqrt_w, m)
        if m_eff < m or n <= m + 1:
            return max(m_eff, 1)
        resid = _residuals(a_mat, _least_squares(q, r, sqrt_w, eta), eta)
        rss = (resid * resid).sum()
        if rss > limits[0, m - 1]:
            continue
        if m == max_order or limits.shape[0] < 2:
            return m
        a_next, q_next, r_next, m_next = weighted_qr(xi_s, sqrt_w, m + 1)
        if m_next <= m or n <= m + 2:
            return m
        rest = _residuals(a_next, _least_squares(q_next, r_next, sqrt_w, eta), eta)
        if rss - (rest * rest).sum() <= limits[1, m - 1]:
            return m
    return max_order


@njit
def fit_points(
    xy: np.ndarray,
    weights: np.ndarray,
    d_state: np.ndarray,
    d_noise: np.ndarray,
    order: int,
    variate: int,
    shape_fixed: bool,
    auto_order: bool,
    limits: np.ndarray,
) -> tuple[int, int, np.ndarray, float, float, float, np.ndarray, np.ndarray, np.ndarray, float]:
    """The weighted LMS fit of points ``xy`` (N, 2) with ``weights`` (N,) > 0 and their
    derivatives ``d_state`` (N, 2, S) and ``d_noise`` (N, 2, K).

    ``variate`` 0 chooses it by the principal direction; ``order`` ≥ 1 is the largest order,
    lowered to the distinct abscissae (and, with ``auto_order``, to the lowest order whose
    residuals pass ``limits`` (1 or 2, order): :func:`_select_order`); a rank-deficient
    design lowers it further.
    ``shape_fixed`` differentiates c0 with the shape held (∂c0/∂η_i = w_i/Σw,
    ∂c0/∂ξ_i = −w_i B'(ξ_i)/Σw), else through the whole solution.

    Returns (variate, m, coeffs (order+1,) zero beyond m, lo, hi, rms of the η residuals,
    G_x (S,), G_y (K,), R (m+1, m+1) of √W A on ξ/s, s)."""
    n = xy.shape[0]
    var = principal_variate(xy, weights) if variate == 0 else variate
    k_xi, k_eta = (0, 1) if var == 1 else (1, 0)
    xi = xy[:, k_xi].copy()
    eta = xy[:, k_eta].copy()
    scale = max(np.abs(xi).max(), 1e-9)
    w = weights / weights.max()
    m = min(order, _distinct_count(xi, max(scale, 1.0)) - 1)
    xi_s = xi / scale
    sqrt_w = np.sqrt(w)
    if auto_order and m > 1:
        m = _select_order(xi_s, eta, sqrt_w, m, limits)
    a_mat, q, r, m = weighted_qr(xi_s, sqrt_w, m)
    a_s = _least_squares(q, r, sqrt_w, eta)
    resid = _residuals(a_mat, a_s, eta)
    coeffs = np.zeros(order + 1)
    for j in range(m + 1):
        coeffs[j] = a_s[j] / scale**j
    if shape_fixed:
        total = w.sum()
        dc0 = np.empty((n, 2))
        for i in range(n):
            slope = 0.0  # B'(ξ_i) by Horner's scheme on j·a_j
            for j in range(m, 0, -1):
                slope = slope * xi[i] + j * coeffs[j]
            dc0[i, 0] = -w[i] * slope / total
            dc0[i, 1] = w[i] / total
    else:
        e0 = np.zeros(m + 1)
        e0[0] = 1.0
        dc0 = coefficient_gradient(e0, scale, w, a_mat, r, a_s, resid)
    gx = np.zeros(d_state.shape[2])
    gy = np.zeros(d_noise.shape[2])
    for i in range(n):
        u_x, u_y = (dc0[i, 0], dc0[i, 1]) if var == 1 else (dc0[i, 1], dc0[i, 0])
        for s in range(d_state.shape[2]):
            gx[s] += u_x * d_state[i, 0, s] + u_y * d_state[i, 1, s]
        for s in range(d_noise.shape[2]):
            gy[s] += u_x * d_noise[i, 0, s] + u_y * d_noise[i, 1, s]
    rms = math.sqrt((resid * resid).sum() / n)
    return var, m, coeffs, xi.min(), xi.max(), rms, gx, gy, r, scale


@njit
def sample_into(
    c: np.ndarray,
    variate: int,
    extent: tuple[float, float],
    c0: tuple[int, float],
    turn: tuple[int, float],
    xy: np.ndarray,
    d_state: np.ndarray,
    weights: np.ndarray,
    start: int,
    n: int,
) -> None:
    """``n`` points equally spaced over ξ ∈ ``extent`` on the curve ``c`` (``variate``) into
    rows ``start`` … ``start + n − 1`` of ``xy`` (·, 2), ``d_state`` (·, 2, S, zeros on
    entry) and ``weights``: the model of :func:`~polyslam_env.slam.fitting.polynomial_points`
    (``c0`` = (c0's state index, its variance): ∂η/∂c0 = 1, weight 1/var; ``turn`` = (α's
    state index or −1, pivot ξ): ∂π/∂α = J (π − π_c)).

    The floats of its numpy form (``tests/slam/reference_fitting.py``), bit for bit, signed
    zeros included: ``(π − π_c) @ Jᵀ`` is BLAS's product, a chain of FMAs from 0 along
    the inner index, zeros of J included (``docs/notes/paperenv.md``)."""
    pts = equally_spaced(c, variate, extent[0], extent[1], n)
    eta_axis = 1 if variate == 1 else 0
    c0_index, weight = c0[0], 1.0 / c0[1]
    turn_index = turn[0]
    centre = equally_spaced(c, variate, turn[1], turn[1], 1)
    for i in range(n):
        row = start + i
        xy[row, 0], xy[row, 1] = pts[i, 0], pts[i, 1]
        d_state[row, eta_axis, c0_index] = 1.0
        if turn_index >= 0:  # J = [[0, −1], [1, 0]]: the product's row is (−d_y, d_x)
            dx, dy = pts[i, 0] - centre[0, 0], pts[i, 1] - centre[0, 1]
            d_state[row, 0, turn_index] = fma(dy, -1.0, fma(dx, 0.0, 0.0))
            d_state[row, 1, turn_index] = fma(dy, 0.0, fma(dx, 1.0, 0.0))
        weights[row] = weight


@njit
def stored_point_arrays(
    xy0: np.ndarray,
    direction: np.ndarray,
    sigma: np.ndarray,
    anchor: np.ndarray,
    at: np.ndarray,
    noise: np.ndarray,
    n_state: int,
    square: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(xy (N, 2), d_state (N, 2, S), d_noise (N, 2, N), noise_cov (N, N)) of stored points
    ``xy0`` (N, 2) with beam directions ``direction`` (N, 2) and range σ ``sigma`` (N,),
    attached to the pose ``anchor`` (3,) and evaluated at the pose ``at`` with range errors
    ``noise`` (N,): the model of :func:`~polyslam_env.slam.fitting.stored_points`.

    The floats of its numpy form (``tests/slam/reference_fitting.py``), bit for bit: the
    products with R(θ − θ̂)ᵀ and Jᵀ are BLAS's chains of FMAs from 0 along the inner index
    (as :func:`sample_into`'s), R's entries numpy's ``cos``/``sin`` (libm's), the variances
    σ² libm's ``pow`` (``square`` = 2.0 an argument, as :func:`turn_gradient`'s)."""
    n = xy0.shape[0]
    turn = at[2] - anchor[2]
    c, s = math.cos(turn), math.sin(turn)
    xy = np.empty((n, 2))
    d_state = np.zeros((n, 2, n_state))
    d_noise = np.zeros((n, 2, n))
    noise_cov = np.zeros((n, n))
    for i in range(n):
        dx, dy = xy0[i, 0] - anchor[0], xy0[i, 1] - anchor[1]
        rx = fma(dy, -s, fma(dx, c, 0.0))  # (π̂ − p̂) R(θ − θ̂)ᵀ: Rᵀ = [[c, s], [−s, c]]
        ry = fma(dy, c, fma(dx, s, 0.0))
        xy[i, 0] = at[0] + rx + noise[i] * direction[i, 0]
        xy[i, 1] = at[1] + ry + noise[i] * direction[i, 1]
        d_state[i, 0, 0] = d_state[i, 1, 1] = 1.0
        d_state[i, 0, 2] = fma(ry, -1.0, fma(rx, 0.0, 0.0))  # rel Jᵀ = (−rel_y, rel_x)
        d_state[i, 1, 2] = fma(ry, 0.0, fma(rx, 1.0, 0.0))
        d_noise[i, 0, i], d_noise[i, 1, i] = direction[i, 0], direction[i, 1]
        noise_cov[i, i] = math.pow(sigma[i], square)
    return xy, d_state, d_noise, noise_cov


@njit
def _slope_at(coeffs: np.ndarray, x: float) -> float:
    """dη/dξ at ``x`` of the polynomial ``coeffs`` in ``Polynomial.slope``'s floats (``polyval``
    of the derivative's coefficients j·c_j, Horner from ``c[-1] + x·0``)."""
    n = coeffs.size
    if n < 2:
        return coeffs[0] * 0.0 + x * 0.0
    value = coeffs[n - 1] * (n - 1) + x * 0.0
    for j in range(n - 2, 0, -1):
        value = coeffs[j] * j + value * x
    return value


@njit
def turn_gradient(
    xy: np.ndarray,
    weights: np.ndarray,
    d_state: np.ndarray,
    variate: int,
    order: int,
    coeffs: np.ndarray,
    rms: float,
    pivot: float,
    square: float,
) -> tuple[np.ndarray, float]:
    """(∂α/∂X (S,), residual variance) of the turn α about ξ = ``pivot`` of the fit
    (``variate``, ``order``, ``coeffs``, ``rms``) of points ``xy`` (N ≥ 2, 2) with
    ``weights`` and derivatives ``d_state`` (N, 2, S): the model is
    :func:`~polyslam_env.slam.fitting.turn_gradient`'s. ``square`` is 2.0, an argument as
    :func:`~polyslam_env.slam.map_kernels.rotation_fit_var`'s: Python's ``x ** 2`` is libm's
    ``pow``, and LLVM turns a literal ``pow(x, 2.0)`` into ``x · x``, which rounds otherwise.

    The floats of its readable numpy form (``tests/slam/reference_fitting.py``), bit for bit:
    the residual's product goes through BLAS's gemv as numpy's does (numba calls the same
    routine), powers through ``pow``, the sum of squares in numpy's pairwise order and the
    contraction in ``np.einsum``'s (the points in order, ξ before η of each, one running sum
    per state entry)."""
    k_xi, k_eta = (0, 1) if variate == 1 else (1, 0)
    xi = xy[:, k_xi].copy()
    eta = xy[:, k_eta].copy()
    scale = max(np.abs(xi).max(), 1e-9)
    w = weights / weights.max()
    a_mat, _, r, m = weighted_qr(xi / scale, np.sqrt(w), order)
    a_s = np.empty(m + 1)
    for j in range(m + 1):
        a_s[j] = coeffs[j] * math.pow(scale, float(j))
    resid = eta - a_mat @ a_s
    e = np.zeros(m + 1)  # p'(ξ_p) = Σ_k k a_s[k] (ξ_p/s)^(k−1) / s
    for j in range(1, m + 1):
        e[j] = j * math.pow(pivot / scale, float(j - 1)) / scale
    slope = _slope_at(coeffs, pivot)
    d = coefficient_gradient(e, scale, w, a_mat, r, a_s, resid) / (1.0 + math.pow(slope, square))
    squares = np.empty(d.shape[0])
    for i in range(d.shape[0]):
        squares[i] = d[i, 1] * d[i, 1]
    residual_var = math.pow(rms, square) * sum_like_numpy(squares, 0, squares.size)
    sign = 1.0 if variate == 1 else -1.0  # α turns counter-clockwise in (x¹, x²)
    out = np.zeros(d_state.shape[2])
    for i in range(d.shape[0]):
        for c in range(2):  # the point's x¹ then x² derivative
            u = d[i, c] if variate == 1 else d[i, 1 - c]
            for s in range(out.size):
                out[s] += u * d_state[i, c, s]
    for s in range(out.size):
        out[s] = sign * out[s]
    return out, residual_var


# -- which of a cluster's points make one wall ----------------------------------------------
@njit
def _tls_direction(xy: np.ndarray) -> np.ndarray:
    """(2,) unit direction of the total-least-squares line through the points ``xy`` (k, 2)."""
    centred = xy - np.array([xy[:, 0].mean(), xy[:, 1].mean()])
    return np.linalg.svd(centred, full_matrices=False)[2][0].copy()


@njit
def _line_distances(fit_xy: np.ndarray, direction: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Perpendicular distances (N,) of ``xy`` to the line along ``direction`` through the
    centroid of ``fit_xy``."""
    cx, cy = fit_xy[:, 0].mean(), fit_xy[:, 1].mean()
    out = np.empty(xy.shape[0])
    for k in range(xy.shape[0]):
        out[k] = abs(-direction[1] * (xy[k, 0] - cx) + direction[0] * (xy[k, 1] - cy))
    return out


@njit
def _dominant_line(xy: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The line best supported by the points: its direction (2,) and all distances (N,) to
    it. Candidates are the lines through every pair of points (i < j, row-major); the score
    is the truncated quadratic Σ min(d, tol)² (MSAC), the first best on ties; the winner is
    refined by total least squares on its inliers."""
    n = xy.shape[0]
    best_i, best_nx, best_ny, best_score = -1, 0.0, 0.0, np.inf
    if n >= 3:
        for i in range(n):
            for j in range(i + 1, n):
                cx, cy = xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
                length = math.sqrt(cx * cx + cy * cy)
                if not length > 1e-9:
                    continue
                nx, ny = -cy / length, cx / length
                score = 0.0
                for k in range(n):
                    d = min(abs(nx * (xy[k, 0] - xy[i, 0]) + ny * (xy[k, 1] - xy[i, 1])), tol)
                    score += d * d
                if score < best_score:
                    best_i, best_nx, best_ny, best_score = i, nx, ny, score
    if best_i < 0:
        direction = _tls_direction(xy) if n >= 2 else np.array([1.0, 0.0])
        return direction, _line_distances(xy, direction, xy)
    inside = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        d = abs(best_nx * (xy[k, 0] - xy[best_i, 0]) + best_ny * (xy[k, 1] - xy[best_i, 1]))
        inside[k] = d <= tol
    inliers = xy[inside]
    direction = _tls_direction(inliers)
    return direction, _line_distances(inliers, direction, xy)


@njit
def _select_wall(xy: np.ndarray, tol: float, min_second: int, corner_angle: float) -> np.ndarray:
    """(N,) mask of the points of one wall: the dominant line's points, or all points when
    the rest make no second straight wall or one at less than ``corner_angle`` (radians) to
    the first; at a corner, the points within ``tol`` of the first line and nearer to it."""
    n = xy.shape[0]
    dir_on, dist_on = _dominant_line(xy, tol)
    off = dist_on > tol
    if off.sum() < min_second:
        return ~off
    dir_off, dist_off_sub = _dominant_line(xy[off], tol)
    second = dist_off_sub <= tol
    if second.sum() < min_second:
        return np.ones(n, dtype=np.bool_)  # no second straight wall: one curved wall
    dist_off = _line_distances(xy[off][second], dir_off, xy)
    cosine = min(abs(dir_on[0] * dir_off[0] + dir_on[1] * dir_off[1]), 1.0)
    if math.acos(cosine) < corner_angle:
        return np.ones(n, dtype=np.bool_)  # a gentle bend, not a corner
    return (dist_on <= dist_off) & (dist_on <= tol)


@njit
def _largest_run(xy: np.ndarray, mask: np.ndarray, max_gap: float) -> np.ndarray:
    """``mask`` restricted to the largest run of its points without a gap > ``max_gap`` along
    their principal direction (the first of the longest on ties)."""
    chosen = np.flatnonzero(mask)
    if chosen.size < 2:
        return mask
    picked = xy[chosen]
    direction = _tls_direction(picked)
    along = picked @ direction
    order = np.argsort(along, kind="mergesort")
    best_start, best_length, start = 0, 0, 0
    for k in range(1, order.size + 1):
        if k == order.size or along[order[k]] - along[order[k - 1]] > max_gap:
            if k - start > best_length:
                best_start, best_length = start, k - start
            start = k
    if best_length == order.size:
        return mask
    out = np.zeros_like(mask)
    for k in range(best_start, best_start + best_length):
        out[chosen[order[k]]] = True
    return out


@njit
def wall_mask(
    xy: np.ndarray, tol: float, min_second: int, corner_angle: float, max_gap: float
) -> np.ndarray:
    """(N,) the cluster points ``xy`` (N, 2) one new landmark is fitted to (steps 1–3b of
    :func:`~polyslam_env.slam.association.fit_cluster`): the points of one wall
    (MSAC dominant lines, corner test), then their largest run without a gap."""
    return _largest_run(xy, _select_wall(xy, tol, min_second, corner_angle), max_gap)


@njit
def merge_fit(
    a_coeffs: np.ndarray, a_variate: int, a_extent: tuple[float, float],
    a_c0: tuple[int, float], a_turn: tuple[int, float],
    b_coeffs: np.ndarray, b_variate: int, b_extent: tuple[float, float],
    b_c0: tuple[int, float], b_turn: tuple[int, float],
    n_each: int, n_state: int, order: int, auto_order: bool, limits: np.ndarray,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray,
    int, int, np.ndarray, float, float, float, np.ndarray, np.ndarray, np.ndarray, float,
]:  # fmt: skip
    """A merge's point set and its fit in one call (``merging.merge_fit``): ``n_each``
    points on each of two curves (:func:`sample_into`, the first's rows first), then their
    shape-fixed LMS fit of the variate their direction chooses (:func:`fit_points`, no noise
    of their own). Returns (xy, d_state, weights) and :func:`fit_points`' results."""
    n = 2 * n_each
    xy, d_state, weights = np.empty((n, 2)), np.zeros((n, 2, n_state)), np.empty(n)
    sample_into(a_coeffs, a_variate, a_extent, a_c0, a_turn, xy, d_state, weights, 0, n_each)
    sample_into(b_coeffs, b_variate, b_extent, b_c0, b_turn, xy, d_state, weights, n_each, n_each)
    var, m, coeffs, lo, hi, rms, gx, gy, r, scale = fit_points(
        xy, weights, d_state, np.zeros((n, 2, 0)), order, 0, True, auto_order, limits
    )
    return xy, d_state, weights, var, m, coeffs, lo, hi, rms, gx, gy, r, scale

"""The readable numpy fits and cluster split that :mod:`polyslam_env.slam.fit_kernels`
compiles: the oracle of ``tests/slam/test_fit_kernels.py``, the production code before the
kernels (LAPACK's QR and SVD through numpy, the triangular solves through LAPACK's
``dtrtrs``, the contractions by ``np.einsum``), with :func:`wall_mask` as the entry point of
the cluster split."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg.lapack
import scipy.special

from polyslam_env.core.geometry import rotation
from polyslam_env.slam.fitting import J_ROT, Fit, PointSet
from polyslam_env.slam.fitting import _diag_noise as diag_noise
from polyslam_env.slam.map_kernels import GAP_SPLIT, equally_spaced
from polyslam_env.slam.polynomial import Polynomial, polyval
from polyslam_env.slam.stored import PointArrays


def choose_variate(xy: np.ndarray, weights: np.ndarray | None = None) -> int:
    """1 if the weighted principal direction is closer to x¹ (|dx| ≥ |dy|), else 2."""
    pts = np.asarray(xy, dtype=float)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, dtype=float)
    centred = pts - (w @ pts) / w.sum()
    cov = (centred * w[:, None]).T @ centred  # (2, 2)
    direction = np.linalg.eigh(cov)[1][:, -1]
    return 1 if abs(direction[0]) >= abs(direction[1]) else 2


def _split(xy: np.ndarray, variate: int) -> tuple[np.ndarray, np.ndarray]:
    """(ξ, η) of points for the given variate."""
    return (xy[:, 0], xy[:, 1]) if variate == 1 else (xy[:, 1], xy[:, 0])


def _scaled(points: PointSet, variate: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """(ξ, η, scale, w) of a fit: the abscissae are scaled by max|ξ| in the design, and the
    weights by their largest (a fit is invariant to a common weight factor)."""
    xi, eta = _split(points.xy, variate)
    return xi, eta, max(float(np.abs(xi).max()), 1e-9), points.weights / points.weights.max()


def _distinct_count(xi: np.ndarray, scale: float) -> int:
    """Number of distinct abscissae, up to a relative tolerance of 1e-9."""
    sorted_xi = np.sort(xi)
    return 1 + int(np.count_nonzero(np.diff(sorted_xi) > 1e-9 * scale))


def solve_upper(r: np.ndarray, rhs: np.ndarray, transposed: bool = False) -> np.ndarray:
    """x with R x = rhs (Rᵀ x = rhs when ``transposed``), R (n, n) upper triangular float64:
    ``scipy.linalg.solve_triangular``'s LAPACK call (``dtrtrs``, on Rᵀ as a lower triangle
    when R is C-ordered), the same bits, without its ~50 Python calls of argument handling
    (a fit solves 2–5 times). Non-finite input and a singular R raise as it does."""
    if not (np.isfinite(r).all() and np.isfinite(rhs).all()):
        raise ValueError("array must not contain infs or NaNs")
    trans = 1 if transposed else 0
    if r.flags.f_contiguous:
        x, info = scipy.linalg.lapack.dtrtrs(r, rhs, lower=0, trans=trans)
    else:
        x, info = scipy.linalg.lapack.dtrtrs(r.T, rhs, lower=1, trans=1 - trans)
    if info > 0:
        raise np.linalg.LinAlgError(f"singular matrix: resolution failed at diagonal {info - 1}")
    if info < 0:
        raise ValueError(f"illegal value in {-info}-th argument of internal trtrs")
    return np.asarray(x)


def _weighted_qr(
    xi_s: np.ndarray, sqrt_w: np.ndarray, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """QR of √W A on scaled abscissae, lowering the order until it has full rank."""
    while True:
        a_mat = np.vander(xi_s, order + 1, increasing=True)  # (N, m+1)
        q, r = np.linalg.qr(sqrt_w[:, None] * a_mat)
        diag = np.abs(np.diag(r))
        if order == 0 or diag.min() > 1e-10 * diag.max():
            return a_mat, q, r, order
        order -= 1


def select_order(
    xi: np.ndarray,
    eta: np.ndarray,
    w: np.ndarray,
    max_order: int,
    noise_var: float = 0.0,
    next_term: bool = False,
) -> int:
    """The lowest order in 1..max_order whose residuals the point noise explains.

    The paper's m is the *largest* order a segment may take: a cubic through a dozen points
    with 2 cm noise over half a metre of straight wall has slopes that are pure noise, and
    those slopes enter ∂h/∂x and ∂h/∂θ, making the pose look observable where it is not (an
    overconfident filter). With a known per-point noise variance, order m is accepted when
    its residual sum of squares is below the 99 % χ² quantile with N − m − 1 dof times the
    variance. Without noise (points sampled on polynomials) the lowest order that fits to
    0.1 mm RMS is taken. ``next_term`` (``SlamConfig.curvature_test``): and the next order's
    one more coefficient is not significant at 1 %.
    """
    n_pts = len(xi)
    scale = max(float(np.abs(xi).max()), 1e-9)
    sqrt_w = np.sqrt(w / w.max())
    for m in range(1, max_order + 1):
        a_mat, q, r, m_eff = _weighted_qr(xi / scale, sqrt_w, m)
        if m_eff < m or n_pts <= m + 1:
            return max(m_eff, 1)
        coef = solve_upper(r, q.T @ (sqrt_w * eta))
        resid = eta - a_mat @ coef
        rss = float(resid @ resid)
        if noise_var > 0:
            limit = float(scipy.special.chdtri(n_pts - m - 1, 0.01)) * noise_var
        else:
            limit = n_pts * 1e-8
        if rss > limit:
            continue
        if not next_term or m == max_order:
            return m
        a_next, q_next, r_next, m_next = _weighted_qr(xi / scale, sqrt_w, m + 1)
        if m_next <= m or n_pts <= m + 2:
            return m
        rest = eta - a_next @ solve_upper(r_next, q_next.T @ (sqrt_w * eta))
        # the next coefficient's z²: χ²(1) when it is zero (the noise known)
        if rss - float(rest @ rest) <= float(scipy.special.chdtri(1, 0.01)) * noise_var:
            return m
    return max_order


def fit_polynomial(
    points: PointSet,
    order: int = 3,
    variate: int | None = None,
    shape_fixed: bool = False,
    auto_order: bool = False,
    min_noise_var: float = 0.0,
    curvature_test: bool = False,
) -> Fit:
    """Weighted LMS polynomial a = (AᵀWA)⁻¹AᵀWη, with ∂c0/∂X and ∂c0/∂noise.

    The variate is chosen by direction unless given; the extent is [min ξ, max ξ]. With fewer
    distinct ξ than order+1 (or a rank-deficient design) the order is lowered and the missing
    coefficients are zero, so the result always has ``order + 1`` coefficients. Columns are
    scaled by max|ξ| and solved by QR, never by forming (AᵀWA)⁻¹. Derivatives of c0 = a_0
    (M = AᵀWA, r_i the residual, A_i' = d/dξ of row A_i):
    ∂a/∂η_i = M⁻¹A_iᵀ w_i and ∂a/∂ξ_i = M⁻¹[w_i A_i'ᵀ r_i − w_i A_iᵀ (A_i' a)];
    G_x = Σ_i ∂c0/∂π_i ∂π_i/∂X and G_y likewise. The weights are treated as constants.

    ``shape_fixed=True`` differentiates c0 with the shape b held at its fitted value instead
    (same c0: the normal equation of the constant column gives c0 = Σw(η − B(ξ))/Σw), i.e.
    ∂c0/∂η_i = w_i/Σw and ∂c0/∂ξ_i = −w_i B'(ξ_i)/Σw. That matches the SLAM's model, where
    c0 is a rigid offset of a fixed shape; the full derivative also carries the change of
    shape extrapolated to ξ = 0, which is huge for a segment far from the origin.

    ``auto_order=True`` fits the order :func:`select_order` picks (at most ``order``), with
    the points' mean noise variance, floored at ``min_noise_var``: points sampled on
    polynomials (merges, refits) carry no noise of their own, but their polynomials came from
    noisy ranges, and a 1 cm disagreement between two segments of one straight wall must
    not buy a cubic whose spurious curvature then makes the pose look observable.
    """
    if points.n_points == 0:
        raise ValueError("cannot fit a polynomial to zero points")
    if order < 1:
        raise ValueError(f"order must be >= 1, got {order}")
    var = choose_variate(points.xy, points.weights) if variate is None else variate
    xi, eta, scale, w = _scaled(points, var)
    m = min(order, _distinct_count(xi, max(scale, 1.0)) - 1)
    if auto_order and m > 1:
        noise_var = max(float(np.trace(points.noise_cov)) / points.n_points, min_noise_var)
        own_noise = float(np.trace(points.noise_cov)) > 0  # beam hits, not sampled points
        m = select_order(xi, eta, w, m, noise_var, curvature_test and own_noise)
    a_mat, q, r, m = _weighted_qr(xi / scale, np.sqrt(w), m)
    a_s = solve_upper(r, q.T @ (np.sqrt(w) * eta))  # scaled coefficients
    resid = eta - a_mat @ a_s  # (N,)
    if shape_fixed:
        slope = (
            polyval(xi, a_s / scale ** np.arange(m + 1), derivative=1)
            if m > 0
            else np.zeros_like(xi)
        )
        dc0 = np.stack([-w * slope, w], axis=-1) / w.sum()  # (N, 2) in (ξ, η)
    else:
        e0 = np.zeros(m + 1)
        e0[0] = 1.0
        dc0 = _coefficient_gradient(e0, scale, w, a_mat, r, a_s, resid, m)
    dc0_xy = dc0 if var == 1 else dc0[:, ::-1]
    coeffs = np.zeros(order + 1)
    coeffs[: m + 1] = a_s / scale ** np.arange(m + 1)
    return Fit(
        poly=Polynomial(var, coeffs, float(xi.min()), float(xi.max())),
        c0=float(coeffs[0]),
        Gx=np.einsum("nj,njs->s", dc0_xy, points.d_state)[None, :],
        Gy=np.einsum("nj,njk->k", dc0_xy, points.d_noise)[None, :],
        V=points.noise_cov,
        rms=float(np.sqrt(np.mean(resid**2))),
        order=m,
    )


def _coefficient_gradient(
    e: np.ndarray,
    scale: float,
    w: np.ndarray,
    a_mat: np.ndarray,
    r: np.ndarray,
    a_s: np.ndarray,
    resid: np.ndarray,
    m: int,
) -> np.ndarray:
    """(N, 2): ∂(eᵀa_s)/∂ξ_i and ∂(eᵀa_s)/∂η_i of a linear function e (m+1,) of the scaled
    coefficients a_s, from the normal equations (see :func:`fit_polynomial`)."""
    # eᵀM⁻¹ = eᵀR⁻¹R⁻ᵀ, from two triangular solves
    row = solve_upper(r, solve_upper(r, e, transposed=True))
    powers = np.arange(m + 1)
    # d/dξ of (ξ/s)^j = j (ξ/s)^(j−1) / s
    d_a = np.zeros_like(a_mat)
    d_a[:, 1:] = powers[1:] * a_mat[:, :-1] / scale  # (N, m+1)
    slope = d_a @ a_s  # (N,) dη/dξ at each point
    q_a = a_mat @ row  # (N,) eᵀ M⁻¹ A_iᵀ
    q_da = d_a @ row  # (N,) eᵀ M⁻¹ A_i'ᵀ
    d_eta = w * q_a
    d_xi = w * (q_da * resid - q_a * slope)
    return np.stack([d_xi, d_eta], axis=-1)


def turn_gradient_with(
    points: PointSet,
    fit: Fit,
    pivot: float,
    weighted_qr: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray, int]],
    coefficient_gradient: Callable[..., np.ndarray],
) -> tuple[np.ndarray, float]:
    """:func:`~polyslam_env.slam.fitting.turn_gradient` in numpy (the production code before
    :func:`~polyslam_env.slam.fit_kernels.turn_gradient`) with the fit's QR
    (``fit_kernels.weighted_qr``'s signature) and the gradient of a linear function of the
    coefficients (``fit_kernels.coefficient_gradient``'s) given: with the compiled ones it is
    the kernel's bit-for-bit oracle, with this module's readable ones the conditioning
    bound's."""
    poly = fit.poly
    xi, eta, scale, w = _scaled(points, poly.variate)
    a_mat, _, r, m = weighted_qr(xi / scale, np.sqrt(w), fit.order)
    a_s = poly.coeffs[: m + 1] * scale ** np.arange(m + 1)
    resid = eta - a_mat @ a_s
    e = np.zeros(m + 1)  # p'(ξ_p) = Σ_k k a_s[k] (ξ_p/s)^(k−1) / s
    e[1:] = np.arange(1, m + 1) * (pivot / scale) ** np.arange(m) / scale
    slope = float(poly.slope(pivot))
    d = coefficient_gradient(e, scale, w, a_mat, r, a_s, resid) / (1.0 + slope**2)
    d_xy = d if poly.variate == 1 else d[:, ::-1]
    sign = 1.0 if poly.variate == 1 else -1.0  # α turns counter-clockwise in (x¹, x²)
    residual_var = fit.rms**2 * float(np.sum(d[:, 1] ** 2))
    return sign * np.einsum("nj,njs->s", d_xy, points.d_state), residual_var


def turn_gradient(points: PointSet, fit: Fit, pivot: float) -> tuple[np.ndarray, float]:
    """:func:`~polyslam_env.slam.fitting.turn_gradient` on this module's readable QR and
    coefficient gradient (the rest of it is :func:`turn_gradient_with`; its
    derivative is checked by finite differences in ``tests/slam/test_merging.py``)."""

    def gradient(
        e: np.ndarray, scale: float, w: np.ndarray, a_mat: np.ndarray, r: np.ndarray,
        a_s: np.ndarray, resid: np.ndarray,
    ) -> np.ndarray:  # fmt: skip
        return _coefficient_gradient(e, scale, w, a_mat, r, a_s, resid, a_mat.shape[1] - 1)

    return turn_gradient_with(points, fit, pivot, _weighted_qr, gradient)


# -- which of a cluster's points make one wall (association.fit_cluster, steps 1–3b) -----
def wall_mask(
    xy: np.ndarray, tol: float, min_second: int, corner_angle: float, max_gap: float | None
) -> np.ndarray:
    """The readable :func:`~polyslam_env.slam.fit_kernels.wall_mask`."""
    return _largest_run(xy, _select_wall(xy, tol, min_second, corner_angle), max_gap)


def _largest_run(xy: np.ndarray, mask: np.ndarray, max_gap: float | None) -> np.ndarray:
    """``mask`` (N,) restricted to the largest run of its points without a gap > ``max_gap``
    along their principal direction (step 3b of :func:`fit_cluster`)."""
    gap = GAP_SPLIT if max_gap is None else max_gap
    chosen = np.flatnonzero(mask)
    if len(chosen) < 2:
        return mask
    along = xy[chosen] @ _tls_direction(xy[chosen])  # (k,)
    order = np.argsort(along, kind="stable")
    cuts = np.flatnonzero(np.diff(along[order]) > gap) + 1
    if len(cuts) == 0:
        return mask
    runs = np.split(order, cuts)
    best = max(runs, key=len)  # first of the longest on ties
    out = np.zeros_like(mask)
    out[chosen[best]] = True
    return out


def _select_wall(xy: np.ndarray, tol: float, min_second: int, corner_angle: float) -> np.ndarray:
    """(N,) mask of the points of one wall (steps 1–3 of :func:`fit_cluster`)."""
    dir_on, dist_on = _dominant_line(xy, tol)
    off = dist_on > tol
    if np.count_nonzero(off) < min_second:
        return ~off
    dir_off, dist_off_sub = _dominant_line(xy[off], tol)
    if np.count_nonzero(dist_off_sub <= tol) < min_second:
        return np.ones(len(xy), dtype=bool)  # no second straight wall: one curved wall
    dist_off = _line_distances(xy[off][dist_off_sub <= tol], dir_off, xy)
    angle = np.arccos(min(abs(float(dir_on @ dir_off)), 1.0))
    if angle < corner_angle:
        return np.ones(len(xy), dtype=bool)  # a gentle bend, not a corner
    return np.asarray((dist_on <= dist_off) & (dist_on <= tol))


def _line_distances(fit_xy: np.ndarray, direction: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Perpendicular distances (N,) of ``xy`` to the line along ``direction`` through the
    centroid of ``fit_xy``."""
    normal = np.array([-direction[1], direction[0]])
    return np.abs((xy - fit_xy.mean(axis=0)) @ normal)


def _tls_direction(xy: np.ndarray) -> np.ndarray:
    """(2,) unit direction of the total-least-squares line through the points."""
    return np.asarray(np.linalg.svd(xy - xy.mean(axis=0), full_matrices=False)[2][0])


def _dominant_line(xy: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The line best supported by the points: its direction (2,) and all distances (N,) to it.

    Candidates are the lines through every pair of points (clusters hold ~ε_Z points); the
    score is the truncated quadratic Σ min(d², tol²) (MSAC), which prefers a tight wall over
    a diagonal band through both arms of a corner that merely counts more points within
    ``tol``. The winner is refined by total least squares on its inliers.
    """
    n_pts = len(xy)
    i, j = np.triu_indices(n_pts, k=1)
    chord = xy[j] - xy[i]  # (L, 2)
    length = np.linalg.norm(chord, axis=1)
    keep = length > 1e-9
    if n_pts < 3 or not keep.any():
        direction = _tls_direction(xy) if n_pts >= 2 else np.array([1.0, 0.0])
        return direction, _line_distances(xy, direction, xy)
    i, chord, length = i[keep], chord[keep], length[keep]
    normal = np.stack([-chord[:, 1], chord[:, 0]], axis=1) / length[:, None]  # (L, 2)
    dist = np.abs(np.einsum("lc,lnc->ln", normal, xy[None, :, :] - xy[i][:, None, :]))
    best = int(np.argmin((np.minimum(dist, tol) ** 2).sum(axis=1)))  # first on ties
    inliers = xy[dist[best] <= tol]
    direction = _tls_direction(inliers)
    return direction, _line_distances(inliers, direction, xy)


def polynomial_points(
    poly: Polynomial,
    c0_index: int,
    c0_var: float,
    n: int,
    lo: float,
    hi: float,
    n_state: int,
    turn: tuple[int, float] | None = None,
) -> PointSet:
    """:func:`~polyslam_env.slam.fitting.polynomial_points` in numpy (before
    :func:`~polyslam_env.slam.fit_kernels.sample_into`): its bit-for-bit oracle."""
    xy = equally_spaced(poly.coeffs, poly.variate, float(lo), float(hi), n)  # (n, 2)
    d_state = np.zeros((n, 2, n_state))
    d_state[:, 1 if poly.variate == 1 else 0, c0_index] = 1.0
    if turn is not None:
        turn_index, pivot = turn
        if not 3 <= turn_index < n_state or turn_index == c0_index:
            raise ValueError(f"turn index must be another state index, got {turn_index}")
        at = float(pivot)  # the curve's point there: points_at's floats, one compiled call
        centre = equally_spaced(poly.coeffs, poly.variate, at, at, 1)[0]  # (2,)
        d_state[:, :, turn_index] = (xy - centre) @ J_ROT.T
    return PointSet(
        xy=xy,
        d_state=d_state,
        d_noise=np.zeros((n, 2, 0)),
        noise_cov=np.zeros((0, 0)),
        weights=np.full(n, 1.0 / float(c0_var)),
    )


def stored_points(
    points: PointArrays, anchor_pose: np.ndarray, n_state: int, pose: np.ndarray | None = None
) -> PointSet:
    """:func:`~polyslam_env.slam.fitting.stored_points` in numpy (before
    :func:`~polyslam_env.slam.fit_kernels.stored_point_arrays`): its oracle, bit for bit at
    the anchor."""
    anchor = np.asarray(anchor_pose, dtype=float)
    at = anchor if pose is None else np.asarray(pose, dtype=float)
    e = np.zeros(len(points))
    xy0 = np.ascontiguousarray(points.xy, dtype=float)  # (N, 2)
    u = np.ascontiguousarray(points.direction, dtype=float)  # (N, 2)
    rel = (xy0 - anchor[:2]) @ rotation(at[2] - anchor[2]).T  # (N, 2) R(θ − θ̂)(π̂ − p̂)
    d_state = np.zeros((len(points), 2, n_state))
    d_state[:, :, :2] = np.eye(2)
    d_state[:, :, 2] = rel @ J_ROT.T
    return PointSet(
        xy=at[:2] + rel + e[:, None] * u,
        d_state=d_state,
        d_noise=diag_noise(u),
        noise_cov=np.diag([s**2 for s in points.sigma.tolist()]),  # Python's **: libm pow
        weights=np.array(points.weight, dtype=float),
    )

"""The merge test's geometry as readable numpy (the oracle of ``map_kernels.merge_test``):
the overlap of two polynomials on the first one's axis and their two-way RMS error γ there,
as ``slam/merging.py`` computed them before the test was compiled; and a polynomial's
steepest slope as numpy's polynomial functions find it (the oracle of
``Polynomial.max_slope``); and the end-to-end join's offset (the oracle of
``map_kernels.join_offset``); and the choice of a merge partner candidate by candidate
(the oracle of ``merging.choose_merge``'s one compiled call over them)."""

from __future__ import annotations

import numpy as np
import numpy.polynomial.polynomial as P

from polyslam_env.slam import kernels, map_kernels
from polyslam_env.slam.fitting import PointSet, sample_into
from polyslam_env.slam.landmarks import own_orders
from polyslam_env.slam.merging import (
    JOIN_ANGLE_DEG,
    MERGE_ANGLE_DEG,
    THIN_WALL,
    face_normal,
    unit_tangent,
)
from polyslam_env.slam.polynomial import Polynomial

_SAMPLES = 64  # samples of p2 used to project it on p's axis


def overlap_interval(poly: Polynomial, other: Polynomial) -> tuple[float, float, bool] | None:
    """Overlap [a, b] on ``poly``'s ξ axis of ``other`` projected there, and whether one
    includes the other; None when the projections are disjoint."""
    xi_other = poly.from_xy(other.equally_spaced(_SAMPLES))[0]  # (S,)
    lo2, hi2 = float(xi_other.min()), float(xi_other.max())
    a, b = max(poly.lo, lo2), min(poly.hi, hi2)
    if b < a:
        return None
    included = (poly.lo <= lo2 and hi2 <= poly.hi) or (lo2 <= poly.lo and poly.hi <= hi2)
    return a, b, included


def merge_gamma(poly: Polynomial, other: Polynomial, a: float, b: float) -> tuple[float, float]:
    """(γ, angle): two-way RMS approximation error and tangent angle (rad) over ξ ∈ [a, b] of p.

    γ = max(RMS error of ``other`` on m+1 equally spaced points of ``poly`` in the overlap,
    RMS error of ``poly`` on up to m+1 equally spaced samples of ``other`` projecting there);
    the angle is between the curves' tangents at the middle of their overlapping parts.
    """
    m = poly.order
    on_p = poly.equally_spaced(m + 1, a, b)  # (m+1, 2)
    gamma_p = _rms(_errors(on_p, other))
    xi_o = np.linspace(other.lo, other.hi, _SAMPLES)
    samples = other.points_at(xi_o)  # (S, 2)
    xi_s = poly.from_xy(samples)[0]
    inside = np.flatnonzero((xi_s >= a) & (xi_s <= b))
    if len(inside) == 0:
        inside = np.arange(_SAMPLES)
    pick = inside[np.unique(np.linspace(0, len(inside) - 1, m + 1).round().astype(int))]
    gamma_o = _rms(_errors(samples[pick], poly))
    t_p = unit_tangent(poly, 0.5 * (a + b))
    t_o = unit_tangent(other, float(xi_o[inside[len(inside) // 2]]))
    angle = float(np.arccos(min(abs(float(t_p @ t_o)), 1.0)))
    return max(gamma_p, gamma_o), angle


def _errors(points: np.ndarray, poly: Polynomial) -> np.ndarray:  # (k,)
    """The approximation error of each point (k, 2) by ``poly`` (the association's
    ``kernels.nearest_by_error`` with ``poly`` the one candidate)."""
    shape = np.zeros((1, poly.order + 1))
    shape[0, 1:] = poly.coeffs[1:]
    order = own_orders(shape)
    xy = np.ascontiguousarray(points, dtype=float)
    best, errors = np.empty(len(xy), dtype=np.int64), np.empty(len(xy))
    kernels.nearest_by_error(
        xy, np.zeros(1, dtype=np.int64), np.array([poly.variate], dtype=np.int64), order, shape,
        np.array([poly.lo]), np.array([poly.hi]), np.array([poly.c0]), False, best, errors,
    )  # fmt: skip
    return errors


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def max_slope(poly: Polynomial) -> float:
    """``Polynomial.max_slope`` as numpy's polynomial functions compute it, for any order:
    the slope at the ends and at the real roots of p'' inside the extent."""
    curvature = P.polytrim(P.polyder(poly.coeffs, 2))
    turns = P.polyroots(curvature) if len(curvature) > 1 else np.zeros(0)
    real = turns.real[np.abs(turns.imag) <= 1e-9 * np.maximum(1.0, np.abs(turns.real))]
    inside = real[(real > poly.lo) & (real < poly.hi)]
    return float(np.max(np.abs(poly.slope(np.concatenate([[poly.lo, poly.hi], inside])))))


def join_gamma(poly: Polynomial, other: Polynomial, max_gap: float) -> float | None:
    """``merging.join_gamma`` on numpy arrays, as it was before its end points went to plain
    floats (the oracle, bit for bit; of ``map_kernels.join_offset`` since)."""
    ends_p = poly.points_at(np.array([poly.lo, poly.hi]))  # (2, 2)
    ends_o = other.points_at(np.array([other.lo, other.hi]))
    gaps = np.linalg.norm(ends_p[:, None, :] - ends_o[None, :, :], axis=2)  # (2, 2)
    i, k = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
    if gaps[i, k] > max_gap:
        return None
    t_p = unit_tangent(poly, poly.lo if i == 0 else poly.hi)
    t_o = unit_tangent(other, other.lo if k == 0 else other.hi)
    if np.degrees(np.arccos(min(abs(float(t_p @ t_o)), 1.0))) > JOIN_ANGLE_DEG:
        return None
    delta = ends_o[k] - ends_p[i]
    cross = [float(t[0] * delta[1] - t[1] * delta[0]) for t in (t_p, t_o)]
    offset = max(abs(cross[0]), abs(cross[1]))
    return offset if offset <= THIN_WALL else None


def choose_merge(
    new_poly: Polynomial,
    new_c0: float,
    polys: list[Polynomial],
    c0s: list[float],
    gamma_max: float,
    min_overlap: float,
    new_side: int,
    sides: list[int],
    join_gap: float | None,
) -> tuple[int, float, bool] | None:
    """``merging.choose_merge`` as it was before its merge tests ran in one compiled call
    (the oracle): candidate by candidate, the merge test against the best γ so far (the tangents
    checked only where γ would count), a join tried where no γ was measured."""
    p = new_poly.with_c0(new_c0)
    best: tuple[int, float, bool] | None = None
    best_gamma = gamma_max
    found = np.empty(4)
    for j, (p2, c02) in enumerate(zip(polys, c0s, strict=True)):
        other = p2.with_c0(float(c02))
        side = sides[j]
        opposite = new_side * side < 0 and _faces_opposite(p, new_side, other, side)
        limit = min(best_gamma, THIN_WALL) if opposite else best_gamma
        below = None if join_gap is not None else limit
        gamma: float | None = None
        measured = map_kernels.merge_test(
            p.variate, p.coeffs, p.lo, p.hi, other.variate, other.coeffs, other.lo, other.hi,
            min_overlap, found,
        )  # fmt: skip
        if measured == map_kernels.MEASURED and (below is None or found[2] < below):
            a, b, g, xi_other = found.tolist()
            t_p = unit_tangent(p, 0.5 * (a + b))
            t_o = unit_tangent(other, xi_other)
            angle = float(np.arccos(min(abs(float(t_p @ t_o)), 1.0)))
            gamma = g if np.degrees(angle) <= MERGE_ANGLE_DEG else None
        joined = False
        if gamma is None and join_gap is not None:
            gamma, joined = join_gamma(p, other, join_gap), True
        if gamma is not None and gamma < limit:
            best, best_gamma = (j, gamma, joined), gamma
    return best


def _faces_opposite(poly: Polynomial, side: int, other: Polynomial, other_side: int) -> bool:
    n_p = face_normal(poly, 0.5 * (poly.lo + poly.hi), side)
    n_o = face_normal(other, 0.5 * (other.lo + other.hi), other_side)
    return float(n_p @ n_o) < 0.0


def merge_points(
    poly_a: Polynomial,
    c0_index_a: int,
    c0_var_a: float,
    poly_b: Polynomial,
    c0_index_b: int,
    c0_var_b: float,
    eps_m: int,
    n_state: int,
    turn_a: tuple[int, float] | None = None,
    turn_b: tuple[int, float] | None = None,
) -> PointSet:
    """ε_M equally spaced points on each polynomial (whole extents), for the merged LMS fit:
    the points of ``merging.merge_fit`` (its oracle with :func:`~polyslam_env.slam.fitting.
    fit_polynomial`), each set weighing 1/var(c0) of its own landmark, with ∂π/∂α on their
    turns α with ``turn_a``, ``turn_b`` = (α's state index, pivot ξ)."""
    n = 2 * eps_m
    out = np.empty((n, 2)), np.zeros((n, 2, n_state)), np.empty(n)
    sample_into(poly_a, c0_index_a, c0_var_a, (poly_a.lo, poly_a.hi, eps_m), turn_a, out, 0)
    sample_into(poly_b, c0_index_b, c0_var_b, (poly_b.lo, poly_b.hi, eps_m), turn_b, out, eps_m)
    xy, d_state, weights = out
    return PointSet(xy, d_state, np.zeros((n, 2, 0)), np.zeros((0, 0)), weights)

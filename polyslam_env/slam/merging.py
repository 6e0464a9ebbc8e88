"""Map merging (paper §3.3, SPEC §3 "Map merging").

When a new (or received) polynomial p overlaps a map polynomial p2 — one's extent includes
the other's, or they overlap for at least ``min_overlap`` metres — take m+1 equally spaced
points on p in the overlap; if the RMS approximation error γ of p2 on them is below γ_M the
two are replaced by one weighted LMS polynomial through ε_M equally spaced points on each
(:func:`merge_points` → :func:`~polyslam_env.slam.fitting.fit_polynomial`).

Choices where the paper is silent:

* overlap is measured on the new polynomial's independent axis ξ: p2 is sampled and projected
  on it, so polynomials of different variates compare geometrically;
* ``min_overlap`` defaults to 0.1 m (about two beam spacings at 1 m range: shorter overlaps are
  end-to-end contacts of successive walls, not the same stretch of wall);
* γ is checked both ways (p2 on points of p, and p on points of p2 in the overlap) and the
  tangents of the two curves in the overlap must be within ``max_angle_deg`` (30°): with the
  paper's γ_M = 0.35 m the one-sided test alone would merge perpendicular walls at a corner,
  whose projection on p's axis is a short interval "included" in p.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from polyslam_env.slam.association import nearest_by_error
from polyslam_env.slam.fitting import PointSet, concat, polynomial_points
from polyslam_env.slam.landmarks import pack
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
    t_p = _tangent(poly, 0.5 * (a + b))
    t_o = _tangent(other, float(xi_o[inside[len(inside) // 2]]))
    angle = float(np.arccos(min(abs(float(t_p @ t_o)), 1.0)))
    return max(gamma_p, gamma_o), angle


def _errors(points: np.ndarray, poly: Polynomial) -> np.ndarray:  # (k,)
    """The approximation error of each point (k, 2) by ``poly`` (``nearest_by_error``)."""
    rows = pack([poly]).rows()
    return np.array([eps for _, eps in nearest_by_error(points.tolist(), [0], rows, [poly.c0])])


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def _tangent(poly: Polynomial, xi: float) -> np.ndarray:
    """(2,) unit tangent of the curve at ξ, in (x¹, x²)."""
    slope = float(poly.slope(xi))
    t = np.array([1.0, slope]) if poly.variate == 1 else np.array([slope, 1.0])
    return np.asarray(t / np.linalg.norm(t))


def find_merge(
    new_poly: Polynomial,
    new_c0: float,
    polys: Sequence[Polynomial],
    c0s: Sequence[float] | np.ndarray,
    gamma_max: float,
    min_overlap: float = 0.1,
    max_angle_deg: float = 30.0,
    exclude: int | None = None,
) -> int | None:
    """Index of the map polynomial to merge ``new_poly`` with (smallest γ < γ_M), or None.

    ``exclude`` skips one index (the new polynomial itself when it is already in the map).
    """
    p = new_poly.with_c0(new_c0)
    best: int | None = None
    best_gamma = gamma_max
    for j, (p2, c02) in enumerate(zip(polys, c0s, strict=True)):
        if j == exclude:
            continue
        other = p2.with_c0(float(c02))
        overlap = overlap_interval(p, other)
        if overlap is None:
            continue
        a, b, included = overlap
        if not (included or b - a >= min_overlap):
            continue
        gamma, angle = merge_gamma(p, other, a, b)
        if gamma < best_gamma and np.degrees(angle) <= max_angle_deg:
            best, best_gamma = j, gamma
    return best


def merge_points(
    poly_a: Polynomial,
    c0_index_a: int,
    c0_var_a: float,
    poly_b: Polynomial,
    c0_index_b: int,
    c0_var_b: float,
    eps_m: int,
    n_state: int,
) -> PointSet:
    """ε_M equally spaced points on each polynomial (whole extents), for the merged LMS fit.

    Both polynomials must carry their current c0; each set weighs 1/var(c0) of its own
    landmark, so the fit's G_x has entries on both c0s.
    """
    return concat(
        polynomial_points(poly_a, c0_index_a, c0_var_a, eps_m, poly_a.lo, poly_a.hi, n_state),
        polynomial_points(poly_b, c0_index_b, c0_var_b, eps_m, poly_b.lo, poly_b.hi, n_state),
    )

"""Landmark extraction and data association (paper §3.1, SPEC §3).

Each beam point π is compared with every map polynomial by the approximation error ε
(:func:`nearest_by_error`); with p* the best polynomial:

* ε ≤ ρ_k — good: the beam updates c0 of p* in the EKF;
* ρ_k < ε ≤ σ_k — the point joins Q_bad(p*); when |Q_bad| > ε_M, p* is refit on Q_bad ∪ R;
* ε > σ_k — the point joins the cluster with most points within radius R (or a new one);
  when a cluster holds more than ε_Z points it becomes a new polynomial (:func:`fit_cluster`).

Not in the paper (``SlamConfig.stretch_ends``): a point with ε > ρ_k that lies past p*'s end by
at most :data:`GAP_SPLIT` and on p*'s curve continued there (the caller's ``extends`` test) is
the same wall seen a little further on: it stretches p*'s extent to itself instead of waiting
in a cluster. A wall whose hits are sparse (a beam sweeping it at range, 0.3 m apart at full
speed) then grows hit by hit, as it would with denser hits through the paper's case 1; a gap
wider than :data:`GAP_SPLIT` (a doorway) is never crossed.

The association runs compiled over the map's buffers
(:func:`~polyslam_env.slam.map_kernels.associate_scan`, in the step's first call): it stores
the clusters' and Q_bad sets' points (:class:`~polyslam_env.slam.stored.StoredPoints`),
stretches extents, and leaves the rare rest as requests: the caller builds their point sets
(:func:`qbad_refit_points`, :func:`fit_cluster`), fits them and augments / removes state
entries and the landmark table's rows. It never touches the EKF.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from polyslam_env.slam import fit_kernels, kernels
from polyslam_env.slam.fitting import (
    MAX_SLOPE,
    Fit,
    PointSet,
    concat,
    fit_polynomial,
    polynomial_points,
    stored_points,
)
from polyslam_env.slam.landmarks import ShapeArrays, ShapeRow, shape_arrays
from polyslam_env.slam.map_kernels import GAP_SPLIT
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.stored import PointArrays

__all__ = [
    "GAP_SPLIT",
    "ClusterFit",
    "fit_cluster",
    "nearest_by_error",
    "qbad_refit_points",
]


# -- approximation error ---------------------------------------------------------------------
def nearest_by_error(
    xy: Sequence[Sequence[float]] | np.ndarray,
    candidates: Sequence[int] | np.ndarray,
    shapes: ShapeArrays | Sequence[ShapeRow],
    c0s: Sequence[float] | np.ndarray,
    squared: bool = False,
) -> list[tuple[int, float]]:
    """Per point (``xy`` (P, 2)), (index of the landmark with the smallest approximation
    error ε, that ε) over ``candidates``, or (−1, inf) without candidates.

    ε of a point by a polynomial: inside its extent the vertical (variate 1) / horizontal
    (variate 2) distance |η − p(ξ)|; outside, the distance to the nearer end point; metres, or
    the paper's squared form with ``squared=True``. Compiled
    (:func:`~polyslam_env.slam.kernels.nearest_by_error`); ``shapes`` as
    ``LandmarkTable.arrays()`` or rows."""
    arrays = shape_arrays(shapes)
    points = np.ascontiguousarray(xy, dtype=float).reshape(-1, 2)
    cand = np.asarray(candidates, dtype=np.int64).reshape(-1)
    c0 = np.ascontiguousarray(c0s, dtype=float)
    n = len(arrays.variate)
    if c0.shape != (n,):
        raise ValueError(f"c0s must have shape ({n},), got {c0.shape}")
    best, err = np.empty(len(points), dtype=np.int64), np.empty(len(points))
    kernels.nearest_by_error(points, cand, *arrays, c0, bool(squared), best, err)
    return list(zip(best.tolist(), err.tolist(), strict=True))


# -- building the fits ----------------------------------------------------------------------
def qbad_refit_points(
    qbad: PointArrays,
    poly: Polynomial,
    c0_index: int,
    c0_var: float,
    eps_m: int,
    anchor_pose: np.ndarray,
    n_state: int,
    turn: tuple[int, float] | None = None,
) -> PointSet:
    """Q_bad ∪ R: the stored bad points plus ε_M equally spaced points on p* (full extent).

    ``poly`` must carry the current c0; the fit's G_x then has entries on the pose (through
    the stored points) and on the old c0 (through R), and on p*'s turn α with ``turn`` =
    (α's state index, pivot ξ) (:func:`~polyslam_env.slam.fitting.polynomial_points`).
    """
    on_poly = polynomial_points(poly, c0_index, c0_var, eps_m, poly.lo, poly.hi, n_state, turn)
    return concat(stored_points(qbad, anchor_pose, n_state), on_poly)


@dataclass(frozen=True, eq=False)
class ClusterFit:
    """A cluster's new landmark (or None) and how the cluster's points were split."""

    fit: Fit | None
    used: PointArrays
    leftover: PointArrays  # given back as a cluster (StoredPoints.add_cluster)


def fit_cluster(
    points: PointArrays,
    anchor_pose: np.ndarray,
    n_state: int,
    max_rms: float,
    order: int = 3,
    line_tol: float | None = None,
    min_second: int = 3,
    corner_angle_deg: float = 30.0,
    shape_fixed: bool = False,
    auto_order: bool = False,
    min_noise_var: float = 0.0,
    max_gap: float | None = None,
    curvature_test: bool = False,
) -> ClusterFit:
    """A new polynomial from a cluster, without cutting across corners or gaps.

    The paper fits one cubic to the whole cluster, but a cluster of radius R = 0.35 m can
    straddle a corner, and a cubic through both walls rounds the corner off (by ~5 cm for a
    45°-rotated right angle, where its rms still passes ρ_k). So:

    1. find the dominant line: the MSAC-best line through a pair of points, with inlier
       tolerance ``line_tol`` (default 3 × the largest range σ, ≥ 1 cm: the points' mutual
       consistency depends on the range noise, not on the absolute pose uncertainty);
    2. fewer than ``min_second`` points off it: fit the line's points (one or two strays
       cannot make a wall; they are left over);
    3. otherwise find the dominant line of the off-line points; if it has ≥ ``min_second``
       points and makes ≥ ``corner_angle_deg`` with the first, it is a corner: fit the points
       within ``line_tol`` of the first line and nearer to it than to the second. Otherwise
       the points are one curved wall and all are fitted;
    3b. the wall's points are ordered along its principal direction and cut at every gap
       wider than ``max_gap`` (default :data:`GAP_SPLIT`: a doorway or an occlusion, which a
       polynomial must not bridge); the run with most points is fitted (ties: the first);
    4. the fit is accepted with ≥ order + 2 points, rms ≤ ``max_rms`` (the caller's ρ_k) and
       no tangent steeper than :data:`~polyslam_env.slam.fitting.MAX_SLOPE` on its extent;
       otherwise no landmark and every point is left over. ``shape_fixed`` is passed to
       :func:`~polyslam_env.slam.fitting.fit_polynomial`, and so are ``auto_order``,
       ``min_noise_var`` and ``curvature_test``.

    Bounds (tested): for a noiseless right-angle corner the polynomial lies on one wall
    (1e-6 m); with σ = 2 cm range noise and arms of 0.3–0.4 m it stays within 0.15 m of one
    wall, where the paper's single cubic spans both (≈ 0.3 m off either wall). A wall bending
    by more than ``corner_angle_deg`` within a cluster becomes two landmarks.
    """
    xy = np.ascontiguousarray(points.xy, dtype=float)  # (N, 2)
    tol = line_tol if line_tol is not None else max(3.0 * max(points.sigma.tolist()), 0.01)
    gap = GAP_SPLIT if max_gap is None else max_gap
    mask = fit_kernels.wall_mask(xy, tol, min_second, math.radians(corner_angle_deg), gap)
    if np.count_nonzero(mask) >= min(order + 2, len(points)) and np.count_nonzero(mask) >= 2:
        used = points.subset(mask)
        fit = fit_polynomial(
            stored_points(used, anchor_pose, n_state),
            order,
            None,
            shape_fixed,
            auto_order,
            min_noise_var,
            curvature_test,
        )
        if fit.rms <= max_rms and fit.poly.max_slope() <= MAX_SLOPE:
            return ClusterFit(fit, used, points.subset(~mask))
    return ClusterFit(None, points.subset(np.zeros(len(points), dtype=bool)), points)

"""How good a robot's map is: mapping error ν (both forms), completeness, hit fraction.

Maps are polynomials in the robot's start frame; they are sampled along their arc length and
moved to the absolute frame before they are compared with the true boundary.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from polyslam_env.core.geometry import transform_points
from polyslam_env.metrics.boundary import boundary_samples, distance_to_boundary
from polyslam_env.metrics.pose import _check_pose
from polyslam_env.slam.polynomial import Polynomial, polyval_rows
from polyslam_env.world.layout import Layout


# -- mapping error and completeness -----------------------------------------------------------
def sample_arclength_batch(
    polys: Sequence[Polynomial], step: float, dense: int = 512
) -> list[np.ndarray]:
    """``[p.sample_arclength(step, dense) for p in polys]``, bit for bit, in one numpy pass.

    The completeness resamples a whole map whenever it changes, and one polynomial at a time
    the overhead of ~15 numpy calls each dominates. Every operation here is elementwise or runs
    along one row (linspace, Horner, diff, cumsum) exactly as in
    :meth:`~polyslam_env.slam.polynomial.Polynomial.sample_arclength`, so the points are the
    same; only ``np.interp`` runs per polynomial. A zero extent (or a ξ step that underflows
    to 0, which linspace treats apart) takes the polynomial's own method.
    """
    out = [np.zeros((0, 2))] * len(polys)
    batch: list[Polynomial] = []  # (Q) the polynomials done here, and their places in out
    places: list[int] = []
    for k, poly in enumerate(polys):
        if (poly.hi - poly.lo) / (dense - 1) != 0.0:
            batch.append(poly)
            places.append(k)
        else:
            out[k] = poly.sample_arclength(step, dense)
    if not batch:
        return out
    coeffs = np.zeros((len(batch), max(len(p.coeffs) for p in batch)))  # (Q, m+1), zero-padded
    for row, poly in enumerate(batch):
        coeffs[row, : len(poly.coeffs)] = poly.coeffs
    lo = np.array([p.lo for p in batch])  # (Q,)
    hi = np.array([p.hi for p in batch])
    # linspace(lo, hi, dense) per row, as numpy computes it: k · ((hi − lo) / (dense − 1)) + lo,
    # the last one set to hi (a linspace call with array ends is slower than this).
    xi = np.arange(dense, dtype=float) * ((hi - lo) / (dense - 1))[:, None] + lo[:, None]
    xi[:, -1] = hi  # (Q, dense)
    eta = polyval_rows(coeffs, xi)
    # Arc length: the norm of each (Δx, Δy) is sqrt(Δx² + Δy²) (add.reduce of two squares),
    # and Δξ² + Δη² is the same sum whichever of ξ, η is x.
    dxi, deta = np.diff(xi, axis=1), np.diff(eta, axis=1)  # (Q, dense − 1)
    arc = np.zeros((len(batch), dense))  # (Q, dense)
    np.cumsum(np.sqrt(dxi * dxi + deta * deta), axis=1, out=arc[:, 1:])
    total = arc[:, -1]  # (Q,)
    counts = np.maximum(np.floor(total / step).astype(np.intp) + 1, 2)  # (Q,)
    # linspace(0, total, n) per row, the same way: k · (total / (n − 1)) + 0, the last = total.
    owner = np.repeat(np.arange(len(batch)), counts)  # (M,)
    ends = np.cumsum(counts)
    index = np.arange(len(owner)) - np.repeat(ends - counts, counts)  # (M,) within its row
    targets = index.astype(float) * (total / (counts - 1))[owner] + 0.0
    targets[ends - 1] = total
    xi_q = np.concatenate(
        [
            np.interp(targets[end - n : end], arc[row], xi[row])
            for row, (n, end) in enumerate(zip(counts.tolist(), ends.tolist(), strict=True))
        ]
    )  # (M,)
    eta_q = polyval_rows(coeffs[owner], xi_q[:, None])[:, 0]
    second = np.array([p.variate == 2 for p in batch])[owner]  # (M,): ξ is y
    pts = np.column_stack([np.where(second, eta_q, xi_q), np.where(second, xi_q, eta_q)])
    for k, n, end in zip(places, counts.tolist(), ends.tolist(), strict=True):
        out[k] = pts[end - n : end]
    return out


def map_points(
    polys: Sequence[Polynomial], start_pose: np.ndarray, step: float = 0.01
) -> list[np.ndarray]:
    """Each polynomial's points every ``step`` of arc length, in the absolute frame: (n_q, 2)."""
    x0 = _check_pose(start_pose)
    own = sample_arclength_batch(polys, step)
    if not own:
        return []
    # One transform for all points (it is pointwise, so the same numbers as one per polynomial).
    return np.split(transform_points(np.vstack(own), x0), np.cumsum([len(q) for q in own])[:-1])


def map_distances(
    polys: Sequence[Polynomial], start_pose: np.ndarray, layout: Layout, step: float = 0.01
) -> list[np.ndarray]:
    """Per polynomial, δ (n_q,): distance of each arc-length sample to the true boundary."""
    pts = map_points(polys, start_pose, step)
    if not pts:
        return []
    d = distance_to_boundary(np.vstack(pts), layout)
    return np.split(d, np.cumsum([len(p) for p in pts])[:-1])


def nu(
    polys: Sequence[Polynomial], start_pose: np.ndarray, layout: Layout, step: float = 0.01
) -> float:
    """ν_j = (1/n_j) Σ_q Σ_i δ_{q,i}, the paper's form (a sum per polynomial, so it grows with
    polynomial length and the sampling step matters). 0.0 for an empty map: the paper's sum is
    empty; use :func:`completeness` so that mapping nothing is not rewarded."""
    ds = map_distances(polys, start_pose, layout, step)
    return float(np.mean([d.sum() for d in ds])) if ds else 0.0


def nu_mean(
    polys: Sequence[Polynomial], start_pose: np.ndarray, layout: Layout, step: float = 0.01
) -> float:
    """Mean δ over all map points (metres). NaN for an empty map (no points, no error defined):
    callers should skip it when averaging (``np.nanmean``) and report the count of empty maps;
    a reward should treat it as "no change"."""
    ds = map_distances(polys, start_pose, layout, step)
    return float(np.concatenate(ds).mean()) if ds else float("nan")


def _covered_fraction(points: np.ndarray, layout: Layout, tol: float, step: float) -> float:
    """Fraction of the true boundary length within ``tol`` of some point (N, 2)."""
    if tol < 0:
        raise ValueError(f"tol must be >= 0, got {tol}")
    bpts, weights = boundary_samples(layout, step)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    total = float(weights.sum())
    if len(pts) == 0 or total == 0.0:
        return 0.0
    d, _ = cKDTree(pts).query(bpts, k=1, distance_upper_bound=tol)
    return float(weights[np.isfinite(d)].sum()) / total


def completeness(
    polys: Sequence[Polynomial],
    start_pose: np.ndarray,
    layout: Layout,
    tol: float = 0.05,
    step: float = 0.01,
) -> float:
    """Fraction of the true boundary length within ``tol`` of the map (0.0 for an empty map).

    Both the boundary and the polynomials are sampled every ``step``; a boundary piece counts
    when its centre is within ``tol`` of a polynomial sample (so within tol ± step/2).
    """
    pts = map_points(polys, start_pose, step)
    return _covered_fraction(np.vstack(pts) if pts else np.zeros((0, 2)), layout, tol, step)


def hit_fraction(
    hit_points_abs: np.ndarray, layout: Layout, tol: float = 0.05, step: float = 0.01
) -> float:
    """Fraction of the true boundary within ``tol`` of the beams' hit points (H, 2), absolute.

    This is the boundary the robot could have mapped (the denominator of the completeness
    target); it doubles as the "boundary coverage" exploration metric. Non-finite rows
    (no return) are ignored.
    """
    return _covered_fraction(hit_points_abs, layout, tol, step)

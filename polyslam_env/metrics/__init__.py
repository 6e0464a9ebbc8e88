"""Evaluation metrics (SPEC §5): NEES, mapping error ν, completeness and area coverage.

Each robot estimates in its own start frame R_{j,0}. Its true start pose x_{j,0} = (x0, y0, θ0)
in the absolute frame is known here (never to the robot), so estimates and maps are mapped to
the absolute frame before they are compared with ground truth:
``x_abs = x0 + R(θ0) [x, y]``, ``θ_abs = θ0 + θ``, ``P_abs = T P Tᵀ`` with
``T = blockdiag(R(θ0), 1)``.

numpy/scipy only: no pymunk, no PettingZoo. The SLAM wall time τ is measured by its caller.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import chi2

from polyslam_env.core import raster
from polyslam_env.core.geometry import compose, transform_covariance, transform_points, wrap_angle
from polyslam_env.slam.polynomial import Polynomial, polyval_rows
from polyslam_env.world.layout import Layout

__all__ = [
    "CoverageGrid",
    "boundary_points",
    "boundary_samples",
    "completeness",
    "cov_to_absolute",
    "distance_to_boundary",
    "hit_fraction",
    "map_distances",
    "map_points",
    "nees",
    "nees_band",
    "nees_paper",
    "nees_paper_series",
    "nees_series",
    "nu",
    "nu_mean",
    "pose_to_absolute",
    "time_to_fraction",
    "wrap_angle",
]

# Spacing of the dense boundary samples behind the distance tree: the nearest sample is at most
# half of it away from the true nearest boundary point, so distances err by ≤ 1 mm at worst
# (and are exact whenever the nearest segment is among the K_REFINE nearest samples' segments).
_TREE_SPACING = 0.002
_K_REFINE = 4


# -- frames ---------------------------------------------------------------------------------


def _check_pose(start_pose: np.ndarray) -> np.ndarray:  # (3,)
    p = np.asarray(start_pose, dtype=float)
    if p.shape != (3,):
        raise ValueError(f"start_pose must have shape (3,), got {p.shape}")
    return p


def pose_to_absolute(poses: np.ndarray, start_pose: np.ndarray) -> np.ndarray:  # (K, 3)
    """Poses (K, 3) in the robot's start frame to the absolute frame (heading wrapped)."""
    x0 = _check_pose(start_pose)
    p = np.asarray(poses, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must have shape (K, 3), got {p.shape}")
    return compose(x0, p)


def cov_to_absolute(covs: np.ndarray, start_pose: np.ndarray) -> np.ndarray:  # (K, 3, 3)
    """Pose covariances (K, 3, 3) in the start frame to the absolute frame: T P Tᵀ."""
    x0 = _check_pose(start_pose)
    c = np.asarray(covs, dtype=float)
    if c.ndim != 3 or c.shape[1:] != (3, 3):
        raise ValueError(f"covs must have shape (K, 3, 3), got {c.shape}")
    return transform_covariance(c, x0)


# -- NEES -----------------------------------------------------------------------------------
def _pose_errors(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute-frame errors (K, 3) (heading wrapped) and covariances (K, 3, 3)."""
    truth = np.asarray(true_poses, dtype=float)
    est = pose_to_absolute(est_poses, start_pose)
    cov = cov_to_absolute(est_covs, start_pose)
    if truth.shape != est.shape or len(cov) != len(est):
        raise ValueError(
            f"shapes disagree: true {truth.shape}, estimate {est.shape}, covariance {cov.shape}"
        )
    err = truth - est
    err[:, 2] = wrap_angle(err[:, 2])
    return err, cov


def nees_series(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> np.ndarray:  # (K,)
    """Per-step NEES eᵀP⁻¹e (standard form, via ``solve``); raises LinAlgError on singular P."""
    err, cov = _pose_errors(true_poses, est_poses, est_covs, start_pose)
    sol = np.linalg.solve(cov, err[..., None])[..., 0]  # (K, 3)
    return np.asarray(np.einsum("ki,ki->k", err, sol))


def nees_paper_series(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> np.ndarray:  # (K,)
    """Per-step eᵀPe, the index as the paper prints it (gives its ~1e-6 values)."""
    err, cov = _pose_errors(true_poses, est_poses, est_covs, start_pose)
    return np.asarray(np.einsum("ki,kij,kj->k", err, cov, err))


def _mean_of(series: np.ndarray) -> float:
    if len(series) == 0:
        raise ValueError("NEES needs at least one step")
    return float(series.mean())


def nees(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> float:
    """μ_j: mean over steps of eᵀP⁻¹e; ≈ 3 for a consistent filter on a 3-D pose.

    ``true_poses`` (K, 3) are absolute; ``est_poses`` (K, 3) and ``est_covs`` (K, 3, 3) are in
    the robot's start frame and are mapped through ``start_pose`` first.
    """
    return _mean_of(nees_series(true_poses, est_poses, est_covs, start_pose))


def nees_paper(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> float:
    """μ_j as the paper literally writes it: mean of eᵀPe (same arguments as :func:`nees`)."""
    return _mean_of(nees_paper_series(true_poses, est_poses, est_covs, start_pose))


def nees_band(dof: int = 3, runs: int = 1, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` χ² band for the NEES at one step averaged over ``runs`` runs.

    ``runs · NEES̄ ~ χ²(runs · dof)`` for a consistent filter. The band is for run-averages at a
    fixed step; a time average over one run has correlated terms and no such simple band.
    """
    if dof < 1 or runs < 1 or not 0.0 < prob < 1.0:
        raise ValueError(f"need dof >= 1, runs >= 1, 0 < prob < 1; got {dof}, {runs}, {prob}")
    n = dof * runs
    lo = float(chi2.ppf((1.0 - prob) / 2.0, n)) / runs
    hi = float(chi2.ppf((1.0 + prob) / 2.0, n)) / runs
    return lo, hi


# -- the true boundary ----------------------------------------------------------------------
_BoundaryCache = dict[tuple[str, float], tuple[np.ndarray, ...]]
_CACHE: weakref.WeakKeyDictionary[Layout, _BoundaryCache] = weakref.WeakKeyDictionary()
_TREES: weakref.WeakKeyDictionary[Layout, tuple[cKDTree | None, np.ndarray]] = (
    weakref.WeakKeyDictionary()
)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _segment_samples(
    segs: np.ndarray, step: float, midpoints: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (M, 2), weights (M,) and segment ids (M,) spaced ≤ ``step`` along each segment.

    ``midpoints``: the centres of n = ⌈L/step⌉ equal pieces, each weighing L/n (for length
    fractions); otherwise n + 1 points including both ends (so corners are exact).
    """
    lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])  # (S,)
    pieces = np.maximum(np.ceil(lengths / step).astype(int), 1)
    counts = pieces if midpoints else pieces + 1
    seg_id = np.repeat(np.arange(len(segs)), counts)  # (M,)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    k = np.arange(len(seg_id)) - first
    frac = (k + 0.5) / pieces[seg_id] if midpoints else k / pieces[seg_id]
    a, b = segs[seg_id, 0:2], segs[seg_id, 2:4]
    pts = a + frac[:, None] * (b - a)
    return pts, lengths[seg_id] / pieces[seg_id], seg_id


def _pillar_samples(pillars: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) and weights (M,) at the centres of equal arcs ≤ ``step`` on each pillar."""
    if len(pillars) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    circ = 2.0 * np.pi * pillars[:, 2]
    pieces = np.maximum(np.ceil(circ / step).astype(int), 3)
    pid = np.repeat(np.arange(len(pillars)), pieces)
    k = np.arange(len(pid)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    ang = 2.0 * np.pi * (k + 0.5) / pieces[pid]
    p = pillars[pid]
    pts = np.column_stack([p[:, 0] + p[:, 2] * np.cos(ang), p[:, 1] + p[:, 2] * np.sin(ang)])
    return pts, circ[pid] / pieces[pid]


def boundary_samples(layout: Layout, step: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The true boundary (wall segments and pillar circles) sampled every ≤ ``step`` metres.

    Returns points (M, 2) at the centres of equal pieces and the length each stands for (M,),
    so weighted sums give boundary lengths. Cached per layout; the arrays are read-only.
    """
    if step <= 0:
        raise ValueError(f"step must be > 0, got {step}")
    per_layout = _CACHE.setdefault(layout, {})
    key = ("samples", float(step))
    if key not in per_layout:
        wp, ww, _ = _segment_samples(layout.segments, step, midpoints=True)
        pp, pw = _pillar_samples(np.asarray(layout.pillars, dtype=float), step)
        per_layout[key] = (_frozen(np.vstack([wp, pp])), _frozen(np.concatenate([ww, pw])))
    pts, weights = per_layout[key]
    return pts, weights


def boundary_points(layout: Layout, step: float = 0.01) -> np.ndarray:  # (M, 2)
    """The true boundary sampled every ≤ ``step`` metres (see :func:`boundary_samples`)."""
    return boundary_samples(layout, step)[0]


def _wall_tree(layout: Layout) -> tuple[cKDTree | None, np.ndarray]:
    """KD-tree over dense wall samples (with ends) and each sample's segment id; cached."""
    if layout not in _TREES:
        if len(layout.segments) == 0:
            _TREES[layout] = (None, np.zeros(0, dtype=int))
        else:
            pts, _, seg_id = _segment_samples(layout.segments, _TREE_SPACING, midpoints=False)
            _TREES[layout] = (cKDTree(pts), seg_id)
    return _TREES[layout]


def _paired_segment_distance(points: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Distance from points (…, 2) to the segment (…, 4) paired with each: shape (…)."""
    a, b = segs[..., 0:2], segs[..., 2:4]
    ab = b - a
    denom = np.maximum(np.einsum("...i,...i->...", ab, ab), 1e-300)
    t = np.clip(np.einsum("...i,...i->...", points - a, ab) / denom, 0.0, 1.0)
    return np.asarray(np.linalg.norm(points - (a + t[..., None] * ab), axis=-1))


def distance_to_boundary(points: np.ndarray, layout: Layout) -> np.ndarray:  # (N,)
    """Distance from each point (N, 2) to the nearest true boundary point (walls, pillars).

    Walls: a KD-tree over samples every 2 mm gives the K nearest samples; the exact
    point-to-segment distance to their segments refines it. The result lies between the exact
    distance and the exact distance + 1 mm, and is exact in practice. Pillars: exact |‖q−c‖ − r|.
    """
    q = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(layout.segments) == 0 and len(layout.pillars) == 0:
        raise ValueError(f"layout {layout.name!r} has no walls and no pillars")
    dist = np.full(len(q), np.inf)
    tree, seg_id = _wall_tree(layout)
    if tree is not None and len(q):
        k = min(_K_REFINE, tree.n)
        d_s, idx = tree.query(q, k=k)
        d_s, idx = d_s.reshape(len(q), k), idx.reshape(len(q), k)
        cand = layout.segments[seg_id[idx]]  # (N, k, 4)
        exact = _paired_segment_distance(q[:, None, :], cand).min(axis=1)
        dist = np.minimum(exact, d_s[:, 0])
    if len(layout.pillars):
        p = np.asarray(layout.pillars, dtype=float)
        dp = np.abs(np.hypot(q[:, None, 0] - p[:, 0], q[:, None, 1] - p[:, 1]) - p[:, 2])
        dist = np.minimum(dist, dp.min(axis=1))
    return dist


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


# -- coverage -------------------------------------------------------------------------------
class CoverageGrid:
    """Which free cells any range beam has swept, for the team and per robot.

    Grid convention: ``free[i, j]`` is the cell x ∈ [ox + j·res, ox + (j+1)·res),
    y ∈ [oy + i·res, oy + (i+1)·res) with ``origin = (ox, oy)`` its lower-left corner (row
    index grows with y). Beams are sampled every res/2 (both ends included), so a cell that a
    beam crosses over at least res/2 is always marked and a barely clipped corner may not be.
    """

    def __init__(self, free: np.ndarray, origin: tuple[float, float], resolution: float) -> None:
        mask = np.asarray(free)
        if mask.ndim != 2 or mask.dtype != bool:
            raise ValueError(f"free must be a boolean (H, W) mask, got {mask.dtype} {mask.shape}")
        if not resolution > 0:
            raise ValueError(f"resolution must be > 0, got {resolution}")
        self.free = _frozen(mask.copy())  # (H, W)
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.n_free = int(mask.sum())
        self.swept = np.zeros_like(mask)  # (H, W): swept by any beam (free or not)
        self.robot_swept: dict[int, np.ndarray] = {}  # robot -> (H, W)
        self.gain = 0  # new free cells of the team in the last sweep
        self._n_swept_free = 0
        self._linspaces: dict[tuple[int, int], np.ndarray] = {}

    def cells_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows, columns (N,) of points (N, 2) and whether each lies inside the grid."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        col = np.floor((p[:, 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((p[:, 1] - self.origin[1]) / self.resolution).astype(np.int64)
        h, w = self.free.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        return row, col, inside

    def _fractions(self, n: int, width: int) -> np.ndarray:  # (width,)
        """``linspace(0, 1, n)`` padded with 1.0 to ``width`` (a beam's end sampled again, which
        adds no cell), cached: only a few ``n`` occur and linspace is slow."""
        out = self._linspaces.get((n, width))
        if out is None:
            out = np.ones(width)
            out[:n] = np.linspace(0.0, 1.0, n)
            self._linspaces[n, width] = _frozen(out)
        return out

    def beam_cells(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> np.ndarray:  # (M,) flat cell ids, repeats kept
        """Flat ids (row · W + col) of the grid cells under the samples of each beam.

        Arguments as in :meth:`sweep`; ``origins`` may also be one (2,) origin for all beams.
        Beams are sampled every ≤ res/2, both ends included. Nothing is marked:
        :meth:`new_free_cells` and :meth:`mark` take the result.
        """
        a = np.asarray(angles, dtype=float).reshape(1, -1)
        o = np.asarray(origins, dtype=float).reshape(1, -1, 2)
        r = np.asarray(ranges, dtype=float).reshape(1, -1)
        return self.scan_cells(o, a, r, max_range)[0]

    def scan_cells(
        self, origins: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> list[np.ndarray]:  # K × (M_k,) flat cell ids, repeats kept
        """:meth:`beam_cells` of K scans in one numpy pass (a robot's beams are few, so numpy
        call overhead is most of the cost): ``origins`` (K, 2) or (K, R, 2), ``angles`` and
        ``ranges`` (K, R). Each scan is sampled as if alone (its own sample count)."""
        if not max_range > 0:
            raise ValueError(f"max_range must be > 0, got {max_range}")
        a = np.asarray(angles, dtype=float)
        r = np.asarray(ranges, dtype=float)
        o = np.asarray(origins, dtype=float)
        o = o[:, None, :] if o.ndim == 2 else o  # (K, R or 1, 2)
        if not (a.ndim == 2 and a.shape == r.shape and o.shape[0] == len(a)) or (
            o.shape[1] not in (1, a.shape[1])
        ):
            raise ValueError(f"origins {o.shape}, angles {a.shape}, ranges {r.shape} disagree")
        if (r < 0).any():
            raise ValueError("ranges must be >= 0 (use inf or nan for no return)")
        if len(a) == 0:
            return []
        length = np.fmin(r, max_range)  # (K, R): fmin maps nan (and inf) to max_range
        spacing = 0.5 * self.resolution
        counts = [math.ceil(max(m, 0.0) / spacing) + 1 for m in length.max(axis=1, initial=0.0)]
        width = max(counts)
        frac = np.array([self._fractions(n, width) for n in counts])  # (K, width)
        t = length[:, :, None] * frac[:, None, :]  # (K, R, width), spacing ≤ res/2
        flat, inside = raster.beam_cells(
            o[..., 0:1], o[..., 1:2], a, t, self.origin, self.resolution, self.free.shape
        )  # (K, R, width)
        return [flat[k][inside[k]] for k in range(len(flat))]

    def new_free_cells(self, cells: np.ndarray) -> int:
        """How many distinct free cells among ``cells`` (flat ids, repeats allowed) nobody has
        swept yet."""
        free, swept = self.free.reshape(-1), self.swept.reshape(-1)  # (H·W,) views
        fresh = cells[free[cells] & ~swept[cells]]  # few, usually none
        return _count_distinct(fresh)

    def mark(self, cells: np.ndarray, robot: int | None = None) -> int:
        """Mark ``cells`` (flat ids from :meth:`beam_cells`) swept, and ``robot``'s own mask.

        Returns (and stores as ``gain``) the number of newly swept free cells of the team.
        """
        self.gain = self.new_free_cells(cells)
        self._n_swept_free += self.gain
        self.swept.reshape(-1)[cells] = True
        if robot is not None:
            mine = self.robot_swept.setdefault(int(robot), np.zeros_like(self.swept))
            mine.reshape(-1)[cells] = True
        return self.gain

    def sweep(
        self,
        origins: np.ndarray,
        angles: np.ndarray,
        ranges: np.ndarray,
        max_range: float,
        robot: int | None = None,
    ) -> int:
        """Mark the cells along each beam up to its hit (or ``max_range`` for no return).

        ``origins`` (R, 2), absolute ``angles`` (R,), ``ranges`` (R,) with inf/nan meaning no
        return; ranges beyond ``max_range`` are cut there. ``robot`` also marks that robot's own
        mask. Returns (and stores as ``gain``) the number of newly swept free cells of the team.
        """
        return self.mark(self.beam_cells(origins, angles, ranges, max_range), robot)

    @property
    def coverage(self) -> float:
        """Swept free cells / free cells (0.0 for a grid without free cells)."""
        if self.n_free == 0:
            return 0.0
        return self._n_swept_free / self.n_free

    def robot_coverage(self, robot: int) -> float:
        """Free cells swept by ``robot`` / free cells."""
        mine = self.robot_swept.get(int(robot))
        if mine is None or self.n_free == 0:
            return 0.0
        return int(np.count_nonzero(mine & self.free)) / self.n_free

    def overlap(self) -> float:
        """Free cells swept by ≥ 2 robots / free cells swept by any (0.0 if none swept).

        Sweeps without a ``robot`` count in the denominator only.
        """
        swept = self._n_swept_free
        if swept == 0 or not self.robot_swept:
            return 0.0
        counts = np.sum([m & self.free for m in self.robot_swept.values()], axis=0)
        return int(np.count_nonzero(counts >= 2)) / swept


def _count_distinct(values: np.ndarray) -> int:
    """Number of distinct values in a 1-D integer array (cheaper than ``len(np.unique(…))``)."""
    if len(values) < 2:
        return len(values)
    v = np.sort(values)
    return 1 + int(np.count_nonzero(v[1:] != v[:-1]))


def time_to_fraction(series: np.ndarray, fraction: float) -> int | None:
    """First index where ``series`` (K,) reaches ``fraction``; None if it never does."""
    s = np.asarray(series, dtype=float).reshape(-1)
    hits = np.flatnonzero(s >= fraction)
    return int(hits[0]) if len(hits) else None

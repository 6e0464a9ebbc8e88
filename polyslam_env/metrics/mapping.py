"""How good a robot's map is: mapping error ν (both forms), completeness, hit fraction, and
the map-quality metrics of issue 14 (precision, completeness over the seen boundary,
duplicates).

Maps are polynomials in the robot's start frame; they are sampled along their arc length
(every ``step``, so a map's sample count is proportional to its length, give or take one
sample per polynomial) and moved to the absolute frame by a **placing pose** before they are
compared with the true boundary.

**Which placing pose.** A robot's map is built from pose estimates that start at 0 in its own
frame. When the robot's true start differs from its frame origin (``initial_error``: the true
start is drawn from N(0, P0) around the nominal start), that offset is unobservable without an
absolute reference, so the map is the world *as seen from the true start*: map quality is
measured with the map placed by the robot's **true start pose** (``RobotRun.true_poses[0]``).
``nu_mean_abs`` places it by the nominal frame instead and so includes the initial offset.
Without initial error the two poses coincide and so do the numbers.

**Empty maps.** Every metric is defined for an empty map: the error metrics (ν, ``nu_mean``,
``duplicates``) are 0.0 and ``map_precision`` 1.0 (nothing wrong was mapped), the coverage
metrics (``completeness``, ``completeness_seen``) 0.0 (nothing was mapped); callers report
``has_map`` beside them so that an empty map is not mistaken for a perfect one.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy import special

from polyslam_env.core.geometry import transform_points
from polyslam_env.metrics.boundary import (
    boundary_buckets,
    boundary_faces,
    boundary_samples,
    distance_to_boundary,
)
from polyslam_env.metrics.kernels import (
    covered_by,
    covered_on_face,
    map_quality_sums,
    map_sums,
    parallel_neighbours,
    sample_rows,
)
from polyslam_env.metrics.pose import _check_pose
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.layout import Layout
from polyslam_env.world.nearby import wall_index


# -- mapping error and completeness -----------------------------------------------------------
class MapShapes(NamedTuple):
    """A polynomial map as arrays (what the compiled sampler reads): row i is polynomial i
    with its current c0."""

    variate: np.ndarray  # (n,) int, 1 or 2
    coeffs: np.ndarray  # (n, m+1): [c0, b_1, …, b_m], zero-padded to the largest order
    lo: np.ndarray  # (n,) extent on ξ
    hi: np.ndarray  # (n,)

    @classmethod
    def of(cls, polys: Sequence[Polynomial] | MapShapes) -> MapShapes:
        """``polys`` as arrays (as given when already packed)."""
        if isinstance(polys, MapShapes):
            return polys
        width = max((len(p.coeffs) for p in polys), default=2)
        coeffs = np.zeros((len(polys), width))  # (n, m+1)
        for row, poly in enumerate(polys):
            coeffs[row, : len(poly.coeffs)] = poly.coeffs
        variate = np.array([p.variate for p in polys], dtype=np.int64)
        lo = np.array([p.lo for p in polys], dtype=float)
        hi = np.array([p.hi for p in polys], dtype=float)
        return cls(variate, coeffs, lo, hi)

    def __len__(self) -> int:  # rows, not fields
        return len(self.variate)


MapLike = Sequence[Polynomial] | MapShapes


def sample_shapes(
    shapes: MapShapes, step: float, rows: np.ndarray | None = None, dense: int = 512
) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) every ``step`` of arc length along the polynomials ``rows`` (all when
    None), in that order, and where each one's points start (Q + 1,): ``Polynomial.
    sample_arclength(step, dense)`` of each, bit for bit, in one compiled call
    (:func:`~polyslam_env.metrics.kernels.sample_rows`)."""
    picked = np.arange(len(shapes), dtype=np.int64) if rows is None else rows
    return sample_rows(
        np.ascontiguousarray(shapes.variate, dtype=np.int64),
        np.ascontiguousarray(shapes.coeffs, dtype=float),
        np.ascontiguousarray(shapes.lo, dtype=float),
        np.ascontiguousarray(shapes.hi, dtype=float),
        np.ascontiguousarray(picked, dtype=np.int64),
        float(step),
        int(dense),
    )


def sample_arclength_batch(polys: MapLike, step: float, dense: int = 512) -> list[np.ndarray]:
    """``[p.sample_arclength(step, dense) for p in polys]``, bit for bit, in one compiled call
    (:func:`sample_shapes`)."""
    shapes = MapShapes.of(polys)
    points, starts = sample_shapes(shapes, step, dense=dense)
    bounds = starts.tolist()
    return [points[a:b] for a, b in itertools.pairwise(bounds)]


def _placed(polys: MapLike, start_pose: np.ndarray, step: float) -> tuple[np.ndarray, list[int]]:
    """Every polynomial's points every ``step`` of arc length, in the absolute frame, as one
    array (M, 2), and where each polynomial's points start (n + 1,); (0, 2) and [0] for an
    empty map. One transform for all points (it is pointwise, so the same numbers as one per
    polynomial)."""
    own, starts = _sampled(polys, step)
    return _moved(own, start_pose), starts


def _sampled(polys: MapLike, step: float) -> tuple[np.ndarray, list[int]]:
    """Every polynomial's points every ``step`` of arc length in the map's own frame (M, 2),
    and where each one's points start (n + 1,); (0, 2) and [0] for an empty map."""
    shapes = MapShapes.of(polys)
    if not len(shapes):
        return np.zeros((0, 2)), [0]
    own, starts = sample_shapes(shapes, step)
    return own, starts.tolist()


def _moved(own: np.ndarray, start_pose: np.ndarray) -> np.ndarray:  # (M, 2)
    """Own-frame samples (:func:`_sampled`) placed by ``start_pose`` (3,)."""
    x0 = _check_pose(start_pose)
    return transform_points(own, x0) if len(own) else own


def _pieces(values: np.ndarray, starts: list[int]) -> list[np.ndarray]:
    """``values`` cut at ``starts`` (n + 1,): one piece per polynomial (views, as ``np.split``
    gives, without its Python-level calls per piece)."""
    return [values[a:b] for a, b in itertools.pairwise(starts)]


def map_points(polys: MapLike, start_pose: np.ndarray, step: float = 0.01) -> list[np.ndarray]:
    """Each polynomial's points every ``step`` of arc length, in the absolute frame: (n_q, 2)."""
    points, starts = _placed(polys, start_pose, step)
    return _pieces(points, starts)


def map_distances(
    polys: MapLike, start_pose: np.ndarray, layout: Layout, step: float = 0.01
) -> list[np.ndarray]:
    """Per polynomial, δ (n_q,): distance of each arc-length sample to the true boundary."""
    return _distances(*_placed(polys, start_pose, step), layout)


def _distances(points: np.ndarray, starts: list[int], layout: Layout) -> list[np.ndarray]:
    """:func:`map_distances` of the placed samples (:func:`_placed`)."""
    if len(starts) == 1:
        return []
    return _pieces(distance_to_boundary(points, layout), starts)


def nu(polys: MapLike, start_pose: np.ndarray, layout: Layout, step: float = 0.01) -> float:
    """ν_j = (1/n_j) Σ_q Σ_i δ_{q,i}, the paper's form (a sum per polynomial, so it grows with
    polynomial length and the sampling step matters). 0.0 for an empty map: the paper's sum is
    empty; use :func:`completeness` so that mapping nothing is not rewarded."""
    return _nu(map_distances(polys, start_pose, layout, step))


def _nu(ds: list[np.ndarray]) -> float:
    """:func:`nu` of the map's distances ``ds`` (:func:`map_distances`)."""
    return float(np.mean([d.sum() for d in ds])) if ds else 0.0


def nu_mean(polys: MapLike, start_pose: np.ndarray, layout: Layout, step: float = 0.01) -> float:
    """Mean δ over all map points (metres), the map placed by ``start_pose`` (see the module
    docstring for which pose). 0.0 for an empty map (no points, no error): report
    :func:`has_map` beside it."""
    return _nu_mean(map_distances(polys, start_pose, layout, step))


def _nu_mean(ds: list[np.ndarray]) -> float:
    """:func:`nu_mean` of the map's distances ``ds`` (:func:`map_distances`)."""
    return float(np.concatenate(ds).mean()) if ds else 0.0


def has_map(polys: MapLike) -> float:
    """1.0 if the map holds at least one polynomial, else 0.0 (the flag beside the metrics)."""
    return 1.0 if len(polys) else 0.0


def map_error_length(
    polys: MapLike, start_pose: np.ndarray, layout: Layout, step: float = 0.01
) -> float:
    """∫ δ ds over the map (m²): each arc-length sample's δ times ``step``. It is ``nu_mean``
    times the mapped length, so it grows with wrong map and is not lowered by deleting map
    that is right (the ``map_error`` reward term differences it). 0.0 for an empty map."""
    ds = map_distances(polys, start_pose, layout, step)
    return float(np.concatenate(ds).sum()) * step if ds else 0.0


def map_precision(
    polys: MapLike,
    start_pose: np.ndarray,
    layout: Layout,
    tol: float = 0.05,
    step: float = 0.01,
) -> float:
    """Fraction of the map's arc length (its samples every ``step``) within ``tol`` of a true
    wall: the mirror of :func:`completeness`, lowered by spurious and runaway polynomials.
    1.0 for an empty map (nothing wrong mapped; report :func:`has_map` beside it)."""
    return _precision(map_distances(polys, start_pose, layout, step), tol)


def _precision(ds: list[np.ndarray], tol: float) -> float:
    """:func:`map_precision` of the map's distances ``ds`` (:func:`map_distances`)."""
    if not ds:
        return 1.0
    d = np.concatenate(ds)
    return float(np.count_nonzero(d <= tol)) / len(d)


def expected_precision(
    lengths: np.ndarray,
    jacobian: np.ndarray,
    cov: np.ndarray,
    tol: float = 0.05,
    floor: float = 0.9,
    draws: int = 400,
    seed: int = 0,
    frozen: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[float, float]:
    """:func:`map_precision` as the filter itself expects it: (its mean, the probability that
    it is below ``floor``), for a map whose points (arc lengths ``lengths`` (M,) m) are off
    their true walls along the normal by e = ``jacobian`` (M, S) times the state error, and
    that error ~ N(0, ``cov``) (S, S) (``PolySlam.map_error_jacobian`` and ``PolySlam.cov``),
    plus, with ``frozen`` = (variances (M,), landmark of each point (M,)) (``PolySlam.
    map_frozen_variance``), each landmark's frozen error, which no state holds: independent
    of the state's and of other landmarks', N(0, variance) at each point and in the draws one
    normal variate per landmark (its points' frozen errors are one curve's: taken fully
    correlated, which spreads the precision most, so the probability is not understated).

    No ground truth goes in: it is the robot's own estimate of its map's precision. The mean
    is exact, Σ ℓ_i P(|e_i| ≤ tol) / Σ ℓ_i with e_i ~ N(0, J_i P J_iᵀ); the probability comes
    from ``draws`` draws of the state error (the points' errors are correlated through it),
    from ``default_rng(seed)``, so the same inputs give the same numbers. An empty map gives
    (1.0, 0.0), as :func:`map_precision` gives 1.0."""
    lengths = np.asarray(lengths, dtype=float)
    if lengths.size == 0 or not lengths.sum() > 0:
        return 1.0, 0.0
    used = np.flatnonzero(np.any(jacobian != 0.0, axis=0))
    jac = jacobian[:, used]  # (M, U)
    block = cov[np.ix_(used, used)]
    values, vectors = np.linalg.eigh(0.5 * (block + block.T))
    root = vectors * np.sqrt(np.clip(values, 0.0, None))  # block = root rootᵀ (PSD part)
    sd = np.linalg.norm(jac @ root, axis=1)  # (M,)
    if frozen is not None:
        sd = np.sqrt(sd**2 + frozen[0])
    weights = lengths / lengths.sum()
    with np.errstate(divide="ignore"):
        within = np.where(sd > 0, special.erf(tol / (np.sqrt(2.0) * sd)), 1.0)
    mean = float(weights @ within)
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((root.shape[1], draws))
    errors = jac @ (root @ z)  # (M, draws)
    if frozen is not None:
        own, landmark = frozen
        per_landmark = rng.standard_normal((int(landmark.max()) + 1, draws))
        errors += np.sqrt(own)[:, None] * per_landmark[landmark]
    precision = weights @ (np.abs(errors) <= tol)  # (draws,)
    return mean, float(np.mean(precision < floor))


def count_interval(probs: Sequence[float], prob: float = 0.95) -> tuple[float, int, int]:
    """How many of independent events with probabilities ``probs`` happen: the expected count
    and the central ``prob`` interval (lo, hi) of its exact (Poisson-binomial) distribution."""
    pmf = np.ones(1)
    for p in probs:
        pmf = np.convolve(pmf, [1.0 - p, p])
    cdf = np.cumsum(pmf)
    lo = int(np.searchsorted(cdf, (1.0 - prob) / 2.0 - 1e-12))
    hi = int(np.searchsorted(cdf, (1.0 + prob) / 2.0 - 1e-12))
    return float(np.sum(probs)), lo, min(hi, len(pmf) - 1)


#: Radius (m) around the robot's true beam hits within which the true boundary of the hit's
#: own face counts as seen by :func:`completeness_seen`: half of v_max·T = 0.3 m, the most a
#: robot moves in one step at the default speed limit, so while a beam sweeps a wall facing it
#: its consecutive hits are at most 0.3 m apart and every boundary point between them is
#: within 0.15 m of one. That argument holds along the face the beam sweeps, so the radius
#: does not reach across a corner onto the next face, nor onto another surface a few
#: centimetres behind the hit one (a wall behind furniture): :func:`seen_samples`.
SEEN_RADIUS = 0.15


def seen_samples(
    hit_points_abs: np.ndarray, layout: Layout, radius: float = SEEN_RADIUS, step: float = 0.01
) -> np.ndarray:
    """Which boundary samples (``boundary_samples(layout, step)``) the beams saw (M,) bool:
    those within ``radius`` of a true beam hit (H, 2, absolute; non-finite rows ignored) and on
    the hit's own face (:func:`~polyslam_env.metrics.boundary.boundary_faces`, the face of the
    sample nearest to the hit)."""
    bpts = boundary_samples(layout, step)[0]
    hits = np.ascontiguousarray(np.asarray(hit_points_abs, dtype=float).reshape(-1, 2))
    if len(hits) == 0:
        return np.zeros(len(bpts), dtype=bool)
    faces = boundary_faces(layout, step)
    found = boundary_buckets(layout, step, radius)
    return covered_on_face(bpts, faces, *found, hits, float(radius))


def seen_boundary(
    layout: Layout, hit_points_abs: np.ndarray, radius: float = SEEN_RADIUS, step: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """The boundary samples (M, 2) the beams saw (:func:`seen_samples`: within ``radius`` of a
    true beam hit (H, 2), absolute, on its face) and their lengths (M,), read-only; non-finite
    hits are ignored."""
    bpts, weights = boundary_samples(layout, step)
    seen = seen_samples(hit_points_abs, layout, radius, step)
    seen_pts, seen_weights = bpts[seen], weights[seen]
    # read-only like the cached samples (numba types a read-only array apart: one compiled
    # specialisation of ``covered`` serves callers that query them)
    seen_pts.setflags(write=False)
    seen_weights.setflags(write=False)
    return seen_pts, seen_weights


def completeness_seen(
    polys: MapLike,
    start_pose: np.ndarray,
    layout: Layout,
    hit_points_abs: np.ndarray,
    radius: float = SEEN_RADIUS,
    tol: float = 0.05,
    step: float = 0.01,
) -> float:
    """:func:`completeness` over only the boundary the robot's beams hit: the seen length
    (:func:`seen_samples`) within ``tol`` of the map, over the seen length. 0.0 when the map
    is empty or nothing was seen."""
    return _completeness_seen(
        *_placed(polys, start_pose, step), layout, hit_points_abs, radius, tol, step
    )


def _completeness_seen(
    points: np.ndarray,
    starts: list[int],
    layout: Layout,
    hit_points_abs: np.ndarray,
    radius: float,
    tol: float,
    step: float,
    near: np.ndarray | None = None,
) -> float:
    """:func:`completeness_seen` of the placed samples (:func:`_placed`); ``near`` is
    :func:`_near` of them if the caller has it. The seen samples' weights are summed as
    :func:`seen_boundary` returns them (the same elements in the same order)."""
    weights = boundary_samples(layout, step)[1]
    seen = seen_samples(hit_points_abs, layout, radius, step)
    total = float(weights[seen].sum())
    if len(starts) == 1 or total == 0.0:
        return 0.0
    if near is None:
        near = _near(points, layout, tol, step)
    return float(weights[seen & near].sum()) / total


#: Distance (m) and angle (rad) within which a piece of map duplicates another polynomial: the
#: 10 cm and 10° of SPEC §5 (10 cm is five range-noise σ, so two fits of one wall from honest
#: poses lie well inside it; 10° is the near-tangent cut of the measurement model).
DUPLICATE_TOL, DUPLICATE_ANGLE = 0.10, np.deg2rad(10.0)


def duplicates(
    polys: MapLike,
    tol: float = DUPLICATE_TOL,
    angle: float = DUPLICATE_ANGLE,
    step: float = 0.01,
) -> float:
    """Fraction of the map's arc length lying within ``tol`` of, and parallel (tangents within
    ``angle``, either direction) to, another polynomial of the same map: a sample of polynomial
    a counts when a sample of a different polynomial b is within ``tol`` with |sin| of the
    angle between their tangents ≤ sin(angle) (a zero-extent polynomial has no direction and
    never counts). Tangents are central differences of the samples. Invariant under moving the
    map, so computed in the robot's frame. 0.0 for an empty map."""
    return _duplicates(*_sampled(polys, step), tol, angle)


def _duplicates(own: np.ndarray, starts: list[int], tol: float, angle: float) -> float:
    """:func:`duplicates` of the map's own-frame samples (:func:`_sampled`)."""
    bounds = np.asarray(starts, dtype=np.int64)
    counts = bounds[1:] - bounds[:-1]  # (n,)
    counts = counts[counts > 0]  # polynomials without samples take no part
    if not len(counts):
        return 0.0
    pts = np.ascontiguousarray(own, dtype=float)  # (M, 2)
    owner = np.repeat(np.arange(len(counts)), counts)  # (M,)
    tangent = _tangents(pts, counts)
    norm = np.linalg.norm(tangent, axis=1, keepdims=True)  # 0: a zero-extent polynomial
    tangent = np.divide(tangent, norm, out=np.zeros_like(tangent), where=norm > 0)
    has_dir = norm[:, 0] > 0
    marked = parallel_neighbours(pts, owner, tangent, has_dir, float(tol), float(np.sin(angle)))
    return float(np.count_nonzero(marked)) / len(pts)


def _tangents(points: np.ndarray, counts: np.ndarray) -> np.ndarray:  # (M, 2)
    """``np.gradient(p, axis=0)`` of each polynomial's points p (``counts`` (n,) ≥ 1 rows each,
    one after the other in ``points`` (M, 2)), zeros for a single point, computed for all at
    once with numpy's own formulas (central differences / 2 inside, one-sided at the ends), so
    the same numbers without a ``gradient`` call per polynomial."""
    out = np.zeros_like(points)
    out[1:-1] = (points[2:] - points[:-2]) / 2.0  # rows at a polynomial's ends are redone below
    ends = np.cumsum(counts)
    long = counts > 1
    first, last = (ends - counts)[long], ends[long] - 1
    out[first] = points[first + 1] - points[first]
    out[last] = points[last] - points[last - 1]
    out[(ends - 1)[~long]] = 0.0
    return out


def _covered_fraction(
    points: np.ndarray, layout: Layout, tol: float, step: float, near: np.ndarray | None = None
) -> float:
    """Fraction of the true boundary length within ``tol`` of some point (N, 2); ``near`` is
    :func:`_near` of them if the caller has it."""
    if tol < 0:
        raise ValueError(f"tol must be >= 0, got {tol}")
    weights = boundary_samples(layout, step)[1]
    total = float(weights.sum())
    if total == 0.0:
        return 0.0
    if near is None:  # no finite point: nothing near, 0.0
        near = _near(points, layout, tol, step)
    return float(weights[near].sum()) / total


def _near(points: np.ndarray, layout: Layout, tol: float, step: float) -> np.ndarray:
    """Which of the boundary samples (``boundary_samples(layout, step)``) lie strictly within
    ``tol`` of a finite point (N, 2) (M,) bool: ``covered_by`` over the samples bucketed once
    per layout (each call only walks the points), the same booleans as ``covered(samples,
    finite points, tol)``."""
    bpts = boundary_samples(layout, step)[0]
    pts = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))
    if len(pts) == 0:
        return np.zeros(len(bpts), dtype=bool)
    found = boundary_buckets(layout, step, tol)
    return covered_by(bpts, *found, pts, float(tol))


def completeness(
    polys: MapLike,
    start_pose: np.ndarray,
    layout: Layout,
    tol: float = 0.05,
    step: float = 0.01,
) -> float:
    """Fraction of the true boundary length within ``tol`` of the map (0.0 for an empty map).

    Both the boundary and the polynomials are sampled every ``step``; a boundary piece counts
    when its centre is within ``tol`` of a polynomial sample (so within tol ± step/2).
    """
    return _covered_fraction(_placed(polys, start_pose, step)[0], layout, tol, step)


def map_quality(
    polys: MapLike,
    start_pose: np.ndarray,
    frame: np.ndarray,
    hit_points_abs: np.ndarray,
    layout: Layout,
) -> dict[str, float]:
    """``nu``, ``nu_mean``, ``completeness``, ``completeness_seen``, ``map_precision`` (their
    defaults) of the map placed by ``start_pose``, ``nu_mean_abs`` (:func:`nu_mean` placed by
    ``frame``), ``duplicates`` and ``has_map``: the same numbers as those functions, from one
    compiled call over the map (:func:`~polyslam_env.metrics.kernels.map_quality_sums`: one
    sampling, and the distances, covered boundary and duplicates each computed once; each
    function alone samples and places the map again)."""
    step, tol = 0.01, 0.05
    shapes = MapShapes.of(polys)
    pose = _check_pose(start_pose)
    frame = _check_pose(frame)
    if not len(shapes):
        empty = (0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
        return dict(zip(QUALITY_KEYS, empty, strict=True))
    samples, weights = boundary_samples(layout, step)
    if len(layout.segments) == 0 and len(layout.pillars) == 0:
        raise ValueError(f"layout {layout.name!r} has no walls and no pillars")
    seen = seen_samples(hit_points_abs, layout, SEEN_RADIUS, step)  # the seen boundary samples
    pieces, total, total_abs, covered, covered_seen, within, duplicated, n = map_quality_sums(
        np.ascontiguousarray(shapes.variate, dtype=np.int64),
        np.ascontiguousarray(shapes.coeffs, dtype=float),
        np.ascontiguousarray(shapes.lo, dtype=float),
        np.ascontiguousarray(shapes.hi, dtype=float),
        step,
        512,  # Polynomial.sample_arclength's dense
        pose,
        float(np.cos(pose[2])),
        float(np.sin(pose[2])),
        frame,
        float(np.cos(frame[2])),
        float(np.sin(frame[2])),
        bool(np.array_equal(frame, pose)),
        wall_index(layout).arrays,
        np.asarray(layout.pillars, dtype=float).reshape(-1, 3),
        samples,
        weights,
        boundary_buckets(layout, step, tol),
        tol,
        seen,
        DUPLICATE_TOL,
        float(np.sin(DUPLICATE_ANGLE)),
    )
    boundary = float(weights.sum())
    seen_length = float(weights[seen].sum())
    return {
        "nu": pieces / len(shapes),
        "nu_mean": total / n,
        "nu_mean_abs": total_abs / n,
        "completeness": covered / boundary if boundary != 0.0 else 0.0,
        "completeness_seen": covered_seen / seen_length if seen_length != 0.0 else 0.0,
        "map_precision": float(within) / n,
        "duplicates": float(duplicated) / n,
        "has_map": 1.0,
    }


#: The keys of :func:`map_quality`, in order (the per-robot metrics and the reproduction table
#: list them through this tuple).
QUALITY_KEYS = (
    "nu",
    "nu_mean",
    "nu_mean_abs",
    "completeness",
    "completeness_seen",
    "map_precision",
    "duplicates",
    "has_map",
)


def completeness_and_error(
    polys: MapLike,
    start_pose: np.ndarray,
    layout: Layout,
    tol: float = 0.05,
    step: float = 0.01,
) -> tuple[float, float]:
    """``(completeness(...), map_error_length(...))`` with the same arguments, from one
    compiled call (:func:`~polyslam_env.metrics.kernels.map_sums`: one sampling of the map,
    the same numbers; the env's reward needs both each time a map changes). ``polys`` may be
    the map as arrays (:class:`MapShapes`)."""
    if tol < 0:
        raise ValueError(f"tol must be >= 0, got {tol}")
    pose = _check_pose(start_pose)
    shapes = MapShapes.of(polys)
    samples, weights = boundary_samples(layout, step)
    if not len(shapes):
        return 0.0, 0.0
    if len(layout.segments) == 0 and len(layout.pillars) == 0:
        raise ValueError(f"layout {layout.name!r} has no walls and no pillars")
    covered, error = map_sums(
        np.ascontiguousarray(shapes.variate, dtype=np.int64),
        np.ascontiguousarray(shapes.coeffs, dtype=float),
        np.ascontiguousarray(shapes.lo, dtype=float),
        np.ascontiguousarray(shapes.hi, dtype=float),
        float(step),
        512,  # Polynomial.sample_arclength's dense
        pose,
        float(np.cos(pose[2])),
        float(np.sin(pose[2])),
        wall_index(layout).arrays,
        np.asarray(layout.pillars, dtype=float).reshape(-1, 3),
        samples,
        weights,
        boundary_buckets(layout, step, tol),
        float(tol),
    )
    total = float(weights.sum())
    return (covered / total if total != 0.0 else 0.0), error * step


def hit_fraction(
    hit_points_abs: np.ndarray, layout: Layout, tol: float = 0.05, step: float = 0.01
) -> float:
    """Fraction of the true boundary within ``tol`` of the beams' hit points (H, 2), absolute.

    This is the boundary the robot could have mapped (the denominator of the completeness
    target); it doubles as the "boundary coverage" exploration metric. Non-finite rows
    (no return) are ignored.
    """
    return _covered_fraction(hit_points_abs, layout, tol, step)

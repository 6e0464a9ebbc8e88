"""Aligning two landmark maps without a rendezvous (seed 004, Ballesta et al.; SPEC §8).

Two robots map from unknown relative poses. Each map is a :class:`FeatureMap`: landmark
positions in the robot's own frame and an appearance descriptor per landmark. An aligner finds
the transform ``T = (t_x, t_y, θ)`` that takes map B's frame into map A's
(``p_A = R(θ) p_B + t``, the SE(2) convention of :mod:`polyslam_env.core.geometry`):

* ``ransac`` — candidate matches by descriptor (nearest descriptor, distance < th0), then M
  times: two random candidates that pass the geometric test (their distances in the two maps
  differ by < th1), the transform they define, its supports (B's landmarks that land within
  th2 of an A landmark); the transform with the most supports wins;
* ``svd`` — the candidates that pass the geometric test with most other candidates, aligned
  in one least-squares solve (the rigid SVD solution of Arun et al., not the seed's affine
  pseudo-inverse, which can return a non-rigid T);
* ``icp`` — from one RANSAC-style initial estimate, alternate nearest-neighbour
  correspondences (within th2) and the SVD solve until the correspondences stop changing;
* ``imp_icp`` — ICP from three initial estimates; the one with the most supports wins.

Every aligner's estimate is then refined by least squares that drops outliers (residuals
beyond 3 robust standard deviations) until the set is stable, which also gives the
transform's covariance from the residuals. ``AlignConfig.refinement`` says over which
correspondences:

* ``nearest`` (default, :func:`refine`): the nearest-neighbour supports of the current
  transform (within th2), found again at every iteration. Every aligner that lands near the
  right transform then ends on the same answer, whatever correspondences it found;
* ``own`` (:func:`refine_own`, the seed's §6): the correspondences the aligner itself found
  (RANSAC's supports of its best hypothesis, SVD's geometrically consistent descriptor
  matches, ICP's final nearest neighbours), never re-paired.

``AlignConfig.declines`` says when an aligner **declines** (returns an :class:`Alignment`
with ``transform`` None and the reason):

* ``guarded`` (default): any aligner, when fewer than ``min_support`` refined
  correspondences support it, or fewer than a wrong transform collects by chance on maps
  that dense (:func:`chance_supports`). A wrong merge is worse than none;
* ``seed``: only RANSAC, when its best hypothesis has fewer than ``min_support`` supports
  (the seed's min = 20). The other aligners answer whenever they can compute a transform.

**Oriented features** (corners of wall maps, :mod:`polyslam_env.slam.corners`) carry a heading
that turns with the map, and descriptors that tell kinds of corner apart rather than
individuals. For them every descriptor-compatible pair is a candidate, one candidate is a whole
hypothesis, supports must agree in heading too, and RANSAC tries every hypothesis: it ranks them
by the caller's ``score`` (the exchange's: metres of wall laid on wall), lets the caller
``veto`` some (the radio's range, free space), and declines when a distinct transform comes
close to the best (``ambiguity_ratio``) — buildings repeat, and a transform shifted by one
period of a shelf row matches as many corners as the true one.

Where the seed's printed formulas are off we use the geometric meaning: its constraint (1)
compares *squared* distances against th1 = 0.8 m; we compare the distances themselves.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from polyslam_env.core.config import Config, check_choice, check_positive
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import rotation, wrap_angle, wrap_scalar

__all__ = [
    "ALIGNERS",
    "DECLINES",
    "REFINEMENTS",
    "AlignConfig",
    "Alignment",
    "FeatureMap",
    "align",
    "candidate_matches",
    "icp",
    "imp_icp",
    "ransac",
    "refine",
    "refine_own",
    "rigid_fit",
    "svd",
    "transform_from_pairs",
]


#: The caller's veto over a transform (3,): the reason to refuse it, or "" to let it stand.
Veto = Callable[[np.ndarray], str]
#: The caller's score of a transform (3,): higher is better supported (see :func:`ransac`).
Score = Callable[[np.ndarray], float]

#: Probability that a wrong transform collects the supports an accepted one needs (see
#: :func:`chance_supports`).
CHANCE_P = 1e-6
#: Which correspondences the least-squares refinement runs over (see the module docstring).
REFINEMENTS: tuple[str, ...] = ("nearest", "own")
#: When an aligner declines (see the module docstring).
DECLINES: tuple[str, ...] = ("guarded", "seed")


@dataclass(frozen=True)
class AlignConfig(Config):
    """Thresholds of the aligners; the defaults are the seed's (§5.1)."""

    descriptor_threshold: float = 0.7  # th0: largest descriptor distance of a candidate match
    geometric_threshold: float = 0.8  # th1, m: largest difference of a pair's two distances
    support_threshold: float = 0.4  # th2, m: a support lands this close to an A landmark
    iterations: int = 70  # M: RANSAC hypotheses
    min_support: int = 20  # fewer supports than this: decline
    icp_max_iterations: int = 50  # ICP stops here if the correspondences still change
    imp_icp_starts: int = 3  # initial estimates of the improved ICP
    outlier_sigmas: float = 3.0  # refine drops residuals beyond this many robust std devs
    # Oriented features only (corners): a support's heading is within this of its match's.
    heading_threshold_deg: float = 10.0
    # Oriented features only: RANSAC tries every candidate, so it knows the runner-up; it
    # declines unless the best transform has ``ambiguity_ratio`` times the supports of every
    # distinct one. Buildings repeat (shelf rows, rooms along a corridor): a transform shifted
    # by one period matches nearly as many corners as the true one, and only a clear margin
    # says which is true. 1.5: the best must beat any rival by half again its supports.
    ambiguity_ratio: float = 1.5
    refinement: str = "nearest"  # "nearest" (re-paired supports) or "own" (the seed's)
    declines: str = "guarded"  # "guarded" (every aligner, chance level) or "seed"

    def validate(self) -> None:
        check_choice("alignment.refinement", self.refinement, REFINEMENTS)
        check_choice("alignment.declines", self.declines, DECLINES)
        for name in ("descriptor_threshold", "geometric_threshold", "support_threshold"):
            check_positive(f"alignment.{name}", getattr(self, name))
        check_positive("alignment.outlier_sigmas", self.outlier_sigmas)
        check_positive("alignment.heading_threshold_deg", self.heading_threshold_deg)
        if not self.ambiguity_ratio >= 1.0:
            raise ConfigError(
                f"alignment.ambiguity_ratio: must be >= 1, got {self.ambiguity_ratio!r}"
            )
        for name in ("iterations", "icp_max_iterations", "imp_icp_starts"):
            if getattr(self, name) < 1:
                raise ConfigError(f"alignment.{name}: must be >= 1, got {getattr(self, name)!r}")
        if self.min_support < 3:
            raise ConfigError(
                f"alignment.min_support: must be >= 3 (a transform has 3 parameters and"
                f" the residuals need at least as many points), got {self.min_support!r}"
            )


@dataclass(frozen=True)
class FeatureMap:
    """Landmarks of one robot's map: positions (n, 2) in its frame, descriptors (n, d), and
    for oriented features (corners, :mod:`polyslam_env.slam.corners`) headings (n,) in rad
    that turn with the map (None: points, such as pillars)."""

    positions: np.ndarray
    descriptors: np.ndarray
    headings: np.ndarray | None = None

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=float).reshape(-1, 2)
        desc = np.asarray(self.descriptors, dtype=float)
        desc = desc.reshape(len(pos), -1) if desc.size else np.zeros((len(pos), 0))
        if len(desc) != len(pos):
            raise ValueError(f"{len(pos)} positions but {len(desc)} descriptors")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "descriptors", desc)
        if self.headings is not None:
            head = np.asarray(self.headings, dtype=float).reshape(-1)
            if len(head) != len(pos):
                raise ValueError(f"{len(pos)} positions but {len(head)} headings")
            object.__setattr__(self, "headings", head)

    @property
    def oriented(self) -> bool:
        return self.headings is not None

    def __len__(self) -> int:
        return len(self.positions)


@dataclass(frozen=True)
class Alignment:
    """An aligner's answer: B's frame in A's, or None with the reason it declined."""

    method: str
    transform: np.ndarray | None  # (3,) (t_x, t_y, θ), p_A = R(θ) p_B + t
    covariance: np.ndarray | None  # (3, 3) from the refinement's residuals
    inliers: int  # correspondences that support the final transform
    candidates: int  # descriptor matches the aligner started from
    reason: str = ""  # why it declined ("" when it did not)
    raw: np.ndarray | None = None  # (3,) the aligner's own estimate, before the refinement
    pairs: np.ndarray | None = None  # (k, 2) (i in A, j in B) the refinement kept

    @property
    def accepted(self) -> bool:
        return self.transform is not None


# -- building blocks -------------------------------------------------------------------------------
def candidate_matches(a: FeatureMap, b: FeatureMap, threshold: float) -> np.ndarray:
    """Pairs (k, 2) of indices (i in A, j in B): for each B landmark its nearest A landmark by
    descriptor distance, kept when that distance is below ``threshold`` (seed step a).

    Oriented features (corners) have descriptors that tell kinds apart, not individuals (most
    corners of a building open at 90°): there every pair within ``threshold`` is a candidate,
    in order of B's index then A's."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), dtype=int)
    if a.oriented and b.oriented:
        near = cKDTree(a.descriptors).query_ball_point(b.descriptors, r=threshold)
        pairs = [(i, j) for j, found in enumerate(near) for i in sorted(found)]
        return np.array(pairs, dtype=int).reshape(-1, 2)
    dist, nearest = cKDTree(a.descriptors).query(b.descriptors)
    keep = np.flatnonzero(dist < threshold)
    return np.column_stack([nearest[keep], keep]).astype(int)


def transform_from_pairs(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """The transform (3,) taking two B points (2, 2) onto two A points (2, 2): θ from the
    directions of the two segments, t so that the midpoints coincide (seed eqs. 2–4)."""
    va, vb = pa[0] - pa[1], pb[0] - pb[1]
    theta = math.atan2(vb[0] * va[1] - vb[1] * va[0], vb[0] * va[0] + vb[1] * va[1])
    t = pa.mean(axis=0) - rotation(theta) @ pb.mean(axis=0)
    return np.array([t[0], t[1], theta])


def rigid_fit(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Least-squares rigid transform (3,) with pa ≈ R pb + t over k ≥ 2 pairs (k, 2): centre
    both sets, θ from the SVD of their cross-covariance (Arun, Huang & Blostein 1987; in 2-D
    the angle of Σ (b_c × a_c, b_c · a_c), which is the same solution and never a reflection)."""
    ca, cb = pa.mean(axis=0), pb.mean(axis=0)
    da, db = pa - ca, pb - cb
    sin = float(np.sum(db[:, 0] * da[:, 1] - db[:, 1] * da[:, 0]))
    cos = float(np.sum(db[:, 0] * da[:, 0] + db[:, 1] * da[:, 1]))
    theta = math.atan2(sin, cos)
    t = ca - rotation(theta) @ cb
    return np.array([t[0], t[1], theta])


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:  # (k, 2)
    return points @ rotation(float(transform[2])).T + transform[:2]


def _supports(
    transform: np.ndarray, tree_a: cKDTree, a: FeatureMap, b: FeatureMap, cfg: AlignConfig
) -> np.ndarray:
    """Nearest-neighbour correspondences (k, 2) (i in A, j in B) within th2 of B's landmarks
    moved by ``transform``; an A landmark supports at most one (the nearest) B one. Oriented
    features also need their headings, B's turned by θ, within ``heading_threshold_deg``."""
    if len(b) == 0:
        return np.zeros((0, 2), dtype=int)
    dist, nearest = tree_a.query(
        _apply(transform, b.positions), distance_upper_bound=cfg.support_threshold
    )
    found = np.isfinite(dist)
    if a.oriented and b.oriented:
        assert a.headings is not None and b.headings is not None
        diff = b.headings + transform[2] - a.headings[np.where(found, nearest, 0)]
        found &= np.abs(wrap_angle(diff)) <= math.radians(cfg.heading_threshold_deg)
    ok = np.flatnonzero(found)
    order = ok[np.argsort(dist[ok], kind="stable")]
    _, first = np.unique(nearest[order], return_index=True)
    keep = np.sort(order[first])
    return np.column_stack([nearest[keep], keep]).astype(int)


def chance_supports(a: FeatureMap, b: FeatureMap, cfg: AlignConfig) -> int:
    """Supports a *wrong* transform reaches by chance with probability ≤ ``CHANCE_P``.

    Under a wrong transform B's landmarks land at places unrelated to A's; one lands within
    th2 of some A landmark with probability p ≈ n_A·π·th2² / area(A) (area of A's bounding
    box, p capped at 1), so the support count is about Binomial(n_B, p). On dense maps that is
    more than ``min_support`` (120 landmarks on 20 × 12 m give p ≈ 0.25): accepting 20
    supports there would accept wrong merges. Returns the binomial's 1 − CHANCE_P quantile + 1.
    """
    if len(a) == 0 or len(b) == 0:
        return 0
    span = a.positions.max(axis=0) - a.positions.min(axis=0)
    th2 = cfg.support_threshold
    area = float(np.prod(np.maximum(span, 2.0 * th2)))
    p = min(1.0, len(a) * math.pi * th2 * th2 / area)
    if a.oriented and b.oriented:  # and its heading, uniform under a wrong transform
        p *= min(1.0, math.radians(cfg.heading_threshold_deg) / math.pi)
    import scipy.stats  # here: importing it takes ~1 s, and most runs never align

    return int(scipy.stats.binom.ppf(1.0 - CHANCE_P, len(b), p)) + 1


def _geometric_ok(pa: np.ndarray, pb: np.ndarray, threshold: float) -> bool:
    """Seed constraint (1), on distances: a rigid motion keeps the pair's distance."""
    return abs(float(np.hypot(*(pa[0] - pa[1]))) - float(np.hypot(*(pb[0] - pb[1])))) < threshold


def _random_hypothesis(
    a: FeatureMap, b: FeatureMap, matches: np.ndarray, cfg: AlignConfig, rng: np.random.Generator
) -> np.ndarray | None:
    """One transform from two random candidates that pass the geometric test (seed step b),
    or from one random candidate of oriented features; None if ``cfg.iterations`` draws find
    no such pair."""
    if a.oriented and b.oriented:
        return _oriented_hypothesis(a, b, matches[int(rng.integers(len(matches)))])
    for _ in range(cfg.iterations):
        k, m = rng.choice(len(matches), size=2, replace=False)
        (ia, jb), (ia2, jb2) = matches[k], matches[m]
        pa = a.positions[[ia, ia2]]
        pb = b.positions[[jb, jb2]]
        if ia != ia2 and jb != jb2 and _geometric_ok(pa, pb, cfg.geometric_threshold):
            return transform_from_pairs(pa, pb)
    return None


def _distinct(first: np.ndarray, second: np.ndarray, b: FeatureMap, cfg: AlignConfig) -> bool:
    """Whether two transforms differ: the second turns more than the heading threshold from
    the first, or moves some landmark of B more than th2 from where the first puts it."""
    turn = abs(wrap_scalar(float(second[2] - first[2])))
    if turn > math.radians(cfg.heading_threshold_deg):
        return True
    shift = np.hypot(*(_apply(second, b.positions) - _apply(first, b.positions)).T)
    return bool(shift.max() > cfg.support_threshold)


def _ransac_oriented(
    a: FeatureMap,
    b: FeatureMap,
    matches: np.ndarray,
    tree: cKDTree,
    cfg: AlignConfig,
    veto: Veto | None,
    score: Score | None,
) -> Alignment:
    """RANSAC over oriented features: one candidate is a hypothesis, so every one is tried.

    Hypotheses that put B's centroid in the same th2 cell with θ in the same heading bin are
    one (the first kept). Each is valued by ``score`` (the caller's richer evidence, such as
    the length of wall both maps agree on), or by its supports when None. A scored hypothesis
    is first refitted on its supports (:func:`refine`): one corner's heading is a few degrees
    off, which moves walls 10 m away by more than the score's few centimetres, so the true
    transform, taken from a single corner, could score below a transform shifted by one
    shelf period (a warehouse: 67 m of wall against the true transform's 99 m). In
    decreasing value a hypothesis that ``veto`` refuses (the radio's range, free space) is
    dropped; the first one left is the best, and the next one left that is :func:`_distinct`
    from it its rival.
    The aligner declines when the rival's value is more than 1 / ``ambiguity_ratio`` of the
    best's (see :class:`AlignConfig`); the best then goes through :func:`refine` and its
    support tests like any aligner's answer.

    Why a score: in a building that repeats, the true transform may share only one or two of
    the corners both maps found while a transform shifted by one period shares more, yet the
    true one lays metres more wall on wall.
    """
    hypotheses = np.array([_oriented_hypothesis(a, b, m) for m in matches])  # (k, 3)
    centre = b.positions.mean(axis=0)
    cos, sin = np.cos(hypotheses[:, 2]), np.sin(hypotheses[:, 2])
    placed = hypotheses[:, :2] + np.column_stack(
        [cos * centre[0] - sin * centre[1], sin * centre[0] + cos * centre[1]]
    )  # (k, 2): where each hypothesis puts B's centroid
    bins = np.column_stack(
        [
            np.floor(placed / cfg.support_threshold),
            np.floor(hypotheses[:, 2] / math.radians(cfg.heading_threshold_deg)),
        ]
    ).astype(np.int64)
    _, first = np.unique(bins, axis=0, return_index=True)
    candidates = hypotheses[np.sort(first)]
    if score is not None:
        candidates = np.array([refine(a, b, h, cfg)[0] for h in candidates])
        values = np.array([score(h) for h in candidates])
    else:
        values = np.array([len(_supports(h, tree, a, b, cfg)) for h in candidates], float)
    best = -1
    rival = 0.0
    first_reason = ""
    for k in np.argsort(-values, kind="stable"):
        if best >= 0 and values[k] * cfg.ambiguity_ratio <= values[best]:
            break
        if best >= 0 and not _distinct(candidates[best], candidates[k], b, cfg):
            continue  # the best again, from another bin
        reason = veto(candidates[k]) if veto is not None else ""
        if reason:
            first_reason = first_reason or reason
            continue
        if best < 0:
            best = int(k)
        else:
            rival = float(values[k])
            break
    if best < 0:
        return Alignment(
            "ransac", None, None, 0, len(matches), first_reason or "no hypothesis", None
        )
    transform = candidates[best]
    supports = len(_supports(transform, tree, a, b, cfg))
    if rival > 0:
        return Alignment(
            "ransac",
            None,
            None,
            supports,
            len(matches),
            f"ambiguous: a distinct transform scores {rival:.3g} against the best's"
            f" {values[best]:.3g} (ambiguity_ratio {cfg.ambiguity_ratio:g})",
            transform,
        )
    return _answer("ransac", a, b, transform, _supports(transform, tree, a, b, cfg), matches, cfg)


def _oriented_hypothesis(a: FeatureMap, b: FeatureMap, match: np.ndarray) -> np.ndarray:
    """The transform (3,) that lays oriented feature j of B onto feature i of A: θ from their
    headings, t from their positions."""
    assert a.headings is not None and b.headings is not None
    i, j = int(match[0]), int(match[1])
    theta = wrap_scalar(float(a.headings[i] - b.headings[j]))
    t = a.positions[i] - rotation(theta) @ b.positions[j]
    return np.array([t[0], t[1], theta])


def refine(
    a: FeatureMap, b: FeatureMap, transform: np.ndarray, cfg: AlignConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares refinement that drops outliers (the seed's final step).

    Correspondences are the supports of the current transform (within th2); the rigid fit
    over them is repeated, keeping only correspondences whose residual is within
    ``outlier_sigmas`` robust standard deviations (1.4826 × the median absolute residual per
    coordinate, plus a nanometre for rounding), until the kept set stops changing.
    Returns (transform (3,), covariance (3, 3), pairs (k, 2)). The covariance is
    σ² (JᵀJ)⁻¹ with σ² the residual variance per coordinate (2k − 3 degrees of freedom) and J
    the residuals' Jacobian w.r.t. (t_x, t_y, θ) at the solution.
    """
    tree = cKDTree(a.positions)
    pairs = _supports(transform, tree, a, b, cfg)
    for _ in range(cfg.icp_max_iterations):
        if len(pairs) < 3:
            break
        transform = rigid_fit(a.positions[pairs[:, 0]], b.positions[pairs[:, 1]])
        limit = _outlier_limit(_residuals(a, b, transform, pairs), cfg)
        near = _supports(transform, tree, a, b, cfg)
        new_pairs = near[np.all(np.abs(_residuals(a, b, transform, near)) <= limit, axis=1)]
        if np.array_equal(new_pairs, pairs):
            break
        pairs = new_pairs
    if len(pairs) >= 3:
        transform = rigid_fit(a.positions[pairs[:, 0]], b.positions[pairs[:, 1]])
    return transform, _covariance(a, b, transform, pairs), pairs


def refine_own(
    a: FeatureMap, b: FeatureMap, transform: np.ndarray, pairs: np.ndarray, cfg: AlignConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares refinement over the aligner's own correspondences ``pairs`` (k, 2) (the
    seed's §6: "the set of correspondences and this estimate are used as the input of a least
    squares minimization that eliminates outliers"); never re-paired.

    From the aligner's estimate ``transform``: keep the pairs whose residuals are within
    ``outlier_sigmas`` robust standard deviations of those kept so far (all, at first), fit
    them, and repeat until the kept set stops changing. Returns (transform, covariance,
    kept pairs) as :func:`refine` does; fewer than 2 pairs leave the estimate as it is.
    """
    kept = pairs
    for _ in range(cfg.icp_max_iterations):
        if len(kept) < 2:
            break
        limit = _outlier_limit(_residuals(a, b, transform, kept), cfg)
        new = pairs[np.all(np.abs(_residuals(a, b, transform, pairs)) <= limit, axis=1)]
        if len(new) < 2:
            break
        transform = rigid_fit(a.positions[new[:, 0]], b.positions[new[:, 1]])
        if np.array_equal(new, kept):
            break
        kept = new
    return transform, _covariance(a, b, transform, kept), kept


def _residuals(
    a: FeatureMap, b: FeatureMap, transform: np.ndarray, pairs: np.ndarray
) -> np.ndarray:
    """A − T(B) (k, 2) over pairs (k, 2) (i in A, j in B)."""
    return a.positions[pairs[:, 0]] - _apply(transform, b.positions[pairs[:, 1]])


def _outlier_limit(res: np.ndarray, cfg: AlignConfig) -> float:
    """``outlier_sigmas`` robust standard deviations of residuals (k, 2): 1.4826 × their
    median absolute value per coordinate, plus a nanometre for rounding."""
    return cfg.outlier_sigmas * 1.4826 * float(np.median(np.abs(res))) + 1e-9


def _covariance(
    a: FeatureMap, b: FeatureMap, transform: np.ndarray, pairs: np.ndarray
) -> np.ndarray:
    """σ² (JᵀJ)⁻¹ of the rigid fit over ``pairs`` (see :func:`refine`); inf if underdetermined."""
    k = len(pairs)
    if k < 3:
        return np.full((3, 3), np.inf)
    pb = b.positions[pairs[:, 1]]
    moved = _apply(transform, pb)
    res = a.positions[pairs[:, 0]] - moved
    sigma2 = float(np.sum(res * res)) / max(2 * k - 3, 1)
    # residual r = a − (R b + t): ∂r/∂t = −I, ∂r/∂θ = −R' b = −(−(Rb)_y, (Rb)_x)
    rb = moved - transform[:2]
    J = np.zeros((2 * k, 3))
    J[0::2, 0] = J[1::2, 1] = -1.0
    J[0::2, 2] = rb[:, 1]
    J[1::2, 2] = -rb[:, 0]
    info = J.T @ J
    if np.linalg.matrix_rank(info) < 3:
        return np.full((3, 3), np.inf)
    cov: np.ndarray = sigma2 * np.linalg.inv(info)
    return 0.5 * (cov + cov.T)


def _answer(
    method: str,
    a: FeatureMap,
    b: FeatureMap,
    transform: np.ndarray | None,
    own: np.ndarray,
    matches: np.ndarray,
    cfg: AlignConfig,
) -> Alignment:
    """An aligner's estimate ``transform`` and its own correspondences ``own`` (k, 2) through
    the refinement and the decline rule ``cfg`` names."""
    if transform is None:
        return Alignment(method, None, None, 0, len(matches), "no geometrically consistent pair")
    raw = transform.copy()
    raw[2] = wrap_scalar(float(raw[2]))
    if cfg.refinement == "own":
        refined, cov, pairs = refine_own(a, b, transform, own, cfg)
    else:
        refined, cov, pairs = refine(a, b, transform, cfg)
    if cfg.declines == "seed":
        needed = cfg.min_support if method == "ransac" else 0
        support = len(own)  # RANSAC's supports of its best hypothesis (step d)
        rule = f"min_support {cfg.min_support} of the seed's RANSAC"
    else:
        needed = max(cfg.min_support, chance_supports(a, b, cfg))
        support = len(pairs)
        rule = f"min_support {cfg.min_support}, or what a wrong transform reaches by chance"
    if support < needed:
        return Alignment(
            method,
            None,
            None,
            len(pairs),
            len(matches),
            f"{support} supports < {needed} needed ({rule})",
            raw,
            pairs,
        )
    refined = refined.copy()
    refined[2] = wrap_scalar(float(refined[2]))
    return Alignment(method, refined, cov, len(pairs), len(matches), "", raw, pairs)


def _too_few(method: str, matches: np.ndarray, cfg: AlignConfig) -> Alignment | None:
    """Decline before aligning: fewer descriptor matches than ``min_support`` (guarded), or
    than the two any transform needs (seed)."""
    needed = 2 if cfg.declines == "seed" else max(2, cfg.min_support)
    if len(matches) < needed:
        return Alignment(
            method,
            None,
            None,
            0,
            len(matches),
            f"{len(matches)} descriptor matches < {needed} needed",
        )
    return None


# -- the four aligners -----------------------------------------------------------------------------
def ransac(
    a: FeatureMap,
    b: FeatureMap,
    rng: np.random.Generator,
    cfg: AlignConfig | None = None,
    veto: Veto | None = None,
    score: Score | None = None,
) -> Alignment:
    """RANSAC over descriptor matches (seed §5.1), then the refinement; its own
    correspondences are its best hypothesis' supports. Over oriented features every candidate
    is a hypothesis, ranked by ``score``; ``veto`` may refuse some, and an ambiguous answer is
    declined (:func:`_ransac_oriented`)."""
    cfg = cfg or AlignConfig()
    matches = candidate_matches(a, b, cfg.descriptor_threshold)
    if (declined := _too_few("ransac", matches, cfg)) is not None:
        return declined
    tree = cKDTree(a.positions)
    if a.oriented and b.oriented:
        return _ransac_oriented(a, b, matches, tree, cfg, veto, score)
    best, best_supports = None, np.zeros((0, 2), dtype=int)
    for _ in range(cfg.iterations):
        k, m = rng.choice(len(matches), size=2, replace=False)
        (ia, jb), (ia2, jb2) = matches[k], matches[m]
        pa, pb = a.positions[[ia, ia2]], b.positions[[jb, jb2]]
        if ia == ia2 or jb == jb2 or not _geometric_ok(pa, pb, cfg.geometric_threshold):
            continue
        hypothesis = transform_from_pairs(pa, pb)
        supports = _supports(hypothesis, tree, a, b, cfg)
        if best is None or len(supports) > len(best_supports):
            best, best_supports = hypothesis, supports
    return _answer("ransac", a, b, best, best_supports, matches, cfg)


def svd(
    a: FeatureMap, b: FeatureMap, rng: np.random.Generator, cfg: AlignConfig | None = None
) -> Alignment:
    """One least-squares solve over the descriptor matches that are geometrically consistent
    with most other matches (seed §5.2; they are its own correspondences), then the
    refinement. ``rng`` is unused (kept so every aligner has the same signature)."""
    del rng
    cfg = cfg or AlignConfig()
    matches = candidate_matches(a, b, cfg.descriptor_threshold)
    if (declined := _too_few("svd", matches, cfg)) is not None:
        return declined
    pa, pb = a.positions[matches[:, 0]], b.positions[matches[:, 1]]
    da = np.linalg.norm(pa[:, None] - pa[None], axis=-1)  # (k, k)
    db = np.linalg.norm(pb[:, None] - pb[None], axis=-1)
    votes = (np.abs(da - db) < cfg.geometric_threshold).sum(axis=1) - 1  # minus itself
    consistent = votes > 0.5 * (len(matches) - 1)
    own = matches[consistent]
    if len(own) < 2:
        return _answer("svd", a, b, None, own, matches, cfg)
    return _answer("svd", a, b, rigid_fit(pa[consistent], pb[consistent]), own, matches, cfg)


def _icp_from(
    a: FeatureMap, b: FeatureMap, start: np.ndarray, cfg: AlignConfig
) -> tuple[np.ndarray, np.ndarray]:
    """ICP from ``start``: nearest-neighbour correspondences within th2 and the rigid fit,
    alternated until the correspondences stop changing (seed §5.3). Returns the transform and
    the correspondences (k, 2) it was fitted to (none if it never moved from ``start``)."""
    tree = cKDTree(a.positions)
    transform, pairs = start, np.zeros((0, 2), dtype=int)
    for k in range(cfg.icp_max_iterations):
        new = _supports(transform, tree, a, b, cfg)
        if len(new) < 2 or (k > 0 and np.array_equal(new, pairs)):
            break
        pairs = new
        transform = rigid_fit(a.positions[pairs[:, 0]], b.positions[pairs[:, 1]])
    return transform, pairs


def icp(
    a: FeatureMap, b: FeatureMap, rng: np.random.Generator, cfg: AlignConfig | None = None
) -> Alignment:
    """ICP from one RANSAC-style initial estimate (seed §5.3), then the refinement; its own
    correspondences are its final nearest neighbours."""
    cfg = cfg or AlignConfig()
    matches = candidate_matches(a, b, cfg.descriptor_threshold)
    if (declined := _too_few("icp", matches, cfg)) is not None:
        return declined
    start = _random_hypothesis(a, b, matches, cfg, rng)
    if start is None:
        return _answer("icp", a, b, None, np.zeros((0, 2), dtype=int), matches, cfg)
    return _answer("icp", a, b, *_icp_from(a, b, start, cfg), matches, cfg)


def imp_icp(
    a: FeatureMap, b: FeatureMap, rng: np.random.Generator, cfg: AlignConfig | None = None
) -> Alignment:
    """ICP from ``imp_icp_starts`` initial estimates; the most supported result wins (§5.4)."""
    cfg = cfg or AlignConfig()
    matches = candidate_matches(a, b, cfg.descriptor_threshold)
    if (declined := _too_few("imp_icp", matches, cfg)) is not None:
        return declined
    tree = cKDTree(a.positions)
    best, best_pairs, best_support = None, np.zeros((0, 2), dtype=int), -1
    for _ in range(cfg.imp_icp_starts):
        start = _random_hypothesis(a, b, matches, cfg, rng)
        if start is None:
            continue
        result, pairs = _icp_from(a, b, start, cfg)
        support = len(_supports(result, tree, a, b, cfg))
        if support > best_support:
            best, best_pairs, best_support = result, pairs, support
    return _answer("imp_icp", a, b, best, best_pairs, matches, cfg)


ALIGNERS = {"ransac": ransac, "svd": svd, "icp": icp, "imp_icp": imp_icp}


def align(
    method: str,
    a: FeatureMap,
    b: FeatureMap,
    rng: np.random.Generator,
    cfg: AlignConfig | None = None,
    veto: Veto | None = None,
    score: Score | None = None,
) -> Alignment:
    """Run the aligner named ``method`` (one of :data:`ALIGNERS`). ``veto(transform)``: the
    caller's other evidence, a reason to refuse a transform or ""; RANSAC over oriented
    features consults it for every hypothesis that could win, and every aligner's answer is
    put to it (a refused answer is declined with that reason). ``score(transform)``: how
    RANSAC over oriented features ranks its hypotheses (default: their supports)."""
    try:
        aligner = ALIGNERS[method]
    except KeyError:
        raise ConfigError(
            f"alignment method: unknown {method!r} (known: {', '.join(ALIGNERS)})"
        ) from None
    result = ransac(a, b, rng, cfg, veto, score) if aligner is ransac else aligner(a, b, rng, cfg)
    if veto is not None and result.transform is not None:
        reason = veto(result.transform)
        if reason:
            return dataclasses.replace(result, transform=None, covariance=None, reason=reason)
    return result

"""Fusing SEIF maps with unknown relative pose and non-unique landmarks (seed 001, §4).

A map to fuse is an :class:`InformationMap`: landmark means and the landmarks' joint
information matrix (the robot's pose eliminated, :meth:`PointSeif.landmark_information`).
Fusion of map B into map A:

1. **hypotheses from triplets**: every landmark with its two nearest neighbours makes a
   triangle; its side lengths (sorted) do not depend on the frame. Triangles of A and B whose
   sides agree within ``triangle_tolerance`` give a hypothesis: the rigid transform that maps
   B's three vertices onto A's (vertices ordered by the opposite side's length);
2. **correspondences** for a hypothesis: each B landmark moved into A's frame is paired with
   the nearest A landmark when their Mahalanobis distance d² (the two marginal covariances
   added) is below ``gate`` — one to one;
3. **likelihood against a penalty**: collapsing a pair costs d²/2 of log-likelihood and
   gains the constant ``gain``; a hypothesis scores Σ (gain − d²/2) over its pairs. The best
   hypothesis is refined (least squares over its pairs, then pairs again) and the fusion is
   accepted only if its score is positive and it collapses at least as many landmarks as a
   wrong transform would pair by chance (``chance_supports`` of
   :mod:`polyslam_env.slam.alignment.aligners`, with the gate's radius) and
   ``min_pairs``: fusing unrelated places is worse than not fusing;
4. **fusion**: B's information is rotated into A's frame (H_B' = R H_B Rᵀ per landmark,
   block-wise; the transform is taken as exact), the two maps are joined block-diagonally and
   each corresponding pair is collapsed into one landmark by adding its rows and columns
   (equating two variables in information form). Means follow from H μ = b.

Landmark identities (``ids``) ride along for evaluation only; matching never reads them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.special
from scipy.spatial import cKDTree

from polyslam_env.core.config import Config, check_positive
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import rotation
from polyslam_env.slam.alignment.aligners import (
    AlignConfig,
    FeatureMap,
    chance_supports,
    rigid_fit,
)

__all__ = [
    "Fusion",
    "FusionConfig",
    "InformationMap",
    "find_fusion",
    "fuse",
    "fuse_jointly",
    "fuse_with_transform",
    "transform_covariance",
]


#: χ²'s 99 % quantile with 2 dof, as ``scipy.stats.chi2.ppf(0.99, 2)`` computes it (2·P⁻¹(1, p),
#: the inverse regularised incomplete gamma function), without importing scipy.stats (~1 s).
CHI2_2DOF_99 = float(2.0 * scipy.special.gammaincinv(1.0, 0.99))


@dataclass(frozen=True)
class FusionConfig(Config):
    triangle_tolerance: float = 0.5  # m, largest side-length difference of matching triplets
    gate: float = CHI2_2DOF_99  # d² of a correspondence (99 %, 2 dof)
    gain: float = 0.5 * CHI2_2DOF_99  # log-likelihood per collapse
    hypotheses: int = 300  # triplet matches tried (at random beyond that)
    min_pairs: int = 6

    def validate(self) -> None:
        for name in ("triangle_tolerance", "gate", "gain"):
            check_positive(f"fusion.{name}", getattr(self, name))
        if self.hypotheses < 1 or self.min_pairs < 3:
            raise ConfigError(
                f"fusion.hypotheses must be >= 1 and min_pairs >= 3, got {self.hypotheses},"
                f" {self.min_pairs}"
            )


@dataclass(frozen=True)
class InformationMap:
    """Landmarks (n) in one frame: means (n, 2), joint information H (2n, 2n), their truth
    ids (n,) for evaluation only."""

    means: np.ndarray
    information: np.ndarray
    ids: np.ndarray

    def __len__(self) -> int:
        return len(self.means)

    def covariances(self) -> np.ndarray:  # (n, 2, 2) marginals
        cov = np.linalg.inv(self.information)
        n = len(self.means)
        return np.array([cov[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] for k in range(n)])


@dataclass(frozen=True)
class Fusion:
    transform: np.ndarray  # (3,) B's frame in A's
    pairs: np.ndarray  # (k, 2) (index in A, index in B)
    score: float  # Σ (gain − d²/2)
    # (3, 3) the transform's uncertainty, carried into B's landmarks by :func:`fuse`; None:
    # the transform is taken as exact (the seed's fusion)
    covariance: np.ndarray | None = None


def _triangles(means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per landmark with ≥ 2 neighbours: sorted side lengths (n, 3) and the vertex indices
    (n, 3), each vertex listed opposite the side of the same rank."""
    n = len(means)
    if n < 3:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=int)
    _, near = cKDTree(means).query(means, k=3)
    sides, verts = [], []
    for tri in near:
        p = means[tri]
        # side opposite vertex v: between the other two
        opp = [float(np.hypot(*(p[(v + 1) % 3] - p[(v + 2) % 3]))) for v in range(3)]
        order = np.argsort(opp, kind="stable")
        sides.append(np.array(opp)[order])
        verts.append(tri[order])
    return np.array(sides), np.array(verts, dtype=int)


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ rotation(float(transform[2])).T + transform[:2]


def _pairs(
    a_means: np.ndarray,
    a_covs: np.ndarray,
    b_means: np.ndarray,
    b_covs: np.ndarray,
    transform: np.ndarray,
    cfg: FusionConfig,
    tree: cKDTree,
) -> tuple[np.ndarray, float]:
    """One-to-one gated correspondences (k, 2) under ``transform`` and their score."""
    R = rotation(float(transform[2]))
    moved = _apply(transform, b_means)
    radius = math.sqrt(cfg.gate * float(np.max(np.linalg.eigvalsh(a_covs)) * 2 + 1e-12))
    radius = max(radius, 1e-6)
    cand = tree.query_ball_point(moved, r=radius)
    best: dict[int, tuple[float, int]] = {}
    for j, near in enumerate(cand):
        cov_b = R @ b_covs[j] @ R.T
        for i in near:
            d = a_means[i] - moved[j]
            d2 = float(d @ np.linalg.solve(a_covs[i] + cov_b, d))
            if d2 < cfg.gate and (j not in best or d2 < best[j][0]):
                best[j] = (d2, i)
    taken: dict[int, tuple[float, int]] = {}
    for j, (d2, i) in sorted(best.items(), key=lambda kv: kv[1][0]):
        if i not in taken:
            taken[i] = (d2, j)
    pairs = np.array([(i, j) for i, (_, j) in sorted(taken.items())], dtype=int).reshape(-1, 2)
    score = float(sum(cfg.gain - 0.5 * d2 for d2, _ in taken.values()))
    return pairs, score


def find_fusion(
    a: InformationMap, b: InformationMap, rng: np.random.Generator, cfg: FusionConfig | None = None
) -> Fusion | None:
    """The accepted fusion hypothesis of B into A, or None (see the module docstring)."""
    cfg = cfg or FusionConfig()
    if len(a) < 3 or len(b) < 3:
        return None
    sides_a, verts_a = _triangles(a.means)
    sides_b, verts_b = _triangles(b.means)
    tree_sides = cKDTree(sides_a)
    matches = [
        (ia, ib)
        for ib, near in enumerate(
            tree_sides.query_ball_point(sides_b, r=cfg.triangle_tolerance, p=np.inf)
        )
        for ia in near
    ]
    if not matches:
        return None
    if len(matches) > cfg.hypotheses:
        pick = rng.choice(len(matches), size=cfg.hypotheses, replace=False)
        matches = [matches[k] for k in sorted(pick)]
    a_covs, b_covs = a.covariances(), b.covariances()
    tree = cKDTree(a.means)
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for ia, ib in matches:
        t = rigid_fit(a.means[verts_a[ia]], b.means[verts_b[ib]])
        pairs, score = _pairs(a.means, a_covs, b.means, b_covs, t, cfg, tree)
        if best is None or score > best[0]:
            best = (score, t, pairs)
    assert best is not None
    score, t, pairs = best
    if len(pairs) >= 3:  # refine on the pairs, then pair again
        t = rigid_fit(a.means[pairs[:, 0]], b.means[pairs[:, 1]])
        pairs, score = _pairs(a.means, a_covs, b.means, b_covs, t, cfg, tree)
    radius = math.sqrt(cfg.gate * float(np.median(np.linalg.eigvalsh(a_covs).max(axis=1))) * 2)
    chance = chance_supports(
        FeatureMap(a.means, np.zeros((len(a), 0))),
        FeatureMap(b.means, np.zeros((len(b), 0))),
        AlignConfig(support_threshold=max(radius, 1e-6)),
    )
    if score <= 0 or len(pairs) < max(cfg.min_pairs, chance):
        return None
    return Fusion(t, pairs, score)


def transform_covariance(a: InformationMap, b: InformationMap, fusion: Fusion) -> np.ndarray:
    """(3, 3) covariance of the transform fitted to ``fusion.pairs``: the weighted least
    squares information Σ Jᵀ (Σ_A,i + R Σ_B,j Rᵀ)⁻¹ J over the pairs (J = ∂(R b_j + t)/∂T),
    inverted; the pairs' errors taken as independent."""
    t = fusion.transform
    R = rotation(float(t[2]))
    a_covs, b_covs = a.covariances(), b.covariances()
    info = np.zeros((3, 3))
    for i, j in fusion.pairs:
        jac = np.zeros((2, 3))
        jac[:, :2] = np.eye(2)
        rb = R @ b.means[j]
        jac[:, 2] = [-rb[1], rb[0]]
        w = np.linalg.inv(a_covs[i] + R @ b_covs[j] @ R.T)
        info += jac.T @ w @ jac
    cov = np.linalg.inv(info)
    return np.asarray(0.5 * (cov + cov.T))


def fuse_with_transform(
    a: InformationMap,
    b: InformationMap,
    transform: np.ndarray,
    transform_cov: np.ndarray | None = None,
    cfg: FusionConfig | None = None,
) -> InformationMap:
    """B fused into A near a known ``transform`` (B's frame in A's): the correspondences
    found again by the gated one-to-one pairing of :func:`find_fusion`, then
    :func:`fuse_jointly` (the transform re-estimated with the landmarks and marginalised);
    with fewer than 3 pairs, :func:`fuse` with ``transform_cov`` (None: exact)."""
    cfg = cfg or FusionConfig()
    if len(a) == 0:
        return fuse(a, b, Fusion(transform, np.zeros((0, 2), dtype=int), 0.0, transform_cov))
    pairs, score = _pairs(
        a.means, a.covariances(), b.means, b.covariances(), transform, cfg, cKDTree(a.means)
    )
    return fuse_jointly(a, b, Fusion(transform, pairs, score, transform_cov))


def fuse_jointly(
    a: InformationMap, b: InformationMap, fusion: Fusion, iterations: int = 3
) -> InformationMap:
    """B fused into A with the transform estimated **jointly** with the landmarks, then
    marginalised: the consistent form of :func:`fuse` when the transform was fitted to the
    very pairs being fused (``fuse`` takes it as exact; with a covariance it still ignores
    that the pairs fixed it).

    Unknowns x = (A's landmarks, B's unpaired landmarks, T). A's map is a prior on its
    landmarks (information H_A); B's map is a measurement of its landmarks in its own frame,
    b_j = R(θ)ᵀ (m_k − t) with information H_B, k the A landmark it is paired with or its own
    new one. Gauss–Newton from ``fusion.transform`` (``iterations`` relinearisations), then
    T is eliminated (Schur complement) from the information. A and B must be independent
    (each robot's own map). Fewer than 3 pairs cannot fix T: :func:`fuse` with the fusion's
    covariance instead."""
    pairs = np.asarray(fusion.pairs, dtype=int).reshape(-1, 2)
    if len(pairs) < 3:
        return fuse(a, b, fusion)
    na, nb = len(a), len(b)
    slot_of = {int(j): int(i) for i, j in pairs}
    keep_b = [j for j in range(nb) if j not in slot_of]
    for n, j in enumerate(keep_b):
        slot_of[j] = na + n
    nf = na + len(keep_b)
    dim = 2 * nf + 3
    x = np.concatenate(
        [a.means.ravel(), _apply(fusion.transform, b.means[keep_b]).ravel(), fusion.transform]
    )
    H = np.zeros((dim, dim))
    for _ in range(iterations):
        theta = float(x[-1])
        c, s = math.cos(theta), math.sin(theta)
        rt = np.array([[c, s], [-s, c]])  # R(θ)ᵀ
        drt = np.array([[-s, c], [-c, -s]])  # ∂R(θ)ᵀ/∂θ
        J = np.zeros((2 * nb, dim))
        h = np.zeros(2 * nb)
        t = x[2 * nf : 2 * nf + 2]
        for j in range(nb):
            k = slot_of[j]
            d = x[2 * k : 2 * k + 2] - t
            h[2 * j : 2 * j + 2] = rt @ d
            J[2 * j : 2 * j + 2, 2 * k : 2 * k + 2] = rt
            J[2 * j : 2 * j + 2, 2 * nf : 2 * nf + 2] = -rt
            J[2 * j : 2 * j + 2, 2 * nf + 2] = drt @ d
        H = np.zeros((dim, dim))
        g = np.zeros(dim)
        H[: 2 * na, : 2 * na] = a.information
        g[: 2 * na] = a.information @ a.means.ravel()
        H += J.T @ b.information @ J
        g += J.T @ b.information @ (b.means.ravel() - h + J @ x)
        x = np.linalg.solve(H, g)
    h_mm, h_mt, h_tt = H[: 2 * nf, : 2 * nf], H[: 2 * nf, 2 * nf :], H[2 * nf :, 2 * nf :]
    h_m = h_mm - h_mt @ np.linalg.solve(h_tt, h_mt.T)
    ids = np.concatenate([a.ids, b.ids[keep_b]])
    return InformationMap(x[: 2 * nf].reshape(-1, 2), 0.5 * (h_m + h_m.T), ids)


def fuse(a: InformationMap, b: InformationMap, fusion: Fusion) -> InformationMap:
    """One map in A's frame: B rotated in, the corresponding pairs collapsed (module step 4)."""
    R = rotation(float(fusion.transform[2]))
    nb = len(b)
    rot = np.kron(np.eye(nb), R)  # (2nb, 2nb) block-diagonal rotation
    h_b = rot @ b.information @ rot.T
    means_b = _apply(fusion.transform, b.means)
    if fusion.covariance is not None and nb:
        # B's joint covariance in A's frame plus the transform's: Σ' = R Σ Rᵀ + J Σ_T Jᵀ,
        # J (2nb, 3) = ∂(R b + t)/∂T, then back to information
        jac = np.zeros((2 * nb, 3))
        jac[0::2, 0] = jac[1::2, 1] = 1.0
        rb = means_b - fusion.transform[:2]
        jac[0::2, 2] = -rb[:, 1]
        jac[1::2, 2] = rb[:, 0]
        cov_b = np.linalg.inv(h_b) + jac @ fusion.covariance @ jac.T
        h_b = np.linalg.inv(0.5 * (cov_b + cov_b.T))
    na = len(a)
    merged_into = {int(j): int(i) for i, j in fusion.pairs}
    keep_b = [j for j in range(nb) if j not in merged_into]
    # M maps the fused variables (A's, then B's unmatched) onto the joint ones (A's, B's)
    nf = na + len(keep_b)
    M = np.zeros((2 * (na + nb), 2 * nf))
    M[: 2 * na, : 2 * na] = np.eye(2 * na)
    for slot, j in enumerate(keep_b):
        M[2 * (na + j) : 2 * (na + j) + 2, 2 * (na + slot) : 2 * (na + slot) + 2] = np.eye(2)
    for j, i in merged_into.items():
        M[2 * (na + j) : 2 * (na + j) + 2, 2 * i : 2 * i + 2] = np.eye(2)
    joint = np.zeros((2 * (na + nb), 2 * (na + nb)))
    joint[: 2 * na, : 2 * na] = a.information
    joint[2 * na :, 2 * na :] = h_b
    b_joint = joint @ np.concatenate([a.means.ravel(), means_b.ravel()])
    h = M.T @ joint @ M
    h = 0.5 * (h + h.T)
    means = np.linalg.solve(h, M.T @ b_joint).reshape(-1, 2)
    ids = np.concatenate([a.ids, b.ids[keep_b]])
    return InformationMap(means, h, ids)

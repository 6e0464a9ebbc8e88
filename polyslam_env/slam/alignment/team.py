"""Consistent alignment of n > 2 maps (seed 004 §7): one global least-squares solve.

Pairwise aligners give, for some pairs (i, j), the transform z_ij of map j's frame in map i's
with a covariance. Around a cycle those need not compose to the identity. The team solver
estimates one pose X_i per map in the anchor map's frame (X_anchor = 0) by minimising
Σ ‖z_ij ⊖ (X_i⁻¹ ⊕ X_j)‖² whitened by each covariance (``scipy.optimize.least_squares``);
the consistent pairwise transforms are then X_i⁻¹ ⊕ X_j, which compose exactly around every
cycle. Maps no alignment connects to the anchor get no pose.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from polyslam_env.core.geometry import between, compose, wrap_remainder

__all__ = ["PairwiseAlignment", "TeamSolution", "solve_team"]


@dataclass(frozen=True)
class PairwiseAlignment:
    """Map j's frame in map i's, ``transform`` (3,), with its ``covariance`` (3, 3)."""

    i: int
    j: int
    transform: np.ndarray
    covariance: np.ndarray


@dataclass(frozen=True)
class TeamSolution:
    """Poses (n, 3) of every map's frame in the anchor's (NaN rows: not connected)."""

    poses: np.ndarray
    anchor: int
    cost: float  # ½ Σ whitened squared residuals at the solution

    @property
    def connected(self) -> np.ndarray:  # (n,) bool
        return np.all(np.isfinite(self.poses), axis=1)

    def relative(self, i: int, j: int) -> np.ndarray:  # (3,)
        """The consistent transform of map j's frame in map i's."""
        out: np.ndarray = between(self.poses[i], self.poses[j], wrap_remainder)
        return out


def _whitener(cov: np.ndarray) -> np.ndarray:
    """L with Lᵀ L = cov⁻¹ (upper Cholesky factor of the information); a covariance that is
    not finite and positive definite weighs the pair with unit information instead."""
    cov = np.asarray(cov, dtype=float)
    if not np.all(np.isfinite(cov)):
        return np.eye(3)
    try:
        return np.asarray(np.linalg.cholesky(np.linalg.inv(cov)).T)
    except np.linalg.LinAlgError:
        return np.eye(3)


def _spanning_guess(n: int, pairs: Sequence[PairwiseAlignment], anchor: int) -> np.ndarray:
    """Initial poses by composing the alignments along a breadth-first tree from the anchor."""
    poses = np.full((n, 3), np.nan)
    poses[anchor] = 0.0
    edges: dict[int, list[tuple[int, np.ndarray]]] = {k: [] for k in range(n)}
    for p in pairs:
        z = np.asarray(p.transform, dtype=float)
        edges[p.i].append((p.j, z))
        edges[p.j].append((p.i, between(z, np.zeros(3), wrap_remainder)))  # z⁻¹
    queue = deque([anchor])
    while queue:
        k = queue.popleft()
        for other, z in edges[k]:
            if np.isnan(poses[other, 0]):
                poses[other] = compose(poses[k], z)
                queue.append(other)
    return poses


def solve_team(n: int, pairs: Sequence[PairwiseAlignment], anchor: int = 0) -> TeamSolution:
    """The globally consistent poses of ``n`` maps from pairwise alignments (see module)."""
    if not 0 <= anchor < n:
        raise ValueError(f"anchor must be in 0..{n - 1}, got {anchor}")
    for p in pairs:
        if not (0 <= p.i < n and 0 <= p.j < n) or p.i == p.j:
            raise ValueError(f"alignment between maps {p.i} and {p.j} of {n}")
    guess = _spanning_guess(n, pairs, anchor)
    free = [k for k in range(n) if k != anchor and np.isfinite(guess[k, 0])]
    used = [p for p in pairs if np.isfinite(guess[p.i, 0]) and np.isfinite(guess[p.j, 0])]
    if not free:
        return TeamSolution(guess, anchor, 0.0)
    whiten = [_whitener(p.covariance) for p in used]

    def poses_of(x: np.ndarray) -> np.ndarray:
        poses = guess.copy()
        poses[free] = x.reshape(-1, 3)
        return poses

    def residuals(x: np.ndarray) -> np.ndarray:
        poses = poses_of(x)
        out = np.empty(3 * len(used))
        for k, (p, w) in enumerate(zip(used, whiten, strict=True)):
            predicted = between(poses[p.i], poses[p.j], wrap_remainder)
            r = np.asarray(p.transform, dtype=float) - predicted
            r[2] = wrap_remainder(float(r[2]))
            out[3 * k : 3 * k + 3] = w @ r
        return out

    fit = scipy.optimize.least_squares(residuals, guess[free].ravel(), method="lm", xtol=1e-12)
    poses = poses_of(fit.x)
    poses[:, 2] = wrap_remainder(poses[:, 2])
    return TeamSolution(poses, anchor, float(fit.cost))

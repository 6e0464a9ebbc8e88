"""Particle state of a point-landmark FastSLAM and the pure functions that act on it.

Everything is vectorised over the N particles: a robot's poses are one (N, 3) array, every
particle's landmark EKFs one (N, C, 2) array of means and one (N, C, 2, 2) of covariances
(C ≥ landmarks seen, slots in order of first sighting). With known data association all
particles have seen the same landmarks, so the id → slot table is shared.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.points import models
from polyslam_env.slam.points.config import PointSlamConfig

#: Added to pose covariances only where a Gaussian *density* of a pose is evaluated, so a
#: zero-noise motion model (a point mass) gives a finite log ratio; 1e-12 m² is far below any
#: noise the filters model.
DENSITY_JITTER = 1e-12


@dataclass
class PoseBlock:
    """One robot's particle poses; between sensor sweeps each is a Gaussian (mean, cov)."""

    poses: np.ndarray  # (N, 3)
    covs: np.ndarray  # (N, 3, 3), zero right after a sweep's sampling

    @classmethod
    def at(cls, pose: np.ndarray, n: int) -> PoseBlock:
        """N particles at a known pose."""
        return cls(np.tile(np.asarray(pose, dtype=float), (n, 1)), np.zeros((n, 3, 3)))

    def take(self, index: np.ndarray) -> None:
        self.poses = self.poses[index]
        self.covs = self.covs[index]


@dataclass
class LandmarkBlock:
    """Per-particle landmark EKFs with a shared id → slot table."""

    n: int  # particles
    means: np.ndarray = field(init=False)  # (N, C, 2)
    covs: np.ndarray = field(init=False)  # (N, C, 2, 2)
    ids: list[int] = field(default_factory=list)  # slot → id
    slots: dict[int, int] = field(default_factory=dict)  # id → slot

    def __post_init__(self) -> None:
        self.means = np.zeros((self.n, 16, 2))
        self.covs = np.zeros((self.n, 16, 2, 2))

    def slots_of(self, ids: np.ndarray) -> np.ndarray:
        return np.array([self.slots[int(i)] for i in ids], dtype=np.int64)

    def add(self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray) -> None:
        """New landmarks (per particle means (N, m, 2), covs (N, m, 2, 2))."""
        start = len(self.ids)
        need = start + len(ids)
        if need > self.means.shape[1]:
            grow = max(need, 2 * self.means.shape[1]) - self.means.shape[1]
            self.means = np.concatenate([self.means, np.zeros((self.n, grow, 2))], axis=1)
            self.covs = np.concatenate([self.covs, np.zeros((self.n, grow, 2, 2))], axis=1)
        self.means[:, start:need] = means
        self.covs[:, start:need] = covs
        for k, i in enumerate(ids):
            self.slots[int(i)] = start + k
            self.ids.append(int(i))

    def take(self, index: np.ndarray) -> None:
        m = len(self.ids)
        self.means[:, :m] = self.means[index, :m]
        self.covs[:, :m] = self.covs[index, :m]


# -- prediction and the FastSLAM 2.0 proposal -----------------------------------------------
def predict(block: PoseBlock, controls: np.ndarray, config: PointSlamConfig) -> None:
    """Push every particle's pose Gaussian through ``config.motion`` for each control row."""
    for control in controls:
        block.poses, jac_pose, jac_ctrl, q = models.motion(block.poses, control, config)
        block.covs = jac_pose @ block.covs @ jac_pose.swapaxes(
            -1, -2
        ) + jac_ctrl @ q @ jac_ctrl.swapaxes(-1, -2)


def proposal(
    mean: np.ndarray,
    cov: np.ndarray,
    lm_means: np.ndarray,
    lm_covs: np.ndarray,
    z: np.ndarray,
    noise: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """FastSLAM 2.0's proposal: the predicted pose Gaussian (N, 3), (N, 3, 3) updated by one
    EKF step with all m re-observed landmarks stacked (a 2m-vector measurement whose noise is
    block-diagonal: each landmark's uncertainty lm_covs (N, m, 2, 2) mapped into measurement
    space plus the sensor noise). Montemerlo et al. process the landmarks one after the
    other; stacking gives the same result for a linear model and one solve instead of m."""
    n, m = len(mean), len(z)
    z_hat, h_pose, h_point = models.observe(mean[:, None, :], lm_means)  # (N,m,2),(N,m,2,3)
    block = h_point @ lm_covs @ h_point.swapaxes(-1, -2) + noise  # (N, m, 2, 2)
    h = h_pose.reshape(n, 2 * m, 3)
    s = h @ cov @ h.swapaxes(-1, -2)
    for k in range(m):
        s[:, 2 * k : 2 * k + 2, 2 * k : 2 * k + 2] += block[:, k]
    pht = cov @ h.swapaxes(-1, -2)  # (N, 3, 2m)
    gain = np.linalg.solve(s, pht.swapaxes(-1, -2)).swapaxes(-1, -2)  # P Hᵀ S⁻¹
    v = models.residual(z[None], z_hat).reshape(n, 2 * m)
    new_mean = mean + (gain @ v[..., None])[..., 0]
    new_mean[:, 2] = wrap_angle(new_mean[:, 2])
    new_cov = cov - gain @ pht.swapaxes(-1, -2)
    return new_mean, 0.5 * (new_cov + new_cov.swapaxes(-1, -2))


def sample(rng: np.random.Generator, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """One draw per particle from N(mean (N, 3), cov (N, 3, 3)); a zero cov gives the mean."""
    vals, vecs = np.linalg.eigh(cov)
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))[:, None, :]
    x = mean + (root @ rng.standard_normal(mean.shape)[..., None])[..., 0]
    x[:, 2] = wrap_angle(x[:, 2])
    return x


def gaussian_logpdf(v: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """log N(v; 0, cov) for v (..., d), cov (..., d, d)."""
    chol = np.linalg.cholesky(cov)
    y = np.linalg.solve(chol, v[..., None])[..., 0]
    log_det = 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(-1)
    d = v.shape[-1]
    return -0.5 * ((y * y).sum(-1) + log_det + d * np.log(2.0 * np.pi))


def inverse2(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses and determinants of 2 × 2 matrices (..., 2, 2), in closed form (numpy's
    batched solve costs more than the arithmetic for so small a matrix)."""
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    inv = np.empty_like(a)
    inv[..., 0, 0] = a[..., 1, 1] / det
    inv[..., 1, 1] = a[..., 0, 0] / det
    inv[..., 0, 1] = -a[..., 0, 1] / det
    inv[..., 1, 0] = -a[..., 1, 0] / det
    return inv, det


def gaussian_logpdf2(v: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """:func:`gaussian_logpdf` for d = 2 in closed form."""
    inv, det = inverse2(cov)
    maha = np.einsum("...i,...ij,...j->...", v, inv, v)
    return -0.5 * (maha + np.log(det)) - np.log(2.0 * np.pi)


def log_weight(
    x: np.ndarray,
    prior: tuple[np.ndarray, np.ndarray],
    prop: tuple[np.ndarray, np.ndarray],
    lm_means: np.ndarray,
    lm_covs: np.ndarray,
    z: np.ndarray,
    noise: np.ndarray,
) -> np.ndarray:
    """log of eq. 3's factor p(z | x, map) p(x | x_{k−1}, u) / q(x | x_{k−1}, z, u) at poses
    x (N, 3): the landmark EKFs' predictive likelihood times the motion prior over the
    proposal density (the prior and proposal as (mean, cov) pairs)."""
    out = np.zeros(len(x))
    if len(z):
        z_hat, _, h_point = models.observe(x[:, None, :], lm_means)
        s = h_point @ lm_covs @ h_point.swapaxes(-1, -2) + noise
        out += gaussian_logpdf2(models.residual(z[None], z_hat), s).sum(-1)
    jitter = DENSITY_JITTER * np.eye(3)
    out += gaussian_logpdf(models.pose_difference(x, prior[0]), prior[1] + jitter)
    out -= gaussian_logpdf(models.pose_difference(x, prop[0]), prop[1] + jitter)
    return out


# -- landmark EKFs (eqs. 9–13) --------------------------------------------------------------
def update_landmarks(
    means: np.ndarray,
    covs: np.ndarray,
    poses: np.ndarray,
    z: np.ndarray,
    noise: np.ndarray,
    step: float = 0.0,
    neighbours: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 9–13 for landmarks (N, m, 2), (N, m, 2, 2) re-observed as z (m, 2) from poses (N, 3).

    μ ← μ + K (z − ẑ) + ε Σ_n (μ^n − μ), where ``neighbours`` = (Σ_n μ^n (m, 2), count (m,))
    over the other robots' best-particle estimates; ``None`` or ε = 0 is the plain EKF. The
    covariance takes the Joseph form of eq. 13 (equal in exact arithmetic, stays PSD); the
    consensus term leaves it alone, as eq. 13 does.
    """
    z_hat, _, h = models.observe(poses[:, None, :], means)
    s = h @ covs @ h.swapaxes(-1, -2) + noise
    gain = covs @ h.swapaxes(-1, -2) @ inverse2(s)[0]
    v = models.residual(z[None], z_hat)
    new_means = means + (gain @ v[..., None])[..., 0]
    if neighbours is not None:  # ε = 0 adds exactly zero
        total, count = neighbours
        new_means += step * (total[None] - count[None, :, None] * means)
    i_kh = np.eye(2) - gain @ h
    new_covs = i_kh @ covs @ i_kh.swapaxes(-1, -2) + gain @ noise @ gain.swapaxes(-1, -2)
    return new_means, 0.5 * (new_covs + new_covs.swapaxes(-1, -2))


def init_landmarks(
    poses: np.ndarray, z: np.ndarray, noise: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """New landmarks' EKFs (N, m, 2), (N, m, 2, 2) from first measurements z (m, 2)."""
    points, jac = models.locate(poses[:, None, :], z[None])
    return points, jac @ noise @ jac.swapaxes(-1, -2)


# -- weights, resampling, estimates ---------------------------------------------------------
def normalise(log_w: np.ndarray) -> np.ndarray:
    """Log weights shifted so that the weights sum to one."""
    shifted = log_w - np.max(log_w)  # exact for the largest: no underflow, no cancellation
    return shifted - np.log(np.exp(shifted).sum())


def effective_size(log_w: np.ndarray) -> float:
    """N_eff = 1 / Σ w̄² of normalised log weights."""
    return float(1.0 / np.square(np.exp(log_w)).sum())


def systematic_resample(rng: np.random.Generator, log_w: np.ndarray) -> np.ndarray:
    """Low-variance resampling: N evenly spaced pointers from one uniform offset."""
    n = len(log_w)
    cum = np.cumsum(np.exp(log_w))
    cum[-1] = 1.0
    pointers = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cum, pointers, side="right").astype(np.int64)


def surviving_ancestors(parents: Sequence[np.ndarray], start: int, stop: int) -> int:
    """How many of the particles present after step ``start`` still have descendants after
    step ``stop`` (> ``start``), given each step's ``parents`` (N,) (particle k after step s
    descends from particle parents[s][k] before it; ``arange`` when nothing was resampled).
    N when resampling has lost no history in between, 1 when every particle descends from
    one: the trajectory (and map) hypotheses the filter still holds from that far back."""
    index = np.arange(len(parents[stop]))
    for s in range(stop, start, -1):
        index = parents[s][index]
    return len(np.unique(index))


def pose_estimate(poses: np.ndarray, log_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (circular in heading) and covariance of particle poses (N, 3)."""
    w = np.exp(log_w)
    mean = np.empty(3)
    mean[:2] = w @ poses[:, :2]
    mean[2] = np.arctan2(w @ np.sin(poses[:, 2]), w @ np.cos(poses[:, 2]))
    d = models.pose_difference(poses, mean[None])
    return mean, (w[:, None] * d).T @ d


def map_estimate(block: LandmarkBlock, log_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each landmark's particle mixture as one Gaussian: means (M, 2), covs (M, 2, 2)."""
    m = len(block.ids)
    w = np.exp(log_w)
    mu = block.means[:, :m]
    mean = np.einsum("n,nmi->mi", w, mu)
    d = mu - mean[None]
    cov = np.einsum("n,nmij->mij", w, block.covs[:, :m]) + np.einsum("n,nmi,nmj->mij", w, d, d)
    return mean, cov

"""Estimates against the truth: frames, position and landmark errors, NEES (both forms) and
its χ² band (SPEC §5).

Each robot estimates in its own start frame R_{j,0}. Its true start pose x_{j,0} = (x0, y0, θ0)
in the absolute frame is known here (never to the robot), so estimates are mapped to the
absolute frame before they are compared with ground truth: ``x_abs = x0 + R(θ0) [x, y]``,
``θ_abs = θ0 + θ``, ``P_abs = T P Tᵀ`` with ``T = blockdiag(R(θ0), 1)``.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import (
    compose,
    transform_covariance,
    transform_points,
    wrap_angle,
)


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


def position_error(true_poses: np.ndarray, est_poses: np.ndarray, start_pose: np.ndarray) -> float:
    """Mean position error ‖p̂ − p‖ (m) over the steps: estimates (K, 3) in the frame
    ``start_pose`` (3,) against the true poses (K, 3); 0.0 for no steps."""
    if len(est_poses) == 0:
        return 0.0
    est = pose_to_absolute(est_poses, start_pose)
    d = np.asarray(true_poses, dtype=float)[:, :2] - est[:, :2]
    return float(np.mean(np.hypot(d[:, 0], d[:, 1])))


def landmark_distances(
    means: np.ndarray, frame: np.ndarray, truth: np.ndarray
) -> np.ndarray:  # (M,)
    """Distance (m) of each landmark estimate ``means`` (M, 2), given in the frame ``frame``
    (3,), to its true position ``truth`` (M, 2) (absolute)."""
    est = transform_points(np.asarray(means, dtype=float).reshape(-1, 2), frame)
    d = est - np.asarray(truth, dtype=float).reshape(-1, 2)
    return np.hypot(d[:, 0], d[:, 1])


def nearest_points(means: np.ndarray, frame: np.ndarray, truth: np.ndarray) -> np.ndarray:  # (M,)
    """For each estimate ``means`` (M, 2) in the frame ``frame`` (3,), the index of the nearest
    of the true points ``truth`` (P, 2) (absolute)."""
    est = transform_points(np.asarray(means, dtype=float).reshape(-1, 2), frame)
    d = est[:, None, :] - np.asarray(truth, dtype=float)[None, :, :]
    return np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)


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
    return _standard(*_pose_errors(true_poses, est_poses, est_covs, start_pose))


def nees_paper_series(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> np.ndarray:  # (K,)
    """Per-step eᵀPe, the index as the paper prints it (gives its ~1e-6 values)."""
    return _paper(*_pose_errors(true_poses, est_poses, est_covs, start_pose))


def _standard(err: np.ndarray, cov: np.ndarray) -> np.ndarray:  # (K,)
    """eᵀP⁻¹e of each absolute error (K, 3) and covariance (K, 3, 3) (:func:`_pose_errors`)."""
    sol = np.linalg.solve(cov, err[..., None])[..., 0]  # (K, 3)
    return np.asarray(np.einsum("ki,ki->k", err, sol))


def _paper(err: np.ndarray, cov: np.ndarray) -> np.ndarray:  # (K,)
    """eᵀPe of each absolute error (K, 3) and covariance (K, 3, 3) (:func:`_pose_errors`)."""
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


def nees_and_paper(
    true_poses: np.ndarray, est_poses: np.ndarray, est_covs: np.ndarray, start_pose: np.ndarray
) -> tuple[float, float]:
    """(:func:`nees`, :func:`nees_paper`) of the same arguments, from one mapping of the
    estimates to the absolute frame (the same numbers as the two calls)."""
    err, cov = _pose_errors(true_poses, est_poses, est_covs, start_pose)
    return _mean_of(_standard(err, cov)), _mean_of(_paper(err, cov))


def nees_band(dof: int = 3, runs: int = 1, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` χ² band for the NEES at one step averaged over ``runs`` runs.

    ``runs · NEES̄ ~ χ²(runs · dof)`` for a consistent filter. The band is for run-averages at a
    fixed step; a time average over one run has correlated terms and no such simple band.
    """
    if dof < 1 or runs < 1 or not 0.0 < prob < 1.0:
        raise ValueError(f"need dof >= 1, runs >= 1, 0 < prob < 1; got {dof}, {runs}, {prob}")
    from scipy.stats import chi2  # here: importing scipy.stats takes ~1 s, every process

    n = dof * runs
    lo = float(chi2.ppf((1.0 - prob) / 2.0, n)) / runs
    hi = float(chi2.ppf((1.0 + prob) / 2.0, n)) / runs
    return lo, hi

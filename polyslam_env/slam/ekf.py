"""EKF core of the polynomial SLAM as pure functions on (mean, cov) (SPEC §3, STYLE habit 8).

State X = [x¹, x², θ, c0_1 … c0_n] (3+n,), covariance P (3+n, 3+n). Every function returns
new arrays and leaves its inputs untouched, except the prediction and the update the SLAM
step runs in place (:func:`predict_inplace`, :func:`update_sparse_inplace`: an O(n²) copy
per step would cost more than their arithmetic); a thin per-robot class strings them
together. Landmark i's c0 sits at state index 3+i.

Their textbook forms (dense F P Fᵀ + L W Lᵀ; a gated Joseph update with any H and R) are the
test oracles in ``tests/slam/reference.py``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.special

from polyslam_env.core.geometry import symmetric_eigvals3, wrap_angle
from polyslam_env.slam import kernels


def _symmetrise(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + a.T)


# -- prediction ----------------------------------------------------------------------------------


def predict(
    mean: np.ndarray,
    cov: np.ndarray,
    odometry: np.ndarray,
    W: np.ndarray,
    first_xy: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """EKF prediction from odometry (3,) with noise covariance W (3, 3) in the robot frame.

    Landmarks are static, so only the pose block (F P_pp Fᵀ + L W Lᵀ) and the pose–landmark
    cross-covariances (F P_pl) change: O(n) arithmetic (plus the copy that keeps it pure).
    ``first_xy``: see :func:`predict_inplace`.
    """
    new_mean = mean.astype(float, copy=True)
    new_cov = cov.astype(float, copy=True)
    predict_inplace(new_mean, new_cov, odometry, W, first_xy)
    return new_mean, new_cov


def predict_inplace(
    mean: np.ndarray,
    cov: np.ndarray,
    odometry: np.ndarray,
    W: np.ndarray,
    first_xy: tuple[float, float] | None = None,
) -> None:
    """:func:`predict` writing into ``mean`` (3+n,) and ``cov`` (3+n, 3+n) (float arrays).

    Without the pure version's (3+n)² copy, for the stateful caller whose per-step cost
    should stay O(n). F = ∂f/∂pose = I + a·e₀e₂ᵀ + b·e₁e₂ᵀ of the unicycle composition
    f(pose, u) = [x + cos θ·dx − sin θ·dy, y + sin θ·dx + cos θ·dy, θ + dθ], with the
    odometry u = (dx, dy, dθ) in the robot frame and L = ∂f/∂u, so F P_pl
    adds a and b times the heading row to the position rows, and the 3×3 pose block is
    written out in plain floats from its upper triangle (symmetric by construction).

    **First-estimates Jacobian** (Huang, Mourikis & Roumeliotis 2008). The standard F takes
    a = −Δy, b = Δx from the *updated* pose x̂_{k|k} to the prediction. Given ``first_xy``,
    the position of this pose's first estimate x̂_{k|k−1} (the prediction before the last
    update), it takes a = −(ŷ_{k+1|k} − ŷ_{k|k−1}), b = x̂_{k+1|k} − x̂_{k|k−1}: every
    Jacobian of a pose is then evaluated at one estimate of it, so the product of the
    propagation Jacobians from step 0 to k depends only on x̂_{k|k−1} − x̂_{0} and the
    linearised system keeps the nonlinear one's unobservable directions (a global rotation
    about the start); the standard F lets each update's correction δx̂ leak in as spurious
    information about the heading.
    """
    if mean.dtype != np.float64 or cov.dtype != np.float64:
        raise TypeError("predict_inplace: mean and cov must be float64 arrays")
    n = mean.size
    if mean.shape != (n,) or cov.shape != (n, n) or n < 3:
        raise ValueError(f"predict_inplace: mean {mean.shape} and cov {cov.shape} do not match")
    u = np.ascontiguousarray(odometry, dtype=float).reshape(3)
    w = np.ascontiguousarray(W, dtype=float).reshape(3, 3)
    fx, fy = (math.nan, math.nan) if first_xy is None else (float(first_xy[0]), float(first_xy[1]))
    kernels.predict(mean, cov, u, w, fx, fy)


def start_error_cov(pose: np.ndarray, p0: np.ndarray) -> np.ndarray:  # (3, 3)
    """Covariance J P0 Jᵀ that an unknown start error e₀ ~ N(0, P0) adds to a pose estimate.

    The filter estimates the pose x_S relative to the robot's *true* start (known exactly
    there: it is the origin of what the robot measures), while its frame is the nominal start;
    the true pose in the frame is e₀ ⊕ x_S. Nothing the robot senses is referenced to the
    frame, so e₀ is unobservable and independent of the filter's error: to first order
    Cov = J P0 Jᵀ + P_S with J = ∂(e₀ ⊕ x)/∂e₀ at e₀ = 0 = [[1, 0, −y], [0, 1, x], [0, 0, 1]]
    (a start heading error swings the pose about the start).
    """
    out: np.ndarray = start_error_covs(np.asarray(pose, dtype=float)[None], p0)[0]
    return out


def start_error_covs(poses: np.ndarray, p0: np.ndarray) -> np.ndarray:  # (K, 3, 3)
    """:func:`start_error_cov` of each pose (K, ≥2) (x, y first) in one compiled call
    (:func:`~polyslam_env.slam.kernels.start_error_covs`: the products J P0 Jᵀ as numpy's
    stacked matmul computed them, and the symmetrised result)."""
    poses = np.ascontiguousarray(poses, dtype=float)
    out = np.empty((poses.shape[0], 3, 3))
    kernels.start_error_covs(poses, np.ascontiguousarray(p0, dtype=float), out)
    return out


# -- update -------------------------------------------------------------------------------------
@lru_cache(maxsize=32)
def chi2_1dof_quantile(prob: float) -> float:
    """Quantile of χ² with 1 dof: (√2·erfinv(p))², without importing scipy.stats."""
    if not 0.0 < prob <= 1.0:
        raise ValueError(f"gate probability must lie in (0, 1], got {prob}")
    return float(2.0 * scipy.special.erfinv(prob) ** 2)


def update_sparse_inplace(
    mean: np.ndarray,
    cov: np.ndarray,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    r: np.ndarray,
    gate_prob: float = 0.99,
    alpha_index: np.ndarray | None = None,
    h_alpha: np.ndarray | None = None,
    consider_from: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Gated, batched EKF update with range rows that touch the pose and one c0 each, in place.

    Row i of H is ``h_pose[i]`` (3,) on the pose and ``h_c0[i]`` on state index
    ``c0_index[i]``; R = diag(``r``) (k,); ``innovation`` (k,) must be finite. Writes the new
    estimate into ``mean`` (3+n,) and ``cov`` (3+n, 3+n, symmetric) and returns
    (accepted (k,), nis (k,)).

    Each measurement is gated on its own normalised innovation ν_i²/S_ii against the χ²
    (1 dof) quantile ``gate_prob`` (1.0 disables the gate); the accepted ones update together
    with the Joseph form P⁺ = (I−KH) P (I−KH)ᵀ + K R Kᵀ (the oracle in tests computes it
    literally), expanded as P⁺ = P − (K Wᵀ + W Kᵀ) with W = P Hᵀ − ½ K S, in one compiled pass
    over P that keeps it exactly symmetric (:func:`~polyslam_env.slam.kernels.update_sparse`).
    K comes from a solve with S (SPEC §3: ``solve``, not ``inv``).

    Optionally row i also touches a landmark's shape rotation: ``h_alpha[i]`` on state index
    ``alpha_index[i]`` (−1: none); and the state entries from ``consider_from`` on are
    considered, not estimated (Schmidt–Kalman: zero gain, cross-covariances updated).
    """
    n, k = mean.size, np.size(r)
    if mean.dtype != np.float64 or cov.dtype != np.float64 or cov.shape != (n, n):
        raise ValueError(f"update: mean {mean.shape} and cov {cov.shape} must be float64, matching")
    nu = np.ascontiguousarray(innovation, dtype=float).reshape(-1)
    hp = np.ascontiguousarray(h_pose, dtype=float).reshape(-1, 3)
    idx = np.ascontiguousarray(c0_index, dtype=np.int64).reshape(-1)
    hc = np.ascontiguousarray(h_c0, dtype=float).reshape(-1)
    rv = np.ascontiguousarray(r, dtype=float).reshape(-1)
    if not nu.size == hp.shape[0] == idx.size == hc.size == k:
        raise ValueError(
            f"update: {nu.size} innovations, {hp.shape[0]}/{idx.size}/{hc.size}/{k} rows"
        )
    if k and (idx.min() < 3 or idx.max() >= n):
        raise ValueError(f"update: c0 indices must lie in [3, {n}), got {idx.tolist()}")
    ai, ha = _alpha_rows(alpha_index, h_alpha, k, n)
    accepted, nis = np.empty(k, dtype=bool), np.empty(k)
    gate = chi2_1dof_quantile(gate_prob)
    consider = n if consider_from is None else int(consider_from)
    kernels.update_sparse(mean, cov, nu, hp, idx, hc, ai, ha, rv, gate, consider, accepted, nis)
    kernels.mirror_lower(cov, consider)  # the lower triangle's copy: P symmetric again
    return accepted, nis


def update_rows(
    mean: np.ndarray,
    cov: np.ndarray,
    innovation: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    gate_prob: float = 0.99,
    considered: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """One jointly gated EKF update with m dense rows H (m, N) and noise R (m, m): the
    new (mean, cov, NIS), or None when the NIS ν ᵀS⁻¹ν exceeds the χ²(m) quantile
    ``gate_prob`` (the hypothesis behind the rows is rejected; nothing changes).

    For the rare pseudo-measurements that tie landmarks to each other (:mod:`links`); the
    per-beam rows go through :func:`update_sparse_inplace`. The state entries at
    ``considered`` (indices) are considered, not estimated (Schmidt–Kalman: their rows of K
    are zero). P⁺ is the Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ, right for that gain too,
    expanded as P − K Uᵀ − U Kᵀ + K S Kᵀ with U = P Hᵀ, and symmetrised.
    """
    n = mean.size
    H = np.atleast_2d(np.asarray(H, dtype=float))
    nu = np.asarray(innovation, dtype=float).reshape(-1)
    R = np.atleast_2d(np.asarray(R, dtype=float))
    m = nu.size
    if H.shape != (m, n) or R.shape != (m, m) or cov.shape != (n, n):
        raise ValueError(f"update_rows: H {H.shape}, R {R.shape}, cov {cov.shape}, {m} rows")
    U = cov @ H.T  # (N, m)
    S = _symmetrise(H @ U) + R  # (m, m)
    nis = float(nu @ np.linalg.solve(S, nu))
    if not nis <= _chi2_upper(m, gate_prob):
        return None
    K = np.linalg.solve(S, U.T).T  # (N, m)
    if considered is not None:
        K[np.asarray(considered, dtype=np.int64)] = 0.0
    new_mean = mean + K @ nu
    new_mean[2] = wrap_angle(new_mean[2])
    KU = K @ U.T  # (N, N)
    new_cov = cov - KU - KU.T + K @ S @ K.T
    return new_mean, _symmetrise(new_cov), nis


def _alpha_rows(
    alpha_index: np.ndarray | None, h_alpha: np.ndarray | None, k: int, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """The rows' shape-rotation columns, checked: (k,) int64 indices (−1: none), (k,) values."""
    if alpha_index is None:
        return np.full(k, -1, dtype=np.int64), np.zeros(k)
    ai = np.ascontiguousarray(alpha_index, dtype=np.int64).reshape(-1)
    ha = np.ascontiguousarray(h_alpha, dtype=float).reshape(-1)
    if ai.size != k or ha.size != k:
        raise ValueError(f"update: {ai.size}/{ha.size} rotation columns for {k} rows")
    if k and (ai.max() >= n or ((ai >= 0) & (ai < 3)).any()):
        raise ValueError(f"update: rotation indices must lie in [3, {n}) or be -1")
    return ai, ha


# -- augmentation and removal --------------------------------------------------------------------
def augment(
    mean: np.ndarray,
    cov: np.ndarray,
    value: float,
    Gx: np.ndarray,
    Gy: np.ndarray,
    V: np.ndarray,
    order: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Append a landmark c0 = g(X, y) (paper eq. 4–5).

    ``Gx`` (3+n,) or (1, 3+n) is ∂g/∂X over the whole current state (pose and any c0 the new
    one was built from, e.g. when refitting or merging); ``Gy`` (k,) or (1, k) is ∂g/∂y for
    the k raw inputs y with covariance ``V`` (k, k). The new row/column is
    [Gx P, Gx P Gxᵀ + Gy V Gyᵀ]: the cross-covariance with the pose is kept. With ``order``
    (N+1 indices, N the new entry) the grown state is returned taken in that order, in the
    same compiled call (:func:`~polyslam_env.slam.kernels.augmented`; the state layout puts
    a new entry inside its block so).
    """
    gx, gy, V = _augment_args(mean, Gx, Gy, V)
    order = np.arange(mean.size + 1) if order is None else order
    if order.shape != (mean.size + 1,):
        raise ValueError(f"order must have {mean.size + 1} entries, got {order.shape}")
    return kernels.augmented(
        np.ascontiguousarray(mean, dtype=float), np.ascontiguousarray(cov, dtype=float),
        float(value), gx, gy, V, np.ascontiguousarray(order, dtype=np.int64),
    )  # fmt: skip


def augment_pair(
    mean: np.ndarray,
    cov: np.ndarray,
    value: float,
    Gx: np.ndarray,
    Gy: np.ndarray,
    V: np.ndarray,
    turn_gx: np.ndarray,
    turn_var: float,
    order: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`augment` twice in one compiled call: c0 = g(X, y) appended, then an entry with
    ∂/∂X ``turn_gx`` (N+2,) over that grown state and variance ``turn_var`` beyond it (G_y
    = [1], V = [[turn_var]]: a landmark's turn α, :class:`~polyslam_env.slam.layout.
    StateLayout`), the result taken in ``order`` (N+2 indices); the same floats as the two
    calls (:func:`~polyslam_env.slam.kernels.augmented_pair`)."""
    gx, gy, V = _augment_args(mean, Gx, Gy, V)
    turn = np.ascontiguousarray(turn_gx, dtype=float).reshape(-1)
    if turn.size != mean.size + 1 or order.shape != (mean.size + 2,):
        raise ValueError(
            f"the second entry needs {mean.size + 1} derivatives and {mean.size + 2} order "
            f"entries, got {turn.size} and {order.shape}"
        )
    return kernels.augmented_pair(
        np.ascontiguousarray(mean, dtype=float), np.ascontiguousarray(cov, dtype=float),
        float(value), gx, gy, V, turn, float(turn_var), np.ascontiguousarray(order, dtype=np.int64),
    )  # fmt: skip


def _augment_args(
    mean: np.ndarray, Gx: np.ndarray, Gy: np.ndarray, V: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`augment`'s G_x, G_y (flat) and V (2-D), contiguous floats, checked."""
    gx = np.ascontiguousarray(Gx, dtype=float).reshape(-1)
    gy = np.ascontiguousarray(Gy, dtype=float).reshape(-1)
    V = np.ascontiguousarray(V, dtype=float)
    if V.ndim < 2:  # np.atleast_2d's (1, k), without its per-call checks
        V = V.reshape(1, -1)
    if gx.size != mean.size:
        raise ValueError(f"Gx must have {mean.size} entries, got {gx.size}")
    if V.shape != (gy.size, gy.size):
        raise ValueError(f"V must have shape ({gy.size}, {gy.size}), got {V.shape}")
    return gx, gy, V


def remove(
    mean: np.ndarray, cov: np.ndarray, indices: np.ndarray | list[int] | int
) -> tuple[np.ndarray, np.ndarray]:
    """Drop the landmark state entries at ``indices`` (state indices ≥ 3) and their rows/cols
    (a map change's: one compiled copy, :func:`~polyslam_env.slam.kernels.shrunk`)."""
    drop = np.asarray(indices, dtype=np.int64).reshape(-1)
    if drop.size and (int(drop.min()) < 3 or int(drop.max()) >= mean.size):
        raise ValueError(f"landmark state indices must lie in [3, {mean.size}), got {drop}")
    return kernels.shrunk(
        np.ascontiguousarray(mean, dtype=float), np.ascontiguousarray(cov, dtype=float), drop
    )


# -- divergence and consistency ------------------------------------------------------------------
def spectral_norm_sym(a: np.ndarray) -> float:
    """Spectral norm of a symmetric matrix: its largest |eigenvalue| (eigvalsh, not an SVD).

    Only the lower triangle is read, so pass a symmetric matrix (covariances, K P0 − P).
    3×3 matrices (pose blocks, asked for every step) take the closed form.
    """
    eig = symmetric_eigvals3(a) if a.shape == (3, 3) else np.linalg.eigvalsh(a)  # ascending
    return float(max(-eig[0], eig[-1]))


def divergence_ratio(
    cov_pose: np.ndarray, P0: np.ndarray, K: float, ref_norm: float | None = None
) -> float:
    """f = (‖K P0‖ − ‖K P0 − P‖)/‖K P0‖ with spectral norms (paper §3.1, SPEC §3).

    f = 0 at P = 0 and f = 1 at P = K P0. By the triangle inequality f ≤ 1 always, and it
    falls again (even below 0) as P grows past K P0, so "f > 1" can never flag divergence:
    use :func:`is_diverging`. :func:`thresholds` clips f to [0, 1]. P and P0 are symmetric
    (covariances); a caller that asks every step may pass ``ref_norm`` = ‖K P0‖.
    """
    kp0 = K * np.asarray(P0, dtype=float)
    ref = spectral_norm_sym(kp0) if ref_norm is None else ref_norm
    return float((ref - spectral_norm_sym(kp0 - cov_pose)) / ref)


def thresholds(f: float, lo: float, hi: float) -> float:
    """Adaptive threshold lo + (hi − lo)·clip(f, 0, 1) (ρ_k and σ_k of the paper)."""
    return float(lo + (hi - lo) * min(max(f, 0.0), 1.0))  # builtins: np.clip costs µs


def is_diverging(
    cov_pose: np.ndarray,
    P0: np.ndarray,
    K: float,
    nis: np.ndarray | None = None,
    nis_prob: float = 0.999,
) -> bool:
    """Whether the filter should be reported as diverging.

    Two tests, either flags:
    - the paper's: P_{k|k−1} > K P0, read as "P − K P0 is not negative semidefinite" (the
      pose uncertainty exceeds K P0 in some direction);
    - innovation consistency, when ``nis`` (a window of per-measurement ν²/S values, 1 dof
      each, including the ones the gate rejected) is given: their mean exceeds the upper
      ``nis_prob`` χ² bound. This catches the overconfident filter (process noise far too
      small, biased sensors) whose P stays small while its estimate drifts away.
    """
    excess = np.asarray(cov_pose, dtype=float) - K * np.asarray(P0, dtype=float)
    if np.linalg.eigvalsh(_symmetrise(excess))[-1] > 0.0:
        return True
    if nis is None:
        return False
    values = np.asarray(nis, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return False
    return bool(values.mean() > _chi2_upper(values.size, nis_prob) / values.size)


def normalised_innovations(
    cov: np.ndarray,
    innovation: np.ndarray,
    h_pose: np.ndarray,
    c0_index: np.ndarray,
    h_c0: np.ndarray,
    r: np.ndarray,
    alpha_index: np.ndarray | None = None,
    h_alpha: np.ndarray | None = None,
) -> np.ndarray:  # (k,)
    """ν_i² / S_ii for range rows that touch the pose and one c0 each (the rows of
    :func:`update_sparse_inplace`): S_ii = h P_pp hᵀ + 2 h_c h P_pc + h_c² P_cc + r_i with
    h = ``h_pose[i]`` (3,), h_c = ``h_c0[i]``, c = ``c0_index[i]``; cov (3+n, 3+n); plus the
    shape-rotation terms of rows with ``alpha_index[i]`` ≥ 0."""
    k = np.size(r)
    out = np.empty(k)
    ai, ha = _alpha_rows(alpha_index, h_alpha, k, cov.shape[0])
    kernels.normalised_innovations(
        cov,
        np.ascontiguousarray(innovation, dtype=float),
        np.ascontiguousarray(h_pose, dtype=float).reshape(-1, 3),
        np.ascontiguousarray(c0_index, dtype=np.int64),
        np.ascontiguousarray(h_c0, dtype=float),
        ai,
        ha,
        np.ascontiguousarray(r, dtype=float),
        out,
    )
    return out


@lru_cache(maxsize=32)
def outlier_count_threshold(window: int, outlier_prob: float, false_alarm: float) -> int:
    """The smallest m with P(Bin(``window``, ``outlier_prob``) ≥ m) ≤ ``false_alarm``: an
    alarm on "at least m outliers among ``window`` independent beams, each an outlier with
    probability ``outlier_prob``" then fires with probability ≤ ``false_alarm``. Returns
    ``window + 1`` (never) if even m = window is too likely."""
    if not 0.0 <= outlier_prob <= 1.0 or not 0.0 < false_alarm < 1.0 or window < 1:
        raise ValueError(
            f"outlier_count_threshold: bad window={window}, outlier_prob={outlier_prob},"
            f" false_alarm={false_alarm}"
        )
    for m in range(1, window + 1):
        if scipy.special.bdtrc(m - 1, window, outlier_prob) <= false_alarm:  # P(X > m − 1)
            return m
    return window + 1


def _chi2_upper(dof: int, prob: float) -> float:
    """χ² quantile with ``dof`` degrees of freedom (scipy.special, no scipy.stats import)."""
    return float(scipy.special.chdtri(dof, 1.0 - prob))


def nees(error: np.ndarray, cov: np.ndarray) -> float:
    """Normalised estimation error squared eᵀP⁻¹e of a pose error (3,), heading wrapped."""
    e = np.asarray(error, dtype=float).copy()
    e[2] = wrap_angle(e[2])
    return float(e @ np.linalg.solve(cov, e))

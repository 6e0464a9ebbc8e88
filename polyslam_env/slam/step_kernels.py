"""The compiled SLAM step of one robot: two calls over its buffers, with the rare map changes
(new landmarks, refits, merges, links) in Python between them (STYLE habits 20, 21).

* :func:`begin_step` — prediction from odometry (first-estimates Jacobian), the divergence
  screen's innovations at the predicted pose, the divergence ratio f and this step's
  thresholds ρ_k, σ_k, and the association (:func:`~polyslam_env.slam.map_kernels.
  associate_scan`): this step's points, clusters, Q_bad sets, stretched extents and the
  requests for the map changes;
* :func:`finish_step` — the beams each good point gives the update (their landmark still in
  the map, the beam one of the update's, the landmark long enough), the batched, gated update
  (:func:`~polyslam_env.slam.kernels.update_scan`) and the divergence test's cheap parts.

Both take the filter's state (``mean``, ``cov``), the landmark table's buffers (``real``,
``index``, ``shape`` and ``n``), the stored points' (``preal``, ``pindex``, ``counters``), the
filter's model (``params``, ``switches``, ``fit_inverse``, the per-beam ``beams``) and write
their outcome into ``per_beam``, ``status`` and ``values`` (:mod:`~polyslam_env.slam.columns`
names every field). Each does the operations of the Python it replaced in the same order:
the episodes are bit for bit what they were.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.jit import njit
from polyslam_env.slam import kernels, map_kernels
from polyslam_env.slam.columns import (
    B_ANGLE,
    B_UPDATE,
    CHANGED_AT,
    G_GOOD,
    G_REQUEST,
    G_ROW,
    HI,
    ID,
    LO,
    P_KP0,
    P_KP0_NORM,
    P_MIN_UPDATE_EXTENT,
    P_ODOM_COV,
    P_RHO_MAX,
    P_RHO_MIN,
    P_SIGMA_MAX,
    P_SIGMA_MIN,
    P_SMALL_POSE,
    S_LINK_AGE,
    S_LINKS,
    ST_EXTENTS,
    ST_FRESH,
    ST_OUTLIERS,
    ST_PAPER_TEST,
    ST_SCREEN,
    ST_SCREEN_FILL,
    ST_SCREEN_NEXT,
    ST_USED,
    V_BEFORE,
    V_F,
    V_FIRST_X,
    V_FIRST_Y,
    V_RHO,
    V_SIGMA,
)
from polyslam_env.slam.divergence import SCREEN_WINDOW
from polyslam_env.slam.kernels import _max, _min


@njit
def thresholds(f: float, lo: float, hi: float) -> float:
    """Adaptive threshold lo + (hi − lo)·clip(f, 0, 1) (ρ_k and σ_k of the paper;
    ``ekf.thresholds``, Python's min and max)."""
    return lo + (hi - lo) * _min(_max(f, 0.0), 1.0)


@njit
def _screen(
    mean: np.ndarray,
    cov: np.ndarray,
    ranges: np.ndarray,
    beams: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
    status: np.ndarray,
) -> None:
    """The screen's flags of this step's update beams (``kernels.screen_scan``), at the
    predicted pose against the map as it stood before this step's changes, pushed into the
    window (the oldest leave)."""
    count = 0
    for b in range(ranges.size):
        if beams[B_UPDATE, b] != 0.0:
            count += 1
    angles, screened = np.empty(count), np.empty(count)
    count = 0
    for b in range(ranges.size):
        if beams[B_UPDATE, b] != 0.0:
            angles[count], screened[count] = beams[B_ANGLE, b], ranges[b]
            count += 1
    outlier = np.empty(count, dtype=np.bool_)
    k = kernels.screen_scan(
        mean, cov, angles, screened, outlier, real, index, shape, n, params, switches,
        fit_inverse, step,
    )  # fmt: skip
    for i in range(k):
        slot = status[ST_SCREEN_NEXT]
        status[ST_SCREEN + slot] = 1 if outlier[i] else 0
        status[ST_SCREEN_NEXT] = (slot + 1) % SCREEN_WINDOW
        status[ST_SCREEN_FILL] = min(status[ST_SCREEN_FILL] + 1, SCREEN_WINDOW)


@njit
def predict_step(
    mean: np.ndarray,  # (3+n(+n),) written in place
    cov: np.ndarray,  # written in place
    odometry: np.ndarray,  # (3,) (dx, dy, dθ) in the robot frame
    ranges: np.ndarray,  # (B,) this step's readings
    beams: np.ndarray,  # (N_BEAM_MODEL, B) the beams' angles and update flags
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
    status: np.ndarray,
    values: np.ndarray,
) -> None:
    """The prediction (``ekf.predict_inplace`` with the first-estimates Jacobian from
    ``values``' last predicted position), the screen (with landmarks in the map), and f,
    ρ_k, σ_k into ``values`` (``ekf.divergence_ratio``, ``ekf.thresholds``)."""
    w = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            w[r, c] = params[P_ODOM_COV + 3 * r + c]
    kernels.predict(mean, cov, odometry, w, values[V_FIRST_X], values[V_FIRST_Y])
    values[V_FIRST_X], values[V_FIRST_Y] = mean[0], mean[1]
    if n > 0:
        _screen(mean, cov, ranges, beams, real, index, shape, n, params, switches, fit_inverse,
                step, status)  # fmt: skip
    beyond = np.empty((3, 3))  # K P0 − P
    for r in range(3):
        for c in range(3):
            beyond[r, c] = params[P_KP0 + 3 * r + c] - cov[r, c]
    ref = params[P_KP0_NORM]
    f = (ref - map_kernels.spectral_norm3(beyond)) / ref
    values[V_F] = f
    values[V_RHO] = thresholds(f, params[P_RHO_MIN], params[P_RHO_MAX])
    values[V_SIGMA] = thresholds(f, params[P_SIGMA_MIN], params[P_SIGMA_MAX])


@njit
def associate_step(
    mean: np.ndarray,
    cov: np.ndarray,
    ranges: np.ndarray,
    beams: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    preal: np.ndarray,
    pindex: np.ndarray,
    counters: np.ndarray,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
    per_beam: np.ndarray,  # (N_PER_BEAM, B) int64 out
    status: np.ndarray,
    values: np.ndarray,
) -> None:
    """The association at this step's thresholds (``map_kernels.associate_scan``), and how
    many landmarks changed ``link_age`` steps ago (with links on: links to seek)."""
    status[ST_EXTENTS] = map_kernels.associate_scan(
        mean, cov, ranges, beams[B_ANGLE], step, values[V_RHO], values[V_SIGMA], params,
        switches, fit_inverse, real, index, shape, n, preal, pindex, counters,
        per_beam[G_REQUEST], per_beam[G_GOOD],
    )  # fmt: skip
    fresh = 0
    if switches[S_LINKS]:
        made_at = step - switches[S_LINK_AGE]
        for j in range(n):
            if index[CHANGED_AT, j] == made_at:
                fresh += 1
    status[ST_FRESH] = fresh


@njit
def begin_step(
    mean: np.ndarray,
    cov: np.ndarray,
    odometry: np.ndarray,
    ranges: np.ndarray,
    beams: np.ndarray,
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    preal: np.ndarray,
    pindex: np.ndarray,
    counters: np.ndarray,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
    per_beam: np.ndarray,
    status: np.ndarray,
    values: np.ndarray,
) -> None:
    """:func:`predict_step` then :func:`associate_step` (module docstring)."""
    predict_step(mean, cov, odometry, ranges, beams, real, index, shape, n, params, switches,
                 fit_inverse, step, status, values)  # fmt: skip
    associate_step(mean, cov, ranges, beams, real, index, shape, n, preal, pindex, counters,
                   params, switches, fit_inverse, step, per_beam, status, values)  # fmt: skip


@njit
def finish_step(
    mean: np.ndarray,  # written in place
    cov: np.ndarray,  # written in place
    ranges: np.ndarray,  # (B,)
    beams: np.ndarray,  # (N_BEAM_MODEL, B)
    real: np.ndarray,
    index: np.ndarray,
    shape: np.ndarray,
    n: int,
    params: np.ndarray,
    switches: np.ndarray,
    fit_inverse: np.ndarray,
    step: int,
    per_beam: np.ndarray,
    status: np.ndarray,
    values: np.ndarray,
) -> None:
    """The update with the good beams (module docstring) and the cheap parts of the
    divergence test: ``status[ST_USED]`` the rows used (−1: nothing ran, the state is as it
    was), ``values[V_BEFORE:]`` the pose before, ``per_beam[G_ROW]`` each beam's landmark
    row in the update (−1: not in it), ``status[ST_OUTLIERS]`` the screen's outliers and
    ``status[ST_PAPER_TEST]`` whether the pose block is near enough K P0 for the paper's
    test (``PolySlam._is_diverging``: ‖P‖²_F below (λ_min(K P0)/2)² is far below it)."""
    n_beams = ranges.size
    chosen, rows = np.empty(n_beams, dtype=np.int64), np.empty(n_beams, dtype=np.int64)
    ids = index[ID, :n]  # ascending: ids are given in order and rows keep it
    floor = params[P_MIN_UPDATE_EXTENT]
    count = 0
    for b in range(n_beams):
        per_beam[G_ROW, b] = -1
        landmark_id = per_beam[G_GOOD, b]
        if landmark_id < 0 or beams[B_UPDATE, b] == 0.0:
            continue
        row = np.searchsorted(ids, landmark_id)
        if row >= n or ids[row] != landmark_id:
            continue  # a refit or merge replaced it this step
        if floor > 0.0 and not real[HI, row] - real[LO, row] >= floor:
            continue  # too short to update the pose
        chosen[count], rows[count] = b, row
        per_beam[G_ROW, b] = row
        count += 1
    values[V_BEFORE], values[V_BEFORE + 1], values[V_BEFORE + 2] = mean[0], mean[1], mean[2]
    status[ST_USED] = -1
    if count > 0 and n > 0:
        status[ST_USED] = kernels.update_scan(
            mean, cov, beams[B_ANGLE], ranges, chosen[:count], rows[:count], real, index, shape,
            n, params, switches, fit_inverse, step,
        )  # fmt: skip
    square = 0.0
    for r in range(3):
        for c in range(3):
            square += cov[r, c] * cov[r, c]
    status[ST_PAPER_TEST] = 0 if square < params[P_SMALL_POSE] else 1
    outliers = 0
    for i in range(status[ST_SCREEN_FILL]):
        outliers += status[ST_SCREEN + i]
    status[ST_OUTLIERS] = outliers

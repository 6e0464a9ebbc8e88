"""The filter's model as the compiled step reads it (:func:`step_model`): a robot's
``SlamConfig`` and sensor in three arrays, made once per config and sensor and shared by every
filter built with them (:mod:`~polyslam_env.slam.columns` names their fields)."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from polyslam_env.slam import columns as col
from polyslam_env.slam import ekf
from polyslam_env.slam.config import REUSE_BOUNDS, SlamConfig
from polyslam_env.slam.divergence import screen_alarm

#: Slack (m) added to box distances when selecting the landmarks a beam can reach: covers
#: the root polishing and rounding of the hit point, which the exact test then decides.
REACH_MARGIN = 1e-3


class StepModel(NamedTuple):
    """The three model arrays of the compiled step (``PolySlam`` splats them in)."""

    params: np.ndarray  # (N_PARAMS,) float64
    switches: np.ndarray  # (N_SWITCHES,) int64
    beams: np.ndarray  # (N_BEAM_MODEL, B) float64: angle, in the update


def update_beam_mask(angles: np.ndarray, spacing_deg: float) -> np.ndarray:
    """Which beams (B,) bool enter the EKF update: in order of angle, each beam at least
    ``spacing_deg`` from the last one kept, starting from the first (all when 0)."""
    keep = np.zeros(len(angles), dtype=bool)
    last = -np.inf
    tol = 1e-9
    for i in np.argsort(angles, kind="stable"):
        if np.rad2deg(angles[i] - last) >= spacing_deg - tol:
            keep[i] = True
            last = angles[i]
    return keep


def step_model(config: SlamConfig, beam_angles: np.ndarray, max_range: float) -> StepModel:
    """The model of a robot with ``config`` and a range sensor of ``beam_angles`` (B,) and
    ``max_range`` (module docstring). Derived values are computed as the Python they
    replaced computed them (``x ** 2`` is libm's pow), so the step is bit for bit the same.

    Made once per (config, beam angles, range) and shared: a team's filters, and every
    episode's, read the same arrays (the compiled step never writes them; nothing else may).
    """
    angles = tuple(np.asarray(beam_angles, dtype=float).reshape(-1).tolist())
    return _step_model(config, angles, float(max_range))


@functools.lru_cache(maxsize=64)
def _step_model(config: SlamConfig, angles_tuple: tuple[float, ...], max_range: float) -> StepModel:
    """:func:`step_model` of hashable arguments (the beam angles as a tuple of floats)."""
    p = np.zeros(col.N_PARAMS)
    p[col.P_RANGE_SIGMA] = config.range_sigma
    p[col.P_RANGE_VAR] = config.range_sigma**2
    p[col.P_CLUSTER_RADIUS] = config.cluster_radius
    p[col.P_TURN_VAR_PER_STEP] = config.odom_cov[2, 2]
    p[col.P_SQUARE] = 2.0
    p[col.P_MAX_RANGE] = max_range
    p[col.P_REACH] = max_range + REACH_MARGIN
    p[col.P_MIN_SINE] = float(np.sin(np.deg2rad(config.tangent_min_deg)))
    p[col.P_GATE] = ekf.chi2_1dof_quantile(config.gate_prob)
    p[col.P_END_SIGMA] = config.end_sigma
    p[col.P_MIN_UPDATE_EXTENT] = config.min_update_extent
    p[col.P_RHO_MIN], p[col.P_RHO_MAX] = config.rho_min, config.rho_max
    p[col.P_SIGMA_MIN], p[col.P_SIGMA_MAX] = config.sigma_min, config.sigma_max
    kp0 = config.k_divergence * config.p0  # (3, 3)
    kp0_eig = np.linalg.eigvalsh(kp0)  # (3,) ascending
    p[col.P_KP0_NORM] = float(max(-kp0_eig[0], kp0_eig[-1]))  # ‖K P0‖
    p[col.P_SMALL_POSE] = (0.5 * float(kp0_eig[0])) ** 2  # (λ_min(K P0)/2)²
    p[col.P_KP0 : col.P_KP0 + 9] = kp0.ravel()
    p[col.P_ODOM_COV : col.P_ODOM_COV + 9] = config.odom_cov.ravel()
    s = np.zeros(col.N_SWITCHES, dtype=np.int64)
    s[col.S_SQUARED] = config.squared_error
    s[col.S_STRETCH_ENDS] = config.stretch_ends
    s[col.S_ROTATION_STATES] = config.rotation_states
    s[col.S_LINK_CLUSTERS] = config.link_clusters
    s[col.S_EPS_M] = config.eps_m
    s[col.S_EPS_Z] = config.eps_z
    s[col.S_SHAPE_FOLLOWS_POSE] = config.shape_follows_pose
    s[col.S_N_FIT] = config.eps_z + 1
    s[col.S_LINK_AGE] = config.link_age
    s[col.S_LINKS] = config.link_gap > 0.0 or config.square_walls
    s[col.S_SCREEN_ALARM] = screen_alarm(config)
    s[col.S_REUSE_BOUND] = REUSE_BOUNDS.index(config.reuse_bound)
    s[col.S_SHIFT_WITH_POSE] = config.shape_shift == "pose"
    s[col.S_SEEN_FACES] = config.seen_faces
    angles = np.array(angles_tuple, dtype=float)  # (B,)
    beams = np.zeros((col.N_BEAM_MODEL, angles.size))
    beams[col.B_ANGLE] = angles
    beams[col.B_UPDATE] = update_beam_mask(angles, config.update_spacing_deg)
    if not math.isfinite(max_range) or max_range <= 0:
        raise ValueError(f"max_range must be a positive number, got {max_range}")
    return StepModel(p, s, beams)

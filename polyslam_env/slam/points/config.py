"""``PointSlamConfig``: the parameters of the point-landmark particle filters (seed 003, §4).

Defaults are the seed's experiment: N = 10 particles, EM mobile coefficient
R = [0.008 m, 0.005 m, 0.001 rad], consensus step ε = 0.1, control noise σ_V = 0.3 m/s and
σ_G = 3°, range-bearing noise σ_r = 0.2 m and σ_θ = 2°, resampling when N_eff < 0.75 N. The
car's control period and wheelbase are the seed's unstated simulator values (Bailey's FastSLAM
simulator, which the seed's model and noise figures match: 0.025 s, 4 m).

``motion`` picks the motion model: ``car`` (the seed's, above) or ``odometry`` (the RL env's
differential drives: the measured increment in the robot frame with per-period noise
``odom_sigma_xy``, ``odom_sigma_theta_deg``, as the polynomial EKF assumes).

The three per-robot algorithms differ only in two switches, so one class runs all of them:
``em_move`` (EM-FastSLAM's move before resampling) and ``consensus_step`` ε (MBLCC's
landmark consensus; 0 means no consensus). :func:`algorithm_config` sets them by name.
``em_passes`` repeats the move within a sweep (the seed calls the move an iteration of the
EM method and gives no count; it runs one).

``proposal`` picks where a sweep draws each particle's pose from: ``fastslam2`` (the seed's,
the motion prediction updated by an EKF step with the re-observed landmarks) or ``motion``
(the motion prediction alone, FastSLAM 1.0's; the weight is then the measurement
likelihood). The shared-map baseline runs with either (the seed does not say which proposal
its ref. [10] used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from polyslam_env.core.config import (
    Config,
    check_choice,
    check_non_negative,
    check_positive,
    check_range,
)
from polyslam_env.core.errors import ConfigError

#: The per-robot algorithms and their switches (em_move, consensus on).
ALGORITHMS: tuple[str, ...] = ("fastslam2", "em_fastslam", "mblcc")
#: The motion models (see :mod:`polyslam_env.slam.points.models`).
MOTION_MODELS: tuple[str, ...] = ("car", "odometry")
#: Where a sweep draws the particles' poses from (see the module docstring).
PROPOSALS: tuple[str, ...] = ("fastslam2", "motion")


@dataclass(frozen=True)
class PointSlamConfig(Config):
    """Every setting of a point-landmark FastSLAM back-end (angles in degrees in the file)."""

    particles: int = 10  # N
    resample_fraction: float = 0.75  # resample when N_eff < fraction · N
    em_move: bool = False  # EM-FastSLAM's attraction-repulsion move (eqs. 4, 7, SPEC §8)
    em_mobility: tuple[float, float, float] = (0.008, 0.005, 0.001)  # R: m, m, rad
    em_passes: int = 1  # attraction-repulsion moves per sweep, each followed by eq. 3
    proposal: str = "fastslam2"  # "fastslam2" (EKF-updated) or "motion" (FastSLAM 1.0's)
    consensus_step: float = 0.0  # ε of eq. 12; 0 = independent filters
    sigma_v: float = 0.3  # m/s, speed control noise σ_V
    sigma_g_deg: float = 3.0  # steering control noise σ_G
    sigma_r: float = 0.2  # m, range noise
    sigma_b_deg: float = 2.0  # bearing noise σ_θ
    dt: float = 0.025  # s, control period
    wheelbase: float = 4.0  # m, D of eq. 14
    motion: str = "car"  # "car" (eq. 14, controls (V, G)) or "odometry" (dx, dy, dθ)
    odom_sigma_xy: float = 0.001  # m per period, odometry noise (motion: odometry)
    odom_sigma_theta_deg: float = 0.01  # degrees per period, ditto

    def validate(self) -> None:
        if self.particles < 1:
            raise ConfigError(f"particles: must be >= 1, got {self.particles}")
        check_range("resample_fraction", self.resample_fraction, 0.0, 1.0)
        for i, r in enumerate(self.em_mobility):
            check_non_negative(f"em_mobility[{i}]", r)
        if self.em_passes < 1:
            raise ConfigError(f"em_passes: must be >= 1, got {self.em_passes}")
        check_choice("proposal", self.proposal, PROPOSALS)
        check_range("consensus_step", self.consensus_step, 0.0, 1.0)
        check_non_negative("sigma_v", self.sigma_v)
        check_non_negative("sigma_g_deg", self.sigma_g_deg)
        check_positive("sigma_r", self.sigma_r)  # the landmark EKFs need R > 0
        check_positive("sigma_b_deg", self.sigma_b_deg)
        check_positive("dt", self.dt)
        check_positive("wheelbase", self.wheelbase)
        if self.motion not in MOTION_MODELS:
            raise ConfigError(
                f"motion: must be one of {', '.join(MOTION_MODELS)}; got {self.motion!r}"
            )
        check_non_negative("odom_sigma_xy", self.odom_sigma_xy)
        check_non_negative("odom_sigma_theta_deg", self.odom_sigma_theta_deg)

    @property
    def control_sigmas(self) -> tuple[float, ...]:
        """The control noise: (σ_V in m/s, σ_G in rad) for the car, (σ_x, σ_y in m, σ_θ in
        rad) per period for odometry."""
        if self.motion == "car":
            return self.sigma_v, math.radians(self.sigma_g_deg)
        sxy = self.odom_sigma_xy
        return sxy, sxy, math.radians(self.odom_sigma_theta_deg)

    @property
    def measurement_sigmas(self) -> tuple[float, float]:
        """(σ_r in m, σ_θ in rad)."""
        return self.sigma_r, math.radians(self.sigma_b_deg)


def algorithm_config(name: str, base: PointSlamConfig | None = None) -> PointSlamConfig:
    """``base`` with the switches of ``fastslam2``, ``em_fastslam`` or ``mblcc`` (ε = 0.1)."""
    base = PointSlamConfig() if base is None else base
    if name == "fastslam2":
        return base.replace(em_move=False, consensus_step=0.0)
    if name == "em_fastslam":
        return base.replace(em_move=True, consensus_step=0.0)
    if name == "mblcc":
        eps = base.consensus_step if base.consensus_step > 0 else 0.1
        return base.replace(em_move=True, consensus_step=eps)
    raise ConfigError(f"algorithm: must be one of {', '.join(ALGORITHMS)}; got {name!r}")

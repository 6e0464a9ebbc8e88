"""World configuration: robots, physics, odometry, range beams, camera (SPEC §2)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from polyslam_env.core.config import (
    Config,
    check_non_negative,
    check_positive,
    check_range,
)
from polyslam_env.core.errors import ConfigError


@dataclass(frozen=True)
class RobotConfig(Config):
    """A differential-drive robot (Khepera III-like defaults)."""

    radius: float = 0.065  # m
    mass: float = 0.69  # kg
    v_max: float = 0.3  # m/s, forward speed limit (|v| <= v_max)
    omega_max: float = 1.5  # rad/s, turn-rate limit (|omega| <= omega_max)
    allow_reverse: bool = True  # False clips v to [0, v_max]

    def validate(self) -> None:
        check_positive("robot.radius", self.radius)
        check_positive("robot.mass", self.mass)
        check_positive("robot.v_max", self.v_max)
        check_positive("robot.omega_max", self.omega_max)


@dataclass(frozen=True)
class OdometryConfig(Config):
    """Odometry = displacement actually made (robot frame) + N(0, diag(s_xy², s_xy², s_θ²))."""

    sigma_xy: float = 0.001  # m per step
    sigma_theta_deg: float = 0.01  # degrees per step

    @property
    def sigma_theta(self) -> float:
        return math.radians(self.sigma_theta_deg)

    def validate(self) -> None:
        check_non_negative("odometry.sigma_xy", self.sigma_xy)
        check_non_negative("odometry.sigma_theta_deg", self.sigma_theta_deg)


#: The paper's five distance sensors (degrees from the robot axis), kept by ``configs/paper.yaml``,
#: ``simulate`` and the benchmark's "paper sensors".
PAPER_BEAMS_DEG: tuple[float, ...] = (90.0, 45.0, 0.0, -45.0, -90.0)
#: The default: seventeen beams every 11.25° over the front half-plane, a sparse 180° scanner.
#: On floors of 20 m and more the paper's five beams hit many of the walls they touch too few
#: times for a landmark, and with nine a robot passing a room maps too little of what it sees.
#: The EKF update uses every other beam (``slam.update_spacing_deg``): with all seventeen the
#: error a landmark's shape gives every beam on it, repeated step after step, makes the filter
#: overconfident (docs/design/slam.md, "The update").
DEFAULT_BEAMS_DEG: tuple[float, ...] = tuple(90.0 - 11.25 * i for i in range(17))


@dataclass(frozen=True)
class RangeSensorConfig(Config):
    """Range beams at fixed angles from the robot axis; no return is reported as ``inf``."""

    angles_deg: tuple[float, ...] = DEFAULT_BEAMS_DEG  # degrees from the axis: 17, +90° to −90°
    max_range: float = 2.0  # m
    sigma: float = 0.02  # m, Gaussian range noise
    hit_robots: bool = False  # whether beams also stop at other robots

    @property
    def angles(self) -> tuple[float, ...]:
        return tuple(math.radians(a) for a in self.angles_deg)

    def validate(self) -> None:
        if not self.angles_deg:
            raise ConfigError("range_sensor.angles_deg: at least one beam is needed")
        for i, a in enumerate(self.angles_deg):
            check_range(f"range_sensor.angles_deg[{i}]", a, -360.0, 360.0)
        check_positive("range_sensor.max_range", self.max_range)
        check_non_negative("range_sensor.sigma", self.sigma)


@dataclass(frozen=True)
class CameraConfig(Config):
    """Detects other robots in range and field of view with line of sight."""

    enabled: bool = True  # False: no detections (no rendezvous, empty camera slots)
    range: float = 1.5  # m
    fov_deg: float = 360.0  # full angle, centred on the robot axis
    sigma_d: float = 0.01  # m, distance noise
    sigma_bearing_deg: float = 1.0  # degrees, bearing noise

    @property
    def sigma_bearing(self) -> float:
        return math.radians(self.sigma_bearing_deg)

    def validate(self) -> None:
        check_positive("camera.range", self.range)
        check_range("camera.fov_deg", self.fov_deg, 1e-6, 360.0)
        check_non_negative("camera.sigma_d", self.sigma_d)
        check_non_negative("camera.sigma_bearing_deg", self.sigma_bearing_deg)


@dataclass(frozen=True)
class PillarSensorConfig(Config):
    """Range and bearing to the centres of the pillars in range and line of sight, each with a
    noisy appearance descriptor (seed 003's point sensing, seed 004's descriptors). Off by
    default: the paper's robots have no such sensor."""

    enabled: bool = False  # the point back-ends and pillar alignment need it on
    max_range: float = 4.0  # m, to the pillar's centre
    fov_deg: float = 360.0  # full angle, centred on the robot axis
    sigma_range: float = 0.03  # m
    sigma_bearing_deg: float = 1.0  # degrees
    descriptor_dim: int = 8  # numbers per appearance descriptor
    descriptor_sigma: float = 0.1  # noise per number and sighting (true descriptors ~ N(0, 1))
    # Each reading names its pillar (the seeds' known association). False: the SLAM gets
    # anonymous readings and associates them itself (slam/points/association.py); the ids
    # then serve the metrics only.
    identities: bool = True

    @property
    def sigma_bearing(self) -> float:
        return math.radians(self.sigma_bearing_deg)

    def validate(self) -> None:
        check_positive("pillar_sensor.max_range", self.max_range)
        check_range("pillar_sensor.fov_deg", self.fov_deg, 1e-6, 360.0)
        check_non_negative("pillar_sensor.sigma_range", self.sigma_range)
        check_non_negative("pillar_sensor.sigma_bearing_deg", self.sigma_bearing_deg)
        dim = self.descriptor_dim
        if isinstance(dim, bool) or not isinstance(dim, int) or not 1 <= dim <= 64:
            raise ConfigError(
                f"pillar_sensor.descriptor_dim: must be an integer in 1..64, got {dim!r}"
            )
        check_non_negative("pillar_sensor.descriptor_sigma", self.descriptor_sigma)


@dataclass(frozen=True)
class WorldConfig(Config):
    """The simulated world: control period, physics sub-steps, robots and sensors."""

    dt: float = 1.0  # s, control period T (paper: 1 s)
    substeps: int = 10  # physics sub-steps per control period (the skin: v_max·dt/substeps)
    wall_radius: float = 0.005  # m, half thickness of the wall segments
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    range_sensor: RangeSensorConfig = field(default_factory=RangeSensorConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    pillar_sensor: PillarSensorConfig = field(default_factory=PillarSensorConfig)

    def validate(self) -> None:
        check_positive("dt", self.dt)
        if self.substeps < 1:
            raise ConfigError(f"substeps: must be >= 1, got {self.substeps!r}")
        check_non_negative("wall_radius", self.wall_radius)
        # The contact skin is one sub-step at v_max (world.physics): a contact starts when the
        # skinned circles touch, so no sub-step carries a robot into an obstacle, whatever its
        # length. The skin is also how far short of an obstacle (or of another robot's skin) a
        # robot may stop, a gap the sensors see; keep it at most half a radius.
        step = self.robot.v_max * self.dt / self.substeps
        if step > self.robot.radius / 2:
            need = math.ceil(2 * self.robot.v_max * self.dt / self.robot.radius)
            raise ConfigError(
                f"substeps: {self.substeps} sub-steps move a robot {step:.3f} m each at v_max"
                f" (the contact skin), more than radius/2; use at least {need}"
            )


def paper_world_config() -> WorldConfig:
    """The core paper's world (§4): the defaults with its five distance sensors."""
    return WorldConfig(range_sensor=RangeSensorConfig(angles_deg=PAPER_BEAMS_DEG))

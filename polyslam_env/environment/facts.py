"""The public, static facts of an env that a policy may know besides its observations.

:func:`public_facts` is what :meth:`PolySlamParallelEnv.public_facts` returns: plain numbers,
names and the observation layout, read from the config at construction. Policies build their
context from it (``policies.base.PolicyContext.from_env``), so they never import the env's
config classes or reach its episode state, and cannot read ground truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.observations import STD_CAPS, ObservationEncoder
from polyslam_env.world.maps import resolve_map_path


def public_facts(config: EnvConfig, map_size: tuple[float, float]) -> dict[str, Any]:
    """Static facts of an env with ``config`` on a map of ``map_size`` (the same for every
    agent).

    ``map`` is the config's value (a name, a path or ``"generator:<name>"``); ``map_file`` the
    map file it resolves to (None for generator maps), so a policy tied to one map (``paper``)
    can check it without loading the map. ``map_size`` is (width, height) m of the map's
    bounding box (a floor plan's dimensions; not where the robot starts in it); ``pose_scale``
    the scale in force (:meth:`~polyslam_env.environment.config.ObservationConfig.position_scale`).
    ``pose_std_scale`` is what the observed pose standard deviations are divided by (then
    clipped to [0, 1]); ``p0_sigma`` the standard deviations of the start-error prior P0 that
    the reported pose covariance holds (J P0 Jᵀ, see ``slam.ekf.start_error_cov``), or None
    without SLAM (the observed deviations are then 0). ``radio_range`` is the channel's range
    (``channel.range``; the camera's without a channel): a team's own radio reaches that far
    (``policies.radio``), through the env's :meth:`radio_links`.
    """
    rc, wc, oc = config.world.robot, config.world, config.observation
    map_file: Path | None = None
    if config.generator_name is None:
        map_file = resolve_map_path(config.map).resolve()
    return {
        "num_robots": config.num_robots,
        "map": config.map,
        "map_file": map_file,
        "action_mode": config.action.mode,
        "discrete": np.array(config.action.discrete, dtype=float) * (rc.v_max, rc.omega_max),
        "obs_mode": oc.mode,
        "vector_layout": dict(ObservationEncoder(config, map_size).vector_layout),
        "grid_size": oc.grid_size,
        "grid_resolution": oc.grid_resolution,
        "pose_scale": oc.position_scale(map_size, wc.range_sensor.max_range),
        "pose_std_scale": tuple(float(c) for c in STD_CAPS),
        "p0_sigma": tuple(float(s) for s in config.slam.p0_sigma) if config.slam_enabled else None,
        "map_size": (float(map_size[0]), float(map_size[1])),
        "beam_angles": np.deg2rad(np.asarray(wc.range_sensor.angles_deg, dtype=float)),
        "max_range": wc.range_sensor.max_range,
        "camera_range": wc.camera.range,
        "radio_range": radio_range(config),
        "robot_radius": rc.radius,
        "v_max": rc.v_max,
        "omega_max": rc.omega_max,
        "allow_reverse": rc.allow_reverse,
        "dt": wc.dt,
        "max_steps": config.max_steps,
    }


def radio_range(config: EnvConfig) -> float:
    """m, how far a team's radio reaches: the channel's ``range``, or the camera's without a
    channel (then only a mutual sighting links two robots)."""
    return config.world.camera.range if config.channel is None else config.channel.range

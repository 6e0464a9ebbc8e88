"""The simulated world: layouts, maps, generators, pymunk physics and sensors.

It owns ground truth: ``layout`` (walls, pillars, start poses), ``maps`` (the map file format
and the built-in maps), ``generators`` (seeded layouts), ``physics`` (``World``: one pymunk
space per episode, diff-drive robots, odometry), ``sensors`` (range beams and camera), ``grid``
(free-space grids), ``nearby`` (the wall index), ``replay`` (driving a world along shipped
paths), ``point_sensor`` (range-bearing sensing of point landmarks, a pure function) and
``kinematic`` (seed 003's car world without physics: paths, landmark field, noisy controls and
sweeps). Only this part imports pymunk; it knows nothing of SLAM.
"""

from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import builtin_maps, layout_from_dict, load_map, save_map

__all__ = ["Layout", "WorldConfig", "builtin_maps", "layout_from_dict", "load_map", "save_map"]

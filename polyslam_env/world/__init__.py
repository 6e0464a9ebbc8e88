"""The simulated world: layouts, maps, generators, pymunk physics and sensors."""

from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import builtin_maps, layout_from_dict, load_map, save_map

__all__ = ["Layout", "WorldConfig", "builtin_maps", "layout_from_dict", "load_map", "save_map"]

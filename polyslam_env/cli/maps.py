"""``polyslam maps``: list the built-in maps and the layout generators with their parameters."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

#: Generator fields the env sets itself (from ``num_robots`` and the robot's radius).
SET_BY_ENV = ("num_start_poses", "robot_radius")


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "maps",
        help="list the built-in maps and the layout generators",
        description="List the built-in maps (a name to pass as --map) and the layout"
        " generators (--map generator:<name>: a new layout at every reset), with the"
        " generators' parameters (map_params in an EnvConfig) and their defaults.",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from polyslam_env.environment.config import GENERATOR_PREFIX
    from polyslam_env.world.generators import GENERATORS, SHARED_FIELDS
    from polyslam_env.world.maps import builtin_maps, load_map

    print("built-in maps:")
    for name in builtin_maps():
        layout = load_map(name)
        x0, y0, x1, y1 = layout.bounds
        print(
            f"  {name:<22} {x1 - x0:4.1f} × {y1 - y0:4.1f} m,"
            f" {len(layout.segments):4d} wall segments, {layout.num_start_poses} start poses"
        )
    print("layout generators (a new layout every reset; parameters go in map_params):")
    for name in sorted(GENERATORS):
        defaults = GENERATORS[name]()
        params = ", ".join(
            f"{key}={_plain(getattr(defaults, key))}"
            for key in _listing_order([f.name for f in dataclasses.fields(defaults)], SHARED_FIELDS)
            if key not in SET_BY_ENV
        )
        print(f"  {GENERATOR_PREFIX + name:<22} {params}")
    return 0


def _listing_order(names: list[str], shared: tuple[str, ...]) -> list[str]:
    """The floor's size first, then the family's own parameters, then the shared ones."""
    size = [n for n in names if n in ("width", "height")]
    own = [n for n in names if n not in shared]
    return size + own + [n for n in names if n in shared and n not in size]


def _plain(value: Any) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(map(str, value)) + "]"
    return str(value)

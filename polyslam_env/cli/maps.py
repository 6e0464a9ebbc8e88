"""``polyslam maps``: list the built-in maps."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    parser = sub.add_parser("maps", help="list the built-in maps")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from polyslam_env.world.maps import builtin_maps, load_map

    for name in builtin_maps():
        layout = load_map(name)
        x0, y0, x1, y1 = layout.bounds
        print(
            f"{name:<12} {x1 - x0:4.1f} × {y1 - y0:4.1f} m,"
            f" {len(layout.segments):4d} wall segments, {layout.num_start_poses} start poses"
        )
    return 0

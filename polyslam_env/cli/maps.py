"""``polyslam maps``: list the built-in maps and the layout generators with their parameters;
``polyslam maps import MAP.yaml --out floor.yaml``: a ROS ``map_server`` occupancy map made a
map file (walls traced around its free space, start poses, narrow passages reported)."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

#: Generator fields the env sets itself (from ``num_robots`` and the robot's radius).
SET_BY_ENV = ("num_start_poses", "robot_radius")


#: m: the largest shrink back ``maps import`` tries when it offers one (a costmap's inflation
#: radius is the mapping robot's radius plus a safety distance, rarely above this).
OFFER_LIMIT = 0.5


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "maps",
        help="list the built-in maps and the layout generators; import a ROS map",
        description="List the built-in maps (a name to pass as --map) and the layout"
        " generators (--map generator:<name>: a new layout at every reset), with the"
        " generators' parameters (map_params in an EnvConfig) and their defaults."
        " `polyslam maps import MAP.yaml --out FLOOR.yaml` turns a ROS map_server map into a"
        " map file.",
    )
    parser.add_argument(
        "--plot",
        default=None,
        metavar="PNG",
        help="also draw one layout of each generator (walls, pillars, start poses) to PNG",
    )
    parser.add_argument("--seed", type=int, default=0, help="the layouts' seed (default: 0)")
    parser.add_argument(
        "--only",
        default=None,
        metavar="NAMES",
        help="comma list of the generators to draw (default: all)",
    )
    parser.set_defaults(func=run)
    actions = parser.add_subparsers(dest="action", metavar="ACTION")
    imp = actions.add_parser(
        "import",
        help="a ROS map_server map (YAML + PGM/PNG) made a map file",
        description="Read a ROS map_server map (a YAML with image, resolution, origin,"
        " occupied_thresh, free_thresh, negate, and its PGM/PNG), trace the boundary of its"
        " largest free region into wall polylines simplified to --tolerance (clutter inside"
        " kept as islands), place start poses in free space, validate the result like any map"
        " file and write it to --out. Unknown cells count as wall. Passages narrower than the"
        " robot with its margin are reported (with the --shrink that opens them: a costmap's"
        " obstacles are grown by the mapping robot's radius).",
    )
    imp.add_argument("map", metavar="MAP.yaml", help="the map_server YAML")
    imp.add_argument("--out", required=True, help="the map file to write (YAML)")
    imp.add_argument(
        "--tolerance",
        type=float,
        default=None,
        help="m, how far a simplified wall may leave the traced boundary (default: the"
        " map's resolution)",
    )
    imp.add_argument(
        "--shrink",
        type=float,
        default=0.0,
        help="m, free the occupied cells this close to free space: undoes a costmap's"
        " inflation (default: 0)",
    )
    imp.add_argument(
        "--keep",
        choices=("all", "reachable"),
        default="all",
        help="all free space connected to the largest region, or only where the robot's body"
        " reaches (default: all)",
    )
    imp.add_argument(
        "--min-island",
        type=float,
        default=None,
        help="m², clutter smaller than this is dropped (default: 4 cells)",
    )
    imp.add_argument("--robots", type=int, default=3, help="start poses (default: 3)")
    imp.add_argument(
        "--start-separation",
        type=float,
        default=4.0,
        help="m, least distance between start poses (default: 4)",
    )
    imp.add_argument(
        "--start-near",
        default=None,
        metavar="X,Y",
        help="start poses nearest this point (default: spread over the free space)",
    )
    imp.add_argument(
        "--robot-radius", type=float, default=0.065, help="m (default: 0.065, the env's)"
    )
    imp.add_argument("--seed", type=int, default=0, help="draws the starts (default: 0)")
    imp.add_argument("--name", default=None, help="the map's name (default: the YAML's stem)")
    imp.add_argument("--plot", default=None, help="also draw the imported layout to this PNG")
    imp.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    imp.set_defaults(func=run_import)


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
    if args.plot:
        _plot(args.plot, args.seed, args.only)
    return 0


def _plot(path: str, seed: int, only: str | None) -> None:
    """One layout of each generator (or of those in ``only``) drawn side by side."""
    import numpy as np

    from polyslam_env.cli.common import check_output_file
    from polyslam_env.core.errors import ConfigError
    from polyslam_env.render.plots import plot_layouts
    from polyslam_env.world.generators import GENERATORS, make_generator

    out = check_output_file(path, "--plot")
    names = sorted(GENERATORS) if only is None else [n.strip() for n in only.split(",")]
    for name in names:
        if name not in GENERATORS:
            raise ConfigError(
                f"--only: {name!r} is not a layout generator;"
                f" valid: {', '.join(sorted(GENERATORS))}"
            )
    layouts = [
        (f"{name} (seed {seed})", make_generator(name)(np.random.default_rng(seed)))
        for name in names
    ]
    print(f"wrote {plot_layouts(layouts, out)}")


def _listing_order(names: list[str], shared: tuple[str, ...]) -> list[str]:
    """The floor's size first, then the family's own parameters, then the shared ones."""
    size = [n for n in names if n in ("width", "height")]
    own = [n for n in names if n not in shared]
    return size + own + [n for n in names if n in shared and n not in size]


def _plain(value: Any) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(map(str, value)) + "]"
    return str(value)


def run_import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from polyslam_env.cli.common import check_output_file
    from polyslam_env.core.errors import ConfigError, OutputError
    from polyslam_env.world.floorplan import (
        MIN_REGION,
        ImportOptions,
        layout_from_occupancy,
        shrink_that_opens,
    )
    from polyslam_env.world.maps import map_text
    from polyslam_env.world.occupancy import read_map_yaml

    out = check_output_file(args.out, "--out")
    if out.exists() and not args.force:
        raise OutputError(f"--out: {out} exists; pass --force to overwrite it")
    plot = check_output_file(args.plot, "--plot") if args.plot else None
    near = None
    if args.start_near is not None:
        try:
            x, y = (float(v) for v in args.start_near.split(","))
        except ValueError:
            raise ConfigError(
                f"--start-near: expected X,Y in metres, got {args.start_near!r}"
            ) from None
        near = (x, y)
    options = ImportOptions.from_dict(
        {
            "tolerance": args.tolerance,
            "shrink": args.shrink,
            "keep": args.keep,
            "min_island": args.min_island,
            "robots": args.robots,
            "start_separation": args.start_separation,
            "start_near": near,
            "robot_radius": args.robot_radius,
            "seed": args.seed,
            "name": args.name or Path(args.map).stem,
        },
        where="maps import",
    )
    grid = read_map_yaml(args.map)
    result = layout_from_occupancy(grid, options)
    layout = result.layout
    out.write_text(map_text(layout), encoding="utf-8")
    x0, y0, x1, y1 = layout.bounds
    print(
        f"{out}: {x1 - x0:.1f} × {y1 - y0:.1f} m, {len(layout.walls)} walls"
        f" ({len(layout.walls) - 1} islands), {len(layout.segments)} segments,"
        f" {layout.num_start_poses} start poses"
    )
    for note in result.notes:
        print(f"  {note}")
    if result.pockets:
        print(f"  {result.pockets} pockets under {MIN_REGION:g} m² behind narrow gaps (ignored)")
    if result.passages:
        fit = 2 * (options.robot_radius + options.margin)
        print(
            f"warning: {len(result.passages) + result.more_passages} passages narrower than"
            f" the robot with its margin ({fit:g} m) cut off free space:"
        )
        for passage in result.passages:
            print(f"  {passage.describe()}")
        if result.more_passages:
            print(f"  … and {result.more_passages} more")
        opens = shrink_that_opens(grid, options, OFFER_LIMIT)
        if opens is not None:
            print(
                f"  a costmap's inflated obstacles narrow doors: --shrink {opens:g} opens them"
                f" all (rerun with --shrink {opens:g} --force)"
            )
        else:
            print(f"  no --shrink up to {OFFER_LIMIT:g} m opens them all")
    if plot is not None:
        from polyslam_env.render.plots import plot_layouts

        print(f"wrote {plot_layouts([(layout.name, layout)], plot)}")
    return 0

"""The ``polyslam`` command.

Each subcommand has ``--help``. Errors in the user's input (a bad map file, an unknown key
in a config file, a bad value) are reported in one line naming the problem, exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polyslam_env.errors import PolyslamError


def _fmt(value: float) -> str:
    if value != value:  # NaN
        return "n/a"
    if value == 0 or 1e-2 <= abs(value) < 1e4:
        return f"{value:.3f}"
    return f"{value:.2e}"


def format_table(
    rows: Sequence[dict[str, float]], keys: Sequence[str], names: Sequence[str]
) -> str:
    """A plain-text table: one column per robot, one row per metric."""
    width = max(len(k) for k in keys) + 2
    head = " " * width + "".join(f"{n:>12}" for n in names)
    lines = [head, "-" * len(head)]
    for k in keys:
        lines.append(f"{k:<{width}}" + "".join(f"{_fmt(float(r[k])):>12}" for r in rows))
    return "\n".join(lines)


# -- simulate -----------------------------------------------------------------------------------
SIM_KEYS = (
    "nees",
    "nees_paper",
    "nu",
    "nu_mean",
    "completeness",
    "hit_fraction",
    "landmarks",
    "slam_time_ms",
    "diverged",
    "collisions",
)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from polyslam_env.io import write_json
    from polyslam_env.plotting import plot_runs
    from polyslam_env.simulate import simulate
    from polyslam_env.slam.config import SlamConfig
    from polyslam_env.world.config import WorldConfig

    world_cfg = WorldConfig.from_yaml(args.world_config) if args.world_config else WorldConfig()
    slam_cfg = SlamConfig.from_yaml(args.slam_config) if args.slam_config else SlamConfig()
    steps = args.steps
    with tqdm(
        total=steps,
        desc="simulate",
        unit="step",
        disable=args.quiet or not sys.stderr.isatty(),
        leave=False,
    ) as bar:
        last = [0]

        def progress(k: int) -> None:
            bar.update(k - last[0])
            last[0] = k

        result = simulate(
            args.map,
            num_robots=args.robots,
            steps=steps,
            seed=args.seed,
            world_config=world_cfg,
            slam_config=slam_cfg,
            progress=progress,
        )
        bar.total = result.steps
    rows = result.metrics()
    names = [f"r{i + 1}" for i in range(len(rows))]
    print(f"map {result.layout.name!r}, {len(rows)} robots, {result.steps} steps, seed {args.seed}")
    print(format_table(rows, SIM_KEYS, names))
    out = Path(args.out)
    write_json(
        out / "metrics.json",
        {
            "map": result.layout.name,
            "seed": args.seed,
            "steps": result.steps,
            "robots": {n: r for n, r in zip(names, rows, strict=True)},
        },
    )
    picture = plot_runs(result.layout, result.runs, out / "maps.png")
    print(f"wrote {out / 'metrics.json'} and {picture}")
    return 0


# -- maps -----------------------------------------------------------------------------------------
def _cmd_maps(args: argparse.Namespace) -> int:
    from polyslam_env.world.maps import builtin_maps, load_map

    for name in builtin_maps():
        layout = load_map(name)
        x0, y0, x1, y1 = layout.bounds
        print(
            f"{name:<12} {x1 - x0:4.1f} × {y1 - y0:4.1f} m,"
            f" {len(layout.segments):4d} wall segments, {layout.num_start_poses} start poses"
        )
    return 0


# -- entry point ----------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="polyslam",
        description="Multi-robot exploration with polynomial EKF SLAM in the loop.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = sub.add_parser(
        "simulate",
        help="robots with SLAM along scripted paths: metrics table + picture",
        description="Run robots with polynomial SLAM along the map's scripted paths (the paper"
        " map ships the paper's three paths; other maps use a wall follower), print the"
        " paper's metrics per robot, write metrics.json and maps.png.",
    )
    sim.add_argument(
        "--map", default="paper", help="built-in map name or map file (default: paper)"
    )
    sim.add_argument("--robots", type=int, default=None, help="number of robots (default: 3)")
    sim.add_argument("--steps", type=int, default=None, help="control steps (default: 200)")
    sim.add_argument("--seed", type=int, default=0, help="episode seed (default: 0)")
    sim.add_argument("--out", default="out/simulate", help="output folder (default: out/simulate)")
    sim.add_argument("--world-config", help="YAML file with WorldConfig fields")
    sim.add_argument("--slam-config", help="YAML file with SlamConfig fields (default: paper)")
    sim.add_argument("--quiet", action="store_true", help="no progress bar")
    sim.set_defaults(func=_cmd_simulate)

    maps = sub.add_parser("maps", help="list the built-in maps")
    maps.set_defaults(func=_cmd_maps)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args: Any = parser.parse_args(argv)
    if getattr(args, "robots", None) is not None and args.robots < 1:
        parser.error(f"--robots: must be >= 1, got {args.robots}")
    if getattr(args, "steps", None) is not None and args.steps < 1:
        parser.error(f"--steps: must be >= 1, got {args.steps}")
    try:
        return int(args.func(args))
    except (PolyslamError, FileNotFoundError) as err:
        print(f"polyslam: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("polyslam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

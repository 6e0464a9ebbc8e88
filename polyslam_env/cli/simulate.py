"""``polyslam simulate``: robots with SLAM along scripted paths, no RL environment."""

from __future__ import annotations

import argparse
from typing import Any

from polyslam_env.cli.common import agent_label, check_output_folder, format_table, progress_bar

KEYS = (
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


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "simulate",
        help="robots with SLAM along scripted paths: metrics table + picture",
        description="Run robots with polynomial SLAM along the map's scripted paths (the paper"
        " map ships the paper's three paths; other maps use a wall follower), print the"
        " paper's metrics per robot, write metrics.json and maps.png.",
    )
    parser.add_argument("--map", default="paper", help="built-in map or map file (default: paper)")
    parser.add_argument("--robots", type=int, default=None, help="number of robots (default: 3)")
    parser.add_argument("--steps", type=int, default=None, help="control steps (default: 200)")
    parser.add_argument("--seed", type=int, default=0, help="episode seed (default: 0)")
    parser.add_argument("--out", default="out/simulate", help="output folder")
    parser.add_argument("--world-config", help="YAML file with WorldConfig fields")
    parser.add_argument("--slam-config", help="YAML file with SlamConfig fields (default: paper)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    from polyslam_env.apps.simulate import simulate
    from polyslam_env.core.io import write_json
    from polyslam_env.render.plots import plot_runs
    from polyslam_env.slam.config import SlamConfig, slam_preset
    from polyslam_env.world.config import WorldConfig, paper_world_config

    out = check_output_folder(args.out, "--out")
    world_cfg = (
        WorldConfig.from_yaml(args.world_config) if args.world_config else paper_world_config()
    )
    slam_cfg = SlamConfig.from_yaml(args.slam_config) if args.slam_config else slam_preset("paper")
    with progress_bar(args.steps, "simulate", "step", args.quiet, leave=False) as bar:
        result = simulate(
            args.map,
            num_robots=args.robots,
            steps=args.steps,
            seed=args.seed,
            world_config=world_cfg,
            slam_config=slam_cfg,
            progress=lambda k: bar.update(1),
        )
    rows = result.metrics()
    names = [agent_label(i) for i in range(len(rows))]
    print(f"map {result.layout.name!r}, {len(rows)} robots, {result.steps} steps, seed {args.seed}")
    print(format_table(rows, KEYS, names))
    write_json(
        out / "metrics.json",
        {
            "map": result.layout.name,
            "seed": args.seed,
            "steps": result.steps,
            "robots": dict(zip(names, rows, strict=True)),
        },
    )
    picture = plot_runs(result.layout, result.runs, out / "maps.png")
    print(f"wrote {out / 'metrics.json'} and {picture}")
    return 0

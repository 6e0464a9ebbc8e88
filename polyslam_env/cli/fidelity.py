"""``polyslam fidelity``: issue 14's SLAM-fidelity protocol (large maps, exchange on and off)."""

from __future__ import annotations

import argparse
from typing import Any

from polyslam_env.cli.common import RESULTS_LOG, add_study_arguments


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "fidelity",
        help="SLAM fidelity on large generated maps: targets checked, exchange on vs off",
        description="For each map in --maps (a layout generator, or a fixed map: built-in or"
        " a map file, e.g. an imported building) and each of --seeds seeds, run a"
        " team of --policy (default: frontier) with initial error (where the env supports"
        " it) for --steps steps, with the map exchange on and off on the same seeds; print a"
        " table per map (per robot nu_mean, map_precision, completeness_seen, duplicates,"
        " NEES; team coverage) with the issue's targets checked; write OUT/summary.json and"
        " OUT/table.md, and per map and setting a picture of the map of the robot of lowest"
        f" map_precision. Each finished episode goes to OUT/{RESULTS_LOG} (--resume goes on"
        " from it); --address runs the episodes on a Ray cluster.",
    )
    parser.add_argument(
        "--maps",
        default="office_floor,warehouse,loop",
        help="comma list of layout generators, built-in maps or map files (an imported"
        " building; labelled by its file name) (default: office_floor,warehouse,loop)",
    )
    parser.add_argument("--seeds", type=int, default=10, help="seeds per map (default: 10)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    parser.add_argument("--robots", type=int, default=3, help="robots (default: 3)")
    parser.add_argument("--steps", type=int, default=600, help="steps per episode (default: 600)")
    parser.add_argument(
        "--policy",
        default="frontier",
        help="scripted policy of every robot (default: frontier; frontier_closing adds active"
        " loop closing)",
    )
    parser.add_argument(
        "--set",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="env config fields for every episode, dotted keys and YAML values (e.g."
        " slam.merge_turn=weights): a variant under the same protocol",
    )
    parser.add_argument(
        "--policy-set",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="keyword arguments of the policy, YAML values (e.g. gain=visible)",
    )
    parser.add_argument(
        "--fixed-steps",
        action="store_true",
        help="run --steps on fixed maps too; by default a built-in map or map file runs"
        " --steps per 300 m² of its free area (at least --steps, rounded up to 100)",
    )
    add_study_arguments(parser, "1")
    parser.add_argument("--out", default="out/fidelity", help="output folder (out/fidelity)")
    parser.add_argument(
        "--no-pictures",
        action="store_true",
        help="skip OUT/worst_MAP_SETTING.png: per map and setting, the robot of lowest"
        " map_precision, its episode run again and its map drawn with the stretches farther"
        " than 5 cm from a true wall marked (one more episode each)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from polyslam_env.apps.fidelity import (
        SETTINGS,
        FidelityConfig,
        markdown,
        picture,
        run_fidelity,
        worst_robots,
    )
    from polyslam_env.cli.common import progress_bar, report_failed, study_runner, where_text
    from polyslam_env.core.io import write_atomic, write_json

    maps = tuple(name.strip() for name in args.maps.split(","))
    config = FidelityConfig(
        maps=maps,
        seeds=args.seeds,
        first_seed=args.seed,
        robots=args.robots,
        steps=args.steps,
        policy=args.policy,
        env_set=tuple(args.set),
        policy_set=tuple(args.policy_set),
        area_budget=not args.fixed_steps,
    )
    runner = study_runner(args, args.out, 1, "fidelity")
    out = args.out
    total = len(maps) * len(SETTINGS) * args.seeds
    summary = run_fidelity(config, workers=runner)
    summary["failed"] = runner.failed
    text = markdown(summary)
    print(text)
    report_failed(runner)
    print(
        f"{total} episodes in {summary['elapsed_s']:.0f} s, {where_text(runner)}; all checks"
        f" passed: {'yes' if summary['passed'] else 'NO'}"
    )
    json_path = write_json(Path(out) / "summary.json", summary)
    md_path = write_atomic(Path(out) / "table.md", text + "\n")
    print(f"wrote {json_path}, {md_path}")
    if not args.no_pictures:
        worst = worst_robots(summary)
        with progress_bar(len(worst), "pictures", "ep", args.quiet) as bar:
            for entry in worst:
                path = Path(out) / f"worst_{entry['map']}_{entry['setting']}.png"
                picture(config, entry, path)
                bar.update(1)
        print(
            f"wrote {len(worst)} pictures of the robot of lowest map_precision: {out}/worst_*.png"
        )
    return 0

"""``polyslam reproduce``: the paper's Table 1 and Figures 5–8."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

FRACTION = "r3_multi_beats_single_fraction_of_runs"


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "reproduce",
        help="the paper's Table 1 and Figs 5-8 over seeded runs",
        description="Run the paper's experiment (configs/paper.yaml: three robots along the"
        " paper's paths with map exchange) over seeded runs; print Table 1 (mean ± std per robot)"
        " next to the paper's values; write table.csv, summary.json and the figures.",
    )
    parser.add_argument("--runs", type=int, default=None, help="number of runs (default: 100)")
    parser.add_argument("--out", default="out/reproduce", help="output folder")
    parser.add_argument("--workers", type=int, default=2, help="parallel processes (default: 2)")
    parser.add_argument("--config", help="a YAML file like configs/paper.yaml")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    from polyslam_env.apps.reproduce import (
        ReproduceConfig,
        default_config,
        plot_figures,
        reproduce,
        run_one,
        summarise,
        table_rows,
        write_csv,
    )
    from polyslam_env.cli.common import progress_bar
    from polyslam_env.core.io import write_json

    config = ReproduceConfig.from_yaml(args.config) if args.config else default_config()
    if args.runs is not None:
        config = config.replace(runs=args.runs)
    out = Path(args.out)
    start = time.perf_counter()
    with progress_bar(config.runs, "reproduce", "run", args.quiet, leave=False) as bar:
        runs = reproduce(config, workers=args.workers, progress=lambda n: bar.update(1))
    elapsed = time.perf_counter() - start
    summary = summarise(runs)
    summary["elapsed_s"] = elapsed
    summary["workers"] = args.workers

    rows = table_rows(summary)
    head = ["metric", "r1", "r2", "r3", "paper r1 / r2 / r3"]
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    print(f"{config.runs} runs, {config.map!r} map, {elapsed:.0f} s, {args.workers} workers")
    for row in [head, *rows]:
        print("  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)))
    single = summary["r3_single"]["completeness"]
    multi = summary["table"]["completeness"][2]
    print(
        f"r3 completeness: single-robot {single['mean']:.3f} ± {single['std']:.3f},"
        f" multi-robot {multi['mean']:.3f} ± {multi['std']:.3f}"
        f" (multi better in {100 * summary['checks'][FRACTION]:.0f} % of runs)"
    )
    if summary["bytes_per_message"]:
        b = summary["bytes_per_message"]
        print(f"bytes per message: {b['mean']:.0f} (min {b['min']:.0f}, max {b['max']:.0f})")
    for name, ok in summary["checks"].items():
        if isinstance(ok, bool):
            print(f"check {name}: {'yes' if ok else 'NO'}")

    write_json(out / "summary.json", summary)
    write_csv(out / "table.csv", summary)
    figures = plot_figures(run_one(config, seed=0, keep=True), out)
    print(f"wrote {out / 'summary.json'}, {out / 'table.csv'}, " + ", ".join(map(str, figures)))
    return 0

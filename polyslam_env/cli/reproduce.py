"""``polyslam reproduce``: a seed paper's experiment.

``--paper polynomial`` (default): the core paper's Table 1 and Figures 5–8.
``--paper mblcc``: seed 003's Table 1 (four point-landmark FastSLAM variants, three robots)
and Fig 5 (landmark ARMSE against the number of particles).
``--paper alignment``: seed 004's map alignment without rendezvous (four aligners as two
robots' maps grow; Figs 3–6).
``--paper seif``: seed 001's SEIF map fusion (one run cut into 8 pieces, fused without
relative poses).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from polyslam_env.cli.common import (
    RESULTS_LOG,
    add_study_arguments,
    report_failed,
    study_runner,
    where_text,
)

FRACTION = "r3_multi_beats_single_fraction_of_runs"


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "reproduce",
        help="a seed paper's Table 1 and figures over seeded runs",
        description="Run a seed paper's experiment over seeded runs. polynomial (default):"
        " configs/paper.yaml, three robots along the paper's paths with map exchange; print"
        " Table 1 (mean ± std per robot) next to the paper's values; write table.csv,"
        " summary.json and the figures. mblcc: seed 003's four FastSLAM variants on three"
        " cars; print its Table 1 next to the seed's; write summary.json and fig5_armse.png."
        " alignment: seed 004's four map aligners on two robots' growing FastSLAM maps;"
        " print errors per method and stage; write summary.json and figs3-5/fig6 pictures."
        " seif: seed 001's SEIF fusion of one run cut into 8 pieces; write summary.json."
        f" Each finished run goes to OUT/{RESULTS_LOG} (--resume goes on from it);"
        " --address runs them on a Ray cluster.",
    )
    parser.add_argument(
        "--paper",
        choices=("polynomial", "mblcc", "alignment", "seif"),
        default="polynomial",
        help="which seed's experiment (default: polynomial)",
    )
    parser.add_argument(
        "--runs",
        type=int,
        default=None,
        help="number of runs (default: 100; mblcc 50; alignment and seif 10)",
    )
    parser.add_argument("--out", default="out/reproduce", help="output folder")
    add_study_arguments(parser, "2")
    parser.add_argument(
        "--config",
        help="a YAML file like configs/paper.yaml (mblcc: MblccReproduceConfig's fields,"
        " alignment: AlignmentReproduceConfig's, seif: SeifReproduceConfig's)",
    )
    parser.add_argument(
        "--protocol",
        choices=("guarded", "seed"),
        default=None,
        help="alignment only: guarded (the default: 10 particles, mixture maps, descriptors"
        " that never match the wrong landmark, shared re-paired refinement, every aligner"
        " declining below the chance level) or seed (the seed's: 100 particles, the most"
        " probable particle's map, confusable descriptors, each aligner refined on its own"
        " correspondences, only RANSAC declining below 20 supports)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.protocol is not None and args.paper != "alignment":
        print(f"--protocol applies to --paper alignment only, not {args.paper}", file=sys.stderr)
        return 2
    if args.paper == "mblcc":
        return run_mblcc(args)
    if args.paper == "alignment":
        return run_alignment(args)
    if args.paper == "seif":
        return run_seif(args)

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
    from polyslam_env.core.io import write_json

    config = ReproduceConfig.from_yaml(args.config) if args.config else default_config()
    if args.runs is not None:
        config = config.replace(runs=args.runs)
    out = Path(args.out)
    runner = study_runner(args, out, 2, "reproduce", "run")
    start = time.perf_counter()
    runs = reproduce(config, workers=runner)  # the log keeps plain data: figures run again
    elapsed = time.perf_counter() - start
    summary = summarise(runs)
    _stamp(summary, elapsed, runner)

    rows = table_rows(summary)
    head = ["metric", "r1", "r2", "r3", "paper r1 / r2 / r3"]
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    print(f"{config.runs} runs, {config.map!r} map, {elapsed:.0f} s, {where_text(runner)}")
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
    _print_checks(summary["checks"])
    report_failed(runner)

    write_json(out / "summary.json", summary)
    write_csv(out / "table.csv", summary)
    figures = plot_figures(run_one(config, seed=0, keep=True), out)
    print(f"wrote {out / 'summary.json'}, {out / 'table.csv'}, " + ", ".join(map(str, figures)))
    return 0


def _study_config(cls: Any, args: argparse.Namespace) -> Any:
    """A seed study's config: ``--config`` or the defaults, with ``--runs`` applied."""
    config = cls.from_yaml(args.config) if args.config else cls()
    return config if args.runs is None else config.replace(runs=args.runs)


def _stamp(summary: dict[str, Any], elapsed: float, runner: Any) -> None:
    """Stamp a study's summary with its wall time, where it ran and the runs that failed."""
    summary["elapsed_s"] = elapsed
    summary.update(runner.settings())
    summary["failed"] = runner.failed


def _finish(summary: dict[str, Any], config: Any, elapsed: float, runner: Any) -> None:
    """Stamp a seed study's summary with its run settings."""
    _stamp(summary, elapsed, runner)
    summary["config"] = config.to_dict()


def _print_checks(checks: dict[str, Any]) -> None:
    for name, ok in checks.items():
        if isinstance(ok, bool):
            print(f"check {name}: {'yes' if ok else 'NO'}")


def run_mblcc(args: argparse.Namespace) -> int:
    """Seed 003: the table over ``runs`` seeds, Fig 5's particle sweep, the EM sweep, the
    particles' diversity; summary and figures."""
    from polyslam_env.apps.reproduce_mblcc import (
        MblccReproduceConfig,
        diversity_text,
        em_sweep_text,
        plot_armse,
        plot_diversity,
        reproduce,
        summarise,
        table_text,
        total_jobs,
    )
    from polyslam_env.core.io import write_json

    config = _study_config(MblccReproduceConfig, args)
    out = Path(args.out)
    runner = study_runner(args, out, 2, "reproduce mblcc", "run")
    start = time.perf_counter()
    total = total_jobs(config)
    runs, by_n, by_em = reproduce(config, workers=runner)
    elapsed = time.perf_counter() - start
    summary = summarise(runs, by_n, by_em)
    _finish(summary, config, elapsed, runner)

    print(f"{config.runs} runs (+ {total - config.runs} for Fig 5 and the EM sweep),")
    print(f"{elapsed:.0f} s, {where_text(runner)}; mean ± std over runs, seed's Table 1 mean")
    print(table_text(summary))
    _print_checks(summary["checks"])
    report_failed(runner)
    print("paired differences (mean ± standard error over runs), r1 / r2 / r3:")
    for metric, pairs in summary["paired"].items():
        for pair, cells in pairs.items():
            text = " / ".join(f"{c['mean']:+.3f} ± {c['se']:.3f}" for c in cells)
            print(f"  {metric:<15}{pair:<56}{text}")
    if summary["em_sweep"]:
        print("EM sweep: EM-FastSLAM − FastSLAM 2.0 (m, paired over the same seeds)")
        print(em_sweep_text(summary))
    print("particle diversity (robots' mean; lineages_L: particles of L sweeps ago with heirs)")
    print(diversity_text(summary))
    write_json(out / "summary.json", summary)
    figures = [
        plot_armse(summary, out / "fig5_armse.png"),
        plot_diversity(summary, out / "diversity.png"),
    ]
    print(f"wrote {out / 'summary.json'}, {', '.join(str(f) for f in figures)}")
    return 0


def run_alignment(args: argparse.Namespace) -> int:
    """Seed 004: the aligners over ``runs`` seeds at growing map sizes; summary and figures."""
    from polyslam_env.apps.reproduce_alignment import (
        AlignmentReproduceConfig,
        plot_errors,
        plot_times,
        protocol_config,
        reproduce,
        summarise,
        sweep_text,
        table_text,
    )
    from polyslam_env.core.io import write_json

    config = _study_config(AlignmentReproduceConfig, args)
    if args.protocol is not None:
        config = protocol_config(args.protocol, config)
    out = Path(args.out)
    runner = study_runner(args, out, 2, "reproduce alignment", "run")
    start = time.perf_counter()
    records = reproduce(config, workers=runner)
    elapsed = time.perf_counter() - start
    summary = summarise(config, records)
    _finish(summary, config, elapsed, runner)
    rate = summary["descriptor_wrong_match_rate"]
    measured = "none matched" if rate["measured"] is None else f"{100 * rate['measured']:.1f} %"
    print(f"{config.runs} runs, {elapsed:.0f} s, {where_text(runner)}, protocol")
    print(f"{summary['protocol']}; descriptor confusion {rate['confusion']:g}, wrong matches")
    print(f"{measured}; errors of each aligner's answers against the true transform")
    print(table_text(summary))
    _print_checks(summary["checks"])
    report_failed(runner)
    print("|t| error minus RANSAC's where both answered (mean ± standard error, cells):")
    for method, d in summary["paired_against_ransac"].items():
        print(f"  {method:<9}{d['mean']:+.3f} ± {d['se']:.3f}  ({d['cells']})")
    if len(summary["by_confusion"]) > 1:
        print("over all stages, per descriptor confusion (answers %, |t| error mean ± std / m):")
        print(sweep_text(summary))
    write_json(out / "summary.json", summary)
    figures = [
        plot_errors(summary, out / "figs3-5_errors.png"),
        plot_times(summary, out / "fig6_time.png"),
    ]
    print(f"wrote {out / 'summary.json'}, {', '.join(str(f) for f in figures)}")
    return 0


def run_seif(args: argparse.Namespace) -> int:
    """Seed 001: one run cut into pieces, each mapped by a SEIF, fused without relative poses."""
    from polyslam_env.apps.reproduce_seif import (
        SeifReproduceConfig,
        reproduce,
        summarise,
        table_text,
    )
    from polyslam_env.core.io import write_json

    config = _study_config(SeifReproduceConfig, args)
    out = Path(args.out)
    runner = study_runner(args, out, 2, "reproduce seif", "run")
    start = time.perf_counter()
    runs = reproduce(config, workers=runner)
    elapsed = time.perf_counter() - start
    summary = summarise(config, runs)
    _finish(summary, config, elapsed, runner)
    print(f"{config.runs} runs of {config.pieces} pieces, {elapsed:.0f} s, {where_text(runner)}")
    print(table_text(summary))
    _print_checks(summary["checks"])
    report_failed(runner)
    write_json(out / "summary.json", summary)
    print(f"wrote {out / 'summary.json'}")
    return 0

"""``polyslam benchmark``: SLAM, world and env speed next to references timed in the same run."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

#: The columns of each section's table: (heading, width); the first column of ``env`` is
#: left-aligned, every other right-aligned. Headings and rows are both laid out by
#: :func:`_columns` from this one list, so they cannot drift apart; the widths hold medians
#: up to 999,999.9 and spans up to 99,999.9–999,999.9 (a loaded machine's outliers).
COLUMNS = {
    "slam": [
        ("landmarks", 9),
        ("step µs", 9),
        ("IQR", 9),
        ("min–max", 17),
        ("solve3 µs", 9),
        ("× solve3", 8),
        ("beams", 5),
        ("heading µs", 10),
    ],
    "world": [
        ("robots", 9),
        ("step µs", 9),
        ("IQR", 9),
        ("min–max", 17),
        ("µs/robot", 9),
        ("pymunk µs", 9),
        ("× pymunk", 8),
    ],
    "env": [("env", 20), ("steps/s", 9), ("IQR", 9), ("min–max", 17), ("× MPE", 7)],
    "backends": [("slam.backend", 25), ("steps/s", 9), ("IQR", 9), ("min–max", 17),
                 ("× no SLAM", 9)],
    "team": [("robots", 9), ("steps", 6), ("mean ms", 9), ("median ms", 9), ("max ms", 9),
             ("× first", 8), ("messages", 8), ("polys", 6), ("skipped", 7), ("covered", 7),
             ("refits", 6)],
    "memory": [("episode", 9), ("steps", 6), ("peak MB", 9), ("RSS MB", 9)],
    "compile": [("cold s", 9), ("warm s", 9), ("compile s", 9), ("cached", 7)],
    "workers": [("processes", 9), ("steps/s each", 12), ("total", 9), ("× one", 7)],
    "floor": [("per step", 9), ("mean ms", 9), ("median ms", 9), ("MPE steps", 9),
              ("calls", 7), ("SLAM", 7), ("exchange", 8), ("rest", 7)],
    "reproduce": [("runs", 5), ("workers", 7), ("seconds", 9)],
    "train": [("timesteps", 9), ("env steps", 9), ("seconds", 9), ("env steps/s", 11),
              ("× MPE", 7), ("× today", 7)],
}  # fmt: skip
#: What follows the columns: the SLAM rows end with their stage timings.
TAILS = {
    "slam": "  stages (median µs)",
    "world": "",
    "env": "",
    "backends": "",
    "team": "",
    "memory": "",
    "compile": "",
    "workers": "",
    "floor": "",
    "reproduce": "",
    "train": "",
}


def _columns(section: str, cells: list[str]) -> str:
    """``cells`` laid out in ``section``'s columns (a cell wider than its column pushes the
    rest right rather than being cut)."""
    out = []
    for k, (cell, (_, width)) in enumerate(zip(cells, COLUMNS[section], strict=True)):
        left = section in ("env", "backends", "floor") and k == 0
        out.append(f"{cell:<{width}}" if left else f"{cell:>{width}}")
    return " ".join(out)


HEADERS = {
    section: _columns(section, [heading for heading, _ in columns]) + TAILS[section]
    for section, columns in COLUMNS.items()
}
TITLES = {
    "slam": "SLAM step per robot vs landmarks",
    "world": "world step (physics + scan + camera) vs robots",
    "env": "env steps per second (3 robots, paper map, vector obs, no rendering)",
    "backends": "env steps per second per slam.backend (3 robots, generator:pillar_hall, pillar"
    " sensor on, vector obs)",
    "team": "env step vs team size (generator:rooms, exchange on, no coverage end;"
    " messages and polynomials the exchange applied, polynomials skipped as held, chains"
    " refitted)",
    "memory": "RSS of one env (3 robots, full SLAM) in a fresh process, after each episode",
    "compile": "first env reset + step in a fresh process: empty numba cache vs warm cache",
    "workers": "env steps per second with N processes, each stepping its own env (full SLAM)",
    "floor": "office-floor frontier episode (generator:office_floor seed 9, 3 robots, frontier"
    " team, exchange on), steps 101-400: env step and team act; Python calls per step (cProfile),"
    " the env step's split into the team SLAM's step, its exchange and the rest",
    "reproduce": "polyslam reproduce --runs N (the core paper's runs, 2 workers)",
    "train": "polyslam train --config configs/train_goals.yaml, cut short: env steps per second"
    " of its learning loop after the first rollout (median of the runs; × today: median over"
    " interleaved pairs of runs of both trees)",
    "profile": "profile of the env step",
}


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "benchmark",
        help="speed of the SLAM, the world and the env, with same-run references",
        description="Time the SLAM step against the number of landmarks, the world step against"
        " the number of robots, and env steps per second (full SLAM, no SLAM, the SB3"
        " vectorised path with 2 processes, and PettingZoo MPE simple_spread as reference when"
        " mpe2 is installed). Figures are medians over repeats with their spread; compare"
        " machines by the ratios.",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a few minutes instead of ~15 (without the reproduction and training runs)",
    )
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON here")
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="SECTION",
        choices=(
            "slam",
            "world",
            "env",
            "vec",
            "backends",
            "reference",
            "floor",
            "team",
            "memory",
            "compile",
            "reproduce",
            "train",
        ),
        help="run only these sections: slam world env vec backends reference floor team memory"
        " compile reproduce train (default: all; reproduce and train only without --quick)",
    )
    parser.add_argument(
        "--workers",
        dest="processes",  # a list, not the shared ``--workers`` count main() checks
        type=_counts,
        metavar="N[,N...]",
        help="also env steps/s with N processes each running its own env, e.g. 1,2,4"
        " (alone: only these rows)",
    )
    parser.add_argument(
        "--profile",
        nargs="?",
        const="env",
        choices=("env", "team", "noslam"),
        help="also print the top of a cProfile of the env step: 'env' (default) the full-SLAM"
        " 3-robot paper env, 'team' the 20-robot generated-map env of the team rows, 'noslam'"
        " the 3-robot env with slam_enabled=False (alone: only that)",
    )
    parser.add_argument(
        "--train-baseline",
        metavar="TREE",
        type=Path,
        help="also run the train row from this source tree (e.g. a checkout of issue 41's"
        " 'today', main at d0c6831) and give this tree's env steps/s over it, same run",
    )
    parser.add_argument(
        "--train-repeats",
        type=int,
        metavar="N",
        help="pairs of training runs against --train-baseline, interleaved (default 3; the row"
        " gives the median of the pairs' ratios)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of maps and actions")
    # Hidden: a few steps per figure, only to exercise the command (tests).
    parser.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from polyslam_env.apps.benchmark import PLANS, SECTIONS, run_benchmark
    from polyslam_env.core.io import write_json

    plan = PLANS["tiny" if args.tiny else "quick" if args.quick else "full"]
    if args.train_repeats is not None:
        if args.train_repeats < 1:
            print(f"polyslam: error: --train-repeats: must be >= 1, got {args.train_repeats}",
                  file=sys.stderr)  # fmt: skip
            return 2
        plan = dataclasses.replace(plan, train_repeats=args.train_repeats)
    printer = _Printer()
    extra = bool(args.processes) or args.profile is not None
    sections = args.only or ([] if extra else SECTIONS)
    results = run_benchmark(
        plan,
        sections,
        seed=args.seed,
        report=printer,
        workers=args.processes or (),
        profile=args.profile,
        train_baseline=args.train_baseline,
    )
    print()
    print(_format_targets(results["targets"]))
    print(_format_machine(results["machine"]))
    if args.json:
        print(f"wrote {write_json(args.json, results)}")
    return 0


def _counts(text: str) -> list[int]:
    """``--workers``: comma-separated process counts, each >= 1."""
    try:
        counts = [int(part) for part in text.split(",")]
    except ValueError:
        counts = []
    if not counts or any(n < 1 for n in counts):
        raise argparse.ArgumentTypeError(
            f"--workers: expected process counts >= 1 separated by commas (e.g. 1,2,4),"
            f" got {text!r}"
        )
    return counts


class _Printer:
    """Prints each row as it arrives, with a title and heading before a section's first row."""

    def __init__(self) -> None:
        self.section: str | None = None

    def __call__(self, section: str, row: dict[str, Any]) -> None:
        if section != self.section:
            if self.section is not None:
                print()
            print(TITLES[section])
            if section in HEADERS:
                print(HEADERS[section])
            self.section = section
        print(FORMATTERS[section](row), flush=True)


def _spread(s: dict[str, float], digits: int = 1) -> list[str]:
    """The IQR and min–max cells of a figure's statistics."""
    return [f"{s['iqr']:.{digits}f}", f"{s['min']:.{digits}f}–{s['max']:.{digits}f}"]


def _slam_row(r: dict[str, Any]) -> str:
    s = r["step_us"]
    stages = "  ".join(f"{k} {v:.0f}" for k, v in r["stages_us"].items())
    cells = [
        str(r["landmarks"]),
        f"{s['median']:.1f}",
        *_spread(s),
        f"{r['reference_solve3_us']['median']:.2f}",
        f"{r['ratio_to_solve3']:.1f}",
        f"{r['beams_used_per_step']:.2f}",
        f"{r['heading_step_us']['median']:.1f}",
    ]
    return _columns("slam", cells) + f"  {stages}"


def _world_row(r: dict[str, Any]) -> str:
    s = r["step_us"]
    cells = [
        str(r["robots"]),
        f"{s['median']:.1f}",
        *_spread(s),
        f"{r['per_robot_us']:.1f}",
        f"{r['reference_pymunk_us']['median']:.1f}",
        f"{r['ratio_to_pymunk']:.1f}",
    ]
    return _columns("world", cells)


def _env_row(r: dict[str, Any]) -> str:
    if not r["installed"]:
        return f"{r['label']:<20} {'not installed':>9}"
    s = r["steps_per_s"]
    ratio = r.get("ratio_to_mpe")
    row = _columns("env", [r["label"], f"{s['median']:.1f}", *_spread(s), _opt(ratio)])
    if r.get("cpu_ms_per_env_step") is not None:  # the vectorised rows, workers included
        row += f"   CPU {r['cpu_ms_per_env_step']:.2f} ms/env step"
    if r.get("ratio_to_one_process") is not None:
        row += f"   {r['ratio_to_one_process']:.2f}× one process"
    if "machine_speedup" in r:  # the vectorised row: what the machine allows in parallel
        row += (
            f"   ({r['processes']} processes of small numpy work run"
            f" {r['machine_speedup']:.2f}× faster than one after another here)"
        )
    return row


def _backends_row(r: dict[str, Any]) -> str:
    s = r["steps_per_s"]
    cells = [r["backend"], f"{s['median']:.1f}", *_spread(s), _opt(r["ratio_to_no_slam"])]
    return _columns("backends", cells)


def _opt(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _team_row(r: dict[str, Any]) -> str:
    cells = [str(r["robots"]), str(r["steps"]), f"{r['mean_ms']:.1f}", f"{r['median_ms']:.1f}",
             f"{r['max_ms']:.1f}", f"{r['ratio_to_first']:.1f}", str(r["messages"]),
             str(r["polynomials"]), str(r.get("skipped", "n/a")),
             str(r.get("covered", "n/a")), str(r.get("refits", "n/a"))]  # fmt: skip
    return _columns("team", cells)


def _memory_row(r: dict[str, Any]) -> str:
    rss = "n/a" if r["rss_mb"] is None else f"{r['rss_mb']:.1f}"
    return _columns("memory", [str(r["episode"]), str(r["steps"]), f"{r['peak_mb']:.1f}", rss])


def _compile_row(r: dict[str, Any]) -> str:
    cells = [f"{r['cold_s']:.2f}", f"{r['warm_s']:.2f}", f"{r['compile_s']:.2f}",
             str(r["cached_files"])]  # fmt: skip
    return _columns("compile", cells)


def _workers_row(r: dict[str, Any]) -> str:
    cells = [str(r["processes"]), f"{r['per_process']:.1f}", f"{r['total']:.1f}",
             _opt(r["ratio_to_one"])]  # fmt: skip
    return _columns("workers", cells)


def _profile_table(p: dict[str, Any]) -> str:
    """The profile's two tops (own time, cumulative time), each line with its % of the
    profiled step time."""
    lines = [
        f"{p['robots']} robots, {p['env']} map,"
        f"{'' if p.get('slam_enabled', True) else ' slam_enabled=False,'} {p['steps']} steps,"
        f" {p['step_ms']:.2f} ms per step under the profiler"
    ]
    for key, label in (("tottime", "own time"), ("cumtime", "cumulative time")):
        lines += [
            "",
            f"top by {label} ({key})",
            f"{'calls':>8} {key + ' s':>10} {'%':>6}  function",
        ]
        for e in p[key]:
            lines.append(
                f"{e['ncalls']:>8} {e[key]:>10.3f} {e[key + '_pct']:>6.1f}  {e['function']}"
            )
    return "\n".join(lines)


def _floor_rows(r: dict[str, Any]) -> str:
    """Two lines, the env step (with its calls split) and the team act, and MPE's calls."""
    env, act = r["env_step"], r["team_act"]
    lines = [
        _columns("floor", ["env step", f"{env['mean_ms']:.2f}", f"{env['median_ms']:.2f}",
                           _opt(env["mpe_steps"]), f"{r['env_calls']:.0f}",
                           f"{r['env_calls_slam']:.0f}", f"{r['env_calls_exchange']:.0f}",
                           f"{r['env_calls_rest']:.0f}"]),
        _columns("floor", ["team act", f"{act['mean_ms']:.2f}", f"{act['median_ms']:.2f}",
                           _opt(act["mpe_steps"]), f"{r['act_calls']:.0f}", "", "", ""]),
    ]  # fmt: skip
    if r.get("mpe_calls") is not None:
        lines.append(f"(one MPE simple_spread step: {r['mpe_calls']:.0f} calls;"
                     f" team coverage at the end {100 * r['coverage']:.1f} %)")  # fmt: skip
    return "\n".join(lines)


def _reproduce_row(r: dict[str, Any]) -> str:
    return _columns("reproduce", [str(r["runs"]), str(r["workers"]), f"{r['seconds']:.1f}"])


def _train_row(r: dict[str, Any]) -> str:
    cells = [str(r["timesteps"]), f"{r['env_steps']:.0f}", f"{r['seconds']:.1f}",
             f"{r['env_steps_per_s']:.1f}", _opt(r.get("ratio_to_mpe"), 4),
             _opt(r.get("ratio_to_today"))]  # fmt: skip
    line = _columns("train", cells)
    if r.get("ratios_to_today"):
        pairs = ", ".join(f"{x:.2f}" for x in r["ratios_to_today"])
        cpu = ", ".join(f"{x:.2f}" for x in r["cpu_ratios_to_today"])
        line += f"\n(× today per pair of runs: {pairs}; CPU per env step, today / here: {cpu})"
    return line


FORMATTERS = {
    "slam": _slam_row,
    "world": _world_row,
    "env": _env_row,
    "backends": _backends_row,
    "team": _team_row,
    "memory": _memory_row,
    "compile": _compile_row,
    "workers": _workers_row,
    "floor": _floor_rows,
    "reproduce": _reproduce_row,
    "train": _train_row,
    "profile": _profile_table,
}


def _format_targets(rows: list[dict[str, Any]]) -> str:
    """Issues 15's and 41's targets: measured, goal, met (ratios to MPE are known only at the
    end; n/a: not measured in this run)."""
    lines = [f"{'issue':<6} {'target':<37} {'measured':>10} {'goal':>8}  met"]
    for r in rows:
        met = "n/a" if r["met"] is None else "yes" if r["met"] else "NO"
        value = "n/a" if r["measured"] is None else f"{r['measured']:.2f}"
        goal = ("≤ " if r["at_most"] else "≥ ") + f"{r['goal']:g}"
        lines.append(f"{r['issue']:<6} {r['target']:<37} {value:>10} {goal:>8}  {met}")
    return "\n".join(lines)


def _format_machine(m: dict[str, Any]) -> str:
    def load(value: float | None) -> str:
        return "?" if value is None else f"{value:.2f}"

    return (
        f"machine: {m['cpus']} cpus, load {load(m['load_before'])} → {load(m['load_after'])}"
        f" (1-min average; a loaded machine slows every figure, ratios less), BLAS {m['blas']},"
        f" numpy {m['numpy']}, pymunk {m['pymunk']}, Python {m['python']}"
    )

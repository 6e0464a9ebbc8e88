"""``polyslam evaluate``: N seeded episodes in parallel → table, JSON, CSV, coverage plot."""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path
from typing import Any

from polyslam_env.cli.common import check_output_file, fmt, progress_bar
from polyslam_env.cli.run import add_env_arguments, env_config, explain_choices, policy_kwargs


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "evaluate",
        help="N seeded episodes of a policy: mean and spread per robot and team",
        description="Run episodes with seeds S..S+N-1 in parallel processes; print per-robot"
        " and team means with spread (std, min, max); optionally write JSON, CSV (one row per"
        " robot per episode) and a plot of team coverage over time (mean and min-max band).",
    )
    add_env_arguments(parser)
    parser.add_argument("--episodes", type=int, default=4, help="number of episodes (default 4)")
    parser.add_argument("--workers", type=int, help="processes (default: min(2, episodes))")
    parser.add_argument("--json", help="write all results (per episode + summary) here")
    parser.add_argument("--csv", help="write one row per robot per episode here")
    parser.add_argument("--plot", help="write the team coverage-over-time plot (PNG) here")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from concurrent.futures import ProcessPoolExecutor

    from policies.base import make_team
    from polyslam_env.apps.rollout import EpisodeResult, evaluate_episode, summarise
    from polyslam_env.core.io import write_json
    from polyslam_env.environment.parallel import parallel_env

    for flag in ("json", "csv", "plot"):
        if getattr(args, flag):
            check_output_file(getattr(args, flag), f"--{flag}")
    cfg = env_config(args)
    kwargs = policy_kwargs(args)
    probe = parallel_env(cfg)  # fail here, in one line, on a bad map or policy/env mismatch
    make_team(args.policy, probe, **kwargs)
    explain_choices(args, cfg)
    probe.close()
    seeds = [args.seed + k for k in range(args.episodes)]
    workers = args.workers or min(2, args.episodes)
    config = cfg.to_dict()
    results: list[EpisodeResult] = []
    bar = progress_bar(len(seeds), "evaluate", "ep", args.quiet)
    with bar, ProcessPoolExecutor(max_workers=workers) as pool:
        jobs = [pool.submit(evaluate_episode, config, args.policy, kwargs, s) for s in seeds]
        for job in jobs:
            results.append(job.result())
            bar.update(1)
    summary = summarise(results)
    print(f"policy {args.policy!r}, map {cfg.map!r}, {len(seeds)} episodes, seeds {seeds[0]}..")
    print(format_summary(summary))
    written = []
    if args.json:
        meta = {"policy": args.policy, "map": cfg.map, "seeds": seeds, "config": config}
        episodes = [r.to_dict() for r in results]
        written.append(write_json(args.json, {**meta, "summary": summary, "episodes": episodes}))
    if args.csv:
        written.append(write_csv(args.csv, results))
    if args.plot:
        written.append(plot_coverage(results, args.plot, f"{args.policy} on {cfg.map}"))
    if written:
        print("wrote " + ", ".join(map(str, written)))
    return 0


def format_summary(summary: dict[str, Any]) -> str:
    """Per robot then team: ``metric  mean ± std  [min, max]``, one line each."""
    lines = []
    blocks = [*summary["robots"].items(), ("team", summary["team"])]
    for name, stats in blocks:
        lines.append(f"{name}:")
        for key, s in stats.items():
            extra = f"  (reached in {int(s['reached'])})" if "reached" in s else ""
            lines.append(
                f"  {key:<16}{fmt(s['mean']):>10} ± {fmt(s['std']):<10}"
                f" [{fmt(s['min'])}, {fmt(s['max'])}]{extra}"
            )
    return "\n".join(lines)


def write_csv(path: str | Path, results: list[Any]) -> Path:
    """One row per robot per episode: seed, agent, steps, team coverage, robot metrics."""
    from polyslam_env.core.io import write_atomic

    keys = sorted({k for r in results for m in r.robots.values() for k in m})
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["seed", "agent", "steps", "team_coverage", *keys])
    for r in results:
        for agent, m in r.robots.items():
            cov = r.team.get("coverage")
            writer.writerow([r.seed, agent, r.steps, cov, *(m.get(k) for k in keys)])
    return write_atomic(path, buf.getvalue())


def plot_coverage(results: list[Any], path: str | Path, title: str) -> Path:
    """Team coverage vs step: mean over episodes with a min–max band (episodes that ended
    early hold their last value)."""
    import numpy as np

    from polyslam_env.core.io import write_atomic
    from polyslam_env.render.plots import _pyplot

    plt = _pyplot()
    length = max(len(r.coverage) for r in results)
    series = np.array([r.coverage + [r.coverage[-1]] * (length - len(r.coverage)) for r in results])
    steps = np.arange(length)  # (T,)
    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    ax.fill_between(steps, series.min(axis=0), series.max(axis=0), alpha=0.25, label="min–max")
    ax.plot(steps, series.mean(axis=0), lw=1.8, label=f"mean of {len(results)} episodes")
    ax.set_xlabel("step")
    ax.set_ylabel("team coverage")
    ax.set_ylim(0.0, 1.0)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_atomic(path, buf.getvalue())

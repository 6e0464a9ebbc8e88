"""``polyslam evaluate``: N seeded episodes in parallel → table, JSON, CSV, coverage plot."""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path
from typing import TYPE_CHECKING, Any

from polyslam_env.cli.common import (
    RESULTS_LOG,
    add_study_arguments,
    check_output_file,
    fmt,
    report_failed,
    study_runner,
)
from polyslam_env.cli.run import add_env_arguments, env_config, explain_choices, policy_kwargs

if TYPE_CHECKING:
    from polyslam_env.apps.rollout import EpisodeResult


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "evaluate",
        help="N seeded episodes of a policy: mean and spread per robot and team",
        description="Run episodes with seeds S..S+N-1 in parallel processes; print per-robot"
        " and team means with spread (std, min, max); optionally write JSON, CSV (one row per"
        " robot per episode) and a plot of team coverage over time (mean and min-max band)."
        " A comma list (--policy frontier,random,ppo) runs every policy on the same seeds and"
        " map: one table of mean ± std per policy (team coverage, steps_to_90, nu_mean,"
        " completeness, bytes sent), one JSON/CSV with all, one plot with a line and band per"
        " policy; --checkpoint goes to the policies that take one (ppo).",
    )
    add_env_arguments(parser)
    parser.add_argument("--episodes", type=int, default=4, help="number of episodes (default 4)")
    add_study_arguments(parser, "min(2, episodes)")
    parser.add_argument(
        "--out",
        help=f"keep the study in this folder: {RESULTS_LOG} (each finished episode, for"
        " --resume) and summary.json (as --json)",
    )
    parser.add_argument("--json", help="write all results (per episode + summary) here")
    parser.add_argument("--csv", help="write one row per robot per episode here")
    parser.add_argument("--plot", help="write the team coverage-over-time plot (PNG) here")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from policies.base import make_team
    from polyslam_env.apps.jobs import run_jobs, succeeded
    from polyslam_env.apps.rollout import evaluate_job, summarise
    from polyslam_env.environment.parallel import parallel_env

    for flag in ("json", "csv", "plot"):
        if getattr(args, flag):
            check_output_file(getattr(args, flag), f"--{flag}")
    if "," in args.policy:
        return run_many(args)
    cfg = env_config(args)
    kwargs = policy_kwargs(args)
    probe = parallel_env(cfg)  # fail here, in one line, on a bad map or policy/env mismatch
    make_team(args.policy, probe, **kwargs)
    explain_choices(args, cfg)
    probe.close()
    seeds = [args.seed + k for k in range(args.episodes)]
    runner = study_runner(args, args.out, min(2, args.episodes), "evaluate")
    config = cfg.to_dict()
    jobs = [(config, args.policy, kwargs, s) for s in seeds]
    results = succeeded(run_jobs(evaluate_job, jobs, runner, seed_of=lambda job: job[3]))
    summary = summarise(results)
    print(f"policy {args.policy!r}, map {cfg.map!r}, {len(seeds)} episodes, seeds {seeds[0]}..")
    print(format_summary(summary))
    report_failed(runner)
    meta = {"policy": args.policy, "map": cfg.map, "seeds": seeds, "config": config}
    episodes = [r.to_dict() for r in results]
    data = {**meta, "summary": summary, "episodes": episodes, "failed": runner.failed}
    written = _write_json(args, data)
    if args.csv:
        written.append(write_csv(args.csv, results))
    if args.plot:
        written.append(plot_coverage(results, args.plot, f"{args.policy} on {cfg.map}"))
    if written:
        print("wrote " + ", ".join(map(str, written)))
    return 0


def _policy_names(text: str) -> list[str]:
    from polyslam_env.core.errors import PolyslamError

    names = [n.strip() for n in text.split(",")]
    if any(not n for n in names) or len(set(names)) != len(names):
        raise PolyslamError(f"--policy {text!r}: expected distinct names separated by commas")
    return names


def _write_json(args: argparse.Namespace, data: dict[str, Any]) -> list[Path]:
    """``data`` to ``--json`` and to ``OUT/summary.json``, as asked; the files written."""
    from polyslam_env.core.io import write_json

    paths = [Path(p) for p in (args.json, args.out and Path(args.out) / "summary.json") if p]
    return [write_json(path, data) for path in paths]


def run_many(args: argparse.Namespace) -> int:
    """``--policy a,b,...``: every policy on the same seeds and map, compared in one table."""
    from policies.base import make_team, policy_factory
    from polyslam_env.apps.jobs import run_jobs
    from polyslam_env.apps.rollout import compare, evaluate_job, summarise
    from polyslam_env.core.errors import PolyslamError
    from polyslam_env.environment.parallel import parallel_env

    names = _policy_names(args.policy)
    configs, kwargs, each = {}, {}, {}
    for name in names:
        one = argparse.Namespace(**{**vars(args), "policy": name})
        if not getattr(policy_factory(name), "takes_checkpoint", False):
            one.checkpoint = None
        kwargs[name], configs[name], each[name] = policy_kwargs(one), env_config(one), one
    if args.checkpoint is not None and not any(kwargs.values()):
        raise PolyslamError(f"--checkpoint: none of the policies {args.policy!r} takes one")
    maps = {name: cfg.map for name, cfg in configs.items()}
    if len(set(maps.values())) > 1:
        chosen = ", ".join(f"{n}: {m!r}" for n, m in maps.items())
        raise PolyslamError(
            f"--policy {args.policy}: the policies' maps differ ({chosen}); give --map"
        )
    for name in names:
        probe = parallel_env(configs[name])  # one line on a bad map or policy/env mismatch
        make_team(name, probe, **kwargs[name])
        probe.close()
        explain_choices(each[name], configs[name])
    seeds = [args.seed + k for k in range(args.episodes)]
    runner = study_runner(args, args.out, min(2, len(names) * len(seeds)), "evaluate")
    dicts = {name: cfg.to_dict() for name, cfg in configs.items()}
    jobs = [(dicts[name], name, kwargs[name], s) for name in names for s in seeds]
    results: dict[str, list[EpisodeResult]] = {name: [] for name in names}
    done = run_jobs(evaluate_job, jobs, runner, seed_of=lambda job: job[3])
    for job, result in zip(jobs, done, strict=True):
        if result is not None:
            results[job[1]].append(result)
    table = compare(results)
    the_map = configs[names[0]].map
    print(f"map {the_map!r}, {len(seeds)} episodes per policy, seeds {seeds[0]}..{seeds[-1]}")
    print(format_comparison(table))
    report_failed(runner)
    data = {
        "policies": names,
        "map": the_map,
        "seeds": seeds,
        "configs": dicts,
        "comparison": table,
        "summary": {n: summarise(results[n]) for n in names},
        "episodes": {n: [r.to_dict() for r in results[n]] for n in names},
        "failed": runner.failed,
    }
    written = _write_json(args, data)
    if args.csv:
        written.append(write_csv(args.csv, [(n, r) for n in names for r in results[n]]))
    if args.plot:
        written.append(plot_comparison(results, args.plot, f"{len(seeds)} episodes on {the_map}"))
    if written:
        print("wrote " + ", ".join(map(str, written)))
    return 0


def format_comparison(table: dict[str, dict[str, dict[str, float]]]) -> str:
    """One row per policy: ``mean ± std`` of each compared column (``steps_to_90`` with how
    many episodes reached 90 %)."""
    from polyslam_env.apps.rollout import COMPARED

    heads = {"coverage": "team coverage", "bytes_sent": "bytes sent"}
    width = max(6, *(len(n) for n in table)) + 2
    lines = ["policy".ljust(width) + "".join(f"  {heads.get(k, k):>20}" for k in COMPARED)]
    for name, stats in table.items():
        cells = []
        for key in COMPARED:
            s = stats[key]
            cell = f"{fmt(s['mean'])} ± {fmt(s['std'])}"
            if "reached" in s:
                reached = f"{int(s['reached'])}/{int(s['episodes'])}"
                cell = (
                    f"never (0/{int(s['episodes'])})" if not s["reached"] else f"{cell} ({reached})"
                )
            cells.append(f"  {cell:>20}")
        lines.append(name.ljust(width) + "".join(cells))
    lines.append("mean ± std over episodes; steps_to_90 over those that reached 90 % (k/N)")
    return "\n".join(lines)


def format_summary(summary: dict[str, Any]) -> str:
    """Per robot then team: ``metric  mean ± std  [min, max]``, one line each."""
    lines = []
    blocks = [*summary["robots"].items(), ("team", summary["team"])]
    width = max([16, *(len(k) + 1 for _, stats in blocks for k in stats)])
    for name, stats in blocks:
        lines.append(f"{name}:")
        for key, s in stats.items():
            extra = f"  (reached in {int(s['reached'])})" if "reached" in s else ""
            lines.append(
                f"  {key:<{width}}{fmt(s['mean']):>10} ± {fmt(s['std']):<10}"
                f" [{fmt(s['min'])}, {fmt(s['max'])}]{extra}"
            )
    return "\n".join(lines)


def write_csv(path: str | Path, results: list[Any]) -> Path:
    """One row per robot per episode: seed, agent, steps, team coverage, robot metrics.

    ``results`` are :class:`EpisodeResult` s, or ``(policy, result)`` pairs for a comparison
    (then a first column ``policy``)."""
    from polyslam_env.core.io import write_atomic

    pairs = [r if isinstance(r, tuple) else (None, r) for r in results]
    named = any(p is not None for p, _ in pairs)
    keys = sorted({k for _, r in pairs for m in r.robots.values() for k in m})
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(
        [*(["policy"] if named else []), "seed", "agent", "steps", "team_coverage", *keys]
    )
    for policy, r in pairs:
        for agent, m in r.robots.items():
            cov = r.team.get("coverage")
            first = [policy] if named else []
            writer.writerow([*first, r.seed, agent, r.steps, cov, *(m.get(k) for k in keys)])
    return write_atomic(path, buf.getvalue())


def plot_coverage(results: list[Any], path: str | Path, title: str) -> Path:
    """Team coverage vs step of one policy: mean over episodes with a min–max band (episodes
    that ended early hold their last value); :func:`plot_comparison` with one group."""
    return plot_comparison({f"mean of {len(results)} episodes": results}, path, title)


def _padded(results: list[EpisodeResult]) -> Any:  # (episodes, T)
    """Team coverage per episode and step, episodes that ended early holding their last value."""
    import numpy as np

    length = max(len(r.coverage) for r in results)
    return np.array([r.coverage + [r.coverage[-1]] * (length - len(r.coverage)) for r in results])


def plot_comparison(groups: dict[str, list[EpisodeResult]], path: str | Path, title: str) -> Path:
    """Team coverage vs step, per policy: the mean over its episodes as a line, their min–max
    spread as a band of the same colour."""
    import numpy as np

    from polyslam_env.core.io import write_atomic
    from polyslam_env.render.plots import _pyplot

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    for k, (name, results) in enumerate(groups.items()):
        series = _padded(results)  # (E, T)
        steps = np.arange(series.shape[1])
        color = f"C{k % 10}"
        ax.fill_between(steps, series.min(axis=0), series.max(axis=0), color=color, alpha=0.2)
        ax.plot(steps, series.mean(axis=0), color=color, lw=1.8, label=name)
    ax.set_xlabel("step")
    ax.set_ylabel("team coverage")
    ax.set_ylim(0.0, 1.0)
    ax.set_title(f"{title}: mean (line), min–max (band)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_atomic(path, buf.getvalue())

"""Does a robot's ``nees_rel`` depend on its start draw? (issue 42)

``nees_rel`` is meant to be free of the unobservable start offset e₀ ~ N(0, P0) (its share is
``start_nees`` = e₀ᵀP0⁻¹e₀ ~ χ²(3)). Over many robots, regress each robot's episode ``nees_rel``
on its ``start_nees``: the slope with its 95 % interval (ordinary least squares, and a
bootstrap over episodes, since the robots of one episode share its exchange), Spearman's rank
correlation, and the mean ``nees_rel`` by tercile of ``start_nees``.

Two designs:

* ``--paired K`` (default 0: off): every seed is run K times with the start offsets drawn
  again from an independent stream and everything else (layout, nominal starts, motion,
  sensor and channel noise streams) kept; the slope is estimated within seeds (seed fixed
  effects), which removes the between-seed spread of the noise realisations (``--redraw
  motion`` draws the odometry noise again instead, keeping the start offsets);
* else seeds ``--first-seed`` … as ``polyslam fidelity`` runs them (``--summary`` reads the
  robots of ``polyslam fidelity`` summaries instead of running episodes).

Usage::

    python scripts/nees_start_draw.py --map generator:warehouse --seeds 70 --steps 600 \\
        --workers 2 --out out/nees_start_draw.json
    python scripts/nees_start_draw.py --summary out/fidelity/summary.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

from polyslam_env.apps.jobs import run_jobs
from polyslam_env.apps.rollout import evaluate_episode
from polyslam_env.environment.config import EnvConfig

#: Bootstrap resamples of the episodes for the slope's interval.
BOOTSTRAP = 4000


def env_config(map_name: str, robots: int, steps: int, exchange: bool) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "map": map_name,
        "num_robots": robots,
        "max_steps": steps,
        "coverage_target": None,
        "initial_error": True,
    }
    if not exchange:
        fields["channel"] = None
    return EnvConfig.from_dict(fields).to_dict()


def _job(job: tuple[dict[str, Any], int, int | None, str]) -> list[dict[str, float]]:
    """One episode: per robot (nees_rel, start_nees, nees); ``draw`` not None replaces the
    episode's stream ``redraw`` (``start_error``: the start offsets; ``motion``: the
    odometry noise) by an independent one, (seed, draw), everything else as the seed has it."""
    config, seed, draw, redraw = job
    if draw is not None:
        from polyslam_env.core import seeding
        from polyslam_env.environment import parallel

        def make_rngs(episode_seed: int | None) -> dict[str, np.random.Generator]:
            rngs = seeding.make_rngs(episode_seed)
            rngs[redraw] = np.random.default_rng([seed, 7919, draw])
            return rngs

        parallel.make_rngs = make_rngs  # type: ignore[assignment]  # this worker only
    result = evaluate_episode(config, "frontier", {}, seed)
    return [
        {"seed": seed, "draw": -1 if draw is None else draw, "robot": agent,
         "nees_rel": m["nees_rel"], "start_nees": m["start_nees"], "nees": m["nees"]}
        for agent, m in result.robots.items()
    ]  # fmt: skip


def analyse(rows: list[dict[str, Any]], paired: bool, rng: np.random.Generator) -> dict[str, Any]:
    """Slope of nees_rel on start_nees (OLS; within seeds when ``paired``) with its 95 %
    intervals (t, and a bootstrap over episodes or seeds), Spearman's ρ, tercile means."""
    y = np.array([r["nees_rel"] for r in rows])
    x = np.array([r["start_nees"] for r in rows])
    group = np.array([r["seed"] for r in rows])
    episode = np.array([hash((r["seed"], r["draw"])) for r in rows])

    def slope(idx: np.ndarray) -> float:
        xs, ys = x[idx], y[idx]
        if paired:  # remove each seed's mean: the slope within seeds
            g = group[idx]
            for s in np.unique(g):
                m = g == s
                xs = np.where(m, xs - xs[m].mean(), xs)
                ys = np.where(m, ys - ys[m].mean(), ys)
        else:
            xs, ys = xs - xs.mean(), ys - ys.mean()
        return float((xs * ys).sum() / (xs * xs).sum())

    every = np.arange(len(rows))
    b = slope(every)
    if paired:
        xs = x - np.array([x[group == g].mean() for g in group])
        ys = y - np.array([y[group == g].mean() for g in group])
        dof = len(rows) - len(np.unique(group)) - 1
    else:
        xs, ys, dof = x - x.mean(), y - y.mean(), len(rows) - 2
    resid = ys - b * xs
    se = float(np.sqrt((resid**2).sum() / dof / (xs**2).sum()))
    t = float(scipy.stats.t.ppf(0.975, dof))
    clusters = np.unique(group if paired else episode)
    members = {c: np.flatnonzero((group if paired else episode) == c) for c in clusters}
    boot = []
    for _ in range(BOOTSTRAP):
        pick = rng.choice(clusters, size=len(clusters), replace=True)
        boot.append(slope(np.concatenate([members[c] for c in pick])))
    lo_b, hi_b = np.quantile(boot, [0.025, 0.975])
    rho, p_rho = scipy.stats.spearmanr(x, y)
    edges = np.quantile(x, [1 / 3, 2 / 3])
    tercile = np.digitize(x, edges)
    return {
        "robots": len(rows),
        "episodes": len(clusters) if not paired else len(np.unique(episode)),
        "design": "paired (within seeds)" if paired else "across seeds",
        "slope": b,
        "slope_ci_t": [b - t * se, b + t * se],
        "slope_ci_bootstrap": [float(lo_b), float(hi_b)],
        "spearman_rho": float(rho),
        "spearman_p": float(p_rho),
        "nees_rel_mean": float(y.mean()),
        "tercile_edges": edges.tolist(),
        "tercile_mean": [float(y[tercile == k].mean()) for k in range(3)],
        "tercile_sem": [
            float(y[tercile == k].std(ddof=1) / np.sqrt((tercile == k).sum())) for k in range(3)
        ],
    }


def rows_from_summaries(paths: list[str]) -> list[dict[str, Any]]:
    """The robots of ``polyslam fidelity`` summaries (every map and setting)."""
    rows = []
    for path in paths:
        data = json.loads(Path(path).read_text())
        for name, by_setting in data["episodes"].items():
            for setting, episodes in by_setting.items():
                for e in episodes:
                    for agent, m in e["robots"].items():
                        rows.append({"seed": hash((path, name, setting, e["seed"])), "draw": -1,
                                     "robot": agent, "nees_rel": m["nees_rel"],
                                     "start_nees": m["start_nees"], "nees": m["nees"]})  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", default="generator:warehouse")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seeds", type=int, default=70)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--no-exchange", action="store_true")
    parser.add_argument("--paired", type=int, default=0, help="draws per seed (0: off)")
    parser.add_argument(
        "--redraw",
        default="start_error",
        choices=("start_error", "motion", "sensor"),
        help="the stream --paired draws again (default: start_error, the start offsets)",
    )
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--summary", nargs="+", default=None, help="fidelity summary.json")
    parser.add_argument("--out", default=None, help="JSON of the rows and the analysis")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    if args.summary:
        rows = rows_from_summaries(args.summary)
    else:
        config = env_config(args.map, args.robots, args.steps, not args.no_exchange)
        seeds = range(args.first_seed, args.first_seed + args.seeds)
        draws: list[int | None] = list(range(args.paired)) if args.paired else [None]
        jobs = [(config, s, d, args.redraw) for s in seeds for d in draws]
        rows = [r for out in run_jobs(_job, jobs, args.workers) for r in out]
    result = analyse(rows, args.paired > 0, np.random.default_rng(0))
    result["elapsed_s"] = time.perf_counter() - start
    result["settings"] = vars(args)
    print(json.dumps({k: v for k, v in result.items() if k != "settings"}, indent=1))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({"analysis": result, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Python calls per SLAM step over the office-floor episode: steady steps and map changes.

The episode of ``polyslam benchmark --only floor`` (``generator:office_floor``, layout seed 9,
3 robots, the frontier team, exchange on); every ``PolySlam.step`` of steps ``--first`` + 1 …
``--last`` is profiled on its own (cProfile's count of the Python calls it made, a figure that
does not depend on the machine or its load). Prints the median, mean, 95th percentile and
maximum per SLAM step, per env step (all robots), and the same split into the steps that
changed the map (a landmark created, merged or linked) and the steady ones; with ``--top N``
also the functions most called in the map-change steps.

    python scripts/slam_calls.py --first 100 --last 400 --json calls.json
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
from collections import Counter
from typing import Any

import numpy as np

from policies.base import make_team
from polyslam_env.apps.benchmark_floor import FLOOR_SEED, floor_config
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.slam.robot import PolySlam


def _figures(calls: np.ndarray) -> dict[str, float]:
    if calls.size == 0:
        return {"steps": 0}
    return {
        "steps": int(calls.size),
        "median": float(np.median(calls)),
        "mean": float(calls.mean()),
        "p95": float(np.percentile(calls, 95)),
        "max": int(calls.max()),
    }


def measure(first: int, last: int, top: int = 0) -> dict[str, Any]:
    """Calls of every SLAM step of steps first + 1 … last, and what each step changed."""
    plain_step = PolySlam.step
    measuring = False
    calls: list[int] = []
    changed: list[bool] = []
    busiest: Counter[str] = Counter()

    def step(self: PolySlam, odometry: np.ndarray, ranges: np.ndarray) -> Any:
        if not measuring:
            return plain_step(self, odometry, ranges)
        profiler = cProfile.Profile()
        profiler.enable()
        info = plain_step(self, odometry, ranges)
        profiler.disable()
        stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
        calls.append(int(sum(row[1] for row in stats.values())))
        changed.append(bool(info.created or info.refit or info.merged or info.linked))
        if changed[-1] and top:
            for (path, line, name), row in stats.items():
                busiest[f"{path.split('polyslam_env/')[-1]}:{line} {name}"] += row[1]
        return info

    PolySlam.step = step  # type: ignore[method-assign]
    try:
        env = parallel_env(EnvConfig.from_dict(floor_config(last)))
        team = make_team("frontier", env)
        observations, _ = env.reset(seed=FLOOR_SEED)
        team.reset(FLOOR_SEED)
        rng = np.random.default_rng([FLOOR_SEED, 1])
        for k in range(1, last + 1):
            measuring = k > first
            observations, *_ = env.step(team.act(observations, rng))
        env.close()
    finally:
        PolySlam.step = plain_step  # type: ignore[method-assign]
    per_step, change = np.array(calls), np.array(changed, dtype=bool)
    return {
        "first": first,
        "last": last,
        "per_slam_step": _figures(per_step),
        "per_env_step": float(per_step.sum()) / (last - first),
        "map_change_steps": _figures(per_step[change]),
        "steady_steps": _figures(per_step[~change]),
        "map_change_share_of_calls": float(per_step[change].sum() / max(per_step.sum(), 1)),
        "busiest_in_map_changes": busiest.most_common(top),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, default=100, help="warm-up steps (not counted)")
    parser.add_argument("--last", type=int, default=400, help="last env step")
    parser.add_argument("--top", type=int, default=0, help="print the N most called functions")
    parser.add_argument("--json", help="also write the figures here")
    args = parser.parse_args(argv)
    if not 0 <= args.first < args.last:
        parser.error(f"--first must be in [0, --last), got {args.first} and {args.last}")
    out = measure(args.first, args.last, args.top)
    for name in ("per_slam_step", "map_change_steps", "steady_steps"):
        row = out[name]
        if row["steps"]:
            print(
                f"{name:17s} {row['steps']:5d} steps  median {row['median']:7.0f}  "
                f"mean {row['mean']:8.1f}  p95 {row['p95']:7.0f}  max {row['max']:6d}"
            )
    print(f"calls per env step (all robots' SLAM): {out['per_env_step']:.0f}; map changes "
          f"{100 * out['map_change_share_of_calls']:.0f} % of them")  # fmt: skip
    for name, count in out["busiest_in_map_changes"]:
        print(f"{count:8d}  {name}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

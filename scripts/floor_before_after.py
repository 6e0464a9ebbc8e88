"""The benchmark's office-floor episode from several source trees, for a before / after.

``polyslam benchmark --only floor`` exists only in trees that have the section; this runs the
same episode (``fidelity``'s exchange-on config of ``generator:office_floor``, layout seed 9,
3 robots, the frontier team; steps ``--first`` + 1 … ``--last`` measured) from each tree given
(``--tree``, each on ``PYTHONPATH`` in its own process, one after the other) and prints, per
tree, the mean env step and team act in ms and cProfile's Python calls per env step and per team
act (the machine-independent figure), and the team coverage at the end (equal in every tree
whose arithmetic is the same).

    python scripts/floor_before_after.py --tree /work/wt/envstep-base --tree .
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

#: The child: one timed and one profiled pass over the episode; prints one JSON line.
CHILD = """
import cProfile, json, pstats, sys, time
import numpy as np
from policies.base import make_team
from polyslam_env.apps.fidelity import FidelityConfig, episode_config
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env

first, last, seed = int(sys.argv[1]), int(sys.argv[2]), 9

def episode():
    config = FidelityConfig(maps=("office_floor",), robots=3, steps=last)
    env = parallel_env(EnvConfig.from_dict(episode_config(config, "office_floor", exchange=True)))
    team = make_team("frontier", env)
    observations, _ = env.reset(seed=seed)
    team.reset(seed)
    return env, team, observations, np.random.default_rng([seed, 1])

env, team, observations, rng = episode()
env_s, act_s = [], []
for k in range(1, last + 1):
    t0 = time.perf_counter()
    actions = team.act(observations, rng)
    t1 = time.perf_counter()
    observations, *_ = env.step(actions)
    t2 = time.perf_counter()
    if k > first:
        act_s.append(t1 - t0)
        env_s.append(t2 - t1)
coverage = float(env.episode.coverage.coverage)
env, team, observations, rng = episode()
env_p, act_p = cProfile.Profile(), cProfile.Profile()
for k in range(1, last + 1):
    on = k > first
    if on:
        act_p.enable()
    actions = team.act(observations, rng)
    if on:
        act_p.disable()
        env_p.enable()
    observations, *_ = env.step(actions)
    if on:
        env_p.disable()

def calls(profiler):
    return sum(row[1] for row in pstats.Stats(profiler).stats.values()) / (last - first)

print(json.dumps({"env_ms": 1e3 * float(np.mean(env_s)), "act_ms": 1e3 * float(np.mean(act_s)),
                  "env_calls": calls(env_p), "act_calls": calls(act_p), "coverage": coverage}))
"""


def run(tree: Path, first: int, last: int) -> dict[str, float]:
    """The episode's figures from ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "SDL_VIDEODRIVER": "dummy"}
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(first), str(last)],
        cwd=tree, env=env, check=True, capture_output=True, text=True,
    )  # fmt: skip
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", type=Path, action="append", required=True,
                        help="a source tree (repeat: the first is the reference)")  # fmt: skip
    parser.add_argument("--first", type=int, default=100, help="steps before the measured ones")
    parser.add_argument("--last", type=int, default=400, help="the last measured step")
    args = parser.parse_args(argv)
    if not 0 <= args.first < args.last:
        parser.error(f"--first/--last: expected 0 <= first < last, got {args.first}, {args.last}")
    print(f"{'tree':<32} {'env ms':>8} {'act ms':>8} {'env calls':>10} {'act calls':>10}"
          f" {'coverage':>9}")  # fmt: skip
    for tree in (t.resolve() for t in args.tree):
        print(f"{tree.name} ...", file=sys.stderr, flush=True)
        r = run(tree, args.first, args.last)
        print(f"{tree!s:<32} {r['env_ms']:>8.2f} {r['act_ms']:>8.2f} {r['env_calls']:>10.0f}"
              f" {r['act_calls']:>10.0f} {100 * r['coverage']:>8.2f}%")  # fmt: skip
    print(f"load: {os.getloadavg()[0]:.2f} (1-min average at the end)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

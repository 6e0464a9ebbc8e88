"""Training throughput of ``polyslam train --config configs/train_goals.yaml``, before and after.

Runs the shipped goal-choice training config cut to ``--timesteps`` robot decisions (no
checkpoints between, no final evaluation: a copy of the YAML in a temporary folder) from each
source tree given (``--tree``; each on ``PYTHONPATH`` in its own process), ``--repeats``
times each, interleaved (A, B, A, B, …) so that the machine's load hits every tree alike. Per
run: the wall time of the whole ``polyslam train`` process (worker start and PPO's updates
included), its env steps (robot decisions × ``decide_every`` / ``num_robots``; every decision
is ``decide_every`` env steps of the team) and env steps per second, and the CPU seconds of
the process and its workers per env step (``RUSAGE_CHILDREN``: less sensitive to the load than
the wall time), for the whole process and for its learning loop after the first rollout (what
``polyslam benchmark``'s train row gives: the fixed costs of a process, which a full run pays
once, left out; ``polyslam_env.apps.benchmark_system``). The table gives each tree's medians
and, for the later trees, the ratio of their median loop env steps per second to the first
tree's.

    python scripts/train_throughput.py --tree /work/wt/envstep-base --tree . --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from polyslam_env.apps.benchmark_system import train_in_tree


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", type=Path, action="append", required=True,
                        help="a source tree (repeat: the first is the reference)")  # fmt: skip
    parser.add_argument("--timesteps", type=int, default=2304, help="robot decisions per run")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--n-steps", type=int, help="PPO's decisions per slot and rollout (default: the config's)"
    )
    parser.add_argument("--out", type=Path, help="write the runs as JSON here")
    args = parser.parse_args(argv)
    trees = [t.resolve() for t in args.tree]
    runs: dict[str, list[dict[str, float]]] = {str(t): [] for t in trees}
    for k in range(args.repeats):
        for tree in trees:
            print(f"repeat {k + 1}/{args.repeats}: {tree}", file=sys.stderr, flush=True)
            runs[str(tree)].append(train_in_tree(tree, args.timesteps, n_steps=args.n_steps))
    first = None
    print(f"{'tree':<40} {'whole: env steps/s':>18} {'loop: env steps/s':>17}"
          f" {'CPU ms/env step':>15} {'× first':>8}")  # fmt: skip
    for tree in trees:
        whole = float(np.median([r["env_steps_per_s"] for r in runs[str(tree)]]))
        rate = float(np.median([r["steady"]["env_steps_per_s"] for r in runs[str(tree)]]))
        cpu = float(np.median([r["steady"]["cpu_ms_per_env_step"] for r in runs[str(tree)]]))
        first = rate if first is None else first
        print(f"{tree!s:<40} {whole:>18.2f} {rate:>17.2f} {cpu:>15.2f} {rate / first:>8.2f}")
    print(f"load: {os.getloadavg()[0]:.2f} (1-min average at the end)")
    if args.out is not None:
        args.out.write_text(json.dumps(runs, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

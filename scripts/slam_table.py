"""Single-robot SLAM along the paper's three paths: mean ± std over seeds, next to Table 1.

Each robot runs its own SLAM with the paper's parameters and no map exchange (the exchange
is issue 4's and ``polyslam reproduce``'s business). Usage::

    python scripts/slam_table.py --seeds 20 --workers 2 [--initial-error]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from polyslam_env.apps.simulate import simulate

PAPER = {  # Table 1 of the core paper: μ (their NEES form), ν (their form), τ
    "nees_paper": (1.66e-6, 4.66e-7, 1.02e-6),
    "nu": (0.17, 0.19, 0.34),
    "tau_s": (0.61, 0.66, 0.62),
}
KEYS = ("nees", "nees_paper", "nu", "nu_mean", "completeness", "hit_fraction", "slam_time_ms")


def run(args: tuple[int, bool]) -> list[dict[str, float]]:
    seed, initial_error = args
    return simulate("paper", seed=seed, initial_error=initial_error).metrics()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--initial-error",
        action="store_true",
        help="draw each robot's offset from its frame origin from P0 (consistency check)",
    )
    args = parser.parse_args()
    jobs = [(s, args.initial_error) for s in range(args.seeds)]
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(run, jobs))
    print(f"paper map, paper paths, {args.seeds} seeds, initial_error={args.initial_error}")
    print(f"{'metric':<16}" + "".join(f"{'r' + str(i + 1):>24}" for i in range(3)))
    for key in KEYS:
        cells = []
        for robot in range(3):
            v = np.array([r[robot][key] for r in results])
            cells.append(f"{np.mean(v):.3g} ± {np.std(v):.2g}")
        print(f"{key:<16}" + "".join(f"{c:>24}" for c in cells))
    ratio = [
        np.mean([r[i]["completeness"] / r[i]["hit_fraction"] for r in results]) for i in range(3)
    ]
    print(f"{'compl/hit':<16}" + "".join(f"{v:>24.3f}" for v in ratio))
    print("paper Table 1: " + ", ".join(f"{k} {v}" for k, v in PAPER.items()))


if __name__ == "__main__":
    main()

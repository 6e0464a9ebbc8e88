"""Env steps per second: 3 robots on the paper map with paper sensors, vector observations.

Two runs in one process: full SLAM (with map exchange), and ``slam_enabled=False`` (ground-truth
pose mode, the physics/sensing/observation floor). Random actions come from a seeded generator;
each figure is the median over repeats of a fixed number of steps after a reset.

    python scripts/bench_env.py [--steps 200] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

from polyslam_env.env import PolySlamParallelEnv, parallel_env


def steps_per_second(env: PolySlamParallelEnv, steps: int, seed: int) -> float:
    """Env steps per second over ``steps`` steps (resetting if the episode ends)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    high = np.array([env.config.world.robot.v_max, env.config.world.robot.omega_max])
    start = time.perf_counter()
    for _ in range(steps):
        if not env.agents:
            env.reset(seed=seed + 1)
        actions: dict[str, Any] = {a: rng.uniform(-high, high) for a in env.agents}
        env.step(actions)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    common = {"map": "paper", "num_robots": 3, "max_steps": 10_000}
    rows = []
    for label, extra in (("full SLAM", {}), ("slam_enabled=False", {"slam_enabled": False})):
        env = parallel_env(**common, **extra)
        rates = [steps_per_second(env, args.steps, seed) for seed in range(args.repeats)]
        rows.append((label, statistics.median(rates)))
    ref = rows[0][1]
    for label, rate in rows:
        print(f"{label:20s} {rate:8.1f} env steps/s  ({rate / ref:5.2f} × full SLAM)")


if __name__ == "__main__":
    main()

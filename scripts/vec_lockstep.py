"""Why the SB3 vectorised path gains less than 2× from two worker processes on two cores.

Two measurements on the benchmark's env (paper map, 3 robots, full SLAM, random actions):

1. **The lockstep ceiling.** Two env copies stepped one after the other in this process, each
   step timed: a vectorised step in one process costs the sum of the two, and with two perfect
   workers (no IPC, no slowdown) it would cost the slower of the two, since SB3 steps all envs
   together and waits for the last. mean(sum) / mean(max) is the most two workers can gain.
2. **Where the CPU goes.** The same vectorised env (``make_vec_env``, 2 envs) in one process
   and in 2 worker processes: wall rate, and CPU time per env step of the parent and of each
   worker (from /proc).

    python scripts/vec_lockstep.py --steps 400
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import polyslam_env
from polyslam_env.apps.benchmark_env import cpu_seconds as _cpu_seconds
from polyslam_env.apps.benchmark_harness import ENV_CONFIG
from polyslam_env.environment.vector import make_vec_env

WARMUP = 30


def lockstep(steps: int, seed: int) -> np.ndarray:  # (steps, 2) ms
    """Per-step wall time (ms) of two env copies stepped in turn."""
    envs = [polyslam_env.parallel_env(**ENV_CONFIG) for _ in range(2)]
    for k, env in enumerate(envs):
        env.reset(seed=seed + k)
    rng = np.random.default_rng(seed)
    space = envs[0].action_space(envs[0].possible_agents[0])
    times = []
    for step in range(WARMUP + steps):
        row = []
        for env in envs:
            if not env.agents:
                env.reset()
            actions = {a: rng.uniform(space.low, space.high).astype(np.float32) for a in env.agents}  # type: ignore[attr-defined]
            start = time.perf_counter()
            env.step(actions)
            row.append(time.perf_counter() - start)
        if step >= WARMUP:
            times.append(row)
    return np.array(times) * 1e3


def cpu_split(num_cpus: int, steps: int, seed: int) -> tuple[float, float, list[float]]:
    """Env steps/s, the parent's and each worker's CPU ms per env step of the team."""
    venv = make_vec_env(None, 2, num_cpus=num_cpus, seed=seed, monitor=False, **ENV_CONFIG)
    try:
        venv.reset()
        rng = np.random.default_rng(seed)
        shape = (venv.num_envs, *(venv.action_space.shape or ()))
        for _ in range(WARMUP):
            venv.step(rng.uniform(-1, 1, shape).astype(np.float32))
        workers = [p.pid for p in getattr(venv.unwrapped, "procs", [])]
        pids = [os.getpid(), *workers]
        before = [_cpu_seconds([p]) or 0.0 for p in pids]
        start = time.perf_counter()
        for _ in range(steps):
            venv.step(rng.uniform(-1, 1, shape).astype(np.float32))
        wall = time.perf_counter() - start
        after = [_cpu_seconds([p]) or 0.0 for p in pids]
    finally:
        venv.close()
    env_steps = 2 * steps
    ms = [1e3 * (b - a) / env_steps for a, b in zip(before, after, strict=True)]
    return env_steps / wall, ms[0], ms[1:]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    t = lockstep(args.steps, args.seed)
    total, slowest = t.sum(axis=1), t.max(axis=1)
    print(
        f"env step: mean {t.mean():.2f} ms, median {np.median(t):.2f}, 90th percentile"
        f" {np.percentile(t, 90):.2f}, max {t.max():.1f}"
    )
    print(
        f"lockstep: one process {total.mean():.2f} ms per vectorised step, two perfect workers"
        f" {slowest.mean():.2f} ms: ceiling {total.mean() / slowest.mean():.2f}×"
    )
    rates = {}
    for cpus in (0, 2):
        rate, parent, workers = cpu_split(cpus, args.steps, args.seed)
        rates[cpus] = rate
        split = ", ".join(f"{w:.2f}" for w in workers) or "none"
        print(
            f"{'2 worker processes' if cpus else 'one process':18s}: {rate:.0f} env steps/s;"
            f" CPU ms per env step: parent {parent:.2f}, workers {split}"
            f" (total {parent + sum(workers):.2f})"
        )
    print(f"2 processes / one: {rates[2] / rates[0]:.2f}×")


if __name__ == "__main__":
    main()

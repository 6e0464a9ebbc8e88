"""Python calls per env step, stage by stage: where the env's own calls go.

Runs the benchmark's office-floor episode (``--env floor``: ``fidelity``'s exchange-on config of
``generator:office_floor``, layout seed 9, 3 robots, the frontier team, as ``polyslam benchmark
--only floor``) or the benchmark's paper-map env with seeded uniform random actions (``--env
paper``, ``--env noslam`` for ``slam_enabled=False``), and counts cProfile's Python calls of
each stage of :meth:`~polyslam_env.environment.parallel.PolySlamParallelEnv.step` (the
functions of :mod:`~polyslam_env.environment.stages` and the estimates and rewards it calls)
with one profiler per stage, over steps ``--first`` + 1 … ``--last``. The count does not depend
on the machine or its load; run it from two trees (``PYTHONPATH``) for a before / after.

    python scripts/env_stage_calls.py --env floor --first 100 --last 400
"""

from __future__ import annotations

import argparse
import cProfile
from collections.abc import Callable
from typing import Any

import numpy as np

from polyslam_env.apps import benchmark_floor
from polyslam_env.apps.benchmark_harness import ENV_CONFIG
from polyslam_env.environment import parallel, stages
from polyslam_env.environment.parallel import parallel_env

#: The stages counted: (module, name), in the order the env step runs them.
STAGES = [(stages, name) for name in (
    "simulate", "inject_faults", "sense", "slam", "exchange", "record_histories", "observe",
    "sweep_coverage", "map_bookkeeping", "fail_robots", "done", "infos",
)] + [(parallel, name) for name in ("estimates", "reward_terms", "combine")]  # fmt: skip


def _stepper(env_name: str, last: int) -> tuple[Any, Callable[[], Any], Callable[[Any], None]]:
    """The env (after its seeded reset), the step's actions (the frontier team's act on the
    floor, not counted) and one env step on them."""
    if env_name == "floor":
        env, team, observations, rng = benchmark_floor._episode(last, benchmark_floor.FLOOR_SEED)
        box = [observations]

        def floor_step(actions: Any) -> None:
            box[0], *_ = env.step(actions)

        return env, lambda: team.act(box[0], rng), floor_step
    env = parallel_env(**{**ENV_CONFIG, "slam_enabled": env_name == "paper"})
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    space: Any = env.action_space(env.possible_agents[0])  # a Box

    def random_actions() -> dict[str, np.ndarray]:
        if not env.agents:
            env.reset()
        return {a: rng.uniform(space.low, space.high) for a in env.agents}

    def random_step(actions: Any) -> None:
        env.step(actions)

    return env, random_actions, random_step


def stage_calls(env_name: str, first: int, last: int) -> dict[str, float]:
    """Python calls per env step of each stage (and ``step`` for the env step's own), steps
    ``first + 1 … last``."""
    if not 0 <= first < last:
        raise SystemExit(f"--first/--last: expected 0 <= first < last, got {first}, {last}")
    env, act, step = _stepper(env_name, last)
    outer = cProfile.Profile()
    inner = {name: cProfile.Profile() for _, name in STAGES}
    originals = [(module, name, getattr(module, name)) for module, name in STAGES]
    try:
        for k in range(1, last + 1):
            if k == first + 1:
                for module, name, function in originals:
                    switched = benchmark_floor._switched(function, inner[name], outer)
                    setattr(module, name, switched)
            actions = act()
            if k > first:
                outer.enable()
            step(actions)
            outer.disable()
    finally:
        for module, name, function in originals:
            setattr(module, name, function)
    env.close()
    n = last - first
    counts = {"step": benchmark_floor._calls(outer) / n}
    counts |= {name: benchmark_floor._calls(p) / n for name, p in inner.items()}
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", choices=("floor", "paper", "noslam"), default="floor")
    parser.add_argument("--first", type=int, default=100, help="steps before the counted ones")
    parser.add_argument("--last", type=int, default=400, help="the last step counted")
    args = parser.parse_args()
    counts = stage_calls(args.env, args.first, args.last)
    for name, calls in counts.items():
        print(f"{name:18s} {calls:9.1f}")
    print(f"{'total':18s} {sum(counts.values()):9.1f}  Python calls per env step")


if __name__ == "__main__":
    main()

"""The frontier team's act on the office floor: ms, MPE steps and Python calls per team act.

The episode of issue 41, as ``polyslam benchmark``'s ``floor`` section and ``polyslam fidelity``
play it: the office floor (``generator:office_floor``), 3 robots, seed 9, the exchange on and the
initial error where supported (:func:`polyslam_env.apps.fidelity.episode_config`), a frontier
team drawing from ``default_rng([seed, 1])`` as :func:`~polyslam_env.apps.rollout.run_episode`
seeds it (``--policy`` for another: a registered name or ``module:factory``, e.g.
``policies.goals:GoalPolicy``, the goal-choice policy's loop driving to its frontier goal).
Steps 0 … ``first`` − 1 are played untimed (numba compiles, maps fill), then the team's act (the
three robots' ``act`` calls of one env step) is measured on steps ``first`` … ``last`` − 1:

* ``act_ms``: wall time per team act (mean: planning steps are the costly ones, and the mean is
  what a run pays; median and maximum beside it);
* ``mpe_steps_per_act``: that mean over the step time of PettingZoo MPE ``simple_spread`` (3
  agents, random actions, reset when done, as the benchmark's reference section steps it),
  whose steps are interleaved with the acts (:data:`MPE_PER_ACT` after each act), so that
  both see the same load on a busy machine;
* ``act_cpu_ms``, ``mpe_steps_per_act_cpu``: the same in CPU time (``time.process_time``) of
  this process, which other processes disturb less than wall time;
* ``actions_sha256``: a digest of all the episode's actions (the same in two trees: the same
  decisions);
* ``calls_per_act``: cProfile's total call count (primitive and recursive) of the team acts,
  over the steps, in a second, profiled play of the same episode (machine-independent).

:func:`measure_team_act` returns the figures as a dict (for the benchmark's ``floor`` section);
run as a script it prints them (``--json PATH`` writes them too). ``--compare TREE`` runs the
same measurement on another checkout first (in a child process with that tree first on
``PYTHONPATH``) and prints both, e.g. before/after on one machine in one run::

    PYTHONPATH=. python scripts/bench_team_act.py --compare /work/wt/frontier-base
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import json
import os
import pstats
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

#: The episode: issue 41's office-floor frontier episode (module doc).
MAP, ROBOTS, SEED, FIRST, LAST = "office_floor", 3, 9, 100, 400
#: MPE steps timed after each team act.
MPE_PER_ACT = 5


def _mpe_stepper(seed: int = 0) -> Callable[[], None] | None:
    """One MPE ``simple_spread`` step (3 agents, random actions) per call; None without mpe2."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return None
    env = simple_spread_v3.parallel_env(N=3)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)

    def step() -> None:  # as the benchmark's reference section steps it
        if not env.agents:
            env.reset()
        env.step({a: int(rng.integers(env.action_space(a).n)) for a in env.agents})

    for _ in range(20):
        step()
    return step


def _play(
    policy: str,
    seed: int,
    first: int,
    last: int,
    profiler: cProfile.Profile | None = None,
    mpe: Callable[[], None] | None = None,
) -> tuple[np.ndarray, str]:
    """Play the episode; per team act of steps ``first`` … ``last`` − 1 (profiled by
    ``profiler`` when given): its wall and CPU seconds, then those of :data:`MPE_PER_ACT`
    steps of ``mpe`` run right after it (zero without), (T, 4); and a digest of every action
    of the episode (two trees that take the same decisions give the same digest)."""
    from policies.base import POLICIES, make_team
    from polyslam_env.apps.fidelity import FidelityConfig, episode_config
    from polyslam_env.environment.config import EnvConfig
    from polyslam_env.environment.parallel import parallel_env

    config = FidelityConfig(maps=(MAP,), robots=ROBOTS, steps=last)
    env = parallel_env(EnvConfig.from_dict(episode_config(config, MAP, exchange=True)))
    if ":" in policy:  # module:factory, e.g. policies.goals:GoalPolicy
        POLICIES.setdefault(policy, policy)
    team = make_team(policy, env)
    obs, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = np.random.default_rng([seed, 1])
    rows = []
    digest = hashlib.sha256()
    for step in range(last):
        if not env.agents:
            break
        timed = step >= first
        if timed and profiler is not None:
            profiler.enable()
        wall, cpu = time.perf_counter(), time.process_time()
        actions = team.act(obs, rng)
        act = (time.perf_counter() - wall, time.process_time() - cpu)
        if timed and profiler is not None:
            profiler.disable()
        if timed:
            wall, cpu = time.perf_counter(), time.process_time()
            for _ in range(MPE_PER_ACT if mpe is not None else 0):
                mpe()  # type: ignore[misc]
            rows.append((*act, time.perf_counter() - wall, time.process_time() - cpu))
        for agent in sorted(actions):
            digest.update(np.asarray(actions[agent]).tobytes())
        obs, *_ = env.step(actions)
    env.close()
    return np.array(rows).reshape(-1, 4), digest.hexdigest()[:16]


def measure_team_act(
    policy: str = "frontier", seed: int = SEED, first: int = FIRST, last: int = LAST
) -> dict[str, Any]:
    """Act time (ms, and in MPE ``simple_spread`` steps measured alongside) and Python calls
    per team act on the office-floor episode (module doc)."""
    _play(policy, seed, 0, min(first, last))  # compile the kernels first
    mpe = _mpe_stepper()
    times, actions = _play(policy, seed, first, last, mpe=mpe)  # (T, 4) s
    profiler = cProfile.Profile()
    steps = len(_play(policy, seed, first, last, profiler)[0])
    calls = pstats.Stats(profiler).total_calls  # type: ignore[attr-defined]
    act, act_cpu = 1e3 * times[:, 0], 1e3 * times[:, 1].mean()
    mpe_ms = 1e3 * times[:, 2].sum() / (len(times) * MPE_PER_ACT) if mpe else float("nan")
    mpe_cpu = 1e3 * times[:, 3].sum() / (len(times) * MPE_PER_ACT) if mpe else float("nan")
    return {
        "policy": policy,
        "episode": {
            "map": f"generator:{MAP}",
            "robots": ROBOTS,
            "seed": seed,
            "steps": [first, last],
        },
        "steps": len(times),
        "act_ms": {
            "mean": float(act.mean()),
            "median": float(np.median(act)),
            "max": float(act.max()),
        },
        "mpe_step_ms": mpe_ms,
        "mpe_steps_per_act": float(act.mean()) / mpe_ms,
        "act_cpu_ms": act_cpu,
        "mpe_step_cpu_ms": mpe_cpu,
        "mpe_steps_per_act_cpu": act_cpu / mpe_cpu,
        "calls_per_act": calls / max(steps, 1),
        "actions_sha256": actions,
        "load": os.getloadavg()[0],
    }


def _line(tree: str, r: dict[str, Any]) -> str:
    a = r["act_ms"]
    return (
        f"{tree:<24} act {a['mean']:6.2f} ms (median {a['median']:5.2f}, max {a['max']:6.1f})"
        f" = {r['mpe_steps_per_act']:5.1f} MPE steps (MPE {r['mpe_step_ms']:.3f} ms);"
        f" CPU {r['act_cpu_ms']:5.2f} ms = {r['mpe_steps_per_act_cpu']:5.1f} MPE steps;"
        f" {r['calls_per_act']:6.0f} calls/act; actions {r['actions_sha256']};"
        f" load {r['load']:.1f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", default="frontier")
    parser.add_argument("--compare", metavar="TREE", help="measure this checkout first")
    parser.add_argument("--json", metavar="PATH", help="write the figures here")
    parser.add_argument(
        "--steps", nargs=2, type=int, default=(FIRST, LAST), metavar=("FIRST", "LAST"),
        help=f"measure steps FIRST … LAST − 1 (default {FIRST} {LAST})",
    )  # fmt: skip
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    first, last = args.steps
    if not 0 <= first < last:
        parser.error(f"--steps: need 0 <= FIRST < LAST, got {first} {last}")
    results: dict[str, Any] = {}
    if args.compare:
        env = {**os.environ, "PYTHONPATH": os.path.abspath(args.compare)}
        cmd = [sys.executable, os.path.abspath(__file__), "--child", "--policy", args.policy,
               "--steps", str(first), str(last)]  # fmt: skip
        out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
        results[args.compare] = json.loads(out.strip().splitlines()[-1])
    here = measure_team_act(args.policy, first=first, last=last)
    if args.child:
        print(json.dumps(here))
        return
    results["this tree"] = here
    for tree, r in results.items():
        print(_line(tree, r))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()

"""The benchmark's env figures: env steps per second, each row next to a reference timed in the
same run.

* :func:`bench_env`: env steps per second (3 robots on the paper map, paper sensors, vector
  observations, no rendering), with full SLAM or with ``slam_enabled=False``;
* :func:`bench_vec`: the same config through the SuperSuit / SB3 vectorised path
  (:func:`polyslam_env.environment.vector.make_vec_env`, 2 envs in this process, then in 2
  worker processes);
* :func:`bench_backends`: env steps/s of every ``slam.backend`` on the pillar hall (3 robots,
  pillar sensor on), next to the same env without SLAM;
* :func:`bench_mpe`: PettingZoo MPE ``simple_spread`` (3 agents) through the same harness, when
  ``mpe2`` is installed (the ``bench`` extra): the reference of every ratio to MPE.

Env runs include the resets that happen when episodes end (as in training). Actions come from
seeded generators.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.benchmark_harness import (
    ENV_CONFIG,
    Plan,
    Stats,
    parallel_stepper,
    random_stepper,
    rate,
    rate_rounds,
    rate_samples,
    ratio,
)

__all__ = [
    "BACKEND_ENV",
    "bench_backends",
    "bench_env",
    "bench_env_turns",
    "bench_mpe",
    "bench_vec",
    "cpu_seconds",
    "parallel_speedup",
]


def bench_env(plan: Plan, seed: int = 0, **overrides: Any) -> dict[str, Any]:
    """Env steps/s of the issue-8 config (plus ``overrides``), uniform random actions."""
    step, close = env_stepper(seed, **overrides)
    steps_per_s = rate_samples(step, plan.env_steps, plan.repeats, warmup=ENV_WARMUP)
    close()
    return {"installed": True, "steps_per_s": steps_per_s.to_dict()}


ENV_WARMUP, MPE_WARMUP = 5, 20  # untimed steps before an env's or MPE's samples


def env_stepper(seed: int, **overrides: Any) -> tuple[Callable[[], None], Callable[[], None]]:
    """A seeded random stepper over the issue-8 config (plus ``overrides``), and its close."""
    from polyslam_env.environment.parallel import parallel_env

    env = parallel_env(**{**ENV_CONFIG, **overrides})
    return random_stepper(env, seed), env.close


def bench_env_turns(plan: Plan, seed: int = 0) -> dict[str, dict[str, Any]]:
    """MPE's, the full-SLAM env's and the no-SLAM env's steps/s timed in turns
    (:func:`~polyslam_env.apps.benchmark_harness.rate_rounds`, ``plan.repeats`` rounds): the
    rows ``reference``, ``full_slam`` and ``no_slam``. Each env row carries ``ratio_to_mpe``
    (its median over MPE's) and ``ratio_to_mpe_rounds`` (the ratio round by round: each round's
    blocks ran within a second or two of each other). Without ``mpe2`` the reference row says
    not installed and the env rows carry no ratio."""
    mpe = mpe_stepper(seed)
    full, close_full = env_stepper(seed)
    nos, close_nos = env_stepper(seed, slam_enabled=False)
    steppers, steps, warmups = [full, nos], [plan.env_steps] * 2, [ENV_WARMUP] * 2
    if mpe is not None:  # MPE first in every round
        steppers, steps = [mpe[0], *steppers], [plan.mpe_steps, *steps]
        warmups = [MPE_WARMUP, *warmups]
    samples = rate_rounds(steppers, steps, plan.repeats, warmups)
    close_full()
    close_nos()
    out: dict[str, dict[str, Any]] = {"reference": {"installed": False, "name": MPE_NAME}}
    if mpe is not None:
        mpe[1]()
        mpe_rate = Stats.of(samples[0]).to_dict()
        out["reference"] = {"installed": True, "name": MPE_NAME, "steps_per_s": mpe_rate}
    for label, row_samples in zip(("full_slam", "no_slam"), samples[-2:], strict=True):
        row: dict[str, Any] = {"installed": True, "steps_per_s": Stats.of(row_samples).to_dict()}
        row["ratio_to_mpe"] = ratio(rate(row), rate(out["reference"]))
        if mpe is not None:
            rounds = [a / b for a, b in zip(row_samples, samples[0], strict=True)]
            row["ratio_to_mpe_rounds"] = Stats.of(rounds).to_dict()
        out[label] = row
    return out


#: The env of the back-end rows: 3 robots on the pillar hall with the pillar sensor on.
BACKEND_ENV: dict[str, Any] = {
    **ENV_CONFIG,
    "map": "generator:pillar_hall",
    "world__pillar_sensor__enabled": True,
}


def bench_backends(plan: Plan, seed: int = 0) -> list[dict[str, Any]]:
    """Env steps/s of every ``slam.backend`` on :data:`BACKEND_ENV` (the polynomial EKF with
    its map exchange, the point back-ends as the env runs them: MBLCC with its consensus over a
    25 m radio and known starts, the shared-map filter with known starts), each with
    ``ratio_to_no_slam``, its rate over the same env with ``slam_enabled=False`` timed first in
    the same run."""
    from polyslam_env.slam.config import BACKENDS

    reference = bench_env(plan, seed, **BACKEND_ENV, slam_enabled=False)
    rows = [{"backend": "none (slam_enabled=False)", **reference, "ratio_to_no_slam": 1.0}]
    for backend in BACKENDS:
        extra: dict[str, Any] = {"slam__backend": backend}
        if backend == "mblcc":
            extra.update(initial_error=False, channel__range=25.0)
        if backend == "multirobot_known_start":
            extra.update(initial_error=False)
        row = {"backend": backend, **bench_env(plan, seed, **BACKEND_ENV, **extra)}
        row["ratio_to_no_slam"] = ratio(rate(row), rate(reference))
        rows.append(row)
    return rows


def bench_vec(plan: Plan, seed: int = 0, num_envs: int = 2, num_cpus: int = 2) -> dict[str, Any]:
    """Env steps/s through :func:`make_vec_env` with ``num_envs`` envs, in ``num_cpus`` worker
    processes (0 or 1: all in this process), and the CPU time per env step of this process and
    its workers together (``cpu_ms_per_env_step``; None where /proc is missing).

    One vectorised step advances every env by one step, so it counts ``num_envs`` env steps.
    On a loaded machine the rate of two processes says how many cores were free; the CPU time
    says whether the path itself does more work per env step with workers than without.
    """
    try:
        from polyslam_env.environment.vector import make_vec_env
    except ImportError as err:  # the rl extra (supersuit, stable-baselines3) is missing
        return {"installed": False, "error": str(err)}
    venv = make_vec_env(None, num_envs, num_cpus=num_cpus, seed=seed, monitor=False, **ENV_CONFIG)
    try:
        rng = np.random.default_rng(seed)
        venv.reset()
        shape = (venv.num_envs, *(venv.action_space.shape or ()))  # slots = envs · robots

        def step() -> None:
            venv.step(rng.uniform(-1.0, 1.0, shape).astype(np.float32))

        for _ in range(3):
            step()
        pids = [os.getpid(), *(p.pid for p in getattr(venv.unwrapped, "procs", []))]
        cpu_before = cpu_seconds(pids)
        steps_per_s = rate_samples(step, plan.vec_steps, plan.repeats)
        cpu_after = cpu_seconds(pids)
    finally:
        venv.close()
    processes = num_cpus if min(num_cpus, num_envs) >= 2 else 1
    env_steps = plan.vec_steps * plan.repeats * num_envs
    row = {
        "installed": True,
        "num_envs": num_envs,
        "processes": min(processes, num_envs),
        "steps_per_s": steps_per_s.scaled(num_envs).to_dict(),
        "cpu_ms_per_env_step": None
        if cpu_before is None or cpu_after is None
        else 1e3 * (cpu_after - cpu_before) / env_steps,
    }
    if processes > 1:
        row["machine_speedup"] = parallel_speedup(processes)
    return row


def cpu_seconds(pids: Iterable[int]) -> float | None:
    """User + system CPU seconds so far of the processes ``pids`` (all their threads), from
    /proc (None where there is none)."""
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    total = 0.0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            return None
        total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return total


def _small_numpy_work(n: int) -> float:
    """Seconds for ``n`` numpy operations on 5-element arrays: the env step's kind of work."""
    start = time.perf_counter()
    a = np.zeros(5)
    for _ in range(n):
        a = a + 1.0
    return time.perf_counter() - start


def parallel_speedup(processes: int = 2, n: int = 200_000) -> float:
    """How much faster ``processes`` copies of small-array numpy work finish side by side than
    one after another, in fresh processes (ideal: ``processes``). The vectorised env can gain
    no more than this: on a VM whose vCPUs share a physical core, numpy-heavy processes slow
    each other down even when pure Python ones do not."""
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        pool.map(_small_numpy_work, [1000] * processes)  # start-up, imports
        alone = sum(pool.apply(_small_numpy_work, (n,)) for _ in range(processes))
        start = time.perf_counter()
        pool.map(_small_numpy_work, [n] * processes, chunksize=1)
        together = time.perf_counter() - start
    return alone / together


MPE_NAME = "mpe2 simple_spread_v3"


def mpe_stepper(seed: int) -> tuple[Callable[[], None], Callable[[], None]] | None:
    """A seeded random stepper over MPE ``simple_spread`` (3 agents, defaults) and its close;
    None when ``mpe2`` is not installed."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return None
    env = simple_spread_v3.parallel_env(N=3)
    rng = np.random.default_rng(seed)
    step = parallel_stepper(env, lambda e, a: int(rng.integers(e.action_space(a).n)), seed)
    return step, env.close


def bench_mpe(plan: Plan, seed: int = 0) -> dict[str, Any]:
    """PettingZoo MPE ``simple_spread`` (3 agents, defaults) through the same harness."""
    mpe = mpe_stepper(seed)
    if mpe is None:
        return {"installed": False, "name": MPE_NAME}
    steps_per_s = rate_samples(mpe[0], plan.mpe_steps, plan.repeats, warmup=MPE_WARMUP)
    mpe[1]()
    return {"installed": True, "name": MPE_NAME, "steps_per_s": steps_per_s.to_dict()}

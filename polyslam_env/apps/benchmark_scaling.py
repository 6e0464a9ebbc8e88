"""The benchmark's system figures: processes, team size, memory, compile cost, the profile.

Each runs the full-SLAM env of :data:`~polyslam_env.apps.benchmark_harness.ENV_CONFIG` (3
robots, paper map, vector observations) unless it says otherwise, with seeded uniform random
actions:

* :func:`bench_workers`: ``N`` processes, each stepping its own env, started together; env
  steps/s per process, their total, and the total over the one-process figure of the same run;
* :func:`bench_team`: ms per env step with ``n`` robots on a generated map (``generator:rooms``,
  exchange on, no coverage end, so every run lasts the horizon), and each size over the first;
* :func:`bench_memory`: peak and current RSS of one env in a fresh process after each of several
  episodes (flat when nothing accumulates across resets);
* :func:`bench_compile`: seconds to import the package and take the first env reset and step in
  a fresh process with an empty numba cache (kernels compile), then again with that cache warm;
  the difference is the first-use compile cost, whatever kernels exist;
* :func:`profile_env`: cProfile's top functions of the env step by own and cumulative time,
  each as a percentage of the profiled step time.

Fresh processes start with ``spawn``, so nothing measured in them is inherited from the parent.
"""

from __future__ import annotations

import contextlib
import cProfile
import os
import pstats
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.benchmark_harness import (
    ENV_CONFIG,
    interleaved_calls,
    profiling,
    random_stepper,
)

__all__ = [
    "TEAM_CONFIG",
    "bench_compile",
    "bench_memory",
    "bench_team",
    "bench_workers",
    "profile_env",
]

#: The team-size env: a generated rooms map (new layout per reset), exchange on (the default
#: channel), no coverage target, so every run lasts its horizon whatever the team covers.
TEAM_CONFIG: dict[str, Any] = {
    "map": "generator:rooms",
    "observation__mode": "vector",
    "coverage_target": None,
}


def _env_config() -> dict[str, Any]:
    return dict(ENV_CONFIG)


# -- processes ------------------------------------------------------------------------------
def _worker_rates(args: tuple[dict[str, Any], int, int, int, Any]) -> list[float]:
    """In a worker: env steps/s samples of its own env, timed after every worker is ready."""
    from threadpoolctl import threadpool_limits

    from polyslam_env.environment.parallel import parallel_env

    config, steps, repeats, seed, barrier = args
    threadpool_limits(1, user_api="blas")  # as the vectorised path's workers
    step = random_stepper(parallel_env(**config), seed)
    for _ in range(5):
        step()
    barrier.wait()
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            step()
        rates.append(steps / (time.perf_counter() - start))
    return rates


def bench_workers(
    counts: Sequence[int], steps: int, repeats: int, seed: int = 0
) -> list[dict[str, Any]]:
    """Env steps/s with ``n`` processes for each ``n`` in ``counts``: per process (median of
    each one's samples, then the median over processes), total (sum of the processes'
    medians), and the total over the one-process total of this run (None without n = 1).
    Each process steps its own env (seed + its index) with one BLAS thread."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    config = _env_config()
    rows: list[dict[str, Any]] = []
    for n in counts:
        with ctx.Manager() as manager, ctx.Pool(n) as pool:
            barrier = manager.Barrier(n)
            jobs = [(config, steps, repeats, seed + k, barrier) for k in range(n)]
            samples = pool.map(_worker_rates, jobs, chunksize=1)
        medians = [float(np.median(s)) for s in samples]
        rows.append(
            {"processes": n, "per_process": float(np.median(medians)), "total": sum(medians)}
        )
    alone = next((r["total"] for r in rows if r["processes"] == 1), None)
    for r in rows:
        r["ratio_to_one"] = None if alone is None else r["total"] / alone
    return rows


# -- team size --------------------------------------------------------------------------------
TEAM_WINDOWS = 15  # turns the team sizes' episodes take (bench_team)


def bench_team(sizes: Sequence[int], steps: int, seed: int = 0) -> list[dict[str, Any]]:
    """ms per env step with each team size over ``steps`` steps from a seeded reset (the cost
    grows as maps fill and robots meet, so the figure is the mean over the whole horizon, next
    to the median step), and the ratio of each mean to the first size's. ``messages`` and
    ``polynomials`` count what the exchange applied (in the last episode): integrating them is
    the part of the step that grows with the number of meetings, not with the team size;
    ``skipped`` of those polynomials were versions their receiver held (no transform, no
    refit), ``covered`` were wholly covered by better walls the receiver held (no refit),
    ``refits`` counts the received chains refitted.

    The sizes' episodes are played in turns (``benchmark_harness.interleaved_calls``, up to
    :data:`TEAM_WINDOWS` rounds): each makes the same steps as alone, but a slow spell of the
    machine falls on every size alike instead of on the 3-robot episode's fraction of a second
    or not at all, which moved the ratio by a third from run to run.

    The first size's episode is played once untimed before the timed runs (kernels load from
    numba's cache on their first call in a process, up to ~0.3 s in all); the load of a kernel
    only a larger team reaches is left out of its call's time like any other
    (``benchmark_harness.net_seconds``)."""
    from polyslam_env.environment.parallel import parallel_env

    if sizes:
        env = parallel_env(**TEAM_CONFIG, num_robots=sizes[0])
        step = random_stepper(env, seed)
        for _ in range(steps):
            step()
        env.close()
    envs = [parallel_env(**TEAM_CONFIG, num_robots=n) for n in sizes]
    steppers = [random_stepper(env, seed) for env in envs]
    samples = interleaved_calls(steppers, steps, min(TEAM_WINDOWS, max(steps, 1)))
    rows = []
    for n, env, times in zip(sizes, envs, samples, strict=True):
        exchange = env.episode.exchange if env.episode is not None else None
        history = exchange.history if exchange is not None else []
        env.close()
        rows.append(
            {
                "robots": n,
                "steps": steps,
                "mean_ms": 1e3 * float(np.mean(times)),
                "median_ms": 1e3 * float(np.median(times)),
                "max_ms": 1e3 * float(np.max(times)),
                "messages": len(history),  # applied in the last episode
                "polynomials": sum(d.n_polynomials for d in history),
                # of those, skipped as versions held; received chains refitted
                "skipped": sum(exchange.skipped) if exchange is not None else 0,
                "refits": sum(exchange.refits) if exchange is not None else 0,
                # of the others, covered wholly by better held walls: no refit (rule 1)
                "covered": sum(exchange.covered) if exchange is not None else 0,
            }
        )
    for r in rows:
        r["ratio_to_first"] = r["mean_ms"] / rows[0]["mean_ms"]
    return rows


# -- memory -----------------------------------------------------------------------------------
def _proc_status_mb(field: str) -> float | None:
    """A memory figure of this process from /proc/self/status (MB; None where there is none)."""
    try:
        lines = Path("/proc/self/status").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024 / 1e6  # kB
    return None


def _rss_mb() -> float | None:
    """This process's resident set size now (MB)."""
    return _proc_status_mb("VmRSS")


def _peak_rss_mb() -> float:
    """This process's peak resident set size so far (MB): VmHWM, the high-water mark of its
    own memory; where there is no /proc, ``ru_maxrss``, which on Linux would also count the
    parent's memory at the fork before ``spawn`` exec'd this interpreter."""
    peak = _proc_status_mb("VmHWM")
    if peak is not None:
        return peak
    import resource

    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return maxrss / 1e6 if sys.platform == "darwin" else maxrss * 1024 / 1e6  # bytes / KiB


def _memory_episodes(args: tuple[dict[str, Any], int, int, int]) -> list[dict[str, Any]]:
    """In a fresh process: RSS after each of ``episodes`` episodes of ``steps`` steps."""
    from polyslam_env.environment.parallel import parallel_env

    config, episodes, steps, seed = args
    env = parallel_env(**config, max_steps=steps, coverage_target=None)
    step = random_stepper(env, seed)
    rows = []
    for e in range(episodes):
        env.reset(seed=seed + e)
        taken = 0
        while env.agents:
            step()
            taken += 1
        rows.append(
            {"episode": e + 1, "steps": taken, "peak_mb": _peak_rss_mb(), "rss_mb": _rss_mb()}
        )
    env.close()
    return rows


def bench_memory(episodes: int, steps: int, seed: int = 0) -> dict[str, Any]:
    """Peak and current RSS of one env (3 robots, full SLAM) in a fresh process after each of
    ``episodes`` episodes of ``steps`` steps, and the growth of the peak from the first
    episode's end to the last's (MB; ~0 when memory is flat over episodes)."""
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(1) as pool:
        rows = pool.apply(_memory_episodes, ((_env_config(), episodes, steps, seed),))
    return {
        "robots": _env_config()["num_robots"],
        "episodes": rows,
        "total_steps": sum(r["steps"] for r in rows),
        "peak_mb": max(r["peak_mb"] for r in rows),
        "growth_mb": rows[-1]["peak_mb"] - rows[0]["peak_mb"],
    }


# -- compile cost -----------------------------------------------------------------------------
_FIRST_STEP = """
import time
start = time.perf_counter()
import numpy as np
from polyslam_env.environment.parallel import parallel_env
env = parallel_env(**{config!r})
env.reset(seed=0)
space = env.action_space(env.possible_agents[0])
env.step({{a: np.zeros(space.shape, dtype=space.dtype) for a in env.agents}})
print(time.perf_counter() - start)
"""


def _first_step_seconds(cache_dir: str, config: dict[str, Any]) -> float:
    """Seconds a fresh interpreter takes to import the env and take its first reset and step,
    with numba's cache in ``cache_dir``."""
    env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
    root = str(Path(__file__).resolve().parents[2])  # this checkout's package first
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    out = subprocess.run(
        [sys.executable, "-c", _FIRST_STEP.format(config=config)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return float(out.stdout.strip().splitlines()[-1])


def bench_compile(repeats: int = 1, slam: bool = True) -> dict[str, Any]:
    """Import + first env reset + first step in a fresh process with an empty numba cache
    (``cold``: every kernel the step uses compiles) and then with that cache filled (``warm``:
    kernels load from disk), in seconds (the warm figure is the median of ``repeats``); the
    compile cost is their difference. ``cached_files`` counts numba's index files left in the
    cache (one per cached kernel's source file and function). ``slam=False`` times the env
    without SLAM (``slam_enabled`` in the result says which)."""
    config = {**_env_config(), "slam_enabled": slam}
    with tempfile.TemporaryDirectory(prefix="polyslam-numba-bench-") as cache:
        cold = _first_step_seconds(cache, config)
        warm = [_first_step_seconds(cache, config) for _ in range(max(repeats, 1))]
        index = sorted(Path(cache).rglob("*.nbi"))
    warm_s = float(np.median(warm))
    return {
        "cold_s": cold,
        "warm_s": warm_s,
        "compile_s": cold - warm_s,
        "cached_files": len(index),
        "slam_enabled": slam,
    }


# -- profile ----------------------------------------------------------------------------------
#: Unprofiled env steps before the profile: kernels first used later (landmark creation,
#: merging) would otherwise be loaded from numba's cache inside it.
PROFILE_WARMUP = 60


def profile_env(
    steps: int, top: int = 20, seed: int = 0, team: int | None = None, slam: bool = True
) -> dict[str, Any]:
    """cProfile of ``steps`` full-SLAM env steps (after :data:`PROFILE_WARMUP` unprofiled steps,
    enough for every kernel to be loaded from numba's cache before profiling starts; only
    ``env.step`` and the resets at episode ends are profiled, not the drawing of actions): the
    ``top`` functions by own time (tottime) and by cumulative time (cumtime), each with its
    calls, seconds and share (%) of the profiled calls' wall time (profiler overhead included,
    so ``step_ms`` is slower than the unprofiled step). The env is the benchmark's (3 robots,
    paper map), or with ``team`` that many robots in :data:`TEAM_CONFIG` (the team rows' env);
    ``slam=False`` profiles it with ``slam_enabled=False`` (the no-SLAM row)."""
    from polyslam_env.environment.parallel import parallel_env

    config = _env_config() if team is None else {**TEAM_CONFIG, "num_robots": team}
    env = parallel_env(**config, slam_enabled=slam)
    rng = np.random.default_rng(seed)
    space = env.action_space(env.possible_agents[0])
    env.reset(seed=seed)
    profiler = cProfile.Profile()
    total = 0.0  # wall seconds of the profiled calls: the base of every percentage
    for k in range(PROFILE_WARMUP + steps):
        actions = {a: rng.uniform(space.low, space.high) for a in env.agents}  # type: ignore[attr-defined]
        start = time.perf_counter()
        with profiling(profiler) if k >= PROFILE_WARMUP else contextlib.nullcontext():
            if not env.agents:
                env.reset()
            else:
                env.step(actions)
        if k >= PROFILE_WARMUP:
            total += time.perf_counter() - start
    env.close()
    stats = pstats.Stats(profiler)
    entries = [_entry(func, row, total) for func, row in stats.stats.items()]  # type: ignore[attr-defined]
    by = {key: sorted(entries, key=lambda e: -e[key])[:top] for key in ("tottime", "cumtime")}
    robots = len(env.possible_agents)
    return {
        "env": "paper" if team is None else str(TEAM_CONFIG["map"]),
        "slam_enabled": slam,
        "robots": robots,
        "steps": steps,
        "total_s": total,
        "step_ms": 1e3 * total / steps,
        **by,
    }


def _entry(func: tuple[str, int, str], row: tuple[Any, ...], total: float) -> dict[str, Any]:
    """One profile line: where, calls, own and cumulative seconds and % of ``total``."""
    _, ncalls, tottime, cumtime, _ = row
    path, line, name = func
    where = name if path == "~" else f"{_short(path)}:{line}({name})"
    return {
        "function": where,
        "ncalls": int(ncalls),
        "tottime": float(tottime),
        "cumtime": float(cumtime),
        "tottime_pct": 100.0 * tottime / total if total > 0 else 0.0,
        "cumtime_pct": 100.0 * cumtime / total if total > 0 else 0.0,
    }


def _short(path: str) -> str:
    """A source path from its package folder on (``polyslam_env/slam/robot.py``)."""
    parts = Path(path).parts
    for anchor in ("polyslam_env", "site-packages"):
        if anchor in parts:
            k = parts.index(anchor)
            return str(Path(*parts[k + (anchor == "site-packages") :]))
    return Path(path).name

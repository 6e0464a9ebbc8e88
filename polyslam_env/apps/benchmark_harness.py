"""How ``polyslam benchmark`` times things: the harness every section uses.

Warm-up, repeats, the median with its IQR and min–max (:class:`Stats`, :func:`time_calls`,
:func:`rate_samples`); cProfile's count of Python calls (:func:`count_calls`, a
machine-independent figure); how long each section runs (:class:`Plan`, :data:`PLANS`); the
env most sections time (:data:`ENV_CONFIG`) and seeded steppers over it; and what the figures
depend on (:func:`machine_info`). The sections live in ``benchmark_components`` (the SLAM and
world steps), ``benchmark_env`` (env steps per second), ``benchmark_floor`` (the office-floor
frontier episode), ``benchmark_scaling`` (team size, memory, compile cost, processes, the
profile) and ``benchmark_system`` (reproduction and training wall time); ``benchmark`` runs
them and checks the targets. Every section imports this module, none imports another section.
"""

from __future__ import annotations

import contextlib
import cProfile
import os
import pstats
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from polyslam_env.core.jit import compile_seconds
from polyslam_env.world.config import PAPER_BEAMS_DEG

__all__ = [
    "ENV_CONFIG",
    "PLANS",
    "Plan",
    "Stats",
    "count_calls",
    "interleaved_calls",
    "machine_info",
    "net_seconds",
    "parallel_stepper",
    "random_stepper",
    "rate",
    "rate_rounds",
    "rate_samples",
    "ratio",
    "time_calls",
]

#: The env measured: issue 8's "3 robots, paper sensors, full SLAM, vector observations".
ENV_CONFIG: dict[str, Any] = {
    "map": "paper",
    "num_robots": 3,
    "observation__mode": "vector",
    "world__range_sensor__angles_deg": PAPER_BEAMS_DEG,  # the env's default has seventeen beams
}


@dataclass(frozen=True)
class Stats:
    """Median, quartiles and range of repeated measurements (one unit, e.g. s or steps/s)."""

    median: float
    q25: float
    q75: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, samples: Iterable[float]) -> Stats:
        x = np.asarray(list(samples), dtype=float)  # (n,)
        if x.size == 0:
            raise ValueError("Stats.of: no samples")
        q25, q50, q75 = np.percentile(x, [25, 50, 75])
        return cls(float(q50), float(q25), float(q75), float(x.min()), float(x.max()), x.size)

    @property
    def iqr(self) -> float:
        return self.q75 - self.q25

    def scaled(self, factor: float) -> Stats:
        """The same statistics in another unit (``factor`` > 0, e.g. 1e6 for s → µs)."""
        f = float(factor)
        return Stats(
            self.median * f, self.q25 * f, self.q75 * f, self.min * f, self.max * f, self.n
        )

    def to_dict(self) -> dict[str, float]:
        out: dict[str, float] = asdict(self)
        out["iqr"] = self.iqr
        return out


def time_calls(fn: Callable[[], object], repeats: int, number: int = 1, warmup: int = 0) -> Stats:
    """Seconds per call of ``fn``: ``warmup`` untimed calls, then ``repeats`` samples, each the
    mean over ``number`` back-to-back calls (``number`` > 1 for calls near the timer's grain)."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - start) / number)
    return Stats.of(samples)


def interleaved_calls(
    fns: Sequence[Callable[[], object]], calls: int, windows: int, warmup: int = 0
) -> list[list[float]]:
    """Seconds of each call of each of ``fns`` (one list per function), measured in turns.

    ``warmup`` untimed calls of each, then ``windows`` rounds in which each function makes its
    share of ``calls`` timed calls back to back (the shares differ by at most one). Why in
    turns: this machine has slow spells (5 ms to over a second during which even a fixed numpy
    workload runs up to 1.7× slower, from whatever shares the host). A row timed in one stretch of
    25 ms either misses a spell or sits wholly inside one, so its median came out at one of
    two values from run to run. In turns, a spell falls on a minority of each row's windows
    and on every row alike: the medians are those of the machine's usual state.
    """
    if windows < 1:
        raise ValueError(f"windows: expected >= 1, got {windows}")
    for fn in fns:
        for _ in range(warmup):
            fn()
    samples: list[list[float]] = [[] for _ in fns]
    for w in range(windows):
        share = calls * (w + 1) // windows - calls * w // windows
        for fn, out in zip(fns, samples, strict=True):
            for _ in range(share):
                start, loaded = time.perf_counter(), compile_seconds()
                fn()
                out.append(net_seconds(start, loaded))
    return samples


def net_seconds(start: float, loaded: float) -> float:
    """Wall seconds since ``start`` (``time.perf_counter``) less those spent since then making
    kernels ready (``loaded``: :func:`~polyslam_env.core.jit.compile_seconds` at ``start``).

    A kernel loads from numba's disk cache on its first call in a process, ~0.3 s for the
    exchange's on the first rendezvous: a one-off cost of the process (the ``compile`` rows
    give it), not of the step. Left in, it landed in whichever samples met a kernel first,
    the first rounds of the env rows, and took the paper env's median down by ~0.05 × MPE."""
    return time.perf_counter() - start - (compile_seconds() - loaded)


def rate_samples(step: Callable[[], object], steps: int, repeats: int, warmup: int = 0) -> Stats:
    """Calls per second of ``step``: one sample per block of ``steps`` calls
    (:func:`rate_rounds` of the one stepper)."""
    return Stats.of(rate_rounds([step], [steps], repeats, [warmup])[0])


def rate_rounds(
    steppers: Sequence[Callable[[], object]],
    steps: Sequence[int],
    repeats: int,
    warmups: Sequence[int],
) -> list[list[float]]:
    """Calls per second of each of ``steppers``, measured in turns: ``warmups[k]`` untimed
    calls of each, then ``repeats`` rounds in which each makes one block of ``steps[k]`` calls
    (one sample per block, as :func:`rate_samples`). Sample ``r`` of every stepper comes from
    round ``r``, so ratios can be taken round by round. Why in turns: see
    :func:`interleaved_calls` (a slow spell of the machine falls on every row alike). A block's
    time leaves out what it spent making kernels ready (:func:`net_seconds`)."""
    if not len(steppers) == len(steps) == len(warmups):
        raise ValueError(
            f"rate_rounds: {len(steppers)} steppers, {len(steps)} step counts, "
            f"{len(warmups)} warm-ups: expected one of each per stepper"
        )
    for step, warmup in zip(steppers, warmups, strict=True):
        for _ in range(warmup):
            step()
    samples: list[list[float]] = [[] for _ in steppers]
    for _ in range(repeats):
        for step, count, out in zip(steppers, steps, samples, strict=True):
            start, loaded = time.perf_counter(), compile_seconds()
            for _ in range(count):
                step()
            out.append(count / net_seconds(start, loaded))
    return samples


@contextlib.contextmanager
def profiling(profiler: cProfile.Profile) -> Iterator[None]:
    """``profiler`` enabled for the ``with`` block."""
    profiler.enable()
    try:
        yield
    finally:
        profiler.disable()


def count_calls(profiler: cProfile.Profile) -> int:
    """Python function calls (built-ins included) a profiler saw: cProfile's total count, the
    same on any machine for the same code and inputs."""
    stats = pstats.Stats(profiler)
    return int(sum(row[1] for row in stats.stats.values()))  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Plan:
    """How long each section runs."""

    repeats: int  # samples per figure
    slam_warmup: int  # untimed SLAM steps before timing
    slam_steps: int  # timed SLAM steps (each one sample)
    world_steps: int  # world steps per sample
    env_steps: int  # env steps per sample
    vec_steps: int  # vectorised steps per sample
    mpe_steps: int  # MPE steps per sample
    team_steps: int = 150  # env steps per team size
    memory_episodes: int = 5  # episodes of one env for its RSS
    memory_steps: int = 200  # steps per such episode
    profile_steps: int = 300  # profiled env steps (--profile)
    slam_sizes: tuple[int, ...] = (10, 30, 100, 300)
    # turns the SLAM rows take (interleaved_calls): 5 windows of 100 steps; at 20 windows of 25
    # steps the 300-landmark SLAM reloads its 2.9 MB covariance into cache after every other
    # row's turn, which read 10-30 µs slower than alone
    slam_windows: int = 5
    robot_counts: tuple[int, ...] = (1, 3, 8, 16, 32)
    team_sizes: tuple[int, ...] = (3, 20)
    floor_steps: tuple[int, int] = (100, 400)  # the floor episode: measured steps first…last
    reproduce_runs: int = 100  # runs of the reproduction (0: skip it)
    # timesteps of the training run (0: skip it): 3 rollouts of the shipped config (768
    # decisions each), the first untimed (benchmark_system.bench_train)
    train_timesteps: int = 2304
    train_repeats: int = 3  # pairs of runs against a --train-baseline tree
    # the compile figure's env: with SLAM (every kernel a user's first step compiles, ~70 s
    # cold) or without it (a tenth of the kernels: ``tiny`` only exercises the code)
    compile_slam: bool = True


#: ``quick`` runs in a few minutes and leaves out the reproduction and the training run,
#: ``full`` in about 15 (on a loaded 2-core machine); ``tiny`` only exercises the code (tests).
PLANS = {
    "full": Plan(repeats=9, slam_warmup=30, slam_steps=500, world_steps=200, env_steps=400,
                 vec_steps=200, mpe_steps=2000),
    "quick": Plan(repeats=5, slam_warmup=10, slam_steps=100, world_steps=50, env_steps=100,
                  vec_steps=50, mpe_steps=500, team_steps=100, profile_steps=200,
                  reproduce_runs=0, train_timesteps=0),
    "tiny": Plan(repeats=2, slam_warmup=1, slam_steps=3, world_steps=2, env_steps=3, vec_steps=2,
                 mpe_steps=5, team_steps=2, memory_episodes=2, memory_steps=3, profile_steps=2,
                 slam_sizes=(10, 30), robot_counts=(1, 3), team_sizes=(2, 3),
                 floor_steps=(2, 5), reproduce_runs=2, train_timesteps=0, compile_slam=False),
}  # fmt: skip


# -- steppers -----------------------------------------------------------------------------------
def parallel_stepper(env: Any, action: Callable[[Any, str], Any], seed: int) -> Callable[[], None]:
    """One parallel-env step per call with ``action(env, agent)``; resets when all are done."""
    env.reset(seed=seed)

    def step() -> None:
        if not env.agents:
            env.reset()
        env.step({agent: action(env, agent) for agent in env.agents})

    return step


def random_stepper(env: Any, seed: int) -> Callable[[], None]:
    """One env step per call with seeded uniform random actions; resets when all are done.

    Each action is ``rng.uniform(low, high)`` drawn as ``low + (high − low) · rng.random(d)``:
    the same doubles from the same stream (numpy's uniform is that expression), at a sixth of
    the cost (uniform with array bounds broadcasts and checks them each call, ~18 µs, 3 per env
    step: ~4 % of the paper env's step was the benchmark's own action draws)."""
    rng = np.random.default_rng(seed)
    space = env.action_space(env.possible_agents[0])
    low = np.asarray(space.low, dtype=float)  # (d,) as uniform converts its bounds
    span = np.asarray(space.high, dtype=float) - low
    shape = low.shape
    return parallel_stepper(env, lambda e, a: low + span * rng.random(shape), seed)


# -- figures of a run ---------------------------------------------------------------------------
def rate(row: dict[str, Any] | None) -> float | None:
    """A row's median steps per second (None when it was not measured)."""
    if row is None or not row.get("installed", False):
        return None
    return float(row["steps_per_s"]["median"])


def ratio(a: float | None, b: float | None) -> float | None:
    """a / b, None when either is missing or b is not positive."""
    return None if a is None or b is None or b <= 0 else a / b


def machine_info() -> dict[str, Any]:
    """What the figures depend on: cores, load (the 1-minute average before and after the
    run; absolute figures from a loaded machine are slow, the ratios less so), versions and
    numpy's BLAS threads (the SLAM caps them to ``slam.blas_threads`` while it steps)."""
    import platform

    import pymunk
    from threadpoolctl import threadpool_info

    blas = [f"{lib['internal_api']} ×{lib['num_threads']}" for lib in threadpool_info()
            if lib["user_api"] == "blas"]  # fmt: skip
    return {
        "cpus": os.cpu_count(),
        "load_before": load_average(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "pymunk": pymunk.version,
        "blas": ", ".join(blas) or "unknown",
    }


def load_average() -> float | None:
    """The machine's 1-minute load average (None where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):  # not on every platform
        return None

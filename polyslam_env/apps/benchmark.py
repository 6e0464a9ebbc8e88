"""Speed of the SLAM, the world and the env, each next to a reference timed in the same run.

One harness (:func:`time_calls`, :func:`rate_samples`, :class:`Stats`): warm-up, repeats, the
median with its IQR and min–max. Figures from a loaded machine compare through their ratio to a
reference measured in the same process just before or after:

* ``slam``: one :meth:`PolySlam.step` against the number of landmarks (µs), next to a 3×3
``np.linalg.solve``; a second pass with the SLAM's profiling hook gives the per-stage split; *
``world``: one control step (physics + range scan + camera) against the number of robots (µs), next
to bare pymunk (the same number of free circles, stepped ``substeps`` times); * ``env``: env steps
per second (3 robots on the paper map, paper sensors, vector observations, no rendering) with full
SLAM and with ``slam_enabled=False``; then the same config through the SuperSuit / SB3 vectorised
path (:func:`polyslam_env.environment.vector.make_vec_env`, 2 envs in this process, then in 2
worker processes: ``vec``, whose ratio of the two is issue 15's target); and
PettingZoo MPE ``simple_spread`` (3 agents) through the same harness, when ``mpe2`` is installed
(the ``bench`` extra); * ``backends``: env steps/s of every ``slam.backend`` on the pillar
hall (3 robots, pillar sensor on), next to the same env without SLAM.

Env runs include the resets that happen when episodes end (as in training). Actions come from
seeded generators. The :func:`run_benchmark` result is a JSON-ready dict.

The system figures (:mod:`polyslam_env.apps.benchmark_scaling`): ``team``, ms per env step
with 3 and 20 robots on a generated map with the exchange on; ``memory``, peak RSS of one env
over several episodes; ``compile``, the first env step in a fresh process with a cold numba
cache against a warm one; and on request the env step's profile and multi-process scaling.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pymunk

from polyslam_env.core.geometry import compose
from polyslam_env.core.seeding import make_rngs
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.measurement import cast
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import PAPER_BEAMS_DEG, WorldConfig, paper_world_config
from polyslam_env.world.layout import Layout
from polyslam_env.world.physics import World

__all__ = [
    "PLANS",
    "SECTIONS",
    "TARGETS",
    "Plan",
    "Stats",
    "bench_env",
    "bench_mpe",
    "bench_slam",
    "bench_vec",
    "bench_world",
    "rate_samples",
    "run_benchmark",
    "targets",
    "time_calls",
]

#: Sections of a benchmark run, in the order they run.
SECTIONS = (
    "slam",
    "world",
    "reference",
    "env",
    "vec",
    "backends",
    "team",
    "memory",
    "compile",
)
#: The env measured: issue 8's "3 robots, paper sensors, full SLAM, vector observations".
ENV_CONFIG: dict[str, Any] = {
    "map": "paper",
    "num_robots": 3,
    "observation__mode": "vector",
    "world__range_sensor__angles_deg": PAPER_BEAMS_DEG,  # the env's default has seventeen beams
}
#: Issue 15's targets: (name, goal, True when the figure must be at most the goal).
TARGETS: tuple[tuple[str, float, bool], ...] = (
    ("full-SLAM env / MPE simple_spread", 0.5, False),
    ("slam_enabled=False env / MPE", 1.0, False),
    ("SLAM step µs, 30 landmarks", 60.0, True),
    ("SLAM step µs, 300 landmarks", 200.0, True),
    ("world step, 3 robots / pymunk", 4.0, True),
    ("SB3 vec 2 procs / one process", 1.6, False),
    ("step cost 20 / 3 robots", 10.0, True),
)


# -- the harness ----------------------------------------------------------------------------
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


def rate_samples(step: Callable[[], object], steps: int, repeats: int, warmup: int = 0) -> Stats:
    """Calls per second of ``step``: one sample per block of ``steps`` calls."""
    for _ in range(warmup):
        step()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            step()
        samples.append(steps / (time.perf_counter() - start))
    return Stats.of(samples)


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
    robot_counts: tuple[int, ...] = (1, 3, 8, 16, 32)
    team_sizes: tuple[int, ...] = (3, 20)


#: ``quick`` runs in about 2 minutes, ``full`` in about 6 (on a loaded 2-core machine; the
#: 20-robot team takes a third of it); ``tiny`` only exercises the code (tests).
PLANS = {
    "full": Plan(repeats=9, slam_warmup=30, slam_steps=500, world_steps=200, env_steps=400,
                 vec_steps=200, mpe_steps=2000),
    "quick": Plan(repeats=5, slam_warmup=10, slam_steps=100, world_steps=50, env_steps=100,
                  vec_steps=50, mpe_steps=500, team_steps=100, profile_steps=200),
    "tiny": Plan(repeats=2, slam_warmup=1, slam_steps=3, world_steps=2, env_steps=3, vec_steps=2,
                 mpe_steps=5, team_steps=2, memory_episodes=2, memory_steps=3, profile_steps=2,
                 slam_sizes=(10, 30), robot_counts=(1, 3), team_sizes=(2, 3)),
}  # fmt: skip


# -- SLAM against the number of landmarks -----------------------------------------------------
BEAM_ANGLES = np.radians(PAPER_BEAMS_DEG)  # (5,) the paper's sensor
MAX_RANGE, RANGE_SIGMA, ODOM_SIGMA = 2.0, 0.02, 0.001
SHUTTLE, STEP_DX = 20, 0.01  # steps forward then as many back; m per step


def _local_cubic(xi_c: float, eta_c: float, slope: float, k2: float, k3: float) -> np.ndarray:
    """[c0, b1, b2, b3] of η = η_c + s(ξ−ξ_c) + k2(ξ−ξ_c)² + k3(ξ−ξ_c)³ in powers of ξ."""
    shifted = np.polynomial.polynomial.Polynomial([0.0, 1.0]) - xi_c
    p = eta_c + slope * shifted + k2 * shifted**2 + k3 * shifted**3
    coeffs = np.zeros(4)
    coeffs[: len(p.coef)] = p.coef
    return coeffs


def make_walls(n: int, rng: np.random.Generator) -> list[Polynomial]:
    """Three walls around the origin (y = ±0.5 m, x = 1 m: every beam hits a mapped wall, so
    association and update run every step), then n − 3 short cubics 3–12 m away (out of
    range, but association and ray casting still consider them)."""
    walls = [
        Polynomial(1, np.array([0.5, 0.0, 0.0, 0.0]), -1.5, 0.9),
        Polynomial(1, np.array([-0.5, 0.0, 0.0, 0.0]), -1.5, 0.9),
        Polynomial(2, np.array([1.0, 0.0, 0.0, 0.0]), -0.45, 0.45),
    ]
    for _ in range(n - 3):
        radius, bearing = rng.uniform(3.0, 12.0), rng.uniform(-np.pi, np.pi)
        heading = rng.uniform(0, np.pi)
        centre = radius * np.array([np.cos(bearing), np.sin(bearing)])
        variate = 1 if abs(np.cos(heading)) >= abs(np.sin(heading)) else 2
        xi_c, eta_c = centre if variate == 1 else centre[::-1]
        slope = np.tan(heading) if variate == 1 else 1.0 / np.tan(heading)
        coeffs = _local_cubic(xi_c, eta_c, slope, rng.normal(0, 0.3), rng.normal(0, 0.3))
        half = 0.25 / np.sqrt(1.0 + slope**2)
        walls.append(Polynomial(variate, coeffs, xi_c - half, xi_c + half))
    return walls


def make_slam(walls: list[Polynomial], config: SlamConfig | None = None) -> PolySlam:
    """A PolySlam at the origin whose map holds ``walls`` (inserted without merging)."""
    slam = PolySlam(config or SlamConfig(), BEAM_ANGLES, MAX_RANGE)
    for wall in walls:
        gx = np.zeros((1, slam.mean.size))  # (1, 3+n)
        gx[0, 1 if wall.variate == 1 else 0] = 1.0  # c0 moves with the pose's η
        gx[0, 2] = 0.1  # and a little with its heading
        fit = Fit(
            poly=wall,
            c0=wall.c0,
            Gx=gx,
            Gy=np.ones((1, 1)),
            V=np.array([[RANGE_SIGMA**2]]),
            rms=0.025,
            order=wall.order,
        )
        slam.insert_landmark(fit, merge=False)
    return slam


def make_inputs(
    walls: list[Polynomial], steps: int, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(odometry (3,), ranges (5,)) per step of a shuttle along x, ranges cast on the walls."""
    arrays = LandmarkTable()  # the walls as the SLAM's measurement model takes them
    for wall in walls:
        arrays.append(wall, pivot=0.0, xi_var=0.0, model_var=0.0, fit_half=1.0)
    every, c0s = list(range(len(walls))), [w.c0 for w in walls]
    pose = np.zeros(3)
    out = []
    for k in range(steps):
        motion = np.array([STEP_DX if (k // SHUTTLE) % 2 == 0 else -STEP_DX, 0.0, 0.0])
        pose = compose(pose, motion)
        odometry = motion + rng.normal(0.0, ODOM_SIGMA, 3) * np.array([1.0, 1.0, 0.01])
        x, y, theta = pose.tolist()
        hits = cast(x, y, theta, BEAM_ANGLES.tolist(), every, arrays.rows(), c0s, MAX_RANGE)
        ranges = np.array([math.inf if hit is None else hit.t for hit in hits])
        out.append((odometry, ranges + rng.normal(0.0, RANGE_SIGMA, BEAM_ANGLES.size)))
    return out


def bench_slam(n: int, plan: Plan, seed: int = 0) -> dict[str, Any]:
    """One SLAM step with ``n`` landmarks (µs), a 3×3 solve for reference, stage medians, and
    the same steps with ``shape_rotation="heading"`` (no rotation states: half the state)."""
    rng = np.random.default_rng(seed)
    walls = make_walls(n, rng)
    all_inputs = make_inputs(walls, plan.slam_warmup + 2 * plan.slam_steps, rng)
    inputs = iter(all_inputs)
    slam = make_slam(walls)
    beams = []

    def step() -> None:
        beams.append(slam.step(*next(inputs)).beams_used)

    step_us = time_calls(step, plan.slam_steps, warmup=plan.slam_warmup).scaled(1e6)
    heading = make_slam(walls, SlamConfig(shape_rotation="heading"))
    heading_inputs = iter(all_inputs)
    heading_us = time_calls(
        lambda: heading.step(*next(heading_inputs)), plan.slam_steps, warmup=plan.slam_warmup
    ).scaled(1e6)
    a, b = rng.normal(size=(3, 3)) + 3 * np.eye(3), rng.normal(size=3)
    solve_us = time_calls(lambda: np.linalg.solve(a, b), max(plan.repeats, 5), number=200)
    solve_us = solve_us.scaled(1e6)
    return {
        "landmarks": slam.n_landmarks,
        "step_us": step_us.to_dict(),
        "reference_solve3_us": solve_us.to_dict(),
        "ratio_to_solve3": step_us.median / solve_us.median,
        "heading_step_us": heading_us.to_dict(),
        "beams_used_per_step": float(np.mean(beams[plan.slam_warmup :])),
        "stages_us": slam_stages(slam, [next(inputs) for _ in range(plan.slam_steps)]),
    }


def slam_stages(slam: PolySlam, inputs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Median µs per SLAM stage with the profiling hook on (a separate, slower pass)."""
    slam.profile = {}
    for odometry, ranges in inputs:
        slam.step(odometry, ranges)
    stages = {name: Stats.of(t).median * 1e6 for name, t in slam.profile.items()}
    slam.profile = None
    return stages


# -- world against the number of robots -------------------------------------------------------
def big_box(num_robots: int, spacing: float = 0.6) -> tuple[Layout, np.ndarray]:
    """A square box with one inner wall, and start poses (N, 3) on a grid clear of both."""
    side = int(np.ceil(np.sqrt(num_robots))) + 1
    size = (side + 1) * spacing
    box = np.array([[0.0, 0.0], [size, 0.0], [size, size], [0.0, size], [0.0, 0.0]])
    inner = np.array([[size / 2 + spacing / 2, spacing / 2], [size / 2 + spacing / 2, size / 2]])
    layout = Layout(f"box{num_robots}", (box, inner))
    grid = [(i * spacing, j * spacing) for i in range(1, side + 1) for j in range(1, side + 1)]
    xy = np.array(grid)[:num_robots]  # (N, 2)
    poses = np.column_stack([xy, np.linspace(-np.pi, np.pi, num_robots, endpoint=False)])
    return layout, poses


def world_stepper(n: int, config: WorldConfig, seed: int = 0) -> Callable[[], None]:
    """One env-like world step per call: random commands, physics, scan and camera."""
    layout, poses = big_box(n)
    world = World(layout, config, n, make_rngs(seed), start_poses=poses)
    rng = np.random.default_rng(seed)
    high = np.array([config.robot.v_max, config.robot.omega_max])

    def step() -> None:
        world.step(rng.uniform(-high, high, size=(n, 2)))
        world.scan()
        world.camera()

    return step


def pymunk_stepper(n: int, config: WorldConfig) -> Callable[[], None]:
    """Bare pymunk: n free circles, ``substeps`` space steps, no Python work per body."""
    space = pymunk.Space()
    for i in range(n):
        body = pymunk.Body(1.0, float("inf"))
        body.position = (i * 1.0, 0.0)
        body.velocity = (0.1, 0.0)
        space.add(body, pymunk.Circle(body, config.robot.radius))
    h = config.dt / config.substeps

    def step() -> None:
        for _ in range(config.substeps):
            space.step(h)

    return step


def bench_world(n: int, plan: Plan, config: WorldConfig | None = None) -> dict[str, Any]:
    """One world step with ``n`` robots (µs) next to bare pymunk with as many bodies."""
    cfg = config or paper_world_config()
    world = time_calls(world_stepper(n, cfg), plan.repeats, plan.world_steps, warmup=3)
    ref = time_calls(pymunk_stepper(n, cfg), plan.repeats, plan.world_steps, warmup=3)
    world_us, ref_us = world.scaled(1e6), ref.scaled(1e6)
    return {
        "robots": n,
        "step_us": world_us.to_dict(),
        "per_robot_us": world_us.median / n,
        "reference_pymunk_us": ref_us.to_dict(),
        "ratio_to_pymunk": world_us.median / ref_us.median,
    }


def scaling_exponent(counts: list[int], times: list[float]) -> float:
    """Slope of log(time) against log(count): 1 is linear growth, < 1 better than linear."""
    if len(counts) < 2:
        return float("nan")
    return float(np.polyfit(np.log(counts), np.log(times), 1)[0])


# -- env steps per second ---------------------------------------------------------------------
def parallel_stepper(env: Any, action: Callable[[Any, str], Any], seed: int) -> Callable[[], None]:
    """One parallel-env step per call with ``action(env, agent)``; resets when all are done."""
    env.reset(seed=seed)

    def step() -> None:
        if not env.agents:
            env.reset()
        env.step({agent: action(env, agent) for agent in env.agents})

    return step


def bench_env(plan: Plan, seed: int = 0, **overrides: Any) -> dict[str, Any]:
    """Env steps/s of the issue-8 config (plus ``overrides``), uniform random actions."""
    from polyslam_env.environment.parallel import parallel_env

    env = parallel_env(**{**ENV_CONFIG, **overrides})
    rng = np.random.default_rng(seed)
    space = env.action_space(env.possible_agents[0])
    low, high = space.low, space.high  # type: ignore[attr-defined]
    rate = rate_samples(
        parallel_stepper(env, lambda e, a: rng.uniform(low, high), seed),
        plan.env_steps,
        plan.repeats,
        warmup=5,
    )
    env.close()
    return {"installed": True, "steps_per_s": rate.to_dict()}


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
        row["ratio_to_no_slam"] = _ratio(_rate(row), _rate(reference))
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
        cpu_before = _cpu_seconds(pids)
        rate = rate_samples(step, plan.vec_steps, plan.repeats)
        cpu_after = _cpu_seconds(pids)
    finally:
        venv.close()
    processes = num_cpus if min(num_cpus, num_envs) >= 2 else 1
    env_steps = plan.vec_steps * plan.repeats * num_envs
    row = {
        "installed": True,
        "num_envs": num_envs,
        "processes": min(processes, num_envs),
        "steps_per_s": rate.scaled(num_envs).to_dict(),
        "cpu_ms_per_env_step": None
        if cpu_before is None or cpu_after is None
        else 1e3 * (cpu_after - cpu_before) / env_steps,
    }
    if processes > 1:
        row["machine_speedup"] = parallel_speedup(processes)
    return row


def _cpu_seconds(pids: Iterable[int]) -> float | None:
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


def bench_mpe(plan: Plan, seed: int = 0) -> dict[str, Any]:
    """PettingZoo MPE ``simple_spread`` (3 agents, defaults) through the same harness."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return {"installed": False, "name": "mpe2 simple_spread_v3"}
    env = simple_spread_v3.parallel_env(N=3)
    rng = np.random.default_rng(seed)
    rate = rate_samples(
        parallel_stepper(env, lambda e, a: int(rng.integers(e.action_space(a).n)), seed),
        plan.mpe_steps,
        plan.repeats,
        warmup=20,
    )
    env.close()
    return {"installed": True, "name": "mpe2 simple_spread_v3", "steps_per_s": rate.to_dict()}


# -- the whole run ----------------------------------------------------------------------------
Report = Callable[[str, dict[str, Any]], None]


def _ignore(section: str, row: dict[str, Any]) -> None:
    """The default progress callback: print nothing."""


def run_benchmark(
    plan: Plan,
    sections: Iterable[str] = SECTIONS,
    seed: int = 0,
    report: Report = _ignore,
    workers: Sequence[int] = (),
    profile: str | None = None,
) -> dict[str, Any]:
    """Run ``sections`` (see :data:`SECTIONS`); ``report(section, row)`` after every row.

    The reference (MPE) runs before the env rows, which carry ``ratio_to_mpe`` (the vectorised
    rows run the same 2 envs in one process, then in 2 worker processes; the second carries
    ``ratio_to_one_process`` and ``ratio_to_env``, over full SLAM in one plain env); a ratio is
    None when either figure was not measured. ``workers`` (e.g. ``(1, 2, 4)``) adds a row of env
    steps/s per process count; ``profile`` adds the env step's profile (section ``profile``):
    ``"env"`` of the 3-robot env, ``"team"`` of the largest team size's env, ``"noslam"`` of
    the 3-robot env with ``slam_enabled=False``.
    """
    wanted = set(sections)
    if any(n < 1 for n in workers):
        raise ValueError(f"workers: process counts must be >= 1, got {list(workers)}")
    if profile not in (None, "env", "team", "noslam"):
        raise ValueError(f"profile: expected 'env', 'team' or 'noslam', got {profile!r}")
    unknown = wanted - set(SECTIONS)
    if unknown:
        raise ValueError(f"sections: unknown {sorted(unknown)}; choose from {SECTIONS}")
    out: dict[str, Any] = {"plan": asdict(plan), "seed": seed, "machine": machine_info()}
    if "slam" in wanted:
        out["slam"] = [_emit(report, "slam", bench_slam(n, plan, seed)) for n in plan.slam_sizes]
    if "world" in wanted:
        rows = [_emit(report, "world", bench_world(n, plan)) for n in plan.robot_counts]
        out["world"] = {
            "rows": rows,
            "scaling_exponent": scaling_exponent(
                [r["robots"] for r in rows], [r["step_us"]["median"] for r in rows]
            ),
        }
    mpe = None
    if "reference" in wanted:  # first, so that every env row carries its ratio when printed
        out["reference"] = _emit(report, "env", {"label": "MPE simple_spread", **bench_mpe(plan)})
        mpe = _rate(out["reference"])
    if "env" in wanted:
        full = {"label": "full SLAM", **bench_env(plan, seed)}
        full["ratio_to_mpe"] = _ratio(_rate(full), mpe)
        nos = {"label": "slam_enabled=False", **bench_env(plan, seed, slam_enabled=False)}
        nos["ratio_to_mpe"] = _ratio(_rate(nos), mpe)
        out["env"] = {"full_slam": _emit(report, "env", full), "no_slam": _emit(report, "env", nos)}
    if "vec" in wanted:
        one = {"label": "SB3 vec, 1 proc", **bench_vec(plan, seed, num_cpus=0)}
        one["ratio_to_mpe"] = _ratio(_rate(one), mpe)
        out["vec_one_process"] = _emit(report, "env", one)
        vec = {"label": "SB3 vec, 2 procs", **bench_vec(plan, seed, num_cpus=2)}
        vec["ratio_to_mpe"] = _ratio(_rate(vec), mpe)
        vec["ratio_to_env"] = _ratio(_rate(vec), _rate(out.get("env", {}).get("full_slam")))
        vec["ratio_to_one_process"] = _ratio(_rate(vec), _rate(one))
        out["vec"] = _emit(report, "env", vec)
    if "backends" in wanted:
        out["backends"] = [_emit(report, "backends", r) for r in bench_backends(plan, seed)]
    _system_sections(out, plan, wanted, seed, report, workers, profile)
    out["targets"] = targets(out)
    out["machine"]["load_after"] = _load_average()
    return out


def machine_info() -> dict[str, Any]:
    """What the figures depend on: cores, load (the 1-minute average before and after the
    run; absolute figures from a loaded machine are slow, the ratios less so), versions and
    numpy's BLAS threads (the SLAM caps them to ``slam.blas_threads`` while it steps)."""
    import platform

    from threadpoolctl import threadpool_info

    blas = [f"{lib['internal_api']} ×{lib['num_threads']}" for lib in threadpool_info()
            if lib["user_api"] == "blas"]  # fmt: skip
    return {
        "cpus": os.cpu_count(),
        "load_before": _load_average(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "pymunk": pymunk.version,
        "blas": ", ".join(blas) or "unknown",
    }


def _load_average() -> float | None:
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):  # not on every platform
        return None


def _emit(report: Report, section: str, row: dict[str, Any]) -> dict[str, Any]:
    report(section, row)
    return row


def _rate(row: dict[str, Any] | None) -> float | None:
    if row is None or not row.get("installed", False):
        return None
    return float(row["steps_per_s"]["median"])


def _ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None or b <= 0 else a / b


def _system_sections(
    out: dict[str, Any],
    plan: Plan,
    wanted: set[str],
    seed: int,
    report: Report,
    workers: Sequence[int],
    profile: str | None,
) -> None:
    """The figures of :mod:`polyslam_env.apps.benchmark_scaling`, into ``out``."""
    from polyslam_env.apps import benchmark_scaling as system

    if "team" in wanted:
        rows = system.bench_team(plan.team_sizes, plan.team_steps, seed)
        out["team"] = [_emit(report, "team", r) for r in rows]
    if "memory" in wanted:
        mem = system.bench_memory(plan.memory_episodes, plan.memory_steps, seed)
        out["memory"] = mem
        for row in mem["episodes"]:
            _emit(report, "memory", row)
    if "compile" in wanted:
        out["compile"] = _emit(report, "compile", system.bench_compile())
    if workers:
        rows = system.bench_workers(workers, plan.env_steps, plan.repeats, seed)
        out["workers"] = [_emit(report, "workers", r) for r in rows]
    if profile is not None:
        team = max(plan.team_sizes) if profile == "team" else None
        steps = plan.profile_steps if team is None else plan.team_steps
        row = system.profile_env(steps, 20, seed, team, slam=profile != "noslam")
        out["profile"] = _emit(report, "profile", row)


def targets(out: dict[str, Any]) -> list[dict[str, Any]]:
    """Issue 15's targets (:data:`TARGETS`) with the measured figure and whether it is met
    (None: not measured in this run)."""
    env = out.get("env", {})
    by_size = {r["landmarks"]: r["step_us"]["median"] for r in out.get("slam", [])}
    world = {r["robots"]: r["ratio_to_pymunk"] for r in out.get("world", {}).get("rows", [])}
    team = {r["robots"]: r["mean_ms"] for r in out.get("team", [])}
    measured = [
        (env.get("full_slam") or {}).get("ratio_to_mpe"),
        (env.get("no_slam") or {}).get("ratio_to_mpe"),
        by_size.get(30),
        by_size.get(300),
        world.get(3),
        (out.get("vec") or {}).get("ratio_to_one_process"),
        _ratio(team.get(20), team.get(3)),
    ]
    rows: list[dict[str, Any]] = []
    for (name, goal, at_most), value in zip(TARGETS, measured, strict=True):
        met = None if value is None else (value <= goal if at_most else value >= goal)
        rows.append(
            {"target": name, "measured": value, "goal": goal, "at_most": at_most, "met": met}
        )
    return rows

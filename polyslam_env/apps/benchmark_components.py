"""The benchmark's component figures: the SLAM step and the world step, each next to a
reference timed in the same run.

* :func:`bench_slam`: one :meth:`PolySlam.step` against the number of landmarks (µs), next to a
  3×3 ``np.linalg.solve``; a second pass with the SLAM's profiling hook gives the per-stage
  split;
* :func:`bench_world`: one control step (physics + range scan + camera) against the number of
  robots (µs), next to bare pymunk (the same number of free circles, stepped ``substeps``
  times).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
import pymunk

from polyslam_env.apps.benchmark_harness import Plan, Stats, interleaved_calls, time_calls
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
    "bench_slam",
    "bench_world",
    "big_box",
    "make_inputs",
    "make_slam",
    "make_walls",
    "pymunk_stepper",
    "scaling_exponent",
    "slam_stages",
    "world_stepper",
]


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


SOLVES = 20  # 3×3 solves per reference sample (one solve is near the timer's grain)


def bench_slam(sizes: Sequence[int], plan: Plan, seed: int = 0) -> list[dict[str, Any]]:
    """One SLAM step with each of ``sizes`` landmarks (µs), a 3×3 solve for reference, stage
    medians, and the same steps with ``shape_rotation="heading"`` (no rotation states: half the
    state); one row per size.

    Every size's two SLAMs and the reference are timed in turns (:func:`interleaved_calls`,
    ``plan.slam_windows`` rounds), each SLAM on its own seeded walls and inputs as if timed
    alone: the steps each one makes are the same, only their order in time is shared, so a slow
    spell of the machine falls on the reference too and ``ratio_to_solve3`` does not move with it.
    """
    slams: list[PolySlam] = []
    streams: list[Iterator[tuple[np.ndarray, np.ndarray]]] = []
    beams: list[list[int]] = []
    steppers: list[Callable[[], None]] = []
    for n in sizes:
        rng = np.random.default_rng(seed)
        walls = make_walls(n, rng)
        all_inputs = make_inputs(walls, plan.slam_warmup + 2 * plan.slam_steps, rng)
        slam = make_slam(walls, SlamConfig())
        heading = make_slam(walls, SlamConfig(shape_rotation="heading"))
        slams.append(slam)
        streams.append(iter(all_inputs))  # the timed steps, then the stages' pass
        beams.append([])
        steppers.append(_slam_stepper(slam, streams[-1], beams[-1]))
        steppers.append(_slam_stepper(heading, iter(all_inputs), []))
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(3, 3)) + 3 * np.eye(3), rng.normal(size=3)

    def solves() -> None:  # the reference: SOLVES back-to-back 3×3 solves per sample
        for _ in range(SOLVES):
            np.linalg.solve(a, b)

    windows = min(plan.slam_windows, plan.slam_steps)
    samples = interleaved_calls([*steppers, solves], plan.slam_steps, windows, plan.slam_warmup)
    times = [Stats.of(x) for x in samples]
    solve_us = times[-1].scaled(1e6 / SOLVES)
    out = []
    for k, (slam, inputs) in enumerate(zip(slams, streams, strict=True)):
        step_us = times[2 * k].scaled(1e6)
        out.append(
            {
                "landmarks": slam.n_landmarks,
                "step_us": step_us.to_dict(),
                "reference_solve3_us": solve_us.to_dict(),
                "ratio_to_solve3": step_us.median / solve_us.median,
                "heading_step_us": times[2 * k + 1].scaled(1e6).to_dict(),
                "beams_used_per_step": float(np.mean(beams[k][plan.slam_warmup :])),
                "windows": windows,
                "stages_us": slam_stages(slam, [next(inputs) for _ in range(plan.slam_steps)]),
            }
        )
    return out


def _slam_stepper(
    slam: PolySlam, inputs: Iterator[tuple[np.ndarray, np.ndarray]], beams: list[int]
) -> Callable[[], None]:
    """One step of ``slam`` on the next of ``inputs``; the beams it used appended to ``beams``."""

    def step() -> None:
        beams.append(slam.step(*next(inputs)).beams_used)

    return step


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

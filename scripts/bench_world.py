"""Cost of one world step (physics + range scan + camera) against a bare pymunk reference.

Usage: ``python scripts/bench_world.py [--repeats 7] [--steps 200]``

Prints, per team size, the median µs of one control step with its spread (min–max over the
repeats) and the ratio to a bare ``pymunk.Space.step`` run measured in the same process: the same
number of free circle bodies, stepped ``substeps`` times, with no Python work per body. The ratio
is what to compare across machines; the absolute figures depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import pymunk

from polyslam_env.seeding import make_rngs
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World


def big_box(num_robots: int, spacing: float = 0.6) -> tuple[Layout, np.ndarray]:
    """A square box with one inner wall, and start poses on a grid clear of both."""
    side = int(np.ceil(np.sqrt(num_robots))) + 1
    size = (side + 1) * spacing
    box = np.array([[0.0, 0.0], [size, 0.0], [size, size], [0.0, size], [0.0, 0.0]])
    inner = np.array([[size / 2 + spacing / 2, spacing / 2], [size / 2 + spacing / 2, size / 2]])
    layout = Layout(f"box{num_robots}", (box, inner))
    grid = [(i * spacing, j * spacing) for i in range(1, side + 1) for j in range(1, side + 1)]
    xy = np.array(grid)[:num_robots]
    poses = np.column_stack([xy, np.linspace(-np.pi, np.pi, num_robots, endpoint=False)])
    return layout, poses


def time_steps(step: Callable[[int], None], steps: int, repeats: int) -> list[float]:
    """µs per call of ``step(k)``, one figure per repeat of ``steps`` calls."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for k in range(steps):
            step(k)
        out.append((time.perf_counter() - t0) / steps * 1e6)
    return out


def world_step_fn(
    layout: Layout, n: int, poses: np.ndarray | None, steps: int
) -> Callable[[int], None]:
    """One env-like world step per call: random commands, physics, scan and camera."""
    world = World(layout, WorldConfig(), n, make_rngs(0), start_poses=poses)
    cmds = np.random.default_rng(0).uniform(-0.3, 0.3, size=(steps, n, 2))

    def step(k: int) -> None:
        world.step(cmds[k])
        world.scan()
        world.camera()

    return step


def reference_fn(n: int, substeps: int, dt: float) -> Callable[[int], None]:
    """Bare pymunk: n free circles, ``substeps`` space steps, no Python work per body."""
    space = pymunk.Space()
    for i in range(n):
        body = pymunk.Body(1.0, float("inf"))
        body.position = (i * 1.0, 0.0)
        body.velocity = (0.1, 0.0)
        space.add(body, pymunk.Circle(body, 0.065))
    h = dt / substeps

    def step(k: int) -> None:
        for _ in range(substeps):
            space.step(h)

    return step


def fmt(times: list[float]) -> str:
    return f"{statistics.median(times):9.1f} µs  [{min(times):.1f}–{max(times):.1f}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    cfg = WorldConfig()
    cases: list[tuple[str, Layout, int, np.ndarray | None]] = [
        ("two_rooms", load_map("two_rooms"), 3, None)
    ]
    for n in (1, 8, 16, 32):
        box, grid = big_box(n)
        cases.append((box.name, box, n, grid))
    print(
        f"world step = physics ({cfg.substeps} sub-steps) + scan ({len(cfg.range_sensor.angles)}"
        f" beams) + camera; median [min–max] over {args.repeats} × {args.steps} steps"
    )
    print(f"{'map':<10} {'robots':>6}  {'world step':>28}  {'bare pymunk':>28}  {'ratio':>6}")
    for name, lay, n, start in cases:
        world = time_steps(world_step_fn(lay, n, start, args.steps), args.steps, args.repeats)
        ref = time_steps(reference_fn(n, cfg.substeps, cfg.dt), args.steps, args.repeats)
        ratio = statistics.median(world) / statistics.median(ref)
        print(f"{name:<10} {n:>6}  {fmt(world):>28}  {fmt(ref):>28}  {ratio:6.1f}")


if __name__ == "__main__":
    main()

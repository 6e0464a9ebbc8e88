"""What chipmunk's sub-steps buy: random driving on every layout generator, per sub-step count.

For each ``--substeps`` value and each generator of :data:`polyslam_env.world.generators.
GENERATORS`, a team of ``--robots`` robots drives ``--steps`` control steps with seeded random
commands (uniform in the robot's limits, each held for 1–10 steps, a new layout every
``--episode`` steps), through :class:`~polyslam_env.world.physics.World` alone (no sensing).
Every step's physics result is checked **before the guard** by brute force over all walls,
pillars and robots (not by the guard's own kernel):

* ``through``: a robot centre's path properly crossed a wall line;
* ``wall_overlap`` / ``pillar_overlap``: a robot's true circle ends more than
  ``GUARD_TOLERANCE`` (1 mm) inside a (thickened) wall or a pillar;
* ``robot_overlap``: two robots' true circles overlap by more than 1 mm;

and after the guard ``guard_reverts`` (steps the guard had to undo) and ``after_guard`` (a
violation left after the guard: must be 0). ``collided`` is the share of robot-steps with a
contact that pushed, ``pushes_counted`` the share of robot-steps whose robot moved less than
half its commanded chord (blocked by something) that were reported as collided. The cost is
the median ms per world step and cProfile's Python calls per step (3 robots).

    python scripts/physics_substeps.py --substeps 20,10,5 --steps 100000 --out out/substeps.json
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.generators import GENERATORS, make_generator
from polyslam_env.world.layout import Layout
from polyslam_env.world.physics import GUARD_TOLERANCE, World

#: Checked pairs of (start, raw end) poses of each step, appended by :class:`_Recording`.
Raw = list[tuple[np.ndarray, np.ndarray]]


def world_config(substeps: int) -> WorldConfig:
    """The default world with ``substeps`` sub-steps, below the config's floor too (the study
    measures what the floor protects)."""
    config = WorldConfig()
    object.__setattr__(config, "substeps", substeps)
    return config


class _Recording(World):
    """A world that keeps each step's poses before the guard (the physics' own result)."""

    raw: Raw

    def _guard(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        self.raw.append((start.copy(), end.copy()))
        return super()._guard(start, end)


def _crossings(start: np.ndarray, end: np.ndarray, segments: np.ndarray) -> np.ndarray:  # (N,)
    """Whether each robot's centre path start → end (N, 2) properly crosses a segment (S, 4)."""
    p, q = start[:, None, :], end[:, None, :]  # (N, 1, 2)
    a, b = segments[None, :, :2], segments[None, :, 2:]  # (1, S, 2)

    def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.asarray(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])

    d1, d2 = cross(q - p, a - p), cross(q - p, b - p)
    d3, d4 = cross(b - a, p - a), cross(b - a, q - a)
    return np.asarray(((d1 * d2 < 0) & (d3 * d4 < 0)).any(axis=1))


def _segment_gaps(points: np.ndarray, segments: np.ndarray) -> np.ndarray:  # (N,)
    """Distance from each point (N, 2) to the nearest segment (S, 4)."""
    a, b = segments[None, :, :2], segments[None, :, 2:]
    ab = b - a
    t = ((points[:, None, :] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300)
    foot = a + np.clip(t, 0.0, 1.0)[..., None] * ab
    return np.asarray(np.hypot(*(points[:, None, :] - foot).transpose(2, 0, 1)).min(axis=1))


def violations(
    start: np.ndarray, end: np.ndarray, layout: Layout, config: WorldConfig, active: np.ndarray
) -> dict[str, int]:
    """Brute-force counts of the robots (active ones) that went through or into something."""
    r, tol = config.robot.radius, GUARD_TOLERANCE
    seg = np.asarray(layout.segments, dtype=float).reshape(-1, 4)
    xy0, xy1 = start[active, :2], end[active, :2]
    out = {"through": 0, "wall_overlap": 0, "pillar_overlap": 0, "robot_overlap": 0}
    if len(seg):
        out["through"] = int(_crossings(xy0, xy1, seg).sum())
        gaps = _segment_gaps(xy1, seg)
        out["wall_overlap"] = int((gaps < r + config.wall_radius - tol).sum())
    pillars = np.asarray(layout.pillars, dtype=float).reshape(-1, 3)
    if len(pillars):
        d = np.hypot(*(xy1[:, None, :] - pillars[None, :, :2]).transpose(2, 0, 1))
        out["pillar_overlap"] = int(((d - pillars[None, :, 2]) < r - tol).any(axis=1).sum())
    if len(xy1) > 1:
        d = np.hypot(*(xy1[:, None, :] - xy1[None, :, :]).transpose(2, 0, 1))
        d[np.diag_indices(len(d))] = np.inf
        out["robot_overlap"] = int((d < 2 * r - tol).sum() // 2)
    return out


def drive(
    generator: str, substeps: int, steps: int, robots: int, episode: int, seed: int
) -> dict[str, Any]:
    """``steps`` random control steps on layouts of ``generator``; the counts of the module
    docstring."""
    config = world_config(substeps)
    make = make_generator(generator, num_start_poses=robots)
    rng = np.random.default_rng([seed, substeps])
    lo = np.array([-config.robot.v_max, -config.robot.omega_max])
    hi = -lo
    totals = dict.fromkeys(
        ("through", "wall_overlap", "pillar_overlap", "robot_overlap", "after_guard"), 0
    )
    reverts = collided = blocked = blocked_counted = 0
    done = 0
    while done < steps:
        layout = make(np.random.default_rng([seed, done]))
        world = _Recording(layout, config, robots, make_rngs(seed + done))
        world.raw = []
        hold = np.zeros(robots, dtype=int)
        cmd = np.zeros((robots, 2))
        for _ in range(min(episode, steps - done)):
            renew = hold <= 0
            cmd[renew] = rng.uniform(lo, hi, (int(renew.sum()), 2))
            hold[renew] = rng.integers(1, 11, int(renew.sum()))
            hold -= 1
            result = world.step(cmd)
            start, raw = world.raw.pop()
            for key, value in violations(start, raw, layout, config, world.active).items():
                totals[key] += value
            after = violations(start, world.poses, layout, config, world.active)
            totals["after_guard"] += after["through"] + after["wall_overlap"]
            totals["after_guard"] += after["pillar_overlap"]
            moved = np.hypot(*result.true_odometry[:, :2].T)  # (N,)
            chord = (
                np.abs(result.commands[:, 0])
                * config.dt
                * np.sinc(result.commands[:, 1] * config.dt / (2 * np.pi))
            )
            stuck = (chord > 0.05) & (moved < 0.5 * chord)
            blocked += int(stuck.sum())
            blocked_counted += int((stuck & result.collided).sum())
            collided += int(result.collided.sum())
            done += 1
        reverts += world.guard_reverts
    return {
        "generator": generator,
        "substeps": substeps,
        "skin_m": config.robot.v_max * config.dt / substeps,
        "steps": steps,
        "robots": robots,
        **totals,
        "guard_reverts": reverts,
        "collided": collided / (steps * robots),
        "blocked": blocked,
        "pushes_counted": blocked_counted / blocked if blocked else None,
    }


def cost(substeps: int, steps: int, seed: int = 0) -> dict[str, float]:
    """Median ms per world step (physics only) and Python calls per step, 3 robots on an
    office floor driving random held commands."""
    config = world_config(substeps)
    layout = make_generator("office_floor")(np.random.default_rng(seed))
    world = World(layout, config, 3, make_rngs(seed))
    rng = np.random.default_rng(seed)
    hi = np.array([config.robot.v_max, config.robot.omega_max])
    commands = [rng.uniform(-hi, hi, (3, 2)) for _ in range(steps // 5 + 1)]
    times = []
    for k in range(steps):
        start = time.perf_counter()
        world.step(commands[k // 5])
        times.append(time.perf_counter() - start)
    profiler = cProfile.Profile()
    profiler.enable()
    for k in range(200):
        world.step(commands[k // 5 % len(commands)])
    profiler.disable()
    stats = pstats.Stats(profiler)
    calls = sum(row[1] for row in stats.stats.values()) / 200  # type: ignore[attr-defined]
    return {"ms_per_step": 1e3 * float(np.median(times)), "calls_per_step": calls}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--substeps", default="20,14,10,8,5", help="comma-separated counts")
    parser.add_argument("--steps", type=int, default=100_000, help="control steps per generator")
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--episode", type=int, default=500, help="steps per layout")
    parser.add_argument("--generators", default=",".join(GENERATORS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write the rows as JSON here")
    args = parser.parse_args(argv)
    rows = []
    for n in (int(v) for v in args.substeps.split(",")):
        row_cost = cost(n, 2000, args.seed)
        print(f"substeps {n}: {row_cost['ms_per_step']:.3f} ms, "
              f"{row_cost['calls_per_step']:.0f} calls per world step", flush=True)  # fmt: skip
        for name in args.generators.split(","):
            row = {**drive(name, n, args.steps, args.robots, args.episode, args.seed), **row_cost}
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Injected faults and the initial pose error of an episode (issue 14).

* :func:`perturb_starts`: with ``initial_error`` each robot's true start is its nominal start
  (its frame origin, what its SLAM believes: x̂ = 0, covariance P0) composed with an offset
  drawn from N(0, P0) in the robot's frame (stream ``start_error``).
* :class:`FaultPlan`: the ``faults`` of an :class:`EnvConfig` by step: which robots fail, are
  kidnapped or slip (see :class:`~polyslam_env.environment.config.FaultConfig`).
* :func:`kidnap`: moves a robot's true pose by the fault's distance in a random direction
  (stream ``faults``) to a spot where it fits.

Each fault that happens is reported as a :class:`FaultEvent` (its kind, step and what it did),
which the env puts in ``infos[agent]["faults"]`` at that step.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from polyslam_env.core.geometry import compose
from polyslam_env.environment.config import EnvConfig, FaultConfig
from polyslam_env.world.grid import FreeGrid
from polyslam_env.world.physics import World

__all__ = ["FaultEvent", "FaultPlan", "kidnap", "perturb_starts"]

#: Draws of an initial offset before a robot falls back to its nominal start (see
#: :func:`perturb_starts`); a kidnap tries this many random directions.
MAX_DRAWS = 64


def perturb_starts(world: World, p0: np.ndarray, rng: np.random.Generator) -> None:
    """Move every robot's true start (changes the world, before its first step) from its
    nominal pose x_i to x_i ⊕ e_i, e_i ~ N(0, ``p0``) (3, 3) in the robot's frame.

    A draw where the robot does not fit (:meth:`World.robot_fits`: walls, pillars, the robots
    placed so far; a few cm from a valid start cannot reach the inside of a closed obstacle)
    is redrawn (rejection sampling: e_i is then N(0, P0) conditioned on a free start); after
    :data:`MAX_DRAWS` misses the robot keeps its nominal pose. With P0's 5 cm and start poses
    placed with clearance to spare, a redraw is rare.
    """
    chol = np.linalg.cholesky(p0)  # (3, 3)
    nominal = world.poses
    for i in range(world.num_robots):
        for _ in range(MAX_DRAWS):
            pose = compose(nominal[i], chol @ rng.standard_normal(3))
            if world.robot_fits(i, pose):
                world.displace(i, pose)
                break


@dataclass(frozen=True)
class FaultEvent:
    """A fault that happened: ``kind`` at env ``step`` to ``robot``; a kidnap's true
    displacement (m, rad) and whether it found a free spot; a slip's window."""

    kind: str
    robot: int
    step: int
    moved: tuple[float, float, float] | None = None  # kidnap: (dx, dy, dθ) of the true pose
    done: bool | None = None  # kidnap: False when no free spot at the distance was found
    last_step: int | None = None  # slip: the last slipping step
    scale: float | None = None  # slip: true / reported motion

    def to_info(self) -> dict[str, Any]:
        """Plain data for ``infos`` (the unset fields left out)."""
        return {k: v for k, v in asdict(self).items() if v is not None}


class FaultPlan:
    """The faults of an episode indexed by step (built once from the config)."""

    def __init__(self, config: EnvConfig) -> None:
        self.num_robots = config.num_robots
        self.faults = config.fault_list
        self.fail_at = {f.robot: f.step for f in self.faults if f.kind == "fail"}

    def due(self, step: int, kind: str) -> list[FaultConfig]:
        """The faults of ``kind`` that start at ``step``."""
        return [f for f in self.faults if f.kind == kind and f.step == step]

    def slip(self, step: int) -> np.ndarray | None:
        """Per robot the slip factor (N,) during ``step`` (1 = no slip); None when none slips."""
        slipping = [f for f in self.faults if f.kind == "slip" and f.step <= step <= f.last_step]
        if not slipping:
            return None
        out = np.ones(self.num_robots)
        for f in slipping:
            out[f.robot] = f.scale
        return out


def fits(world: World, free: FreeGrid, i: int, pose: np.ndarray) -> bool:
    """Whether robot ``i`` may be put at ``pose`` (3,): clear of walls, pillars and the other
    robots (:meth:`World.robot_fits`) and in a free cell of ``free`` (which also rules out
    the inside of closed obstacles)."""
    return bool(free.free_at(pose[:2])) and world.robot_fits(i, pose)


def kidnap(
    world: World, fault: FaultConfig, rng: np.random.Generator, free: FreeGrid
) -> FaultEvent:
    """Move robot ``fault.robot``'s true pose by ``fault.distance`` in a random direction and
    turn it by ``fault.angle`` (changes the world). Directions are drawn from ``rng`` until the
    robot fits there (:func:`fits` with the free cells ``free``), at most :data:`MAX_DRAWS`;
    if none fits the robot stays and the event says ``done=False``."""
    i = fault.robot
    pose = world.poses[i]
    for psi in rng.uniform(-math.pi, math.pi, MAX_DRAWS).tolist():
        move = (fault.distance * math.cos(psi), fault.distance * math.sin(psi), fault.angle)
        target = pose + np.array(move)
        if fits(world, free, i, target):
            world.displace(i, target)
            return FaultEvent("kidnap", i, fault.step, moved=move, done=True)
    return FaultEvent("kidnap", i, fault.step, moved=(0.0, 0.0, 0.0), done=False)

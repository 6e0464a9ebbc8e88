"""Replaying precomputed paths in a noise-free :class:`~polyslam_env.world.physics.World`.

:func:`replay_paths` drives a fresh world with a :class:`~polyslam_env.scenarios.paths.Paths`
and records the true trajectory, camera visibility and beam hits; the path design script and
the tests check the paths' promises (who meets whom, no collisions, boundary seen) on it. True
motion does not depend on the seed (noise enters odometry and sensors only), so one replay holds
for all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import beam_endpoints
from polyslam_env.core.seeding import make_rngs
from polyslam_env.scenarios.paths import Paths
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World

__all__ = ["Replay", "contiguous_runs", "replay_paths"]


@dataclass(frozen=True, eq=False)
class Replay:
    """What the team did when driven by a :class:`Paths` (true, noise-free quantities).

    Sample k is the state after k steps (k = 0 is the start), so K steps give K + 1 samples.
    """

    layout: Layout
    poses: np.ndarray  # (K+1, N, 3) true poses
    visible: np.ndarray  # (K+1, N, N) bool, camera visibility (row sees column)
    collided: np.ndarray  # (K, N) bool, StepResult.collided of each step
    commands: np.ndarray  # (K, N, 2) the clipped commands the world applied
    hits: np.ndarray  # (K+1, N, B, 2) absolute beam hit points, NaN for no return
    guard_reverts: int  # World.guard_reverts at the end (0 for a clean run)
    beam_angles: np.ndarray = field(repr=False)  # (B,) rad

    def pair_distances(self) -> np.ndarray:  # (K+1, N, N)
        """Centre-to-centre distances between robots at every sample."""
        rel = self.poses[:, :, None, :2] - self.poses[:, None, :, :2]
        return np.asarray(np.hypot(rel[..., 0], rel[..., 1]))

    def mutual(self, i: int, j: int) -> np.ndarray:  # (K+1,) bool
        """Whether robots i and j see each other (both directions) at every sample."""
        return np.asarray(self.visible[:, i, j] & self.visible[:, j, i])

    def meetings(self, i: int, j: int) -> list[tuple[int, int]]:
        """Contiguous windows (first, last sample, inclusive) in which i and j see each other."""
        return contiguous_runs(self.mutual(i, j))

    def robot_hits(self, i: int) -> np.ndarray:  # (H, 2)
        """All finite hit points of robot i's beams over the run."""
        pts = self.hits[:, i].reshape(-1, 2)
        return np.asarray(pts[np.all(np.isfinite(pts), axis=1)])


def contiguous_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True in a (K,) bool mask as (first, last) indices, inclusive."""
    padded = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))  # starts and one-past-ends, alternating
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def replay_paths(
    paths: Paths,
    layout: Layout | None = None,
    config: WorldConfig | None = None,
    seed: int = 0,
) -> Replay:
    """Drive a fresh :class:`World` with ``paths`` from the map's start poses; record the truth.

    ``layout`` defaults to ``load_map(paths.map)``; ``config`` to ``WorldConfig(dt=paths.dt)``.
    """
    layout = load_map(paths.map) if layout is None else layout
    cfg = WorldConfig(dt=paths.dt) if config is None else config
    if not math.isclose(cfg.dt, paths.dt):
        raise ConfigError(f"dt: paths {paths.name!r} need dt = {paths.dt}, world has {cfg.dt}")
    world = World(layout, cfg, paths.num_robots, make_rngs(seed))
    angles = np.asarray(cfg.range_sensor.angles, dtype=float)  # (B,)
    poses, visible, hits = [world.poses], [_visible(world)], [_hit_points(world, angles)]
    collided, applied = [], []
    for k in range(paths.num_steps):
        result = world.step(paths.step_commands(k))
        collided.append(result.collided)
        applied.append(result.commands)
        poses.append(world.poses)
        visible.append(_visible(world))
        hits.append(_hit_points(world, angles))
    return Replay(
        layout=layout,
        poses=np.stack(poses),
        visible=np.stack(visible),
        collided=np.stack(collided),
        commands=np.stack(applied),
        hits=np.stack(hits),
        guard_reverts=world.guard_reverts,
        beam_angles=angles,
    )


def _visible(world: World) -> np.ndarray:  # (N, N) bool
    """Noise-free camera visibility of the world's current state."""
    mask, _, _ = world.camera_sensor.visible(
        world.poses, world.active, world.segments, world.pillars
    )
    return np.asarray(mask)


def _hit_points(world: World, angles: np.ndarray) -> np.ndarray:  # (N, B, 2)
    """True beam hit points in the absolute frame; NaN where a beam has no return."""
    pose = world.poses  # (N, 3)
    r = world.true_scan()  # (N, B)
    r = np.where(np.isfinite(r), r, np.nan)
    phi = pose[:, 2:3] + angles[None, :]  # (N, B)
    return beam_endpoints(pose[:, None, :2], phi, r)

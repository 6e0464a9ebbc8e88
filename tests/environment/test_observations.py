"""Unit tests of the on-board observation pieces (belief grid, encoder) against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.environment.observations import BeliefGrid, sweep_beliefs
from polyslam_env.environment.parallel import parallel_env


def _brute_force_sweep(
    grid: BeliefGrid, pose: np.ndarray, angles: np.ndarray, ranges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(free, hit) (n, n) marked one beam sample at a time, as the docstring describes."""
    free = np.zeros((grid.n, grid.n), dtype=bool)
    hit = np.zeros_like(free)
    samples = grid._t.size

    def mark(mask: np.ndarray, x: float, y: float) -> None:
        col = math.floor((x - grid.origin) / grid.resolution)
        row = math.floor((y - grid.origin) / grid.resolution)
        if 0 <= row < grid.n and 0 <= col < grid.n:
            mask[row, col] = True

    for a, r in zip(angles, ranges, strict=True):
        phi = pose[2] + a
        c, s = math.cos(phi), math.sin(phi)
        finite = math.isfinite(r)
        reach = min(r, grid.max_range) if finite else grid.max_range
        length = max(reach - 0.5 * grid.resolution, 0.0) if finite else reach
        for k in range(samples):
            t = length * (k / (samples - 1))
            mark(free, pose[0] + t * c, pose[1] + t * s)
        if finite:
            mark(hit, pose[0] + reach * c, pose[1] + reach * s)
    return free, hit


def test_belief_grid__sweep_matches_brute_force_samples() -> None:
    rng = np.random.default_rng(3)
    grid = BeliefGrid(size=4.0, resolution=0.1, max_range=1.5)
    expected_free = np.zeros_like(grid.free)
    expected_hit = np.zeros_like(grid.hit)
    angles = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])
    for _ in range(30):
        pose = np.array([*rng.uniform(-2.5, 2.5, 2), rng.uniform(-np.pi, np.pi)])
        ranges = np.where(rng.uniform(size=5) < 0.3, np.inf, rng.uniform(0.0, 2.0, 5))
        grid.sweep(pose, angles, ranges)
        free, hit = _brute_force_sweep(grid, pose, angles, ranges)
        expected_free |= free
        expected_hit |= hit
    # Samples sitting exactly on a cell edge could round either way; none do in this draw.
    assert np.array_equal(grid.free, expected_free)
    assert np.array_equal(grid.hit, expected_hit)
    assert grid.free.any() and grid.hit.any()


def test_sweep_beliefs__several_robots_at_once_equal_separate_sweeps() -> None:
    rng = np.random.default_rng(5)
    angles = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])
    together = [BeliefGrid(4.0, 0.1, 1.5) for _ in range(3)]
    apart = [BeliefGrid(4.0, 0.1, 1.5) for _ in range(3)]
    for _ in range(10):
        poses = np.column_stack([rng.uniform(-2.5, 2.5, (3, 2)), rng.uniform(-4, 4, 3)])
        ranges = np.where(rng.uniform(size=(3, 5)) < 0.3, np.inf, rng.uniform(0, 2, (3, 5)))
        sweep_beliefs(together, poses, angles, ranges)
        for grid, pose, r in zip(apart, poses, ranges, strict=True):
            grid.sweep(pose, angles, r)
    for a, b in zip(together, apart, strict=True):
        assert np.array_equal(a.free, b.free) and np.array_equal(a.hit, b.hit)
    with pytest.raises(ValueError, match="same size"):
        sweep_beliefs([together[0], BeliefGrid(4.0, 0.2, 1.5)], poses[:2], angles, ranges[:2])


def test_observations__vector_mode_folds_the_grid_mode_channels() -> None:
    envs = {
        mode: parallel_env(map="two_rooms", num_robots=2, observation__mode=mode)
        for mode in ("vector", "grid")
    }
    obs = {mode: env.reset(seed=4)[0] for mode, env in envs.items()}
    rng = np.random.default_rng(4)
    layout = envs["vector"]._encoder.vector_layout
    g = envs["vector"]._encoder.g
    for _ in range(30):
        actions = {a: rng.uniform([0.0, -0.5], [0.2, 0.5]) for a in envs["vector"].agents}
        obs = {mode: env.step(actions)[0] for mode, env in envs.items()}
        for agent, vec in obs["vector"].items():
            grid, short = obs["grid"][agent]["grid"], obs["grid"][agent]["vector"]
            folded = grid[0] * 1.0 + grid[2] * 0.5  # occupied 1, unknown 0.5, free 0
            assert np.array_equal(vec[layout["local_map"]].reshape(g, g), folded)
            rest = np.delete(vec, np.arange(len(vec))[layout["local_map"]])
            assert np.array_equal(rest, short)

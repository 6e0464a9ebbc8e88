"""The coverage grid's team sweep (compiled kernels) against the numpy oracle of the env's
former per-robot loop: gains counted before anything is marked, then each robot's marks."""

from __future__ import annotations

import numpy as np

from polyslam_env.metrics.coverage import CoverageGrid
from tests.core import reference


def test_sweep_team__equals_counting_then_marking_each_robot_with_the_oracle() -> None:
    rng = np.random.default_rng(0)
    free = rng.random((60, 70)) < 0.8
    origin, res, max_range = (-0.3, 0.2), 0.05, 1.2
    grid = CoverageGrid(free, origin, res)
    swept = np.zeros_like(free)
    mine = {r: np.zeros_like(free) for r in range(4)}
    total = 0
    for _ in range(30):
        active = rng.random(4) < 0.7
        robots = np.flatnonzero(active).tolist()
        poses = np.column_stack([rng.uniform(0.0, 3.0, (4, 2)), rng.uniform(-4, 4, 4)])
        angles = rng.uniform(-2, 2, 5)
        ranges = rng.uniform(0.0, 1.6, (4, 5))
        ranges[rng.random((4, 5)) < 0.2] = np.inf
        absolute = poses[active, 2:3] + angles
        cells = reference.even_scan_cells(
            poses[active, :2], absolute, ranges[active], max_range, origin, res, free.shape
        )
        want = np.zeros(4, dtype=int)
        want[active] = [reference.count_distinct_new(c, free, swept) for c in cells]
        for r, c in zip(robots, cells, strict=True):
            total += reference.count_distinct_new(c, free, swept)
            swept.reshape(-1)[c] = True
            mine[r].reshape(-1)[c] = True
        got = grid.sweep_team(poses, angles, ranges, max_range, active)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(grid.swept, swept)
        for r, m in grid.robot_swept.items():
            np.testing.assert_array_equal(m, mine[r])
        assert grid.coverage == total / free.sum()

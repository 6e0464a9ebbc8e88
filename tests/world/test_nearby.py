"""The wall-candidate grid against brute force, and the guard it speeds up."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import point_segment_distance
from polyslam_env.world.maps import load_map
from polyslam_env.world.nearby import SegmentGrid, segment_grid
from polyslam_env.world.physics import World, segments_cross


@pytest.mark.parametrize(("reach", "cell"), [(0.0, 0.1), (0.37, 0.2), (1.0, 0.5)])
def test_segment_grid__candidates_include_every_segment_within_reach(
    reach: float, cell: float
) -> None:
    rng = np.random.default_rng(0)
    segments = rng.uniform(0.0, 5.0, (60, 4))
    segments[:5, 2:] = segments[:5, :2]  # a few zero-length segments
    grid = SegmentGrid(segments, reach, cell)
    points = rng.uniform(-1.5, 6.5, (3000, 2))
    dist = point_segment_distance(points, segments)  # (M, S)
    for p, d in zip(points, dist, strict=True):
        near = np.flatnonzero(d <= reach)
        assert set(near) <= set(grid.candidates(p[None]).tolist())
    if reach < 1.0:  # ...and the lists are short: far fewer candidates than segments
        assert np.mean([len(grid.candidates(p[None])) for p in points[:300]]) < 0.5 * len(segments)


def test_segment_grid__several_points_get_the_union_and_no_segments_is_empty() -> None:
    rng = np.random.default_rng(1)
    segments = rng.uniform(0.0, 3.0, (20, 4))
    grid = SegmentGrid(segments, 0.3, 0.2)
    points = rng.uniform(0.0, 3.0, (4, 2))
    union = set().union(*(set(grid.candidates(p[None]).tolist()) for p in points))
    assert set(grid.candidates(points).tolist()) == union
    assert len(SegmentGrid(np.zeros((0, 4)), 0.3, 0.2).candidates(points)) == 0


def test_segment_grid__cached_per_layout() -> None:
    layout = load_map("paper", robot_radius=0.065)
    assert segment_grid(layout, 0.4, 0.2) is segment_grid(layout, 0.4, 0.2)
    assert segment_grid(layout, 0.4, 0.2) is not segment_grid(layout, 0.5, 0.2)


def test_guard__near_walls_give_the_same_answers_as_all_walls() -> None:
    layout = load_map("paper", robot_radius=0.065)
    world = World(layout, WorldConfig(), 3, make_rngs(0))
    rng = np.random.default_rng(2)
    lo, hi = layout.segments.reshape(-1, 2).min(0), layout.segments.reshape(-1, 2).max(0)
    crossings = deep = 0
    for _ in range(3000):
        start = np.column_stack([rng.uniform(lo, hi, (3, 2)), np.zeros(3)])
        step = rng.normal(size=(3, 2)) * rng.uniform(0.0, 0.25)
        end = start + np.column_stack([step, np.zeros(3)])
        walls = world._guard_walls(start, end)
        cross_all = segments_cross(start[:, :2], end[:, :2], world.segments)
        deep_all = world._too_deep(end[:, :2])
        assert np.array_equal(segments_cross(start[:, :2], end[:, :2], walls), cross_all)
        assert np.array_equal(world._too_deep(end[:, :2], walls), deep_all)
        crossings += int(cross_all.sum())
        deep += int(deep_all.sum())
    assert crossings > 50 and deep > 50  # both cases were exercised

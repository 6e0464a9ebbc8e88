"""Occupancy grids to layouts (world/floorplan.py), on grids made here: a generated layout
rasterised (the truth), with clutter and noise added, costmap-grown walls, thin laser spikes,
narrow gaps. The traced walls must lie within a cell plus the simplification tolerance of the
true walls both ways."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest
from scipy import ndimage

from polyslam_env.core.errors import MapFileError
from polyslam_env.world.floorplan import ImportOptions, layout_from_occupancy
from polyslam_env.world.generators import RoomsGenerator
from polyslam_env.world.grid import free_space_grid, label_components
from polyslam_env.world.layout import Layout, point_segment_distance
from polyslam_env.world.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

RES = 0.05  # m per cell


@functools.cache
def _truth(seed: int) -> Layout:
    return RoomsGenerator(width=8.0, height=6.0)(np.random.default_rng(seed))


def _raster(layout: Layout) -> OccupancyGrid:
    """Free where a cell's centre is more than half a cell from every wall, inside."""
    free = free_space_grid(layout, RES)
    cells = np.where(free.mask, FREE, OCCUPIED).astype(np.int8)
    return OccupancyGrid(cells, RES, (free.origin[0], free.origin[1], 0.0), "<test>")


def _with(grid: OccupancyGrid, cells: np.ndarray) -> OccupancyGrid:
    return OccupancyGrid(cells.astype(np.int8), grid.resolution, grid.origin, grid.source)


def _sample(walls: list[np.ndarray] | tuple[np.ndarray, ...], step: float = 0.02) -> np.ndarray:
    """Points every ``step`` along the walls (n, 2)."""
    out = []
    for w in walls:
        for a, b in itertools.pairwise(w):
            n = max(2, int(np.ceil(np.hypot(*(b - a)) / step)) + 1)
            out.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
    return np.vstack(out)


def _segments(walls: list[np.ndarray] | tuple[np.ndarray, ...]) -> np.ndarray:
    return np.vstack([np.hstack([w[:-1], w[1:]]) for w in walls])


def _clutter(grid: OccupancyGrid, rng: np.random.Generator, count: int) -> tuple[np.ndarray, list]:
    """Occupied boxes of 4–8 cells a side, each at least 12 cells inside free space."""
    cells = grid.cells.copy()
    deep = np.asarray(ndimage.distance_transform_edt(cells == FREE)) > 12
    boxes = []
    while len(boxes) < count:
        r, c = np.argwhere(deep)[rng.integers(deep.sum())]
        h, w = rng.integers(4, 9, size=2)
        if deep[r : r + h, c : c + w].all():
            cells[r : r + h, c : c + w] = OCCUPIED
            deep[max(0, r - 20) : r + h + 20, max(0, c - 20) : c + w + 20] = False
            boxes.append((r, c, h, w))
    return cells, boxes


@pytest.mark.parametrize("seed", range(3))
def test_import__walls_within_a_cell_of_the_truth_clutter_kept_noise_dropped(seed: int) -> None:
    rng = np.random.default_rng(seed)
    truth = _truth(seed)
    grid = _raster(truth)
    cells, boxes = _clutter(grid, rng, 3)
    free = np.argwhere(cells == FREE)
    specks = free[rng.choice(len(free), 40, replace=False)]  # single occupied cells: noise
    cells[specks[:, 0], specks[:, 1]] = OCCUPIED
    # free cells deep in walls or outside: separate free regions the import leaves out
    near_free = ndimage.binary_dilation(cells == FREE, structure=np.ones((3, 3), dtype=bool))
    deep = np.argwhere(~near_free)
    lone = deep[rng.choice(len(deep), 20, replace=False)]
    cells[lone[:, 0], lone[:, 1]] = FREE
    noisy = _with(grid, cells)
    tol = 0.05
    result = layout_from_occupancy(noisy, ImportOptions(tolerance=tol, start_separation=1.0))
    layout = result.layout
    # islands: the clutter boxes (4+ cells a side), not the one-cell specks
    assert len(layout.walls) - 1 == len(boxes)
    # Both ways within a cell's diagonal (a free cell's centre lies up to 1.5 cells from a
    # thin wall, its edge up to one cell; at a corner up to √2 cells) plus the tolerance.
    true_segs = _segments([*truth.walls, *layout.walls[1:]])
    bound = np.sqrt(2) * RES + tol + 1e-9
    assert point_segment_distance(_sample(layout.walls[:1]), true_segs).min(axis=1).max() <= bound
    assert (
        point_segment_distance(_sample(truth.walls), _segments(layout.walls)).min(axis=1).max()
        <= bound
    )
    free_grid = free_space_grid(layout, 0.025, 0.065)
    assert label_components(free_grid)[1] == 1
    assert len(layout.start_poses) == 3


def test_import__shrink_undoes_a_costmaps_grown_walls() -> None:
    """Walls grown by 0.2 m narrow the rooms generator's 0.6 m doors below the robot with its
    margin: warnings at the doors; shrinking by 0.2 m opens them again."""
    truth = _truth(0)
    grid = _raster(truth)
    grown = ndimage.distance_transform_edt(grid.cells == FREE) * RES <= 0.2
    costmap = _with(grid, np.where(grown, OCCUPIED, FREE))
    narrow = layout_from_occupancy(costmap, ImportOptions(start_separation=0.5))
    assert narrow.passages
    ends = np.vstack([w[[0, -1]] for w in truth.walls[1:]])  # door jambs among them
    for p in narrow.passages:
        assert p.width < 2 * (0.065 + 0.05)
        assert np.hypot(*(ends - [p.x, p.y]).T).min() < 0.6  # at a door
    opened = layout_from_occupancy(costmap, ImportOptions(shrink=0.2, start_separation=1.0))
    assert not opened.passages
    assert any("--shrink 0.2 m freed" in n for n in opened.notes)


def test_import__passage_found_where_two_rooms_meet_through_a_narrow_gap() -> None:
    cells = np.full((60, 100), OCCUPIED, dtype=np.int8)
    cells[5:55, 5:45] = FREE
    cells[5:55, 47:95] = FREE  # a wall two cells thick at columns 45–46 …
    cells[28:31, 45:47] = FREE  # … with a gap three cells (0.15 m) wide at rows 28–30
    grid = OccupancyGrid(cells, RES, (0.0, 0.0, 0.0), "<gap>")
    result = layout_from_occupancy(grid, ImportOptions(start_separation=1.0))
    assert len(result.passages) == 1
    p = result.passages[0]
    assert p.x == pytest.approx(46.0 * RES, abs=2 * RES)
    assert p.y == pytest.approx(29.5 * RES, abs=2 * RES)
    assert p.width == pytest.approx(0.15, abs=RES)
    assert p.area == pytest.approx(min(40, 48) * 50 * RES * RES, rel=0.25)


def test_import__keep_reachable_drops_laser_spikes() -> None:
    cells = np.full((80, 80), UNKNOWN, dtype=np.int8)
    cells[10:50, 10:50] = OCCUPIED
    cells[12:48, 12:48] = FREE
    cells[30, 48:75] = FREE  # a laser spike one cell wide through the wall, into unknown
    grid = OccupancyGrid(cells, RES, (0.0, 0.0, 0.0), "<spike>")
    every = layout_from_occupancy(grid, ImportOptions(start_separation=0.5)).layout
    reach = layout_from_occupancy(grid, ImportOptions(keep="reachable", start_separation=0.5))
    assert every.bounds[2] == pytest.approx(75 * RES, abs=1e-9)  # the spike is traced
    assert reach.layout.bounds[2] <= 48 * RES + 1e-9  # gone
    assert any("keep reachable" in n for n in reach.notes)


def test_import__starts_spread_or_near_a_point_and_clear() -> None:
    grid = _raster(_truth(1))
    spread = layout_from_occupancy(grid, ImportOptions(robots=4, start_separation=2.0)).layout
    xy = spread.start_poses[:, :2]
    assert min(np.hypot(*(a - b)) for i, a in enumerate(xy) for b in xy[:i]) >= 2.0
    assert (spread.clearance(xy) >= 2 * 0.065 + 0.05).all()
    near = layout_from_occupancy(
        grid, ImportOptions(robots=2, start_separation=0.5, start_near=(4.0, 3.0))
    ).layout
    assert np.hypot(*(near.start_poses[:, :2] - [4.0, 3.0]).T).max() < 2.0
    with pytest.raises(MapFileError, match="start poses 20 m apart"):
        layout_from_occupancy(grid, ImportOptions(robots=3, start_separation=20.0))


def test_import__no_room_for_a_robot_is_a_one_line_error() -> None:
    cells = np.full((20, 20), OCCUPIED, dtype=np.int8)
    cells[5:15, 9:11] = FREE  # 0.1 m wide
    with pytest.raises(MapFileError, match="<thin>: no free space is 0.23 m wide"):
        layout_from_occupancy(OccupancyGrid(cells, RES, (0, 0, 0), "<thin>"), ImportOptions())

"""Large floor plans (issue 14): office floors, warehouses, loops; the pillar hall (issue 18).

The generic guarantees (enclosed, connected for the robot, seeded) are checked as for the small
generators; the passage widths each generator promises are checked on the free-space raster:
a passage of width w lets a robot of radius r through exactly when the free space grown by r
stays connected, so growing the walls by ``w/2 − RESOLUTION`` (one cell of slack for the
raster) must keep it connected, and (for doors, which the office caps) growing them by
``w_max/2 + RESOLUTION`` must cut the rooms off.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators import (
    LoopGenerator,
    OfficeFloorGenerator,
    PillarHallGenerator,
    WarehouseGenerator,
    is_enclosed,
    make_generator,
)
from polyslam_env.world.grid import component_at, free_space_grid, label_components
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import layout_from_dict, layout_to_dict

SEEDS = range(8)
NAMES = ("office_floor", "warehouse", "loop", "pillar_hall")
SIZES = {
    "office_floor": (24.0, 14.0),
    "warehouse": (20.0, 12.0),
    "loop": (16.0, 10.0),
    "pillar_hall": (20.0, 12.0),
}
#: Check raster (m): neither of the generators' own check rasters (2 and 3 cm).
RESOLUTION = 0.025


@functools.cache
def _layouts(name: str) -> tuple[Layout, ...]:
    return tuple(make_generator(name)(np.random.default_rng(seed)) for seed in SEEDS)


def _components(layout: Layout, inflate: float) -> int:
    return label_components(free_space_grid(layout, RESOLUTION, inflate))[1]


def _fingerprint(layout: Layout) -> bytes:
    parts = [*(w.tobytes() for w in layout.walls), layout.pillars.tobytes()]
    return b"|".join([*parts, layout.start_poses.tobytes()])


@pytest.mark.parametrize("name", NAMES)
def test_large_generator__size_as_asked_and_enclosed(name: str) -> None:
    for seed, layout in zip(SEEDS, _layouts(name), strict=True):
        assert layout.bounds == (0.0, 0.0, *SIZES[name]), seed
        assert is_enclosed(layout), seed
        again = layout_from_dict(layout_to_dict(layout))
        assert _fingerprint(again) == _fingerprint(layout), seed


@pytest.mark.parametrize("name", NAMES)
def test_large_generator__starts_connected_apart_and_clear(name: str) -> None:
    gen = make_generator(name)
    assert isinstance(
        gen, OfficeFloorGenerator | WarehouseGenerator | LoopGenerator | PillarHallGenerator
    )
    for seed, layout in zip(SEEDS, _layouts(name), strict=True):
        grid = free_space_grid(layout, RESOLUTION, inflate=gen.robot_radius)
        _, count = label_components(grid)
        xy = layout.start_poses[:, :2]
        assert count == 1 and (component_at(grid, xy) == 1).all(), seed
        assert len(xy) == gen.num_start_poses, seed
        assert (layout.clearance(xy) >= 2 * gen.robot_radius + gen.margin).all(), seed
        gaps = [float(np.hypot(*(a - b))) for a, b in itertools.combinations(xy, 2)]
        assert min(gaps) >= gen.start_separation, seed


@pytest.mark.parametrize("name", NAMES)
def test_large_generator__seeded(name: str) -> None:
    again = make_generator(name)(np.random.default_rng(3))
    assert _fingerprint(again) == _fingerprint(_layouts(name)[3])
    walls = {b"|".join(w.tobytes() for w in lay.walls) for lay in _layouts(name)}
    assert len(walls) == len(SEEDS)


def test_pillar_hall__columns_keep_the_clearance_and_bays_are_open() -> None:
    """Columns of the drawn radii keep ``clearance`` from every wall and every other column
    (brute force over all pairs), so a robot passes everywhere at that width; partition walls
    cut the hall (at least two vertical walls inside the outer one)."""
    gen = PillarHallGenerator()
    for seed, layout in enumerate(_layouts("pillar_hall")):
        cols = layout.pillars
        assert len(cols) >= 8, seed
        lo, hi = gen.column_radius
        assert ((cols[:, 2] >= lo) & (cols[:, 2] <= hi)).all(), seed
        centres = cols[:, :2]
        wall_gap = layout_wall_gaps(layout, centres) - cols[:, 2]
        assert wall_gap.min() >= gen.clearance - 1e-9, seed
        for a, b in itertools.combinations(range(len(cols)), 2):
            gap = np.hypot(*(centres[a] - centres[b])) - cols[a, 2] - cols[b, 2]
            assert gap >= gen.clearance - 1e-9, (seed, a, b)
        assert _components(layout, gen.clearance / 2 - RESOLUTION) == 1, seed
        inner = [w for w in layout.walls[1:] if np.ptp(w[:, 0]) == 0.0]
        assert len({float(w[0, 0]) for w in inner}) >= gen.partitions[0], seed


def layout_wall_gaps(layout: Layout, points: np.ndarray) -> np.ndarray:
    """Distance (P,) from each point to the nearest wall segment (brute force)."""
    segs = layout.segments
    a, b = segs[:, :2], segs[:, 2:]
    ab = b - a
    t = np.clip(np.einsum("psk,sk->ps", points[:, None, :] - a, ab) / (ab * ab).sum(1), 0, 1)
    nearest = a + t[..., None] * ab
    return np.linalg.norm(points[:, None, :] - nearest, axis=-1).min(axis=1)


def test_office_floor__doors_between_min_and_max_width() -> None:
    lo, hi = OfficeFloorGenerator().door_width
    for seed, layout in enumerate(_layouts("office_floor")):
        assert _components(layout, lo / 2 - RESOLUTION) == 1, seed  # every door >= lo
        assert _components(layout, hi / 2 + RESOLUTION) > 1, seed  # no door wider than hi


def test_warehouse__aisles_at_least_min_width_with_shelves_and_pillars() -> None:
    gen = WarehouseGenerator()
    pillars = 0
    for seed, layout in enumerate(_layouts("warehouse")):
        assert _components(layout, gen.aisle_width[0] / 2 - RESOLUTION) == 1, seed
        boxes = [w for w in layout.walls[1:] if len(w) == 5 and np.array_equal(w[0], w[-1])]
        sides = [np.ptp(b, axis=0) for b in boxes]
        shelves = [s for s in sides if s.max() >= 2.0 and s.min() <= gen.shelf_depth[1] + 1e-9]
        assert len(shelves) >= 4, seed  # two rows at least, each cut by the cross aisle
        pillars += sum(s.max() <= gen.pillar_size[1] + 1e-9 for s in sides)
    assert pillars > 0


def test_loop__ring_around_a_solid_block() -> None:
    gen = LoopGenerator()
    for seed, layout in enumerate(_layouts("loop")):
        assert _components(layout, gen.corridor_width[0] / 2 - RESOLUTION) == 1, seed
        block = layout.walls[1]
        centre = block[:4].mean(axis=0)
        grid = free_space_grid(layout, RESOLUTION)
        assert not grid.free_at(centre[None])[0], seed  # the middle is solid
        width, height = SIZES["loop"]
        inner = np.ptp(block, axis=0)
        # The centre line runs half a corridor outside the block on every side.
        centre_line = inner + (np.array([width, height]) - inner) / 2
        assert 2 * centre_line.sum() >= 20.0, seed


@pytest.mark.parametrize(
    ("name", "kwargs", "field"),
    [
        ("office_floor", {"door_width": [0.1, 0.2]}, "door_width"),
        ("office_floor", {"height": 5.0}, "height"),
        ("office_floor", {"room_width": [3.0, 3.0], "width": 10.0}, "room_width"),
        ("office_floor", {"corridors": [1, 3]}, "corridors"),
        ("warehouse", {"aisle_width": [0.1, 1.0]}, "aisle_width"),
        ("warehouse", {"width": 6.0}, "width"),
        ("warehouse", {"pillar_size": [0.5, 0.3]}, "pillar_size"),
        ("loop", {"corridor_width": [1.6, 1.2]}, "corridor_width"),
        ("loop", {"width": 4.0, "height": 4.0}, "width"),
        ("loop", {"start_separation": -1.0}, "start_separation"),
        ("pillar_hall", {"missing": 1.5}, "missing"),
        ("pillar_hall", {"column_radius": [0.3, 0.1]}, "column_radius"),
        ("pillar_hall", {"partitions": [2, 12]}, "width"),
    ],
)
def test_large_generator__bad_value_names_field(
    name: str, kwargs: dict[str, object], field: str
) -> None:
    with pytest.raises(ConfigError, match=field):
        make_generator(name, **kwargs)

"""Procedural layouts: closed, connected for the robot, valid start poses, seeded by rng only."""

from __future__ import annotations

import functools
import itertools
from collections.abc import Mapping

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators import (
    CaveGenerator,
    GenerationError,
    RoomsGenerator,
    is_enclosed,
    make_generator,
)
from polyslam_env.world.grid import component_at, free_space_grid, label_components
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import layout_from_dict, layout_to_dict

SEEDS = range(30)
NAMES = ("rooms", "cave")
ROBOT_RADIUS = 0.065  # m, the generators' default robot
#: Check raster: 2.5 cm is neither of the rasters the generators check themselves (2 and 3 cm).
RESOLUTION = 0.025


@functools.cache
def _generated(name: str) -> tuple[Layout, ...]:
    return tuple(make_generator(name)(np.random.default_rng(seed)) for seed in SEEDS)


@pytest.fixture
def layouts() -> Mapping[str, tuple[Layout, ...]]:
    """30 seeded layouts per generator, built once per process and only when asked for."""
    return _LazyLayouts()


class _LazyLayouts(dict[str, tuple[Layout, ...]]):
    def __missing__(self, name: str) -> tuple[Layout, ...]:
        return _generated(name)


def _fingerprint(layout: Layout) -> bytes:
    parts = [w.tobytes() for w in layout.walls]
    return b"|".join([*parts, layout.pillars.tobytes(), layout.start_poses.tobytes()])


def _connected_with_poses(layout: Layout, resolution: float = RESOLUTION) -> bool:
    grid = free_space_grid(layout, resolution, inflate=ROBOT_RADIUS)
    _, count = label_components(grid)
    labels = component_at(grid, layout.start_poses[:, :2])
    return count == 1 and bool((labels == 1).all())


@pytest.mark.parametrize("name", NAMES)
def test_generator__outer_boundary_encloses_all_walls(
    layouts: Mapping[str, tuple[Layout, ...]], name: str
) -> None:
    for seed, layout in zip(SEEDS, layouts[name], strict=True):
        assert layout.outer_boundary is not None, seed
        assert is_enclosed(layout), seed


@pytest.mark.parametrize("name", NAMES)
def test_generator__free_space_connected_for_robot(
    layouts: Mapping[str, tuple[Layout, ...]], name: str
) -> None:
    for seed, layout in zip(SEEDS, layouts[name], strict=True):
        assert _connected_with_poses(layout), seed


@pytest.mark.parametrize("name", NAMES)
def test_generator__start_poses_clear_of_walls_and_each_other(
    layouts: Mapping[str, tuple[Layout, ...]], name: str
) -> None:
    gen = make_generator(name)
    assert isinstance(gen, RoomsGenerator | CaveGenerator)
    clear = 2 * gen.robot_radius + gen.margin
    for seed, layout in zip(SEEDS, layouts[name], strict=True):
        xy = layout.start_poses[:, :2]
        assert len(xy) == gen.num_start_poses, seed
        assert (layout.clearance(xy) >= clear).all(), seed
        gaps = [np.hypot(*(a - b)) for a, b in itertools.combinations(xy, 2)]
        assert min(gaps) >= clear, seed
        assert (np.abs(layout.start_poses[:, 2]) <= np.pi).all(), seed


@pytest.mark.parametrize("name", NAMES)
def test_generator__passes_map_file_validation(
    layouts: Mapping[str, tuple[Layout, ...]], name: str
) -> None:
    for seed, layout in zip(SEEDS, layouts[name], strict=True):
        again = layout_from_dict(layout_to_dict(layout))
        assert _fingerprint(again) == _fingerprint(layout), seed


@pytest.mark.parametrize("name", NAMES)
def test_generator__same_seed_gives_bit_identical_layout(
    layouts: Mapping[str, tuple[Layout, ...]], name: str
) -> None:
    for seed in (0, 7, 29):
        again = make_generator(name)(np.random.default_rng(seed))
        assert _fingerprint(again) == _fingerprint(layouts[name][seed]), seed


@pytest.mark.parametrize("name", NAMES)
def test_generator__different_seeds_give_different_layouts(
    layouts: Mapping[str, tuple[Layout, ...]], name: str
) -> None:
    walls_only = {b"|".join(w.tobytes() for w in lay.walls) for lay in layouts[name]}
    assert len(walls_only) == len(SEEDS)


@pytest.mark.parametrize("name", NAMES)
def test_generator__draws_only_from_the_given_rng(name: str) -> None:
    before = np.random.get_state()  # the legacy global stream must stay untouched
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    make_generator(name)(rng)
    after = np.random.get_state()
    assert np.array_equal(after[1], before[1]) and after[2:] == before[2:]
    assert rng.bit_generator.state != state


def test_rooms_generator__walls_are_axis_aligned(layouts: Mapping[str, tuple[Layout, ...]]) -> None:
    for seed, layout in zip(SEEDS, layouts["rooms"], strict=True):
        s = layout.segments
        assert ((s[:, 0] == s[:, 2]) | (s[:, 1] == s[:, 3])).all(), seed


def test_cave_generator__curves_finely_sampled(layouts: Mapping[str, tuple[Layout, ...]]) -> None:
    spacing = CaveGenerator().spacing
    for seed, layout in zip(SEEDS, layouts["cave"], strict=True):
        s = layout.segments
        # Resampling makes every piece at most the spacing; 1e-9 m is float round-off.
        assert np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]).max() <= spacing + 1e-9, seed


def test_cave_generator__islands_appear(layouts: Mapping[str, tuple[Layout, ...]]) -> None:
    islands = [len(layout.walls) - 1 for layout in layouts["cave"]]
    assert min(islands) == 0
    assert max(islands) == CaveGenerator().max_islands


@settings(max_examples=12, deadline=None)
@given(
    width=st.floats(1.5, 9.0),
    height=st.floats(1.5, 9.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_rooms_generator__any_size_is_connected(width: float, height: float, seed: int) -> None:
    layout = RoomsGenerator(width=width, height=height)(np.random.default_rng(seed))
    x0, y0, x1, y1 = layout.bounds
    assert (x1 - x0, y1 - y0) == pytest.approx((width, height), abs=1e-9)  # outline is exact
    assert is_enclosed(layout)
    assert _connected_with_poses(layout, resolution=0.03)


@settings(max_examples=8, deadline=None)
@given(
    width=st.floats(3.0, 8.0),
    height=st.floats(3.0, 8.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_cave_generator__any_size_is_connected(width: float, height: float, seed: int) -> None:
    layout = CaveGenerator(width=width, height=height)(np.random.default_rng(seed))
    x0, y0, x1, y1 = layout.bounds
    # The outline is stretched to the box before resampling; resampling only cuts corners.
    assert x1 - x0 == pytest.approx(width, rel=0.01)
    assert y1 - y0 == pytest.approx(height, rel=0.01)
    assert _connected_with_poses(layout, resolution=0.03)


def test_make_generator__passes_parameters() -> None:
    gen = make_generator("rooms", width=8, height=5, num_start_poses=4)
    layout = gen(np.random.default_rng(0))
    assert layout.bounds == (0.0, 0.0, 8.0, 5.0)
    assert layout.num_start_poses == 4


def test_make_generator__unknown_name_lists_valid_names() -> None:
    with pytest.raises(
        ValueError,
        match=r"'maze'.*valid names: angled_floor, cave, cave_system, curved_floor, loop,"
        r" office_floor, pillar_hall, rooms, warehouse",
    ):
        make_generator("maze")


def test_make_generator__unknown_parameter_named() -> None:
    with pytest.raises(ConfigError, match="door_widht"):
        make_generator("rooms", door_widht=0.5)


@pytest.mark.parametrize(
    ("name", "kwargs", "field"),
    [
        ("rooms", {"door_width": 0.1}, "door_width"),
        ("rooms", {"width": -1.0}, "width"),
        ("rooms", {"min_room_size": 0.5}, "min_room_size"),
        ("rooms", {"split_prob": 1.5}, "split_prob"),
        ("cave", {"roughness": 0.9}, "roughness"),
        ("cave", {"island_gap": 0.1}, "island_gap"),
        ("cave", {"num_start_poses": 0}, "num_start_poses"),
    ],
)
def test_make_generator__bad_value_names_field(
    name: str, kwargs: dict[str, float], field: str
) -> None:
    with pytest.raises(ConfigError, match=field):
        make_generator(name, **kwargs)


def test_generator__infeasible_request_raises_instead_of_returning_broken_map() -> None:
    # A 1.3 m room has ~0.9 m of usable side: 64 poses 0.18 m apart cannot fit.
    gen = RoomsGenerator(width=1.3, height=1.3, num_start_poses=64, max_tries=3)
    with pytest.raises(GenerationError, match="3 tries"):
        gen(np.random.default_rng(0))

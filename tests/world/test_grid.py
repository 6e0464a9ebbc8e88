"""Free-space rasters: exact against brute force, no leaks through walls, connectivity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.world.generators import CaveGenerator
from polyslam_env.world.grid import (
    FreeGrid,
    blocking_distance,
    component_at,
    free_space_grid,
    is_connected,
    label_components,
    polygon_mask,
)
from polyslam_env.world.layout import Layout, points_in_polygon
from polyslam_env.world.maps import load_map

BOX = np.array([[0, 0], [4, 0], [4, 3], [0, 3], [0, 0]], dtype=float)


def _brute_force(layout: Layout, grid: FreeGrid, inflate: float) -> np.ndarray:
    """The free mask by definition, cell by cell against every wall: (H, W)."""
    c = grid.centres()
    free = layout.contains(c) & (layout.clearance(c) > blocking_distance(grid.resolution, inflate))
    outer = layout.outer_boundary
    for w in layout.walls:
        if w is not outer and len(w) >= 4 and np.array_equal(w[0], w[-1]):
            free &= ~points_in_polygon(c, w)
    return np.asarray(free)


@pytest.mark.parametrize(
    ("layout", "resolution", "inflate"),
    [
        (load_map("paper"), 0.05, 0.0),
        (load_map("paper"), 0.04, 0.065),
        (load_map("office"), 0.05, 0.1),
        (CaveGenerator(max_islands=2)(np.random.default_rng(4)), 0.07, 0.3),  # 2 islands,
    ],
    ids=["paper-5cm", "paper-4cm", "office-5cm", "cave-islands"],
)
def test_free_space_grid__matches_brute_force(
    layout: Layout, resolution: float, inflate: float
) -> None:
    grid = free_space_grid(layout, resolution, inflate)
    assert np.array_equal(grid.mask, _brute_force(layout, grid, inflate))


def _points(n: int, lo: tuple[float, float], hi: tuple[float, float]) -> st.SearchStrategy:
    """n points (n, 2) with x in [lo[0], hi[0]] and y in [lo[1], hi[1]]."""
    xy = st.tuples(st.floats(lo[0], hi[0]), st.floats(lo[1], hi[1]))
    return st.lists(xy, min_size=n, max_size=n).map(np.array)


@settings(max_examples=30, deadline=None)
@given(
    ends=_points(8, (0.2, 0.2), (3.8, 2.8)),
    centres=_points(2, (0.5, 0.5), (3.5, 2.5)),
    resolution=st.floats(0.02, 0.2),
    inflate=st.floats(0.0, 0.5),
)
def test_free_space_grid__random_walls_match_brute_force(
    ends: np.ndarray, centres: np.ndarray, resolution: float, inflate: float
) -> None:
    inner = [ends[2 * k : 2 * k + 2] for k in range(4)]  # four straight walls
    pillars = np.column_stack([centres, [0.1, 0.2]])
    layout = Layout("random", walls=(BOX, *inner), pillars=pillars)
    grid = free_space_grid(layout, resolution, inflate)
    assert np.array_equal(grid.mask, _brute_force(layout, grid, inflate))


@settings(max_examples=30, deadline=None)
@given(
    vertices=st.lists(
        st.tuples(st.floats(0.0, 2 * np.pi), st.floats(0.3, 1.5)), min_size=3, max_size=40
    )
)
def test_polygon_mask__matches_points_in_polygon(vertices: list[tuple[float, float]]) -> None:
    """A star-shaped polygon: vertices (angle, radius) about the origin, in angle order."""
    angles, radii = np.array(sorted(vertices)).T
    poly = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    poly = np.vstack([poly, poly[:1]])
    xs, ys = np.linspace(-1.6, 1.6, 57), np.linspace(-1.6, 1.6, 43)
    gx, gy = np.meshgrid(xs, ys)
    expected = points_in_polygon(np.stack([gx, gy], axis=-1), poly)
    assert np.array_equal(polygon_mask(poly, xs, ys), expected)


@pytest.mark.parametrize("resolution", [0.01, 0.02, 0.025, 0.05, 0.1, 0.07])
@pytest.mark.parametrize("x_wall", [2.0, 2.005, 2.0125])
def test_free_space_grid__thin_wall_never_leaks(resolution: float, x_wall: float) -> None:
    wall = np.array([[x_wall, 0.0], [x_wall, 3.0]])
    layout = Layout("split", walls=(BOX, wall))
    grid = free_space_grid(layout, resolution, inflate=0.0)
    assert label_components(grid)[1] == 2


@pytest.mark.parametrize(("door", "connected"), [(0.12, False), (0.3, True)])
def test_free_space_grid__door_must_fit_the_robot(door: float, connected: bool) -> None:
    lower = np.array([[2.0, 0.0], [2.0, 1.5 - door / 2]])
    upper = np.array([[2.0, 1.5 + door / 2], [2.0, 3.0]])
    layout = Layout("door", walls=(BOX, lower, upper))
    # A 0.13 m robot passes a 0.3 m door, not a 0.12 m one.
    assert is_connected(free_space_grid(layout, 0.02, inflate=0.065)) is connected


def test_free_space_grid__open_walls_use_bounding_box() -> None:
    walls = (np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([[0.0, 1.0], [2.0, 1.0]]))
    grid = free_space_grid(Layout("open", walls=walls), 0.1)
    xy = grid.centres()[grid.mask]
    assert len(xy) > 0
    assert ((xy[:, 0] > 0) & (xy[:, 0] < 2) & (xy[:, 1] > 0) & (xy[:, 1] < 1)).all()


def test_free_space_grid__covers_the_layout_with_border() -> None:
    grid = free_space_grid(Layout("box", walls=(BOX,)), 0.1)
    assert grid.origin == (-0.1, -0.1)
    assert grid.shape == (32, 42)
    assert not grid.mask[0].any() and not grid.mask[-1].any()
    # Free area: (4 - 2·0.05) × (3 - 2·0.05) up to one cell ring (0.1 m cells).
    assert grid.free_area == pytest.approx(3.9 * 2.9, abs=0.1 * 2 * (3.9 + 2.9))


def test_free_grid__cell_of_and_component_at() -> None:
    grid = free_space_grid(Layout("box", walls=(BOX,)), 0.1)
    row, col, inside = grid.cell_of(np.array([[0.05, 0.05], [1.23, 2.71], [-5.0, 1.0]]))
    assert row[:2].tolist() == [1, 28] and col[:2].tolist() == [1, 13]
    assert inside.tolist() == [True, True, False]
    labels = component_at(grid, np.array([[1.0, 1.0], [3.0, 2.0], [-5.0, 1.0], [4.05, 1.0]]))
    assert labels.tolist() == [1, 1, 0, 0]


@pytest.mark.parametrize(("resolution", "inflate"), [(0.0, 0.0), (-0.1, 0.0), (0.1, -1.0)])
def test_free_space_grid__bad_arguments_raise(resolution: float, inflate: float) -> None:
    with pytest.raises(ValueError, match="resolution|inflate"):
        free_space_grid(Layout("box", walls=(BOX,)), resolution, inflate)

"""What every layout generator shares: the common fields, the retry template, the checks.

A generator is a frozen :class:`GeneratorBase` dataclass (its parameters, validated on
construction) whose family draws the walls in :meth:`GeneratorBase._draw` (and round pillars in
:meth:`GeneratorBase._pillars`). Calling it runs the template :meth:`GeneratorBase.__call__`:

1. draw walls (then pillars, given the walls) from the ``rng`` only;
2. check the outer boundary encloses every wall (:func:`is_enclosed`);
3. check the free space is one 4-connected component at the robot's inflation, on two rasters
   (:func:`connected_for_robot`; families with walls at angles to the raster accept raster
   slivers there, :attr:`GeneratorBase.slivers`);
4. place ``num_start_poses`` start poses in it, each at least ``2·robot_radius + margin`` from
   every wall and ``max(start_separation, 2·robot_radius + margin)`` from each other;
5. pass the map-file validation (``layout_from_dict(layout_to_dict(...))``).

A draw that fails a check is thrown away and redrawn from the same ``rng`` (at most
``max_tries`` times, then :class:`GenerationError`), so a caller never gets a broken map; the
same generator state gives a bit-identical layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import ClassVar, Protocol

import numpy as np

from polyslam_env.core.config import Config, check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.grid import (
    FreeGrid,
    connected_up_to_slivers,
    free_space_grid,
    is_connected,
)
from polyslam_env.world.layout import Layout, point_segment_distance, points_in_polygon
from polyslam_env.world.maps import layout_from_dict, layout_to_dict

__all__ = [
    "CONNECTIVITY_CHECKS",
    "SHARED_FIELDS",
    "GenerationError",
    "GeneratorBase",
    "LayoutGenerator",
    "Walls",
    "connected_for_robot",
    "is_enclosed",
]

#: Rasters on which generated free space must be one component: (resolution m, extra inflation
#: over the robot radius in units of ``margin``). Two resolutions and a fattened robot make the
#: guarantee robust to the raster a caller later checks with.
CONNECTIVITY_CHECKS: tuple[tuple[float, float], ...] = ((0.02, 0.0), (0.03, 1.0))
#: Candidate start positions drawn per try.
_START_CANDIDATES = 512
#: Candidates whose exact wall clearance is computed at once.
_CLEARANCE_CHUNK = 64

Walls = list[np.ndarray]  # polylines, each (k, 2)


class LayoutGenerator(Protocol):
    """Anything that turns a random generator into a layout."""

    def __call__(self, rng: np.random.Generator) -> Layout: ...


class GenerationError(RuntimeError):
    """No valid layout was drawn within ``max_tries`` (the parameters are probably infeasible)."""


@dataclass(frozen=True)
class GeneratorBase(Config):
    """The fields every generator has, and the retry template (module docstring).

    A family redeclares ``width``, ``height`` and ``name`` (and ``start_separation`` where its
    floors are large) with its own defaults; its own fields follow these in the dataclass
    (:data:`SHARED_FIELDS` lists these). ``width`` and ``height`` are the public size of the
    floor (the env sizes its observation grids by them); the walls lie in that box.
    """

    width: float = 20.0  # m, the box the layout is drawn in (from the origin)
    height: float = 12.0  # m
    start_separation: float = 0.0  # m, least distance between start poses
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m, slack on every clearance
    max_tries: int = 20
    name: str = "layout"

    #: Cells a separate raster sliver may have (touching the main free space diagonally) in the
    #: connectivity check (:func:`~polyslam_env.world.grid.connected_up_to_slivers`): 0 for
    #: the rectilinear families, where none can arise; walls meeting at an angle to the raster
    #: leave one- or two-cell slivers that the robot's centre reaches through the corner.
    slivers: ClassVar[int] = 0

    def validate(self) -> None:
        check_positive("width", self.width)
        check_positive("height", self.height)
        check_positive("robot_radius", self.robot_radius)
        check_positive("margin", self.margin)
        check_range("start_separation", self.start_separation, 0.0, 1e3)
        check_range("num_start_poses", self.num_start_poses, 1, 64)
        check_range("max_tries", self.max_tries, 1, 10_000)
        if not self.name:
            raise ConfigError("name: must be a non-empty string, got ''")

    @property
    def start_clearance(self) -> float:
        """m: the least distance of a start pose from a wall (and from another start)."""
        return 2 * self.robot_radius + self.margin

    def _draw(self, rng: np.random.Generator) -> Walls:
        """The family's walls (the outer boundary among them), drawn from ``rng`` only."""
        raise NotImplementedError

    def _pillars(self, rng: np.random.Generator, walls: Walls) -> np.ndarray:  # (P, 3)
        """Round pillars x, y, r given the walls; none unless the family places some."""
        return np.zeros((0, 3))

    def __call__(self, rng: np.random.Generator) -> Layout:
        for _ in range(self.max_tries):
            walls = self._draw(rng)
            pillars = self._pillars(rng, walls)
            layout = Layout(name=self.name, walls=tuple(walls), pillars=pillars)
            if not is_enclosed(layout):
                continue
            grid = connected_for_robot(layout, self.robot_radius, self.margin, self.slivers)
            if grid is None:
                continue
            poses = self._start_poses(layout, grid, rng)
            if poses is None:
                continue
            data = layout_to_dict(
                Layout(name=self.name, walls=layout.walls, pillars=pillars, start_poses=poses)
            )
            source = f"<{self.name} generator>"
            return layout_from_dict(data, source=source, robot_radius=self.robot_radius)
        raise GenerationError(
            f"{type(self).__name__}: no valid layout in {self.max_tries} tries; "
            f"the parameters are probably infeasible: {self.to_dict()}"
        )

    def _start_poses(
        self, layout: Layout, grid: FreeGrid, rng: np.random.Generator
    ) -> np.ndarray | None:
        """``num_start_poses`` poses (n, 3) in free space, clear of walls, and
        ``start_separation`` (at least the wall clearance) from each other, or None."""
        clear = self.start_clearance
        apart = max(clear, self.start_separation)
        x0, y0, x1, y1 = layout.bounds
        cand = rng.uniform([x0, y0], [x1, y1], size=(_START_CANDIDATES, 2))  # (C, 2)
        heading = rng.uniform(-np.pi, np.pi, size=_START_CANDIDATES)  # (C,)
        free = np.flatnonzero(grid.free_at(cand) & layout.contains(cand))
        chosen: list[int] = []
        for c0 in range(0, len(free), _CLEARANCE_CHUNK):  # exact clearance only where needed
            idx = free[c0 : c0 + _CLEARANCE_CHUNK]
            for i in idx[layout.clearance(cand[idx]) >= clear]:
                if all(math.dist(cand[i], cand[j]) >= apart for j in chosen):
                    chosen.append(int(i))
                    if len(chosen) == self.num_start_poses:
                        return np.column_stack([cand[chosen], heading[chosen]])
        return None


#: The fields of :class:`GeneratorBase`, in order.
SHARED_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(GeneratorBase))


def is_enclosed(layout: Layout, tol: float = 1e-9) -> bool:
    """Whether the layout has an outer boundary and every wall vertex lies inside it or on it."""
    outer = layout.outer_boundary
    if outer is None:
        return False
    segs = np.hstack([outer[:-1], outer[1:]])  # (S, 4)
    for wall in layout.walls:
        if wall is outer:
            continue
        on = point_segment_distance(wall, segs).min(axis=-1) <= tol
        if not (points_in_polygon(wall, outer) | on).all():
            return False
    return True


def connected_for_robot(
    layout: Layout, radius: float, margin: float, slivers: int = 0
) -> FreeGrid | None:
    """The first check raster if free space is one component on every check raster
    (:data:`CONNECTIVITY_CHECKS`; up to raster slivers of at most ``slivers`` cells), else
    None."""
    first = None
    for resolution, extra in CONNECTIVITY_CHECKS:
        grid = free_space_grid(layout, resolution, radius + extra * margin)
        one = connected_up_to_slivers(grid, slivers) if slivers else is_connected(grid)
        if not one:
            return None
        first = first or grid
    return first

"""Seeded procedural layouts (STYLE habit 5): a generator object, ``generator(rng) -> Layout``.

* :class:`RoomsGenerator` — axis-aligned rooms by recursive division, one door per dividing
  wall (so the rooms form a tree and every room is reachable), optionally with corridors.
* :class:`CaveGenerator` — a smooth random closed outline (a radius made of a few Fourier
  terms, finely sampled) with optional rock islands inside.

Both draw only from the ``rng`` they are given (same generator state ⇒ bit-identical layout)
and guarantee, for a robot of ``robot_radius``:

* a closed outer boundary enclosing every wall;
* free space that is one 4-connected component at the robot's inflation, checked on two
  rasters (see :func:`_connected_for_robot`);
* ``num_start_poses`` start poses in that free space, each at least ``2·robot_radius +
  margin`` from every wall and from each other;
* a layout that passes the map-file validation (``layout_from_dict(layout_to_dict(...))``).

A draw that fails a check is thrown away and redrawn from the same ``rng`` (at most
``max_tries`` times, then :class:`GenerationError`), so a caller never gets a broken map.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from polyslam_env.core.config import Config, check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.grid import FreeGrid, free_space_grid, is_connected
from polyslam_env.world.layout import (
    Layout,
    point_segment_distance,
    points_in_polygon,
)
from polyslam_env.world.maps import layout_from_dict, layout_to_dict

#: Rasters on which generated free space must be one component: (resolution m, extra inflation
#: over the robot radius in units of ``margin``). Two resolutions and a fattened robot make the
#: guarantee robust to the raster a caller later checks with.
_CONNECTIVITY_CHECKS: tuple[tuple[float, float], ...] = ((0.02, 0.0), (0.03, 1.0))
#: Candidate start positions drawn per try.
_START_CANDIDATES = 512
#: Roughness of the cave islands' outlines (see :func:`_blob`).
_ISLAND_ROUGHNESS = 0.25
#: Candidates whose exact wall clearance is computed at once.
_CLEARANCE_CHUNK = 64
#: Rooms-generator coordinates (wall positions, doors) are multiples of this (m).
_SNAP = 0.05


class LayoutGenerator(Protocol):
    """Anything that turns a random generator into a layout."""

    def __call__(self, rng: np.random.Generator) -> Layout: ...


class GenerationError(RuntimeError):
    """No valid layout was drawn within ``max_tries`` (the parameters are probably infeasible)."""


Walls = list[np.ndarray]  # polylines, each (k, 2)


# -- rooms ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class RoomsGenerator(Config):
    """Rooms by recursive division of a ``width × height`` rectangle, with doors and corridors.

    A room larger than ``max_room_size`` on a side is always split, one that can still be split
    into two rooms of at least ``min_room_size`` is split with probability ``split_prob``.
    A split is a wall with one door, or with probability ``corridor_prob`` a corridor of
    ``corridor_width`` between two walls, each with one door. Walls never end in a door, and
    doors keep ``2·robot_radius + margin`` from corners.
    """

    width: float = 6.0  # m
    height: float = 4.0  # m
    min_room_size: float = 1.2  # m, smallest room side
    max_room_size: float = 2.5  # m, rooms with a longer side are always split
    split_prob: float = 0.5
    door_width: float = 0.6  # m
    corridor_prob: float = 0.25
    corridor_width: float = 0.7  # m
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m, slack on every clearance
    max_tries: int = 20
    name: str = "rooms"

    def validate(self) -> None:
        for key in (
            "width",
            "height",
            "min_room_size",
            "max_room_size",
            "door_width",
            "corridor_width",
            "robot_radius",
            "margin",
        ):
            check_positive(key, getattr(self, key))
        check_range("split_prob", self.split_prob, 0.0, 1.0)
        check_range("corridor_prob", self.corridor_prob, 0.0, 1.0)
        _check_common(self.num_start_poses, self.max_tries, self.name)
        gap = 2 * (self.robot_radius + self.margin)
        if self.door_width <= gap:
            raise ConfigError(
                f"door_width: must exceed 2·(robot_radius + margin) = {gap:g} m,"
                f" got {self.door_width!r}"
            )
        if self.corridor_width <= gap:
            raise ConfigError(
                f"corridor_width: must exceed 2·(robot_radius + margin) ="
                f" {gap:g} m, got {self.corridor_width!r}"
            )
        need = self.door_width + 2 * self._door_margin
        if self.min_room_size < need:
            raise ConfigError(
                f"min_room_size: must be >= door_width + 2 door margins = "
                f"{need:g} m, got {self.min_room_size!r}"
            )
        if self.max_room_size < self.min_room_size:
            raise ConfigError(
                f"max_room_size: must be >= min_room_size, got {self.max_room_size!r}"
            )
        if min(self.width, self.height) < self.min_room_size:
            raise ConfigError(
                f"width/height: both must be >= min_room_size "
                f"({self.min_room_size:g} m), got {self.width!r} × {self.height!r}"
            )

    @property
    def _door_margin(self) -> float:
        """Distance a door (or a wall end next to a door) keeps from a corner."""
        return 2 * self.robot_radius + self.margin

    def __call__(self, rng: np.random.Generator) -> Layout:
        return _generate(self, self._draw, rng)

    def _draw(self, rng: np.random.Generator) -> Walls:
        walls: list[_Wall] = []
        stack = [(0.0, 0.0, self.width, self.height)]
        while stack:
            rect = stack.pop()
            stack.extend(self._split(rect, walls, rng))
        outer = np.array(
            [[0, 0], [self.width, 0], [self.width, self.height], [0, self.height], [0, 0]],
            dtype=float,
        )
        return [outer] + [piece for w in walls for piece in w.pieces()]

    def _split(self, rect: _Rect, walls: list[_Wall], rng: np.random.Generator) -> list[_Rect]:
        """Add the walls of one split of ``rect`` and return the rooms to split further."""
        x0, y0, x1, y1 = rect
        w, h = x1 - x0, y1 - y0
        if max(w, h) <= self.max_room_size and rng.random() >= self.split_prob:
            return []
        corridor = rng.random() < self.corridor_prob
        vertical_first = w > h or (w == h and rng.random() < 0.5)
        for vertical in (vertical_first, not vertical_first):
            for cw in (self.corridor_width, 0.0) if corridor else (0.0,):
                c = self._split_position(rect, vertical, cw, walls, rng)
                if c is not None:
                    return self._add_split(rect, vertical, c, cw, walls, rng)
        return []

    def _split_position(
        self, rect: _Rect, vertical: bool, cw: float, walls: list[_Wall], rng: np.random.Generator
    ) -> float | None:
        """A snapped wall position across ``rect`` whose walls end clear of every door."""
        x0, y0, x1, y1 = rect
        lo, hi = (x0, x1) if vertical else (y0, y1)
        first = math.ceil(round((lo + self.min_room_size) / _SNAP, 6))
        last = math.floor(round((hi - self.min_room_size - cw) / _SNAP, 6))
        if last < first:
            return None
        cand = np.round(np.arange(first, last + 1) * _SNAP, 9)  # (n,)
        sides = (y0, y1) if vertical else (x0, x1)
        span = (x0, x1) if vertical else (y0, y1)
        ok = np.ones(len(cand), dtype=bool)
        for d0, d1 in _doors_on(walls, not vertical, sides, span):
            for pos in (cand, cand + cw):
                ok &= (pos < d0 - self._door_margin) | (pos > d1 + self._door_margin)
        if not ok.any():
            return None
        return float(rng.choice(cand[ok]))

    def _add_split(
        self,
        rect: _Rect,
        vertical: bool,
        c: float,
        cw: float,
        walls: list[_Wall],
        rng: np.random.Generator,
    ) -> list[_Rect]:
        x0, y0, x1, y1 = rect
        lo, hi = (y0, y1) if vertical else (x0, x1)
        far = round(c + cw, 9)  # the far side of a corridor (== c without one)
        for pos in (c, far) if cw > 0 else (c,):
            walls.append(_Wall(vertical, pos, lo, hi, self._door(lo, hi, rng)))
        if vertical:
            return [(x0, y0, c, y1), (far, y0, x1, y1)]
        return [(x0, y0, x1, c), (x0, far, x1, y1)]

    def _door(self, lo: float, hi: float, rng: np.random.Generator) -> tuple[float, float]:
        first = math.ceil(round((lo + self._door_margin) / _SNAP, 6))
        last = math.floor(round((hi - self._door_margin - self.door_width) / _SNAP, 6))
        start = (
            round(float(rng.integers(first, last + 1)) * _SNAP, 9)
            if last >= first
            else lo + (hi - lo - self.door_width) / 2
        )
        return start, start + self.door_width


_Rect = tuple[float, float, float, float]  # x0, y0, x1, y1


@dataclass
class _Wall:
    """An axis-aligned dividing wall at ``pos`` from ``lo`` to ``hi`` with door gaps."""

    vertical: bool  # x = pos, y in [lo, hi]; else y = pos, x in [lo, hi]
    pos: float
    lo: float
    hi: float
    door: tuple[float, float]

    def pieces(self) -> list[np.ndarray]:
        """The wall as 2-point polylines with the door cut out."""
        out = []
        for a, b in ((self.lo, self.door[0]), (self.door[1], self.hi)):
            if b - a > 1e-9:
                pts = (
                    [[self.pos, a], [self.pos, b]]
                    if self.vertical
                    else [[a, self.pos], [b, self.pos]]
                )
                out.append(np.array(pts, dtype=float))
        return out


def _doors_on(
    walls: list[_Wall], vertical: bool, sides: tuple[float, float], span: tuple[float, float]
) -> list[tuple[float, float]]:
    """Doors of walls with orientation ``vertical`` lying on a line in ``sides`` within ``span``."""
    return [
        w.door
        for w in walls
        if w.vertical == vertical
        and any(abs(w.pos - s) < 1e-9 for s in sides)
        and w.door[1] > span[0]
        and w.door[0] < span[1]
    ]


# -- caves ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class CaveGenerator(Config):
    """A curved cave filling a ``width × height`` box, with up to ``max_islands`` rock islands.

    The outline is star-shaped: radius ρ(φ) = 1 + Σ_{k=2}^{harmonics+1} a_k cos(kφ + φ_k)
    with random phases and amplitudes a_k ∝ u_k/k summing to ``roughness`` (so ρ stays in
    [1 − roughness, 1 + roughness]), stretched to the box and resampled every ``spacing``.
    Islands are smaller blobs of the same kind, kept ``island_gap`` from every other wall.
    """

    width: float = 6.0  # m
    height: float = 4.0  # m
    harmonics: int = 7
    roughness: float = 0.5
    max_islands: int = 2
    island_radius: tuple[float, float] = (0.25, 0.5)  # m, range of the mean island radius
    island_gap: float = 0.6  # m, least distance from an island to any other wall
    spacing: float = 0.03  # m, polyline sample spacing of the curved walls
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m
    max_tries: int = 20
    name: str = "cave"

    def validate(self) -> None:
        for key in ("width", "height", "spacing", "robot_radius", "margin", "island_gap"):
            check_positive(key, getattr(self, key))
        check_range("harmonics", self.harmonics, 1, 32)
        check_range("roughness", self.roughness, 0.0, 0.6)
        check_range("max_islands", self.max_islands, 0, 16)
        r_lo, r_hi = self.island_radius
        check_positive("island_radius[0]", r_lo)
        check_range("island_radius[1]", r_hi, r_lo, 0.25 * min(self.width, self.height))
        check_range("spacing", self.spacing, 1e-3, 0.1)
        gap = 2 * (self.robot_radius + self.margin)
        if self.island_gap <= gap:
            raise ConfigError(
                f"island_gap: must exceed 2·(robot_radius + margin) = {gap:g} m,"
                f" got {self.island_gap!r}"
            )
        _check_common(self.num_start_poses, self.max_tries, self.name)

    def __call__(self, rng: np.random.Generator) -> Layout:
        return _generate(self, self._draw, rng)

    def _draw(self, rng: np.random.Generator) -> Walls:
        outline = _blob(rng, self.harmonics, self.roughness)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        outline = (outline - lo) / (hi - lo) * np.array([self.width, self.height])
        walls = [_resample_closed(outline, self.spacing)]
        for _ in range(int(rng.integers(0, self.max_islands + 1))):
            island = self._island(rng, walls)
            if island is not None:
                walls.append(island)
        return walls

    def _island(self, rng: np.random.Generator, walls: Walls) -> np.ndarray | None:
        """A rock island clear of ``walls`` by ``island_gap``, or None after a few tries."""
        segs = np.vstack([np.hstack([w[:-1], w[1:]]) for w in walls])  # (S, 4)
        for _ in range(20):
            radius = rng.uniform(*self.island_radius)
            centre = rng.uniform([0.0, 0.0], [self.width, self.height])
            shape = _blob(rng, 3, _ISLAND_ROUGHNESS) * radius + centre
            # Cheap necessary test first: the island reaches (1 - roughness)·radius from its
            # centre in every direction, so a nearer wall is certainly too close.
            reach = (1.0 - _ISLAND_ROUGHNESS) * radius + self.island_gap
            if point_segment_distance(centre, segs).min() < reach:
                continue
            poly = _resample_closed(shape, self.spacing)
            if not points_in_polygon(poly, walls[0]).all():
                continue
            if point_segment_distance(poly, segs).min() >= self.island_gap:
                return poly
        return None


def _blob(rng: np.random.Generator, harmonics: int, roughness: float) -> np.ndarray:
    """A densely sampled star-shaped closed curve around the origin, mean radius 1: (K+1, 2)."""
    phi = np.linspace(0.0, 2 * np.pi, 1025)  # (K+1,), last == first angle
    k = np.arange(2, harmonics + 2)  # (h,)
    raw = rng.uniform(0.2, 1.0, size=harmonics) / k
    amp = roughness * raw / raw.sum()
    phase = rng.uniform(0.0, 2 * np.pi, size=harmonics)
    rho = 1.0 + (amp * np.cos(np.outer(phi, k) + phase)).sum(axis=1)
    pts = np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])
    pts[-1] = pts[0]
    return pts


def _resample_closed(poly: np.ndarray, spacing: float) -> np.ndarray:
    """A closed polyline (first == last) resampled at equal arc length ≤ ``spacing``."""
    seg = np.hypot(*np.diff(poly, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])  # (k,)
    n = max(8, math.ceil(s[-1] / spacing))
    t = np.linspace(0.0, s[-1], n + 1)
    out = np.column_stack([np.interp(t, s, poly[:, 0]), np.interp(t, s, poly[:, 1])])
    out[-1] = out[0]
    return out


# -- shared: checks, start poses, retries ---------------------------------------------------
def _check_common(num_start_poses: int, max_tries: int, name: str) -> None:
    check_range("num_start_poses", num_start_poses, 1, 64)
    check_range("max_tries", max_tries, 1, 10_000)
    if not name:
        raise ConfigError("name: must be a non-empty string, got ''")


def _generate(
    gen: RoomsGenerator | CaveGenerator,
    draw: Callable[[np.random.Generator], Walls],
    rng: np.random.Generator,
) -> Layout:
    """Draw walls, check them and place start poses; redraw on failure (bounded)."""
    for _ in range(gen.max_tries):
        layout = Layout(name=gen.name, walls=tuple(draw(rng)))
        if not is_enclosed(layout):
            continue
        grid = _connected_for_robot(layout, gen.robot_radius, gen.margin)
        if grid is None:
            continue
        poses = _start_poses(layout, grid, gen, rng)
        if poses is None:
            continue
        data = layout_to_dict(Layout(name=gen.name, walls=layout.walls, start_poses=poses))
        source = f"<{gen.name} generator>"
        return layout_from_dict(data, source=source, robot_radius=gen.robot_radius)
    raise GenerationError(
        f"{type(gen).__name__}: no valid layout in {gen.max_tries} tries; "
        f"the parameters are probably infeasible: {gen.to_dict()}"
    )


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


def _connected_for_robot(layout: Layout, radius: float, margin: float) -> FreeGrid | None:
    """The first check raster if free space is one component on every check raster."""
    first = None
    for resolution, extra in _CONNECTIVITY_CHECKS:
        grid = free_space_grid(layout, resolution, radius + extra * margin)
        if not is_connected(grid):
            return None
        first = first or grid
    return first


def _start_poses(
    layout: Layout,
    grid: FreeGrid,
    gen: RoomsGenerator | CaveGenerator,
    rng: np.random.Generator,
) -> np.ndarray | None:
    """``num_start_poses`` poses (n, 3) in free space, clear of walls and each other, or None."""
    clear = 2 * gen.robot_radius + gen.margin
    x0, y0, x1, y1 = layout.bounds
    cand = rng.uniform([x0, y0], [x1, y1], size=(_START_CANDIDATES, 2))  # (C, 2)
    heading = rng.uniform(-np.pi, np.pi, size=_START_CANDIDATES)  # (C,)
    free = np.flatnonzero(grid.free_at(cand) & layout.contains(cand))
    chosen: list[int] = []
    for c0 in range(0, len(free), _CLEARANCE_CHUNK):  # exact clearance only where needed
        idx = free[c0 : c0 + _CLEARANCE_CHUNK]
        for i in idx[layout.clearance(cand[idx]) >= clear]:
            if all(math.dist(cand[i], cand[j]) >= clear for j in chosen):
                chosen.append(int(i))
                if len(chosen) == gen.num_start_poses:
                    return np.column_stack([cand[chosen], heading[chosen]])
    return None


# -- registry -------------------------------------------------------------------------------
GENERATORS: dict[str, type[RoomsGenerator] | type[CaveGenerator]] = {
    "rooms": RoomsGenerator,
    "cave": CaveGenerator,
}


def make_generator(name: str, **kwargs: Any) -> LayoutGenerator:
    """A generator by name (``"rooms"``, ``"cave"``) with its parameters validated."""
    cls = GENERATORS.get(name)
    if cls is None:
        raise ValueError(
            f"unknown layout generator {name!r}; valid names: {', '.join(sorted(GENERATORS))}"
        )
    return cls.from_dict(kwargs, where=name)

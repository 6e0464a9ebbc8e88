"""Seeded procedural layouts (STYLE habit 5): a generator object, ``generator(rng) -> Layout``.

* :class:`RoomsGenerator` — axis-aligned rooms by recursive division, one door per dividing
  wall (so the rooms form a tree and every room is reachable), optionally with corridors.
* :class:`CaveGenerator` — a smooth random closed outline (a radius made of a few Fourier
  terms, finely sampled) with optional rock islands inside.

Large floor plans (20 × 12 m and up, issue 14), axis-aligned, coordinates multiples of 5 cm:

* :class:`OfficeFloorGenerator` — rooms off one or two long corridors, one door each;
* :class:`WarehouseGenerator` — shelf rows (long thin closed boxes) with aisles, a cross aisle
  and free-standing pillars in an open loading area;
* :class:`LoopGenerator` — a corridor loop around a solid block;
* :class:`PillarHallGenerator` — a hall of round structural columns on a jittered grid, cut
  into bays by partition walls with openings (pillars for point-landmark sensing and map
  alignment, issues 17 and 18).

Their start poses keep ``start_separation`` from each other, so a team does not start in one
room. All draw only from the ``rng`` they are given (same generator state ⇒ bit-identical layout)
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

import itertools
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


# -- large floor plans: shared pieces ---------------------------------------------------------
Range = tuple[float, float]  # (low, high), both inclusive


def _check_span(name: str, span: Range, low: float, high: float) -> None:
    """``span`` = (a, b) with low <= a <= b <= high, else a ConfigError naming ``name``."""
    a, b = span
    check_range(f"{name}[0]", a, low, high)
    check_range(f"{name}[1]", b, a, high)


def _units(value: float) -> int:
    """``value`` (m) in snap units, rounded."""
    return round(value / _SNAP)


def _draw_snapped(rng: np.random.Generator, span: Range) -> float:
    """A multiple of the snap uniformly in ``span`` (m), or its lower end if none lies inside."""
    lo, hi = math.ceil(round(span[0] / _SNAP, 6)), math.floor(round(span[1] / _SNAP, 6))
    return round((float(rng.integers(lo, hi + 1)) if hi >= lo else span[0] / _SNAP) * _SNAP, 9)


def _partition(
    rng: np.random.Generator, length: float, count: int | None, span: Range
) -> list[float] | None:
    """Widths (m, snapped) of ``count`` pieces (None: a feasible count drawn at random) that
    sum to ``length``, each within ``span``; None if no count fits. Every piece starts at the
    smallest width and the rest is dealt out one snap unit at a time to random pieces below
    the largest width."""
    total, lo, hi = _units(length), math.ceil(round(span[0] / _SNAP, 6)), _units(span[1])
    n_min, n_max = max(1, math.ceil(total / hi)), total // lo if lo > 0 else 0
    if count is not None:
        n_min = n_max = count
    if n_max < n_min or not n_min * lo <= total <= n_min * hi:
        return None
    n = int(rng.integers(n_min, n_max + 1))
    widths = np.full(n, lo)
    for _ in range(total - n * lo):
        open_ = np.flatnonzero(widths < hi)
        widths[open_[int(rng.integers(len(open_)))]] += 1
    return [round(float(w) * _SNAP, 9) for w in widths]


def _tiles(length: float, span: Range) -> bool:
    """Whether some number of pieces with widths in ``span`` (snapped) sums to ``length``."""
    total, lo, hi = _units(length), math.ceil(round(span[0] / _SNAP, 6)), _units(span[1])
    return lo > 0 and any(n * lo <= total <= n * hi for n in range(1, total // lo + 1))


def _box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """A closed axis-aligned rectangle (5, 2): a solid block when inside the outline."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]], dtype=float)


def _line_with_gaps(
    fixed: float, lo: float, hi: float, gaps: list[tuple[float, float]], vertical: bool
) -> Walls:
    """The wall ``x = fixed`` (vertical) or ``y = fixed`` from ``lo`` to ``hi`` without the
    ``gaps`` (doors, openings), as 2-point polylines."""
    out: Walls = []
    start = lo
    for a, b in [*sorted(gaps), (hi, hi)]:
        if a - start > 1e-9:
            pts = [[fixed, start], [fixed, a]] if vertical else [[start, fixed], [a, fixed]]
            out.append(np.array(pts, dtype=float))
        start = max(start, b)
    return out


def _cuts(lo: float, widths: list[float]) -> list[float]:
    """Boundaries lo, lo + w0, … of consecutive pieces (snapped sums)."""
    return [round(lo + float(c), 9) for c in np.concatenate([[0.0], np.cumsum(widths)])]


def _outer(width: float, height: float) -> np.ndarray:
    return _box(0.0, 0.0, width, height)


# -- office floor -----------------------------------------------------------------------------
@dataclass(frozen=True)
class OfficeFloorGenerator(Config):
    """An office floor: rooms off one or two long corridors running along the floor's width.

    The floor is cut across its height into bands of rooms and ``corridors`` corridors (a count
    drawn in the range) of a width drawn from ``corridor_width``; each band is cut along the
    width into rooms of a width drawn from ``room_width``, separated by full-height walls.
    Every room has a door (width drawn from ``door_width``) onto a corridor it borders (a room
    between two corridors onto one or both of them); between two corridors one room slot is
    left open as a hall joining them. Doors keep ``2·robot_radius + margin`` from corners.
    """

    width: float = 24.0  # m
    height: float = 14.0  # m
    corridors: tuple[int, int] = (1, 2)  # range of the number of long corridors
    corridor_width: Range = (1.4, 2.0)  # m
    room_width: Range = (3.0, 5.0)  # m, along the corridor
    min_room_depth: float = 3.0  # m, across the corridor
    door_width: Range = (0.8, 1.0)  # m
    start_separation: float = 4.0  # m, least distance between start poses
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m
    max_tries: int = 20
    name: str = "office_floor"

    def validate(self) -> None:
        for key in ("width", "height", "min_room_depth", "robot_radius", "margin"):
            check_positive(key, getattr(self, key))
        check_range("start_separation", self.start_separation, 0.0, 1e3)
        _check_span("corridors", self.corridors, 1, 2)
        gap = 2 * (self.robot_radius + self.margin)
        _check_span("corridor_width", self.corridor_width, gap, 0.5 * self.height)
        _check_span("door_width", self.door_width, gap, self.room_width[0])
        need = self.door_width[1] + 2 * (2 * self.robot_radius + self.margin)
        _check_span("room_width", self.room_width, need, self.width)
        if not _tiles(self.width, self.room_width):
            raise ConfigError(
                f"room_width: no number of rooms of {self.room_width!r} m fills the width"
                f" {self.width!r} m"
            )
        bands = self.corridors[1] + 1
        need_h = bands * self.min_room_depth + self.corridors[1] * self.corridor_width[1]
        if self.height < need_h:
            raise ConfigError(
                f"height: {self.corridors[1]} corridors of up to {self.corridor_width[1]:g} m"
                f" and {bands} bands of rooms >= min_room_depth need {need_h:g} m,"
                f" got {self.height!r}"
            )
        _check_common(self.num_start_poses, self.max_tries, self.name)

    def __call__(self, rng: np.random.Generator) -> Layout:
        return _generate(self, self._draw, rng, self.start_separation)

    def _draw(self, rng: np.random.Generator) -> Walls:
        n_corr = int(rng.integers(self.corridors[0], self.corridors[1] + 1))
        cw = _draw_snapped(rng, self.corridor_width)
        depth_span = (self.min_room_depth, self.height)
        depths = _partition(rng, self.height - n_corr * cw, n_corr + 1, depth_span)
        if depths is None:
            return [_outer(self.width, self.height)]  # infeasible draw: fails the start check
        walls: Walls = [_outer(self.width, self.height)]
        y = 0.0
        for band, depth in enumerate(depths):
            y0, y1 = y, round(y + depth, 9)
            below, above = band > 0, band < n_corr  # corridor below / above this band
            walls += self._band(rng, y0, y1, below, above)
            y = round(y1 + cw, 9)
        return walls

    def _band(
        self, rng: np.random.Generator, y0: float, y1: float, below: bool, above: bool
    ) -> Walls:
        """Rooms between y0 and y1, doors onto the corridor(s) below and/or above."""
        widths = _partition(rng, self.width, None, self.room_width)
        assert widths is not None, "room_width was validated to tile the width"
        xs = _cuts(0.0, widths)
        hall = int(rng.integers(len(widths))) if below and above and len(widths) > 1 else None
        gaps_below: list[tuple[float, float]] = []
        gaps_above: list[tuple[float, float]] = []
        corner = 2 * self.robot_radius + self.margin
        for k, (a, b) in enumerate(itertools.pairwise(xs)):
            if k == hall:
                gaps_below.append((a, b))
                gaps_above.append((a, b))
                continue
            sides = [g for g, on in ((gaps_below, below), (gaps_above, above)) if on]
            if len(sides) == 2 and rng.random() < 0.5:
                sides = [sides[int(rng.integers(2))]]
            for gaps in sides:
                dw = _draw_snapped(rng, self.door_width)
                start = _draw_snapped(rng, (a + corner, b - corner - dw))
                gaps.append((start, round(start + dw, 9)))
        walls = [w for x in xs[1:-1] for w in _line_with_gaps(x, y0, y1, [], vertical=True)]
        if below:
            walls += _line_with_gaps(y0, 0.0, self.width, gaps_below, vertical=False)
        if above:
            walls += _line_with_gaps(y1, 0.0, self.width, gaps_above, vertical=False)
        return walls


# -- warehouse --------------------------------------------------------------------------------
@dataclass(frozen=True)
class WarehouseGenerator(Config):
    """A warehouse: rows of shelves (long thin closed boxes) along the width, with aisles.

    At one end (left or right, drawn) an open loading area of a width drawn from ``open_area``
    holds ``pillars`` (a count drawn in the range) free-standing square pillars of a side drawn
    from ``pillar_size``; the rest is shelf rows of a depth drawn from ``shelf_depth``
    separated by aisles drawn from ``aisle_width`` (also between the rows and the outer walls),
    every row cut by one cross aisle of a width drawn from ``cross_aisle_width``. Pillars keep
    ``aisle_width[0]`` from every other wall, so every passage is at least that wide.
    """

    width: float = 20.0  # m
    height: float = 12.0  # m
    shelf_depth: Range = (0.8, 1.2)  # m
    aisle_width: Range = (1.2, 1.8)  # m
    cross_aisle_width: Range = (1.6, 2.4)  # m
    open_area: Range = (3.0, 5.0)  # m
    pillars: tuple[int, int] = (2, 5)
    pillar_size: Range = (0.3, 0.5)  # m, side of a square pillar
    start_separation: float = 4.0  # m
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m
    max_tries: int = 20
    name: str = "warehouse"

    def validate(self) -> None:
        for key in ("width", "height", "robot_radius", "margin"):
            check_positive(key, getattr(self, key))
        check_range("start_separation", self.start_separation, 0.0, 1e3)
        gap = 2 * (self.robot_radius + self.margin)
        _check_span("shelf_depth", self.shelf_depth, _SNAP, self.height)
        _check_span("aisle_width", self.aisle_width, gap, self.height)
        _check_span("cross_aisle_width", self.cross_aisle_width, gap, self.width)
        _check_span("open_area", self.open_area, 0.0, self.width)
        _check_span("pillars", self.pillars, 0, 64)
        _check_span("pillar_size", self.pillar_size, _SNAP, 2.0)
        need_w = self.open_area[1] + self.cross_aisle_width[1] + self.aisle_width[1] + 2.0
        if self.width < need_w:
            raise ConfigError(
                f"width: the open area, cross aisle, an end aisle and two 1 m shelves need"
                f" {need_w:g} m, got {self.width!r}"
            )
        need_h = 2 * self.aisle_width[1] + self.shelf_depth[1]
        if self.height < need_h:
            raise ConfigError(
                f"height: one shelf row between two aisles needs {need_h:g} m, got {self.height!r}"
            )
        _check_common(self.num_start_poses, self.max_tries, self.name)

    def __call__(self, rng: np.random.Generator) -> Layout:
        return _generate(self, self._draw, rng, self.start_separation)

    def _draw(self, rng: np.random.Generator) -> Walls:
        open_w = _draw_snapped(rng, self.open_area)
        end_w = _draw_snapped(rng, self.aisle_width)
        open_left = bool(rng.random() < 0.5)
        x0, x1 = (open_w, self.width - end_w) if open_left else (end_w, self.width - open_w)
        cross_w = _draw_snapped(rng, self.cross_aisle_width)
        third = (x1 - x0 - cross_w) / 3
        cx = _draw_snapped(rng, (x0 + third, x1 - third - cross_w))
        walls: Walls = [_outer(self.width, self.height)]
        y = _draw_snapped(rng, self.aisle_width)
        while True:
            depth = _draw_snapped(rng, self.shelf_depth)
            if self.height - (y + depth) < self.aisle_width[0] - 1e-9:
                break
            top = round(y + depth, 9)
            walls += [_box(x0, y, cx, top), _box(round(cx + cross_w, 9), y, x1, top)]
            y = round(top + _draw_snapped(rng, self.aisle_width), 9)
        area = (0.0, x0) if open_left else (x1, self.width)
        count = int(rng.integers(self.pillars[0], self.pillars[1] + 1))
        for _ in range(count):
            pillar = self._pillar(rng, area, walls)
            if pillar is not None:
                walls.append(pillar)
        return walls

    def _pillar(self, rng: np.random.Generator, area: Range, walls: Walls) -> np.ndarray | None:
        """A square pillar in the open area ``area`` (x range) keeping ``aisle_width[0]`` from
        every wall, or None after a few tries. Box-to-box distances are exact: the nearest
        points of two disjoint convex polygons include a vertex of one of them."""
        clear = self.aisle_width[0]
        segs = np.vstack([np.hstack([w[:-1], w[1:]]) for w in walls])  # (S, 4)
        verts = np.vstack(walls)  # (V, 2)
        for _ in range(20):
            side = _draw_snapped(rng, self.pillar_size)
            lo, hi = area[0] + clear, area[1] - clear - side
            if hi < lo:
                return None
            px = _draw_snapped(rng, (lo, hi))
            py = _draw_snapped(rng, (clear, self.height - clear - side))
            box = _box(px, py, round(px + side, 9), round(py + side, 9))
            own = np.hstack([box[:-1], box[1:]])  # (4, 4)
            near = min(
                point_segment_distance(box, segs).min(), point_segment_distance(verts, own).min()
            )
            if near >= clear - 1e-9:
                return box
        return None


# -- loop -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoopGenerator(Config):
    """A corridor loop around a solid rectangular block filling the middle of the floor.

    Each of the four sides of the corridor has its own width drawn from ``corridor_width``, so
    the loop is not symmetric (a robot cannot tell the sides apart by width alone otherwise).
    The loop's centre line is at least ``2·(width + height) − 4·corridor_width[1]`` long.
    """

    width: float = 16.0  # m
    height: float = 10.0  # m
    corridor_width: Range = (1.2, 1.6)  # m
    start_separation: float = 4.0  # m
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m
    max_tries: int = 20
    name: str = "loop"

    def validate(self) -> None:
        for key in ("width", "height", "robot_radius", "margin"):
            check_positive(key, getattr(self, key))
        check_range("start_separation", self.start_separation, 0.0, 1e3)
        gap = 2 * (self.robot_radius + self.margin)
        _check_span("corridor_width", self.corridor_width, gap, 0.5 * min(self.width, self.height))
        block = min(self.width, self.height) - 2 * self.corridor_width[1]
        if block < 2 * _SNAP:
            raise ConfigError(
                f"width/height: no room for the inner block with corridors up to"
                f" {self.corridor_width[1]:g} m, got {self.width!r} × {self.height!r}"
            )
        if self.loop_length < 20.0:
            raise ConfigError(
                f"width/height: the loop's centre line ({self.loop_length:g} m) must be"
                f" >= 20 m, got {self.width!r} × {self.height!r}"
            )
        _check_common(self.num_start_poses, self.max_tries, self.name)

    @property
    def loop_length(self) -> float:
        """Least length (m) of the loop's centre line, with the widest corridors."""
        return 2 * (self.width + self.height) - 4 * self.corridor_width[1]

    def __call__(self, rng: np.random.Generator) -> Layout:
        return _generate(self, self._draw, rng, self.start_separation)

    def _draw(self, rng: np.random.Generator) -> Walls:
        left, bottom, right, top = (_draw_snapped(rng, self.corridor_width) for _ in range(4))
        block = _box(left, bottom, round(self.width - right, 9), round(self.height - top, 9))
        return [_outer(self.width, self.height), block]


# -- pillar hall ------------------------------------------------------------------------------
@dataclass(frozen=True)
class PillarHallGenerator(Config):
    """A hall of round columns: partition walls across the width cut it into bays, each wall
    with one or two openings (widths from ``opening_width``); round columns (radius from
    ``column_radius``) stand on a grid of a spacing drawn from ``column_spacing``, each moved
    by up to ``jitter`` in x and y, a fraction ``missing`` of the grid points left empty.
    A column keeps ``clearance`` from every wall and from every other column's surface, so
    every passage is at least that wide.
    """

    width: float = 20.0  # m
    height: float = 12.0  # m
    partitions: tuple[int, int] = (2, 3)  # partition walls across the width
    opening_width: Range = (1.2, 2.0)  # m
    column_spacing: Range = (2.0, 2.8)  # m
    column_radius: Range = (0.12, 0.2)  # m
    jitter: float = 0.4  # m
    missing: float = 0.15  # fraction of grid points without a column
    clearance: float = 0.9  # m
    start_separation: float = 4.0  # m
    num_start_poses: int = 3
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m
    max_tries: int = 20
    name: str = "pillar_hall"

    def validate(self) -> None:
        for key in ("width", "height", "robot_radius", "margin", "clearance"):
            check_positive(key, getattr(self, key))
        check_range("start_separation", self.start_separation, 0.0, 1e3)
        check_range("jitter", self.jitter, 0.0, 10.0)
        check_range("missing", self.missing, 0.0, 1.0)
        _check_span("partitions", self.partitions, 0, 16)
        _check_span("opening_width", self.opening_width, 2 * (self.robot_radius + self.margin),
                    self.height / 2)  # fmt: skip
        _check_span("column_spacing", self.column_spacing, _SNAP, max(self.width, self.height))
        _check_span("column_radius", self.column_radius, _SNAP, 1.0)
        bay = self.width / (self.partitions[1] + 1)
        if bay < 2 * self.clearance:
            raise ConfigError(
                f"width: {self.partitions[1]} partitions leave bays of {bay:g} m, less than"
                f" twice the clearance {self.clearance:g} m; got {self.width!r}"
            )
        _check_common(self.num_start_poses, self.max_tries, self.name)

    def __call__(self, rng: np.random.Generator) -> Layout:
        return _generate(self, self._draw, rng, self.start_separation, self._columns)

    def _draw(self, rng: np.random.Generator) -> Walls:
        count = int(rng.integers(self.partitions[0], self.partitions[1] + 1))
        bay = self.width / (count + 1)
        walls: Walls = [_outer(self.width, self.height)]
        for k in range(1, count + 1):
            x = _draw_snapped(rng, (k * bay - 0.25 * bay, k * bay + 0.25 * bay))
            doors = 1 + int(rng.random() < 0.5)
            gaps: list[tuple[float, float]] = []
            band = self.height / doors
            for d in range(doors):
                w = _draw_snapped(rng, self.opening_width)
                y = _draw_snapped(rng, (d * band + 0.1 * band, (d + 1) * band - 0.1 * band - w))
                gaps.append((y, round(y + w, 9)))
            walls += _line_with_gaps(x, 0.0, self.height, gaps, vertical=True)
        return walls

    def _columns(self, rng: np.random.Generator, walls: Walls) -> np.ndarray:
        """Columns (P, 3) x, y, r on the jittered grid, each keeping ``clearance`` from the
        walls and from the columns placed before it."""
        spacing = float(rng.uniform(*self.column_spacing))
        segs = np.vstack([np.hstack([w[:-1], w[1:]]) for w in walls])  # (S, 4)
        xs = np.arange(spacing / 2, self.width, spacing)
        ys = np.arange(spacing / 2, self.height, spacing)
        placed: list[tuple[float, float, float]] = []
        for x, y in itertools.product(xs, ys):
            jit = rng.uniform(-self.jitter, self.jitter, size=2)
            radius = float(rng.uniform(*self.column_radius))
            if rng.random() < self.missing:
                continue
            c = np.array([x, y]) + jit
            if point_segment_distance(c, segs).min() - radius < self.clearance:
                continue
            if any(math.dist(c, q[:2]) - radius - q[2] < self.clearance for q in placed):
                continue
            placed.append((float(c[0]), float(c[1]), radius))
        return np.array(placed).reshape(-1, 3)


AnyGenerator = (
    RoomsGenerator
    | CaveGenerator
    | OfficeFloorGenerator
    | WarehouseGenerator
    | LoopGenerator
    | PillarHallGenerator
)


# -- shared: checks, start poses, retries ---------------------------------------------------
def _check_common(num_start_poses: int, max_tries: int, name: str) -> None:
    check_range("num_start_poses", num_start_poses, 1, 64)
    check_range("max_tries", max_tries, 1, 10_000)
    if not name:
        raise ConfigError("name: must be a non-empty string, got ''")


def _generate(
    gen: AnyGenerator,
    draw: Callable[[np.random.Generator], Walls],
    rng: np.random.Generator,
    separation: float = 0.0,
    columns: Callable[[np.random.Generator, Walls], np.ndarray] | None = None,
) -> Layout:
    """Draw walls (then round pillars with ``columns``, given the walls), check them and place
    start poses at least ``separation`` (m) apart (and never closer than ``2·robot_radius +
    margin``); redraw on failure (bounded)."""
    for _ in range(gen.max_tries):
        walls = draw(rng)
        pillars = np.zeros((0, 3)) if columns is None else columns(rng, walls)
        layout = Layout(name=gen.name, walls=tuple(walls), pillars=pillars)
        if not is_enclosed(layout):
            continue
        grid = _connected_for_robot(layout, gen.robot_radius, gen.margin)
        if grid is None:
            continue
        poses = _start_poses(layout, grid, gen, rng, separation)
        if poses is None:
            continue
        data = layout_to_dict(
            Layout(name=gen.name, walls=layout.walls, pillars=pillars, start_poses=poses)
        )
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
    gen: AnyGenerator,
    rng: np.random.Generator,
    separation: float = 0.0,
) -> np.ndarray | None:
    """``num_start_poses`` poses (n, 3) in free space, clear of walls, and ``separation`` (at
    least the wall clearance) from each other, or None."""
    clear = 2 * gen.robot_radius + gen.margin
    apart = max(clear, separation)
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
                if len(chosen) == gen.num_start_poses:
                    return np.column_stack([cand[chosen], heading[chosen]])
    return None


# -- registry -------------------------------------------------------------------------------
GENERATORS: dict[str, type[AnyGenerator]] = {
    "rooms": RoomsGenerator,
    "cave": CaveGenerator,
    "office_floor": OfficeFloorGenerator,
    "warehouse": WarehouseGenerator,
    "loop": LoopGenerator,
    "pillar_hall": PillarHallGenerator,
}


def make_generator(name: str, **kwargs: Any) -> LayoutGenerator:
    """A generator by name (a key of :data:`GENERATORS`) with its parameters validated."""
    cls = GENERATORS.get(name)
    if cls is None:
        raise ValueError(
            f"unknown layout generator {name!r}; valid names: {', '.join(sorted(GENERATORS))}"
        )
    return cls.from_dict(kwargs, where=name)

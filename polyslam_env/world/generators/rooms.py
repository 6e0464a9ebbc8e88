"""Rooms by recursive division (:class:`RoomsGenerator`): axis-aligned rooms, one door per
dividing wall (so the rooms form a tree and every room is reachable), optionally corridors."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.config import check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.shapes import SNAP


@dataclass(frozen=True)
class RoomsGenerator(GeneratorBase):
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
    name: str = "rooms"

    def validate(self) -> None:
        super().validate()
        for key in (
            "min_room_size",
            "max_room_size",
            "door_width",
            "corridor_width",
        ):
            check_positive(key, getattr(self, key))
        check_range("split_prob", self.split_prob, 0.0, 1.0)
        check_range("corridor_prob", self.corridor_prob, 0.0, 1.0)
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
        first = math.ceil(round((lo + self.min_room_size) / SNAP, 6))
        last = math.floor(round((hi - self.min_room_size - cw) / SNAP, 6))
        if last < first:
            return None
        cand = np.round(np.arange(first, last + 1) * SNAP, 9)  # (n,)
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
        first = math.ceil(round((lo + self._door_margin) / SNAP, 6))
        last = math.floor(round((hi - self._door_margin - self.door_width) / SNAP, 6))
        start = (
            round(float(rng.integers(first, last + 1)) * SNAP, 9)
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

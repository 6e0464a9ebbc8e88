"""Office floors (:class:`OfficeFloorGenerator`): rooms off one or two long corridors, one
door each; axis-aligned, coordinates multiples of 5 cm (issue 14)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.config import check_positive
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.shapes import (
    Range,
    check_span,
    cuts,
    draw_snapped,
    line_with_gaps,
    outline,
    partition,
    tiles,
)


@dataclass(frozen=True)
class OfficeFloorGenerator(GeneratorBase):
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
    name: str = "office_floor"

    def validate(self) -> None:
        super().validate()
        check_positive("min_room_depth", self.min_room_depth)
        check_span("corridors", self.corridors, 1, 2)
        gap = 2 * (self.robot_radius + self.margin)
        check_span("corridor_width", self.corridor_width, gap, 0.5 * self.height)
        check_span("door_width", self.door_width, gap, self.room_width[0])
        need = self.door_width[1] + 2 * (2 * self.robot_radius + self.margin)
        check_span("room_width", self.room_width, need, self.width)
        if not tiles(self.width, self.room_width):
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

    def _draw(self, rng: np.random.Generator) -> Walls:
        n_corr = int(rng.integers(self.corridors[0], self.corridors[1] + 1))
        cw = draw_snapped(rng, self.corridor_width)
        depth_span = (self.min_room_depth, self.height)
        depths = partition(rng, self.height - n_corr * cw, n_corr + 1, depth_span)
        if depths is None:
            return [outline(self.width, self.height)]  # infeasible draw: fails the start check
        walls: Walls = [outline(self.width, self.height)]
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
        widths = partition(rng, self.width, None, self.room_width)
        assert widths is not None, "room_width was validated to tile the width"
        xs = cuts(0.0, widths)
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
                dw = draw_snapped(rng, self.door_width)
                start = draw_snapped(rng, (a + corner, b - corner - dw))
                gaps.append((start, round(start + dw, 9)))
        walls = [w for x in xs[1:-1] for w in line_with_gaps(x, y0, y1, [], vertical=True)]
        if below:
            walls += line_with_gaps(y0, 0.0, self.width, gaps_below, vertical=False)
        if above:
            walls += line_with_gaps(y1, 0.0, self.width, gaps_above, vertical=False)
        return walls

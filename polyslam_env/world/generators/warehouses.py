"""Warehouses (:class:`WarehouseGenerator`): shelf rows (long thin closed boxes) with aisles,
a cross aisle and free-standing pillars in an open loading area (issue 14)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.shapes import (
    SNAP,
    Range,
    check_span,
    draw_snapped,
    outline,
    rectangle,
)
from polyslam_env.world.layout import point_segment_distance


@dataclass(frozen=True)
class WarehouseGenerator(GeneratorBase):
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
    name: str = "warehouse"

    def validate(self) -> None:
        super().validate()
        gap = 2 * (self.robot_radius + self.margin)
        check_span("shelf_depth", self.shelf_depth, SNAP, self.height)
        check_span("aisle_width", self.aisle_width, gap, self.height)
        check_span("cross_aisle_width", self.cross_aisle_width, gap, self.width)
        check_span("open_area", self.open_area, 0.0, self.width)
        check_span("pillars", self.pillars, 0, 64)
        check_span("pillar_size", self.pillar_size, SNAP, 2.0)
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

    def _draw(self, rng: np.random.Generator) -> Walls:
        open_w = draw_snapped(rng, self.open_area)
        end_w = draw_snapped(rng, self.aisle_width)
        open_left = bool(rng.random() < 0.5)
        x0, x1 = (open_w, self.width - end_w) if open_left else (end_w, self.width - open_w)
        cross_w = draw_snapped(rng, self.cross_aisle_width)
        third = (x1 - x0 - cross_w) / 3
        cx = draw_snapped(rng, (x0 + third, x1 - third - cross_w))
        walls: Walls = [outline(self.width, self.height)]
        y = draw_snapped(rng, self.aisle_width)
        while True:
            depth = draw_snapped(rng, self.shelf_depth)
            if self.height - (y + depth) < self.aisle_width[0] - 1e-9:
                break
            top = round(y + depth, 9)
            walls += [rectangle(x0, y, cx, top), rectangle(round(cx + cross_w, 9), y, x1, top)]
            y = round(top + draw_snapped(rng, self.aisle_width), 9)
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
            side = draw_snapped(rng, self.pillar_size)
            lo, hi = area[0] + clear, area[1] - clear - side
            if hi < lo:
                return None
            px = draw_snapped(rng, (lo, hi))
            py = draw_snapped(rng, (clear, self.height - clear - side))
            box = rectangle(px, py, round(px + side, 9), round(py + side, 9))
            own = np.hstack([box[:-1], box[1:]])  # (4, 4)
            near = min(
                point_segment_distance(box, segs).min(), point_segment_distance(verts, own).min()
            )
            if near >= clear - 1e-9:
                return box
        return None

"""Pillar halls (:class:`PillarHallGenerator`): round structural columns on a jittered grid,
cut into bays by partition walls with openings (point landmarks for issues 17 and 18)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.config import check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.shapes import (
    SNAP,
    Range,
    check_span,
    draw_snapped,
    line_with_gaps,
    outline,
)
from polyslam_env.world.layout import point_segment_distance


@dataclass(frozen=True)
class PillarHallGenerator(GeneratorBase):
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
    name: str = "pillar_hall"

    def validate(self) -> None:
        super().validate()
        check_positive("clearance", self.clearance)
        check_range("jitter", self.jitter, 0.0, 10.0)
        check_range("missing", self.missing, 0.0, 1.0)
        check_span("partitions", self.partitions, 0, 16)
        check_span("opening_width", self.opening_width, 2 * (self.robot_radius + self.margin),
                    self.height / 2)  # fmt: skip
        check_span("column_spacing", self.column_spacing, SNAP, max(self.width, self.height))
        check_span("column_radius", self.column_radius, SNAP, 1.0)
        bay = self.width / (self.partitions[1] + 1)
        if bay < 2 * self.clearance:
            raise ConfigError(
                f"width: {self.partitions[1]} partitions leave bays of {bay:g} m, less than"
                f" twice the clearance {self.clearance:g} m; got {self.width!r}"
            )

    def _draw(self, rng: np.random.Generator) -> Walls:
        count = int(rng.integers(self.partitions[0], self.partitions[1] + 1))
        bay = self.width / (count + 1)
        walls: Walls = [outline(self.width, self.height)]
        for k in range(1, count + 1):
            x = draw_snapped(rng, (k * bay - 0.25 * bay, k * bay + 0.25 * bay))
            doors = 1 + int(rng.random() < 0.5)
            gaps: list[tuple[float, float]] = []
            band = self.height / doors
            for d in range(doors):
                w = draw_snapped(rng, self.opening_width)
                y = draw_snapped(rng, (d * band + 0.1 * band, (d + 1) * band - 0.1 * band - w))
                gaps.append((y, round(y + w, 9)))
            walls += line_with_gaps(x, 0.0, self.height, gaps, vertical=True)
        return walls

    def _pillars(self, rng: np.random.Generator, walls: Walls) -> np.ndarray:
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

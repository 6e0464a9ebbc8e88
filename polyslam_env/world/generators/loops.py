"""Loops (:class:`LoopGenerator`): a corridor loop around a solid block (issue 14)."""

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


@dataclass(frozen=True)
class LoopGenerator(GeneratorBase):
    """A corridor loop around a solid rectangular block filling the middle of the floor.

    Each of the four sides of the corridor has its own width drawn from ``corridor_width``, so
    the loop is not symmetric (a robot cannot tell the sides apart by width alone otherwise).
    The loop's centre line is at least ``2·(width + height) − 4·corridor_width[1]`` long.
    """

    width: float = 16.0  # m
    height: float = 10.0  # m
    corridor_width: Range = (1.2, 1.6)  # m
    start_separation: float = 4.0  # m
    name: str = "loop"

    def validate(self) -> None:
        super().validate()
        gap = 2 * (self.robot_radius + self.margin)
        check_span("corridor_width", self.corridor_width, gap, 0.5 * min(self.width, self.height))
        block = min(self.width, self.height) - 2 * self.corridor_width[1]
        if block < 2 * SNAP:
            raise ConfigError(
                f"width/height: no room for the inner block with corridors up to"
                f" {self.corridor_width[1]:g} m, got {self.width!r} × {self.height!r}"
            )
        if self.loop_length < 20.0:
            raise ConfigError(
                f"width/height: the loop's centre line ({self.loop_length:g} m) must be"
                f" >= 20 m, got {self.width!r} × {self.height!r}"
            )

    @property
    def loop_length(self) -> float:
        """Least length (m) of the loop's centre line, with the widest corridors."""
        return 2 * (self.width + self.height) - 4 * self.corridor_width[1]

    def _draw(self, rng: np.random.Generator) -> Walls:
        left, bottom, right, top = (draw_snapped(rng, self.corridor_width) for _ in range(4))
        block = rectangle(left, bottom, round(self.width - right, 9), round(self.height - top, 9))
        return [outline(self.width, self.height), block]

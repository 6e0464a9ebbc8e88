"""Caves: :class:`CaveGenerator`, a smooth random closed outline (a radius made of a few
Fourier terms, finely sampled) with optional rock islands inside."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polyslam_env.core.config import check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.shapes import blob, resample_closed
from polyslam_env.world.layout import point_segment_distance, points_in_polygon

#: Roughness of the cave islands' outlines (see :func:`~.shapes.blob`).
_ISLAND_ROUGHNESS = 0.25


@dataclass(frozen=True)
class CaveGenerator(GeneratorBase):
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
    name: str = "cave"

    def validate(self) -> None:
        super().validate()
        for key in ("spacing", "island_gap"):
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

    def _draw(self, rng: np.random.Generator) -> Walls:
        outline = blob(rng, self.harmonics, self.roughness)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        outline = (outline - lo) / (hi - lo) * np.array([self.width, self.height])
        walls = [resample_closed(outline, self.spacing)]
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
            shape = blob(rng, 3, _ISLAND_ROUGHNESS) * radius + centre
            # Cheap necessary test first: the island reaches (1 - roughness)·radius from its
            # centre in every direction, so a nearer wall is certainly too close.
            reach = (1.0 - _ISLAND_ROUGHNESS) * radius + self.island_gap
            if point_segment_distance(centre, segs).min() < reach:
                continue
            poly = resample_closed(shape, self.spacing)
            if not points_in_polygon(poly, walls[0]).all():
                continue
            if point_segment_distance(poly, segs).min() >= self.island_gap:
                return poly
        return None

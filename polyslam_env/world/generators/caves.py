"""Caves: :class:`CaveGenerator`, a smooth random closed outline (a radius made of a few
Fourier terms, finely sampled) with optional rock islands inside; :class:`CaveSystemGenerator`,
a 20–40 m cave system of such chambers joined by winding narrow passages, with rock islands,
traced from a field (:mod:`~polyslam_env.world.generators.fields`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from polyslam_env.core.config import check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.fields import (
    FieldFn,
    SampleGrid,
    add_shape,
    cut_shape,
    polyline_tube,
    walls_from_field,
)
from polyslam_env.world.generators.shapes import (
    Range,
    blob,
    check_span,
    resample_closed,
    spanning_tree,
)
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


# -- cave systems ---------------------------------------------------------------------------
#: Largest side (m) of a cave system.
_MAX_SIDE = 100.0
#: m: free space keeps this far inside the box.
_BORDER = 0.3
#: m: chambers' outlines stay this far apart (only passages join them).
_CHAMBER_GAP = 1.0
#: m: spacing of a passage's centre line samples.
_SPINE_STEP = 0.5


@dataclass(frozen=True)
class _Star:
    """A star-shaped outline about (cx, cy): radius R·(1 + Σ a_k cos(kφ + φ_k))."""

    cx: float
    cy: float
    radius: float
    amp: np.ndarray  # (h,)
    phase: np.ndarray  # (h,)

    @property
    def reach(self) -> float:
        """m: the farthest the outline gets from its centre (a bound)."""
        return self.radius * (1.0 + float(np.abs(self.amp).sum()))

    def rho(self, phi: np.ndarray) -> np.ndarray:
        k = np.arange(2, len(self.amp) + 2)
        waves = self.amp * np.cos(np.multiply.outer(phi, k) + self.phase)  # (..., h)
        return self.radius * (1.0 + waves.sum(-1))

    def field(self) -> FieldFn:
        """R·ρ(φ) − |p − c|: zero on the outline, positive inside (about the distance to it
        near it)."""

        def values(px: np.ndarray, py: np.ndarray) -> np.ndarray:
            dx, dy = px - self.cx, py - self.cy
            return self.rho(np.arctan2(dy, dx)) - np.hypot(dx, dy)

        return values

    def outline(self) -> np.ndarray:  # (K, 2) closed
        phi = np.linspace(0.0, 2 * np.pi, 361)
        r = self.rho(phi)
        pts = np.column_stack([self.cx + r * np.cos(phi), self.cy + r * np.sin(phi)])
        pts[-1] = pts[0]
        return pts

    def box(self) -> tuple[tuple[float, float], tuple[float, float]]:
        r = self.reach + 0.1
        return ((self.cx - r, self.cy - r), (self.cx + r, self.cy + r))


def _star(rng: np.random.Generator, cx: float, cy: float, radius: float, harmonics: int,
          roughness: float) -> _Star:  # fmt: skip
    """A star outline with the amplitudes and phases :func:`~.shapes.blob` draws."""
    k = np.arange(2, harmonics + 2)
    raw = rng.uniform(0.2, 1.0, size=harmonics) / k
    amp = roughness * raw / raw.sum()
    phase = rng.uniform(0.0, 2 * np.pi, size=harmonics)
    return _Star(cx, cy, radius, amp, phase)


@dataclass(frozen=True)
class CaveSystemGenerator(GeneratorBase):
    """A cave system: open chambers, winding narrow passages, rock islands.

    ``chambers`` (a count drawn) chambers of a mean radius drawn from ``chamber_radius`` are
    star-shaped outlines (``harmonics`` Fourier terms, radius within ±``roughness`` of the
    mean), kept 1 m apart. Passages of a width drawn from ``passage_width`` join them along the
    minimum spanning tree of their centres plus ``loops`` (a count drawn) more, each from
    centre to centre along a bowed line (a parabola across it of ½–1 ``wander`` of its length
    and a slight S-bend, curved everywhere). Up to ``islands`` (tries) rock islands
    of a mean radius from ``island_radius`` stand in the larger chambers, each ``island_gap``
    from every other wall. The free space is
    traced on a grid of ``sample`` m and simplified to ``tolerance`` m.
    """

    width: float = 36.0  # m
    height: float = 24.0  # m
    chambers: tuple[int, int] = (5, 7)
    chamber_radius: Range = (2.5, 4.5)  # m
    harmonics: int = 6
    roughness: float = 0.3
    passage_width: Range = (0.8, 1.4)  # m
    wander: float = 0.12  # of a passage's length
    loops: tuple[int, int] = (1, 2)
    islands: tuple[int, int] = (3, 6)  # tries
    island_radius: Range = (0.3, 0.6)  # m
    island_gap: float = 0.7  # m, least distance from an island to any other wall
    sample: float = 0.04  # m, grid the free space is traced on
    tolerance: float = 0.004  # m, chord tolerance of the traced walls
    start_separation: float = 5.0  # m
    name: str = "cave_system"

    slivers: ClassVar[int] = 2  # walls at angles to the raster (GeneratorBase.slivers)

    def validate(self) -> None:
        super().validate()
        check_range("width", self.width, 12.0, _MAX_SIDE)
        check_range("height", self.height, 12.0, _MAX_SIDE)
        check_span("chambers", self.chambers, 2, 64)
        check_span("chamber_radius", self.chamber_radius, 1.5, min(self.width, self.height) / 4)
        check_range("harmonics", self.harmonics, 1, 32)
        check_range("roughness", self.roughness, 0.0, 0.5)
        gap = 2 * (self.robot_radius + self.margin)
        check_span("passage_width", self.passage_width, gap + 0.2, self.chamber_radius[0])
        check_range("wander", self.wander, 0.0, 0.3)
        check_span("loops", self.loops, 0, 64)
        check_span("islands", self.islands, 0, 64)
        check_span("island_radius", self.island_radius, 0.1, self.chamber_radius[0] / 2)
        if self.island_gap <= gap:
            raise ConfigError(
                f"island_gap: must exceed 2·(robot_radius + margin) = {gap:g} m,"
                f" got {self.island_gap!r}"
            )
        check_range("sample", self.sample, 0.01, 0.1)
        check_range("tolerance", self.tolerance, 0.0, self.sample / 2)

    def _draw(self, rng: np.random.Generator) -> Walls:
        grid = SampleGrid(self.width, self.height, self.sample)
        field = grid.empty()
        chambers = self._chambers(rng)
        for c in chambers:
            add_shape(field, grid, c.box(), c.field())
        centres = np.array([[c.cx, c.cy] for c in chambers])
        pairs = spanning_tree(centres)
        pairs += self._loops(rng, centres, pairs)
        passages = [self._passage(rng, centres[a], centres[b]) for a, b in pairs]
        for spine, half in passages:
            lo, hi = spine.min(axis=0) - half - 0.2, spine.max(axis=0) + half + 0.2
            box = ((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])))
            add_shape(field, grid, box, polyline_tube(spine, half))
        placed: list[_Star] = []
        for _ in range(int(rng.integers(self.islands[0], self.islands[1] + 1))):
            island = self._island(rng, chambers, passages, placed)
            if island is not None:
                cut_shape(field, grid, island.box(), island.field())
                placed.append(island)
        field = np.minimum(field, grid.box_field(_BORDER))
        return walls_from_field(field, grid, self.tolerance, min_island_area=0.01)

    def _chambers(self, rng: np.random.Generator) -> list[_Star]:
        count = int(rng.integers(self.chambers[0], self.chambers[1] + 1))
        placed: list[_Star] = []
        for _ in range(50 * count):
            if len(placed) == count:
                break
            radius = float(rng.uniform(*self.chamber_radius))
            star = _star(rng, 0.0, 0.0, radius, self.harmonics, self.roughness)
            keep = star.reach + _BORDER + 0.2
            if min(self.width, self.height) < 2 * keep:
                continue
            x, y = rng.uniform([keep, keep], [self.width - keep, self.height - keep])
            if all(math.dist((x, y), (q.cx, q.cy)) >= star.reach + q.reach + _CHAMBER_GAP
                   for q in placed):  # fmt: skip
                placed.append(_Star(float(x), float(y), radius, star.amp, star.phase))
        return placed

    def _loops(
        self, rng: np.random.Generator, centres: np.ndarray, tree: list[tuple[int, int]]
    ) -> list[tuple[int, int]]:
        """Extra passages: from a random chamber to its nearest chamber not yet joined to it."""
        joined = {frozenset(e) for e in tree}
        extra: list[tuple[int, int]] = []
        for _ in range(int(rng.integers(self.loops[0], self.loops[1] + 1))):
            a = int(rng.integers(len(centres)))
            order = np.argsort(np.hypot(*(centres - centres[a]).T))
            b = next((int(j) for j in order[1:] if frozenset((a, int(j))) not in joined), None)
            if b is not None:
                joined.add(frozenset((a, b)))
                extra.append((a, b))
        return extra

    def _passage(
        self, rng: np.random.Generator, p: np.ndarray, q: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """A bowed centre line (k, 2) from ``p`` to ``q`` inside the box, and its half width."""
        half = 0.5 * float(rng.uniform(*self.passage_width))
        length = float(np.hypot(*(q - p)))
        t = np.linspace(0.0, 1.0, max(3, math.ceil(length / _SPINE_STEP) + 1))[:, None]
        normal = np.array([-(q - p)[1], (q - p)[0]]) / max(length, 1e-9)
        # a parabolic bow of half to all of ``wander``, either way, and an S-bend small
        # enough (|a2|·2π² < 8|a1|) that the curvature never vanishes: no straight stretch
        a1 = rng.uniform(0.5, 1.0) * rng.choice([-1.0, 1.0]) * self.wander * length
        a2 = rng.uniform(-0.2, 0.2) * abs(a1)
        across = 4 * a1 * t * (1 - t) + a2 * np.sin(2 * np.pi * t)  # (k, 1)
        spine = p + t * (q - p) + across * normal
        keep = _BORDER + half + 0.2
        spine = np.clip(spine, [keep, keep], [self.width - keep, self.height - keep])
        return spine, half

    def _island(
        self,
        rng: np.random.Generator,
        chambers: list[_Star],
        passages: list[tuple[np.ndarray, float]],
        placed: list[_Star],
    ) -> _Star | None:
        """A rock island inside a chamber, ``island_gap`` clear of its outline, the passages
        outside the chambers and the other islands (distances to their sampled outlines and
        centre lines), or None."""
        big = [c for c in chambers if c.radius * (1 - self.roughness) >= 2 * self.island_radius[1]]
        if not big:
            return None
        host = big[int(rng.integers(len(big)))]
        radius = float(rng.uniform(*self.island_radius))
        angle = float(rng.uniform(0, 2 * np.pi))
        off = float(rng.uniform(0.0, 0.5)) * host.radius * (1 - self.roughness)
        island = _star(rng, host.cx + off * math.cos(angle), host.cy + off * math.sin(angle),
                       radius, 3, _ISLAND_ROUGHNESS)  # fmt: skip
        rim = island.outline()[::4]  # (k, 2)
        walls = [c.outline() for c in chambers] + [q.outline() for q in placed]
        segs = np.vstack([np.hstack([w[:-1], w[1:]]) for w in walls])
        if point_segment_distance(rim, segs).min() < self.island_gap:
            return None
        if not points_in_polygon(rim, host.outline()).all():
            return None
        for spine, half in passages:  # the parts outside the chambers (inside: open space)
            outside = np.ones(len(spine) - 1, dtype=bool)
            for c in chambers:
                inside = c.field()(spine[:, 0], spine[:, 1]) > half  # (k,)
                outside &= ~(inside[:-1] & inside[1:])
            spine_segs = np.hstack([spine[:-1], spine[1:]])[outside]
            if len(spine_segs) and (
                point_segment_distance(rim, spine_segs).min() < half + self.island_gap
            ):
                return None
        return island

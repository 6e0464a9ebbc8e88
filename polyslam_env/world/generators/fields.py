"""Free space drawn as a field: the contour-traced generators' shapes and their tracing.

A contour-traced family (caves, curved floors) describes its free space by a scalar field on a
sample grid, positive where free: a union of shapes is the maximum of their fields, a solid
island cuts in with the minimum. Near its boundary each shape's field is the signed distance
to it (m), so the zero level that :func:`~polyslam_env.world.contours.trace_rings` follows by
linear interpolation lies on the shape to a small fraction of the sample spacing (exactly on
straight walls). Away from a shape its field is not needed: each shape is evaluated only in a
window of the grid around it (:meth:`SampleGrid.window`) and is −∞ elsewhere.

:func:`walls_from_field` turns the field into walls: the largest free region's outer ring and
its islands, simplified to a chord tolerance, cut corners of straight walls sharpened.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from polyslam_env.world.contours import (
    main_region,
    rings_touching,
    sharpen_corners,
    simplify_rings,
    trace_rings,
)
from polyslam_env.world.generators.base import Walls

__all__ = [
    "SampleGrid",
    "annular_sector",
    "arc_tube",
    "disc",
    "polyline_tube",
    "rectangle_field",
    "walls_from_field",
]


@dataclass(frozen=True)
class SampleGrid:
    """Samples every ``step`` (m) over the box [0, width] × [0, height] and one sample beyond
    it on every side (the padding the tracing needs): sample (row, col) at
    ``(−step + col·step, −step + row·step)``."""

    width: float
    height: float
    step: float

    @property
    def origin(self) -> tuple[float, float]:
        return (-self.step, -self.step)

    @property
    def shape(self) -> tuple[int, int]:
        return (math.ceil(self.height / self.step) + 3, math.ceil(self.width / self.step) + 3)

    def empty(self) -> np.ndarray:  # (H, W)
        """A field with no free space (−∞ everywhere)."""
        return np.full(self.shape, -np.inf)

    def window(
        self, lo: tuple[float, float], hi: tuple[float, float]
    ) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray]:
        """The grid window covering the box ``lo``–``hi`` (m): its slices and the sample
        coordinates (h, w) there."""
        h, w = self.shape
        c0 = max(0, math.floor((lo[0] + self.step) / self.step))
        c1 = min(w, math.ceil((hi[0] + self.step) / self.step) + 1)
        r0 = max(0, math.floor((lo[1] + self.step) / self.step))
        r1 = min(h, math.ceil((hi[1] + self.step) / self.step) + 1)
        xs = -self.step + np.arange(c0, max(c0, c1)) * self.step
        ys = -self.step + np.arange(r0, max(r0, r1)) * self.step
        px, py = np.meshgrid(xs, ys)
        return (slice(r0, max(r0, r1)), slice(c0, max(c0, c1))), px, py

    def box_field(self, border: float) -> np.ndarray:  # (H, W)
        """Signed distance (m) inside the box shrunk by ``border``: negative outside, so a
        field limited by it keeps its free space ``border`` inside the box."""
        _, px, py = self.window((-self.step, -self.step), (self.width + self.step,
                                                              self.height + self.step))  # fmt: skip
        return (
            np.minimum(np.minimum(px, self.width - px), np.minimum(py, self.height - py)) - border
        )


#: A shape's field at sample coordinates (px, py), each (h, w) → (h, w).
FieldFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
Box = tuple[tuple[float, float], tuple[float, float]]  # bounding box lo, hi of a shape


def add_shape(field: np.ndarray, grid: SampleGrid, box: Box, values: FieldFn) -> None:
    """Union (maximum) of ``field`` with a shape evaluated by ``values(px, py)`` in the window
    of its bounding box ``box``."""
    (rows, cols), px, py = grid.window(*box)
    if px.size:
        field[rows, cols] = np.maximum(field[rows, cols], values(px, py))


def cut_shape(field: np.ndarray, grid: SampleGrid, box: Box, values: FieldFn) -> None:
    """Cut a solid island into ``field``: the minimum with ``−values`` in the island's window
    (``values`` positive inside the island)."""
    (rows, cols), px, py = grid.window(*box)
    if px.size:
        field[rows, cols] = np.minimum(field[rows, cols], -values(px, py))


def disc(cx: float, cy: float, r: float) -> FieldFn:
    """Field of a disc: r − |p − c|."""
    return lambda px, py: r - np.hypot(px - cx, py - cy)


def polyline_tube(points: np.ndarray, half_width: float) -> FieldFn:
    """Field of a tube of half width ``half_width`` along a polyline (k, 2), round ends."""

    def values(px: np.ndarray, py: np.ndarray) -> np.ndarray:
        best = np.full(px.shape, np.inf)
        for (ax, ay), (bx, by) in itertools.pairwise(points):
            dx, dy = bx - ax, by - ay
            t = np.clip(((px - ax) * dx + (py - ay) * dy) / max(dx * dx + dy * dy, 1e-300), 0, 1)
            best = np.minimum(best, np.hypot(px - ax - t * dx, py - ay - t * dy))
        return half_width - best

    return values


def rectangle_field(cx: float, cy: float, length: float, depth: float, angle: float) -> FieldFn:
    """Field of a rectangle ``length × depth`` centred at (cx, cy), its length along
    ``angle``: min(length/2 − |u|, depth/2 − |v|) in its own axes (the signed distance inside
    and near its sides)."""
    c, s = math.cos(angle), math.sin(angle)

    def values(px: np.ndarray, py: np.ndarray) -> np.ndarray:
        u = (px - cx) * c + (py - cy) * s
        v = -(px - cx) * s + (py - cy) * c
        return np.minimum(length / 2 - np.abs(u), depth / 2 - np.abs(v))

    return values


def _angle_from(a0: float, phi: np.ndarray) -> np.ndarray:
    """Counter-clockwise angle (rad) from ``a0`` to ``phi``, in [0, 2π)."""
    return np.mod(phi - a0, 2 * np.pi)


def annular_sector(cx: float, cy: float, r0: float, r1: float, a0: float, span: float) -> FieldFn:
    """Field of the ring sector r0 ≤ |p − c| ≤ r1, angles a0 … a0 + span (span < π, counter-
    clockwise): the least of the distances to its two arcs and its two radial sides."""

    def values(px: np.ndarray, py: np.ndarray) -> np.ndarray:
        dx, dy = px - cx, py - cy
        rho = np.hypot(dx, dy)
        side0 = dx * -math.sin(a0) + dy * math.cos(a0)  # left of the ray at a0
        a1 = a0 + span
        side1 = dx * math.sin(a1) - dy * math.cos(a1)  # right of the ray at a1
        return np.minimum(np.minimum(r1 - rho, rho - r0), np.minimum(side0, side1))

    return values


def arc_tube(
    cx: float, cy: float, radius: float, a0: float, span: float, half_width: float
) -> FieldFn:
    """Field of a tube of half width ``half_width`` along the arc of ``radius`` about (cx, cy)
    from angle ``a0`` counter-clockwise over ``span`` (rad), round ends: the distance to the
    arc is | |p − c| − radius | within its angles, else to the nearer end."""
    ends = [(cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in (a0, a0 + span)]

    def values(px: np.ndarray, py: np.ndarray) -> np.ndarray:
        dx, dy = px - cx, py - cy
        along = _angle_from(a0, np.arctan2(dy, dx)) <= span
        d_arc = np.abs(np.hypot(dx, dy) - radius)
        d_end = np.minimum(*(np.hypot(px - ex, py - ey) for ex, ey in ends))
        return half_width - np.where(along, d_arc, d_end)

    return values


def walls_from_field(
    field: np.ndarray,
    grid: SampleGrid,
    tolerance: float,
    min_island_area: float = 0.0,
    sharpen: bool = False,
) -> Walls:
    """The walls of ``{field > 0}``: the largest free region's outer ring first, then its
    islands (of at least ``min_island_area`` m²), each simplified to ``tolerance`` m
    (:func:`~polyslam_env.world.contours.simplify_rings`); with ``sharpen`` the corners of
    straight walls the grid cut are put back (within 1.5 samples)."""
    rings = trace_rings(field, 0.0, grid.origin, grid.step)
    outer, holes = main_region(rings, min_island_area)
    walls = simplify_rings([outer, *holes], tolerance)
    if not sharpen:
        return walls
    sharp = [sharpen_corners(r, 1.5 * grid.step) for r in walls]
    for i in rings_touching(sharp):  # a sharpened corner reaching another wall: keep it cut
        sharp[i] = walls[i]
    return sharp if not rings_touching(sharp) else walls

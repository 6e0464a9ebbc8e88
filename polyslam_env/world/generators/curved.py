"""Curved architecture (:class:`CurvedFloorGenerator`): round halls, curved and straight
corridors, rooms along them, straight and curved walls mixed.

The free space is a union of shapes traced into walls
(:mod:`~polyslam_env.world.generators.fields`): round halls (discs, some with a ring corridor
around them or a round column in the middle), corridors between the halls (arcs or straight),
and rooms beside corridors and around halls, each separated from its neighbours by a wall of
``wall_thickness`` and reached through one door. Rooms beside a straight corridor are
rectangles, beside a curved corridor or around a hall ring sectors, so walls are straight,
circular, or both in one room.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from polyslam_env.core.config import check_range
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.fields import (
    Box,
    FieldFn,
    SampleGrid,
    add_shape,
    annular_sector,
    arc_tube,
    cut_shape,
    disc,
    polyline_tube,
    rectangle_field,
    walls_from_field,
)
from polyslam_env.world.generators.shapes import Range, check_span, spanning_tree

__all__ = ["CurvedFloorGenerator"]

#: Largest side (m) of a curved floor.
_MAX_SIDE = 100.0
#: m: free space keeps this far inside the box.
_BORDER = 0.3


@dataclass(frozen=True)
class _Spine:
    """A corridor's centre line: a straight segment (``radius`` 0) or an arc of ``radius``
    about ``centre`` from angle ``a0`` counter-clockwise over ``span``; ``half`` its half
    width."""

    start: tuple[float, float]
    end: tuple[float, float]
    half: float
    centre: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0
    a0: float = 0.0
    span: float = 0.0


@dataclass(frozen=True)
class CurvedFloorGenerator(GeneratorBase):
    """A floor of round halls, curved and straight corridors and rooms (module docstring).

    ``halls`` (a count drawn) round halls of a radius drawn from ``hall_radius`` stand at
    least 4 m apart; each gets a ring corridor around it with probability ``ring_prob`` (two
    to three doorways into the hall) and a round column (radius from ``column_radius``) in
    its middle with probability ``column_prob``. Corridors of a width drawn from
    ``corridor_width`` join the halls along the minimum spanning tree of their centres, each
    an arc (with probability ``curved_prob``, bowed by 15–35 % of its chord) or straight.
    Then ``rooms`` (a count of tries drawn) rooms of sides drawn from ``room_size`` are put
    beside corridors or around halls wherever they keep ``wall_thickness`` from everything
    else, each with a door of a width drawn from ``door_width``. The free space is traced on a
    grid of ``sample`` m, simplified to ``tolerance`` m, its straight corners sharpened.
    """

    width: float = 32.0  # m
    height: float = 24.0  # m
    halls: tuple[int, int] = (2, 3)
    hall_radius: Range = (2.5, 4.5)  # m
    ring_prob: float = 0.5
    column_prob: float = 0.5
    column_radius: Range = (0.3, 0.7)  # m
    corridor_width: Range = (1.2, 1.8)  # m
    curved_prob: float = 0.6
    spurs: tuple[int, int] = (2, 4)  # tries; dead-end corridors out of the halls
    spur_length: Range = (4.0, 9.0)  # m
    rooms: tuple[int, int] = (30, 45)  # tries; a room that does not fit is left out
    room_size: Range = (2.5, 4.5)  # m
    door_width: Range = (0.8, 1.1)  # m
    wall_thickness: float = 0.2  # m
    sample: float = 0.04  # m, grid the free space is traced on
    tolerance: float = 0.002  # m, chord tolerance of the traced walls
    start_separation: float = 5.0  # m
    name: str = "curved_floor"

    slivers: ClassVar[int] = 2  # walls at angles to the raster (GeneratorBase.slivers)

    def validate(self) -> None:
        super().validate()
        check_range("width", self.width, 12.0, _MAX_SIDE)
        check_range("height", self.height, 12.0, _MAX_SIDE)
        check_span("halls", self.halls, 1, 16)
        check_span("hall_radius", self.hall_radius, 1.5, min(self.width, self.height) / 3)
        check_range("ring_prob", self.ring_prob, 0.0, 1.0)
        check_range("column_prob", self.column_prob, 0.0, 1.0)
        check_span("column_radius", self.column_radius, 0.1, self.hall_radius[0] / 3)
        gap = 2 * (self.robot_radius + self.margin)
        check_span("corridor_width", self.corridor_width, gap + 0.2, 5.0)
        check_range("curved_prob", self.curved_prob, 0.0, 1.0)
        check_span("spurs", self.spurs, 0, 64)
        check_span("spur_length", self.spur_length, 1.0, _MAX_SIDE)
        check_span("rooms", self.rooms, 0, 256)
        check_span("room_size", self.room_size, 1.5, 20.0)
        check_span("door_width", self.door_width, gap + 0.2, self.room_size[0] - 0.5)
        check_range("wall_thickness", self.wall_thickness, 2 * self.sample, 1.0)
        check_range("sample", self.sample, 0.01, 0.1)
        check_range("tolerance", self.tolerance, 0.0, self.sample / 2)

    def _draw(self, rng: np.random.Generator) -> Walls:
        grid = SampleGrid(self.width, self.height, self.sample)
        field = grid.empty()
        halls = self._halls(rng)
        spines: list[_Spine] = []
        ring_out: list[float] = []  # per hall: outer radius of what surrounds it
        for cx, cy, r in halls:
            add_shape(field, grid, _disc_box(cx, cy, r), disc(cx, cy, r))
            ring_out.append(r)
        for i, (cx, cy, r) in enumerate(halls):
            if rng.random() < self.ring_prob:
                ring_out[i] = self._ring(rng, grid, field, cx, cy, r, halls)
        for a, b in spanning_tree(halls[:, :2]):
            spine = self._corridor(rng, halls, a, b)
            add_shape(field, grid, _spine_box(spine), _spine_field(spine))
            spines.append(spine)
        for _ in range(int(rng.integers(self.spurs[0], self.spurs[1] + 1))):
            spur = self._spur(rng, grid, field, halls, ring_out)
            if spur is not None:
                add_shape(field, grid, _spine_box(spur), _spine_field(spur))
                spines.append(spur)
        for _ in range(int(rng.integers(self.rooms[0], self.rooms[1] + 1))):
            self._room(rng, grid, field, halls, ring_out, spines)
        for cx, cy, _ in halls:
            if rng.random() < self.column_prob:
                rc = float(rng.uniform(*self.column_radius))
                cut_shape(field, grid, _disc_box(cx, cy, rc), disc(cx, cy, rc))
        field = np.minimum(field, grid.box_field(_BORDER))
        return walls_from_field(field, grid, self.tolerance, min_island_area=0.01, sharpen=True)

    # -- halls and corridors ----------------------------------------------------------------
    def _halls(self, rng: np.random.Generator) -> np.ndarray:  # (n, 3) x, y, r
        count = int(rng.integers(self.halls[0], self.halls[1] + 1))
        placed: list[tuple[float, float, float]] = []
        for _ in range(50 * count):
            if len(placed) == count:
                break
            r = float(rng.uniform(*self.hall_radius))
            reach = r + _BORDER + 0.5
            if min(self.width, self.height) < 2 * reach:
                continue
            x, y = rng.uniform([reach, reach], [self.width - reach, self.height - reach])
            if all(math.dist((x, y), q[:2]) >= r + q[2] + 4.0 for q in placed):
                placed.append((float(x), float(y), r))
        return np.array(placed).reshape(-1, 3)

    def _ring(
        self,
        rng: np.random.Generator,
        grid: SampleGrid,
        field: np.ndarray,
        cx: float,
        cy: float,
        r: float,
        halls: np.ndarray,
    ) -> float:
        """A ring corridor around the hall (cx, cy, r) with two or three doorways into it, if
        it keeps clear of the box and the other halls; its outer radius (``r`` without)."""
        t = self.wall_thickness
        w = float(rng.uniform(*self.corridor_width))
        outer = r + t + w
        inside_box = min(cx, cy, self.width - cx, self.height - cy) >= outer + _BORDER + t
        clear = all(
            math.dist((cx, cy), q[:2]) >= outer + q[2] + t + 0.5
            for q in halls
            if (q[0], q[1]) != (cx, cy)
        )
        if not (inside_box and clear):
            return r
        add_shape(field, grid, _disc_box(cx, cy, outer), _ring_field(cx, cy, r + t, outer))
        doors = int(rng.integers(2, 4))
        first = float(rng.uniform(0, 2 * np.pi))
        for k in range(doors):
            self._door(rng, grid, field, (cx, cy), first + k * 2 * np.pi / doors, r, r + t)
        return outer

    def _corridor(self, rng: np.random.Generator, halls: np.ndarray, a: int, b: int) -> _Spine:
        """A corridor from hall ``a``'s centre to hall ``b``'s: an arc or a straight line."""
        p, q = halls[a, :2], halls[b, :2]
        half = 0.5 * float(rng.uniform(*self.corridor_width))
        if rng.random() >= self.curved_prob:
            return _Spine((float(p[0]), float(p[1])), (float(q[0]), float(q[1])), half)
        chord = float(np.hypot(*(q - p)))
        sagitta = chord * float(rng.uniform(0.15, 0.35)) * (1 if rng.random() < 0.5 else -1)
        radius = (chord**2 / 4 + sagitta**2) / (2 * abs(sagitta))
        normal = np.array([-(q - p)[1], (q - p)[0]]) / chord  # left of p → q
        centre = 0.5 * (p + q) - np.sign(sagitta) * normal * (radius - abs(sagitta))
        a_p = math.atan2(p[1] - centre[1], p[0] - centre[0])
        a_q = math.atan2(q[1] - centre[1], q[0] - centre[0])
        span = (a_q - a_p) % (2 * np.pi)
        a0 = a_p
        if span > np.pi:  # the short way round, counter-clockwise from q
            a0, span = a_q, 2 * np.pi - span
        return _Spine(
            (float(p[0]), float(p[1])),
            (float(q[0]), float(q[1])),
            half,
            (float(centre[0]), float(centre[1])),
            radius,
            a0,
            span,
        )

    def _spur(
        self,
        rng: np.random.Generator,
        grid: SampleGrid,
        field: np.ndarray,
        halls: np.ndarray,
        ring_out: list[float],
    ) -> _Spine | None:
        """A dead-end corridor out of a hall, straight or (with ``curved_prob``) an arc, kept if
        the part beyond the hall and its ring stays ``wall_thickness`` clear of everything."""
        i = int(rng.integers(len(halls)))
        cx, cy = float(halls[i, 0]), float(halls[i, 1])
        half = 0.5 * float(rng.uniform(*self.corridor_width))
        length = ring_out[i] + float(rng.uniform(*self.spur_length))
        theta = float(rng.uniform(0, 2 * np.pi))
        d = np.array([math.cos(theta), math.sin(theta)])
        if rng.random() >= self.curved_prob:
            end = (cx + length * d[0], cy + length * d[1])
            spine = _Spine((cx, cy), end, half)
            outside = (cx + (ring_out[i] + self.wall_thickness + half) * d[0],
                       cy + (ring_out[i] + self.wall_thickness + half) * d[1])  # fmt: skip
            check = _Spine(outside, end, half)
        else:
            radius = float(rng.uniform(4.0, 10.0))
            turn = 1.0 if rng.random() < 0.5 else -1.0
            centre = (cx - turn * radius * d[1], cy + turn * radius * d[0])
            start = math.atan2(cy - centre[1], cx - centre[0])
            span = length / radius
            skip = (ring_out[i] + self.wall_thickness + half) / radius
            if span >= np.pi or skip >= span:
                return None
            a0, a_check = (start, start + skip) if turn > 0 else (start - span, start - span)
            spine = _Spine((cx, cy), (cx, cy), half, centre, radius, a0, span)
            check = _Spine((cx, cy), (cx, cy), half, centre, radius, a_check, span - skip)
        if not self._fits(grid, field, _spine_field(check), _spine_box(check)):
            return None
        return spine

    # -- rooms ------------------------------------------------------------------------------
    def _room(
        self,
        rng: np.random.Generator,
        grid: SampleGrid,
        field: np.ndarray,
        halls: np.ndarray,
        ring_out: list[float],
        spines: list[_Spine],
    ) -> None:
        """One room beside a corridor or around a hall, kept if it stays ``wall_thickness``
        clear of everything; its door joins it to what it stands beside."""
        t = self.wall_thickness
        depth = float(rng.uniform(*self.room_size))
        length = float(rng.uniform(*self.room_size))
        side = 1 if rng.random() < 0.5 else -1
        pick = int(rng.integers(len(halls) + len(spines)))
        if pick < len(halls):  # a ring sector around a hall (outside its ring corridor)
            cx, cy = float(halls[pick, 0]), float(halls[pick, 1])
            r0 = ring_out[pick] + t
            span = length / (r0 + depth / 2)
            a0 = float(rng.uniform(0, 2 * np.pi))
            shape = annular_sector(cx, cy, r0, r0 + depth, a0, span)
            box = _disc_box(cx, cy, r0 + depth)
            door = ((cx, cy), a0 + span / 2, ring_out[pick], r0)
        else:
            spine = spines[pick - len(halls)]
            if spine.radius == 0.0:  # a rectangle beside a straight corridor
                p, q = np.array(spine.start), np.array(spine.end)
                along = float(np.hypot(*(q - p)))
                u = (q - p) / along
                n = np.array([-u[1], u[0]]) * side
                s = float(rng.uniform(0.2, 0.8)) * along
                off = spine.half + t + depth / 2
                c = p + s * u + off * n
                angle = math.atan2(u[1], u[0])
                shape = rectangle_field(float(c[0]), float(c[1]), length, depth, angle)
                reach = math.hypot(length, depth) / 2
                box = ((c[0] - reach, c[1] - reach), (c[0] + reach, c[1] + reach))
                foot = p + s * u + spine.half * n
                if not self._fits(grid, field, shape, box):
                    return
                add_shape(field, grid, box, shape)
                self._straight_door(rng, grid, field, foot, u, n, length)
                return
            # a ring sector beside a curved corridor, outside (side 1) or inside its arc
            cx, cy = spine.centre
            if side > 0:
                r0 = spine.radius + spine.half + t
            else:
                r0 = spine.radius - spine.half - t - depth
            if r0 < 1.0:
                return
            span = length / (r0 + depth / 2)
            if span >= spine.span * 0.8:
                return
            a0 = spine.a0 + float(rng.uniform(0.1, 0.9)) * (spine.span - span)
            shape = annular_sector(cx, cy, r0, r0 + depth, a0, span)
            box = _disc_box(cx, cy, r0 + depth)
            inner = spine.radius + spine.half if side > 0 else r0 + depth
            door = ((cx, cy), a0 + span / 2, inner, inner + t)
        if not self._fits(grid, field, shape, box):
            return
        add_shape(field, grid, box, shape)
        centre, angle, r_in, r_out = door
        self._door(rng, grid, field, centre, angle, r_in, r_out)

    def _fits(self, grid: SampleGrid, field: np.ndarray, shape: FieldFn, box: Box) -> bool:
        """Whether a new shape stays ``wall_thickness`` clear of the free space so far and of
        the box edge: no sample within it (grown by the thickness) is free yet."""
        (rows, cols), px, py = grid.window(*box)
        values = shape(px, py)
        core = values > 0
        if not core.any():
            return False
        # half a sample of slack: a room exactly one thickness from a corridor fits
        grown = values > -(self.wall_thickness - 0.5 * self.sample)
        keep = _BORDER + self.wall_thickness
        x, y = px[core], py[core]
        inside = (x > keep) & (x < self.width - keep) & (y > keep) & (y < self.height - keep)
        return bool(inside.all() and not np.any(field[rows, cols][grown] > 0))

    def _door(
        self,
        rng: np.random.Generator,
        grid: SampleGrid,
        field: np.ndarray,
        centre: tuple[float, float],
        angle: float,
        r_in: float,
        r_out: float,
    ) -> None:
        """A radial doorway through the curved wall between radii ``r_in`` and ``r_out``
        about ``centre`` at ``angle``: a rectangle reaching a little into both sides."""
        width = float(rng.uniform(*self.door_width))
        mid = 0.5 * (r_in + r_out)
        c = (centre[0] + mid * math.cos(angle), centre[1] + mid * math.sin(angle))
        length = r_out - r_in + 4 * self.sample
        shape = rectangle_field(c[0], c[1], length, width, angle)
        reach = math.hypot(length, width)
        add_shape(field, grid, ((c[0] - reach, c[1] - reach), (c[0] + reach, c[1] + reach)), shape)

    def _straight_door(
        self,
        rng: np.random.Generator,
        grid: SampleGrid,
        field: np.ndarray,
        foot: np.ndarray,
        u: np.ndarray,
        n: np.ndarray,
        length: float,
    ) -> None:
        """A doorway through the straight wall at ``foot`` (the corridor's side, normal ``n``
        towards the room) somewhere along the room's ``length``."""
        width = float(rng.uniform(*self.door_width))
        s = float(rng.uniform(-1, 1)) * max(0.0, (length - width) / 2 - 0.3)
        c = foot + s * u + 0.5 * self.wall_thickness * n
        angle = math.atan2(n[1], n[0])
        reach = self.wall_thickness + 4 * self.sample
        shape = rectangle_field(float(c[0]), float(c[1]), reach, width, angle)
        r = math.hypot(reach, width)
        add_shape(field, grid, ((c[0] - r, c[1] - r), (c[0] + r, c[1] + r)), shape)


def _disc_box(cx: float, cy: float, r: float) -> Box:
    return ((cx - r - 0.1, cy - r - 0.1), (cx + r + 0.1, cy + r + 0.1))


def _ring_field(cx: float, cy: float, r0: float, r1: float) -> FieldFn:
    """Field of the ring r0 ≤ |p − c| ≤ r1."""

    def values(px: np.ndarray, py: np.ndarray) -> np.ndarray:
        rho = np.hypot(px - cx, py - cy)
        return np.minimum(r1 - rho, rho - r0)

    return values


def _spine_field(spine: _Spine) -> FieldFn:
    if spine.radius == 0.0:
        return polyline_tube(np.array([spine.start, spine.end]), spine.half)
    cx, cy = spine.centre
    return arc_tube(cx, cy, spine.radius, spine.a0, spine.span, spine.half)


def _spine_box(spine: _Spine) -> Box:
    if spine.radius == 0.0:
        pts = np.array([spine.start, spine.end])
    else:
        a = spine.a0 + np.linspace(0.0, spine.span, 33)
        pts = np.column_stack(
            [spine.centre[0] + spine.radius * np.cos(a), spine.centre[1] + spine.radius * np.sin(a)]
        )
    lo, hi = pts.min(axis=0) - spine.half - 0.2, pts.max(axis=0) + spine.half + 0.2
    return ((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])))

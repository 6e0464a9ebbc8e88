"""Non-Manhattan buildings (:class:`AngledFloorGenerator`): walls and corridors at arbitrary
angles, polygonal rooms, turned furniture.

The floor is a convex outline (a rectangle with some corners cut off at an angle) divided
recursively by straight walls, each with one door, so the rooms form a tree and every room is
reachable (as :class:`~polyslam_env.world.generators.rooms.RoomsGenerator` does with
axis-aligned walls). A dividing wall runs along one of a few directions of the building (its
wings' grids: the outline's axes and one or two other angles drawn per floor) or, with
``free_angle_prob``, along any angle; a division may instead be a corridor between two
parallel walls. Rooms are convex polygons. Walls are exact straight segments; a later wall
ends on an earlier one (a T-junction), never inside a door's margin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from polyslam_env.core.config import check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.generators.base import GeneratorBase, Walls
from polyslam_env.world.generators.shapes import Range, check_span
from polyslam_env.world.layout import point_segment_distance

__all__ = ["AngledFloorGenerator"]

#: Smallest interior angle (rad) of a room: sharper corners are unreachable slivers.
_MIN_ANGLE = math.radians(30.0)
#: Tries per division (directions and offsets) before a room is left whole.
_SPLIT_TRIES = 12
#: m: a division's wall end keeps this from a door's edge (beyond the robot's margin, room
#: for the robot to turn into the door past a wall meeting at an angle).
_DOOR_KEEP = 0.35


@dataclass(frozen=True)
class AngledFloorGenerator(GeneratorBase):
    """An angled building (module docstring).

    The outline is the ``width × height`` rectangle with ``chamfers`` (a count drawn) of its
    corners cut off, each cut's legs drawn from ``chamfer_size``. ``directions`` (a count
    drawn) building directions besides the outline's axes are drawn at least 15° from each
    other and from the axes; each wall runs along one of them or its perpendicular (along the
    outline's axes with probability ``axis_prob``, else along a drawn direction). A room
    wider than ``max_room_size`` is always divided, one that can still be divided into two of
    at least ``min_room_size`` (least width across) with probability ``split_prob``; a
    division is a corridor of a width drawn from ``corridor_width`` with probability
    ``corridor_prob``. Doors (widths from ``door_width``) keep ``2·robot_radius + margin``
    from corners. Each room gets up to ``furniture`` (a count drawn) turned boxes of a length
    and depth drawn from ``furniture_size``, each ``furniture_gap`` clear of walls and other
    furniture.
    """

    width: float = 24.0  # m
    height: float = 18.0  # m
    chamfers: tuple[int, int] = (1, 3)
    chamfer_size: Range = (3.0, 8.0)  # m, legs of a corner cut
    directions: tuple[int, int] = (1, 2)
    free_angle_prob: float = 0.2
    axis_prob: float = 0.25
    min_room_size: float = 2.6  # m, least width across a room
    max_room_size: float = 7.0  # m, wider rooms are always divided
    split_prob: float = 0.6
    door_width: Range = (0.8, 1.1)  # m
    corridor_prob: float = 0.3
    corridor_width: Range = (1.3, 1.8)  # m
    furniture: tuple[int, int] = (0, 2)  # per room
    furniture_size: Range = (0.5, 1.6)  # m, sides of a box
    furniture_gap: float = 0.7  # m
    start_separation: float = 5.0  # m
    name: str = "angled_floor"

    slivers: ClassVar[int] = 2  # walls at angles to the raster (GeneratorBase.slivers)

    def validate(self) -> None:
        super().validate()
        check_span("chamfers", self.chamfers, 0, 4)
        check_span("chamfer_size", self.chamfer_size, 0.5, min(self.width, self.height) / 2)
        check_span("directions", self.directions, 0, 3)
        check_range("free_angle_prob", self.free_angle_prob, 0.0, 1.0)
        check_range("axis_prob", self.axis_prob, 0.0, 1.0)
        gap = 2 * (self.robot_radius + self.margin)
        check_span("door_width", self.door_width, gap + 0.2, 5.0)
        check_span("corridor_width", self.corridor_width, gap + 0.2, 10.0)
        need = self.door_width[1] + 2 * (self.start_clearance + _DOOR_KEEP)
        if self.min_room_size < need:
            raise ConfigError(
                f"min_room_size: must be >= the widest door and its two margins = {need:g} m,"
                f" got {self.min_room_size!r}"
            )
        check_range("max_room_size", self.max_room_size, self.min_room_size, 1e3)
        if min(self.width, self.height) < self.min_room_size:
            raise ConfigError(
                f"width/height: both must be >= min_room_size ({self.min_room_size:g} m),"
                f" got {self.width!r} × {self.height!r}"
            )
        check_range("split_prob", self.split_prob, 0.0, 1.0)
        check_range("corridor_prob", self.corridor_prob, 0.0, 1.0)
        check_span("furniture", self.furniture, 0, 16)
        check_span("furniture_size", self.furniture_size, 0.1, 5.0)
        check_range("furniture_gap", self.furniture_gap, gap + 0.1, 10.0)

    def _draw(self, rng: np.random.Generator) -> Walls:
        outline = self._outline(rng)
        dirs = [0.0, 0.5 * math.pi]
        for _ in range(int(rng.integers(self.directions[0], self.directions[1] + 1))):
            for _ in range(20):
                a = float(rng.uniform(0.0, 0.5 * math.pi))
                if all(_angle_gap(a, b) >= math.radians(15) for b in dirs):
                    dirs += [a, a + 0.5 * math.pi]
                    break
        walls: Walls = [np.vstack([outline, outline[:1]])]
        doors: list[np.ndarray] = []  # (2, 2) each: the door gaps so far
        rooms: list[np.ndarray] = []
        stack = [outline]
        while stack:
            poly = stack.pop()
            parts = self._divide(rng, poly, dirs, walls, doors)
            if parts is None:
                rooms.append(poly)
            else:
                stack.extend(parts)
        for room in rooms:
            for _ in range(int(rng.integers(self.furniture[0], self.furniture[1] + 1))):
                box = self._furniture(rng, room, walls)
                if box is not None:
                    walls.append(box)
        return walls

    def _outline(self, rng: np.random.Generator) -> np.ndarray:  # (k, 2) counter-clockwise
        """The rectangle with some corners cut off at an angle (no closing point)."""
        w, h = self.width, self.height
        corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        count = int(rng.integers(self.chamfers[0], self.chamfers[1] + 1))
        cut = set(rng.choice(4, size=count, replace=False).tolist()) if count else set()
        pts: list[tuple[float, float]] = []
        limit = 0.45 * min(w, h)
        for k, (x, y) in enumerate(corners):
            if k not in cut:
                pts.append((x, y))
                continue
            prev, nxt = np.array(corners[k - 1]), np.array(corners[(k + 1) % 4])
            here = np.array([x, y])
            a = min(float(rng.uniform(*self.chamfer_size)), limit)
            b = min(float(rng.uniform(*self.chamfer_size)), limit)
            p = here + a * (prev - here) / np.hypot(*(prev - here))
            q = here + b * (nxt - here) / np.hypot(*(nxt - here))
            pts += [(float(p[0]), float(p[1])), (float(q[0]), float(q[1]))]
        return np.array(pts)

    # -- division ---------------------------------------------------------------------------
    def _divide(
        self,
        rng: np.random.Generator,
        poly: np.ndarray,
        dirs: list[float],
        walls: Walls,
        doors: list[np.ndarray],
    ) -> list[np.ndarray] | None:
        """Divide the convex room ``poly`` (k, 2) by a wall (or a corridor), adding its walls
        and doors; the parts, or None when the room stays whole."""
        if min_width(poly) <= self.max_room_size and rng.random() >= self.split_prob:
            return None
        corridor = rng.random() < self.corridor_prob
        for _ in range(_SPLIT_TRIES):
            normal = self._cut_normal(rng, poly, dirs)
            reach = poly @ normal
            cw = float(rng.uniform(*self.corridor_width)) if corridor else 0.0
            lo = reach.min() + self.min_room_size
            hi = reach.max() - self.min_room_size - cw
            if hi <= lo:
                continue
            offset = float(rng.uniform(lo, hi))
            cuts = [offset, offset + cw] if corridor else [offset]
            pieces = _cut_all(poly, normal, cuts)
            chords = [_chord(poly, normal, c) for c in cuts]
            if pieces is None or any(c is None for c in chords):
                continue
            if not all(self._room_ok(p) for p in pieces[:1] + pieces[-1:]):
                continue
            if corridor and min_width(pieces[1]) < cw - 1e-9:
                continue
            planned = [self._door_on(rng, c, doors) for c in chords if c is not None]
            if any(d is None for d in planned):
                continue
            for chord, door in zip(chords, planned, strict=True):
                assert chord is not None and door is not None
                walls += _wall_with_gap(chord, door)
                doors.append(door)
            return pieces
        return None

    def _cut_normal(
        self, rng: np.random.Generator, poly: np.ndarray, dirs: list[float]
    ) -> np.ndarray:
        """The normal (2,) of a dividing wall: of two drawn directions (a building direction,
        the outline's axes with ``axis_prob``, or any angle with ``free_angle_prob``) the one
        cutting across the room's longer extent, so rooms tend to stay compact."""
        best, extent = np.zeros(2), -1.0
        for _ in range(2):
            if rng.random() < self.free_angle_prob:
                angle = float(rng.uniform(0.0, math.pi))
            elif len(dirs) > 2 and rng.random() >= self.axis_prob:
                angle = dirs[2 + int(rng.integers(len(dirs) - 2))]  # a wing's direction
            else:
                angle = dirs[int(rng.integers(2))]  # the outline's axes
            normal = np.array([-math.sin(angle), math.cos(angle)])
            reach = poly @ normal
            if reach.max() - reach.min() > extent:
                best, extent = normal, float(reach.max() - reach.min())
        return best

    def _room_ok(self, poly: np.ndarray) -> bool:
        """Wide enough across and no corner sharper than :data:`_MIN_ANGLE`."""
        return min_width(poly) >= self.min_room_size - 1e-9 and min_angle(poly) >= _MIN_ANGLE

    def _door_on(
        self, rng: np.random.Generator, chord: np.ndarray, doors: list[np.ndarray]
    ) -> np.ndarray | None:
        """A door gap (2, 2) on the wall ``chord`` (2, 2), clear of its ends, or None when
        the chord is too short or one of its ends lies at a door (a wall may not end in or
        next to a door: it would narrow it)."""
        ends = chord
        keep = self.start_clearance + _DOOR_KEEP
        for door in doors:
            if point_segment_distance(ends, door.reshape(1, 4)).min() < keep:
                return None
        length = float(np.hypot(*(chord[1] - chord[0])))
        width = float(rng.uniform(*self.door_width))
        room = length - width - 2 * keep
        if room < 0:
            return None
        s = keep + float(rng.uniform(0.0, room))
        u = (chord[1] - chord[0]) / length
        return np.array([chord[0] + s * u, chord[0] + (s + width) * u])

    def _furniture(
        self, rng: np.random.Generator, room: np.ndarray, walls: Walls
    ) -> np.ndarray | None:
        """A turned box (5, 2) inside ``room``, ``furniture_gap`` clear of every wall and box,
        or None after a few tries. Distances between the box and the walls are exact: the
        nearest points of two disjoint polylines include a vertex of one of them."""
        segs = np.vstack([np.hstack([w[:-1], w[1:]]) for w in walls])  # (S, 4)
        verts = np.vstack(walls)
        lo, hi = room.min(axis=0), room.max(axis=0)
        for _ in range(10):
            a, b = (float(rng.uniform(*self.furniture_size)) for _ in range(2))
            angle = float(rng.uniform(0.0, math.pi))
            centre = rng.uniform(lo, hi)
            u = np.array([math.cos(angle), math.sin(angle)])
            v = np.array([-u[1], u[0]])
            corners = [centre + sa * a / 2 * u + sb * b / 2 * v
                       for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]  # fmt: skip
            box = np.array([*corners, corners[0]])
            if not _convex_contains(room, box[:4]):
                continue
            own = np.hstack([box[:-1], box[1:]])
            near = min(
                point_segment_distance(box, segs).min(), point_segment_distance(verts, own).min()
            )
            if near >= self.furniture_gap:
                return box
        return None


# -- convex polygon geometry -------------------------------------------------------------------
def _angle_gap(a: float, b: float) -> float:
    """Angle (rad) between two line directions modulo 90°."""
    d = abs(a - b) % (0.5 * math.pi)
    return min(d, 0.5 * math.pi - d)


def min_width(poly: np.ndarray) -> float:
    """Least width of a convex polygon (k, 2): the least, over its edges, of the largest
    distance of a vertex from the edge's line."""
    best = math.inf
    k = len(poly)
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        d = b - a
        n = np.array([-d[1], d[0]]) / np.hypot(*d)
        best = min(best, float(np.abs((poly - a) @ n).max()))
    return best


def min_angle(poly: np.ndarray) -> float:
    """Smallest interior angle (rad) of a convex polygon (k, 2)."""
    prev = np.roll(poly, 1, axis=0) - poly
    nxt = np.roll(poly, -1, axis=0) - poly
    cos = (prev * nxt).sum(axis=1) / (np.hypot(*prev.T) * np.hypot(*nxt.T))
    return float(np.arccos(np.clip(cos, -1.0, 1.0)).min())


def _clip(poly: np.ndarray, normal: np.ndarray, offset: float, keep_above: bool) -> np.ndarray:
    """The part of the convex polygon ``poly`` (k, 2) with ``p·normal ≥ offset`` (or ≤)."""
    s = poly @ normal - offset
    if not keep_above:
        s = -s
    out = []
    k = len(poly)
    for i in range(k):
        a, b, sa, sb = poly[i], poly[(i + 1) % k], s[i], s[(i + 1) % k]
        if sa >= 0:
            out.append(a)
        if (sa >= 0) != (sb >= 0):
            out.append(a + sa / (sa - sb) * (b - a))
    pts = np.array(out).reshape(-1, 2)
    keep = np.ones(len(pts), dtype=bool)  # drop repeated vertices (a cut through a vertex)
    keep[1:] = np.hypot(*(pts[1:] - pts[:-1]).T) > 1e-9
    if len(pts) > 1 and np.hypot(*(pts[-1] - pts[0])) <= 1e-9:
        keep[-1] = False
    return pts[keep]


def _cut_all(poly: np.ndarray, normal: np.ndarray, cuts: list[float]) -> list[np.ndarray] | None:
    """The pieces of ``poly`` between consecutive cuts (offsets along ``normal``, rising),
    below the first to above the last; None if a piece is degenerate."""
    pieces = []
    rest = poly
    for c in cuts:
        pieces.append(_clip(rest, normal, c, keep_above=False))
        rest = _clip(rest, normal, c, keep_above=True)
    pieces.append(rest)
    return pieces if all(len(p) >= 3 for p in pieces) else None


def _chord(poly: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray | None:
    """The segment (2, 2) of the line ``p·normal = offset`` inside the convex ``poly``."""
    s = poly @ normal - offset
    pts = []
    k = len(poly)
    for i in range(k):
        sa, sb = s[i], s[(i + 1) % k]
        if (sa >= 0) != (sb >= 0):
            pts.append(poly[i] + sa / (sa - sb) * (poly[(i + 1) % k] - poly[i]))
    if len(pts) != 2 or np.hypot(*(pts[1] - pts[0])) < 1e-6:
        return None
    return np.array(pts)


def _wall_with_gap(chord: np.ndarray, door: np.ndarray) -> Walls:
    """The wall ``chord`` (2, 2) without the ``door`` gap: two 2-point polylines."""
    return [np.array([chord[0], door[0]]), np.array([door[1], chord[1]])]


def _convex_contains(poly: np.ndarray, points: np.ndarray) -> bool:
    """Whether every point (n, 2) lies inside the convex counter-clockwise ``poly`` (k, 2)."""
    edges = np.roll(poly, -1, axis=0) - poly  # (k, 2)
    rel = points[:, None, :] - poly[None, :, :]  # (n, k, 2)
    cross = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]
    return bool(np.all(cross > 0))

"""Corners of a polynomial map: point features with a heading, for aligning wall maps (seed 004).

Two robots that never see each other can align their maps only on what both mapped. A pillar
map gives points; a wall map gives curves, and a curve's position along itself is not
observable (its extent is where the beams happened to stop). What a wall map does fix are the
places where **two walls meet**: a corner is where the world's geometry, not the robot's
path, ends a wall. Each corner carries

* its **position**: where the end tangent of one wall crosses the other wall (a few Newton
  steps on the curve, so curved walls meet where they really do);
* its **heading**: the direction of the bisector of its two arms (the arms run from the
  corner into each wall), which turns with the map; one corner matched in two maps therefore
  fixes the whole transform (θ from the headings, t from the positions);
* a **descriptor** of its local shape that does not turn with the map: the opening angle
  between the arms (rad) and the convexity, +1 where the walls' observed faces look into the
  opening (a room's corner, seen from inside), −1 where they look away from it (a shelf's or a
  pillar's corner, seen from outside), 0 where the faces are not known.

Three kinds of meeting make a corner: an **L** (both walls end there), a **T** (one wall ends
on the body of another; the arm along the other wall is taken on the ending wall's observed
face, the side the robot was on) and a **gap-bridged L** (the walls stop short of each other
by up to ``reach``: fits are trimmed to their beam hits, and the last centimetres before a
corner are often not hit). Walls meeting at less than ``min_angle_deg`` are one wall seen in
pieces, not a corner. Free wall ends (a wall's end that meets nothing) are **not** features:
their place moves as the robot sees more of the wall, so two maps would put them apart.

Corners of one map closer than ``merge_radius`` are one corner (the first kept): an L is found
from both of its walls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.config import Config, check_positive
from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.alignment import FeatureMap
from polyslam_env.slam.merging import face_normal, unit_tangent
from polyslam_env.slam.polynomial import Polynomial

__all__ = ["CORNER_DESCRIPTOR_DIM", "CornerConfig", "wall_corners"]

CORNER_DESCRIPTOR_DIM = 2  # opening angle (rad), convexity (−1, 0, +1)
_NEWTON_STEPS = 4  # line–curve intersection: a wall's curvature is small over ``reach``


@dataclass(frozen=True)
class CornerConfig(Config):
    """What makes two walls' meeting a corner (see the module docstring)."""

    # m: how far a wall's end may stop short of (or run past) the other wall. Fits end at
    # their last beam hit; near a corner beams graze one of the walls, so a few decimetres
    # are often missing (the map's own merge joins ends within 0.3 m as well).
    reach: float = 0.8
    min_angle_deg: float = 30.0  # walls meeting at less than this are one wall, not a corner
    # m: a wall shorter than this makes no corner; its direction is too uncertain (1 cm of
    # error at each end of 0.5 m is ~2°).
    min_length: float = 0.5
    merge_radius: float = 0.2  # m: corners closer than this are one

    def validate(self) -> None:
        for name in ("reach", "min_length", "merge_radius"):
            check_positive(f"corners.{name}", getattr(self, name))
        if not 0.0 < self.min_angle_deg < 90.0:
            raise ConfigError(
                f"corners.min_angle_deg: must be in (0, 90), got {self.min_angle_deg!r}"
            )


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _meet(
    start: np.ndarray, direction: np.ndarray, wall: Polynomial, xi0: float
) -> tuple[float, float] | None:
    """Where the line ``start + s·direction`` crosses ``wall``: (s, ξ on the wall), by Newton
    steps from ξ0 (each intersects the line with the wall's tangent line at the current ξ);
    None when the line runs parallel to the wall there."""
    xi = xi0
    s = 0.0
    for _ in range(_NEWTON_STEPS):
        q = wall.points_at(np.array([xi]))[0]
        t = unit_tangent(wall, xi)
        den = _cross(direction, t)
        if abs(den) < 1e-9:
            return None
        s = _cross(q - start, t) / den
        point = start + s * direction
        xi = float(wall.from_xy(point)[0])
    return s, xi


def wall_corners(
    polys: Sequence[Polynomial], sides: Sequence[int], cfg: CornerConfig | None = None
) -> FeatureMap:
    """The corners (see the module docstring) of a map of walls ``polys`` whose observed faces
    are ``sides`` (±1, 0 unknown; ``PolySlam.table.side``): positions (n, 2), descriptors
    (n, 2) = (opening angle, convexity) and headings (n,), in the map's frame."""
    cfg = cfg or CornerConfig()
    sin_min = math.sin(math.radians(cfg.min_angle_deg))
    walls = [
        (k, p, int(side))
        for k, (p, side) in enumerate(zip(polys, sides, strict=True))
        if p.length() >= cfg.min_length
    ]
    boxes = {}
    for k, p, _ in walls:
        pts = p.equally_spaced(9)
        boxes[k] = (pts.min(axis=0) - cfg.reach, pts.max(axis=0) + cfg.reach)
    positions: list[np.ndarray] = []
    headings: list[float] = []
    descriptors: list[tuple[float, float]] = []
    for k, wall, side in walls:
        for xi_end, outward in ((wall.lo, -1.0), (wall.hi, 1.0)):
            end = wall.points_at(np.array([xi_end]))[0]
            u = outward * unit_tangent(wall, xi_end)  # leaves the wall at this end
            for m, other, other_side in walls:
                lo_box, hi_box = boxes[m]
                if m == k or np.any(end < lo_box) or np.any(end > hi_box):
                    continue
                xi_near = float(np.clip(other.from_xy(end)[0], other.lo, other.hi))
                hit = _meet(end, u, other, xi_near)
                if hit is None:
                    continue
                s, xi = hit
                if abs(s) > cfg.reach or not other.lo - cfg.reach <= xi <= other.hi + cfg.reach:
                    continue
                t_other = unit_tangent(other, float(np.clip(xi, other.lo, other.hi)))
                if abs(_cross(u, t_other)) < sin_min:
                    continue  # nearly parallel: the same wall in pieces
                arm = -u  # into this wall's body
                if xi - other.lo <= cfg.reach:
                    arm_other = t_other  # the other wall starts here: into its body
                elif other.hi - xi <= cfg.reach:
                    arm_other = -t_other
                else:  # a T: the other wall's arm on this wall's observed face
                    if side == 0:
                        continue
                    normal = face_normal(wall, xi_end, side)
                    arm_other = t_other if float(t_other @ normal) > 0.0 else -t_other
                corner = end + s * u
                if any(np.hypot(*(corner - p)) < cfg.merge_radius for p in positions):
                    continue
                bisector = arm + arm_other
                positions.append(corner)
                headings.append(math.atan2(bisector[1], bisector[0]))
                opening = math.acos(float(np.clip(arm @ arm_other, -1.0, 1.0)))
                descriptors.append(
                    (opening, _convexity(wall, xi_end, side, other, xi, other_side, arm, arm_other))
                )
    return FeatureMap(
        np.array(positions).reshape(-1, 2),
        np.array(descriptors).reshape(-1, CORNER_DESCRIPTOR_DIM),
        np.array(headings),
    )


def _convexity(
    wall: Polynomial,
    xi: float,
    side: int,
    other: Polynomial,
    xi_other: float,
    other_side: int,
    arm: np.ndarray,
    arm_other: np.ndarray,
) -> float:
    """+1 when the observed face of a wall looks into the opening (towards the other arm), −1
    when it looks away, 0 when neither face is known (the first known face decides)."""
    if side != 0:
        return 1.0 if float(face_normal(wall, xi, side) @ arm_other) > 0.0 else -1.0
    if other_side != 0:
        xi_c = float(np.clip(xi_other, other.lo, other.hi))
        return 1.0 if float(face_normal(other, xi_c, other_side) @ arm) > 0.0 else -1.0
    return 0.0

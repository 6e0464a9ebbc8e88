"""Range beams and the robot-detecting camera: pure numpy geometry (no pymunk).

Sensing geometry is kept apart from the physics so it can be tested against brute force and
reused by metrics. Conventions:

* Walls are **infinitely thin lines** for sensing: ``WorldConfig.wall_radius`` only thickens
  them in the physics (so a robot stops ``wall_radius`` before the line, and its beams measure
  the distance to the line itself, as the SLAM's polynomial map models it).
* Beams start at the robot centre, at angle ``θ + β_i``; the range is the distance from the
  centre to the first wall or circle (pillar, or other robot when ``hit_robots``) along the ray.
  No hit within ``max_range`` reads ``inf`` — never a fake number.
* Noise is drawn for every beam (and every robot pair for the camera) at every call, whether it
  hit or not, so the stream of numbers a generator produces does not depend on the geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.world.config import CameraConfig, RangeSensorConfig

#: Rays and segments more parallel than this (|sin| of the angle between them) never hit.
_PARALLEL_EPS = 1e-12


def _ray_segment_hits(
    ox: np.ndarray, oy: np.ndarray, dx: np.ndarray, dy: np.ndarray, segments: np.ndarray
) -> np.ndarray:
    """Ray parameter t of each ray (R,) against each segment (S, 4): shape (R, S), inf if none."""
    ax, ay = segments[:, 0], segments[:, 1]  # (S,)
    ex, ey = segments[:, 2] - ax, segments[:, 3] - ay  # (S,)
    wx, wy = ax[None, :] - ox[:, None], ay[None, :] - oy[:, None]  # (R, S): origin → a
    denom = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]  # (R, S): cross(d, e)
    parallel = np.abs(denom) <= _PARALLEL_EPS
    safe = np.where(parallel, 1.0, denom)
    t = (wx * ey[None, :] - wy * ex[None, :]) / safe  # cross(w, e) / cross(d, e)
    u = (wx * dy[:, None] - wy * dx[:, None]) / safe  # cross(w, d) / cross(d, e)
    ok = ~parallel & (t >= 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.where(ok, t, np.inf)


def _ray_circle_hits(
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    circles: np.ndarray,
    exclude: np.ndarray | None,
) -> np.ndarray:
    """Ray parameter t of each ray (R,) against each circle (C, 3): shape (R, C), inf if none.

    A ray starting inside a circle is blocked at once (t = 0). ``exclude`` (R,) names one circle
    per ray to ignore (−1 for none): a robot's own body for its beams.
    """
    fx, fy = ox[:, None] - circles[None, :, 0], oy[:, None] - circles[None, :, 1]  # (R, C)
    b = fx * dx[:, None] + fy * dy[:, None]  # (R, C), unit direction so a = 1
    c = fx * fx + fy * fy - circles[None, :, 2] ** 2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    t_near = -b - root
    t_far = -b + root
    t = np.where(t_near >= 0.0, t_near, np.where(t_far >= 0.0, 0.0, np.inf))
    t = np.where(disc >= 0.0, t, np.inf)
    if exclude is not None:
        t = np.where(exclude[:, None] == np.arange(len(circles))[None, :], np.inf, t)
    return t


def cast_rays(
    origins: np.ndarray,
    directions: np.ndarray,
    segments: np.ndarray,
    circles: np.ndarray,
    max_range: float,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Distance along each ray to the first segment or circle, ``inf`` beyond ``max_range``.

    origins (R, 2); directions (R,) angles in radians; segments (S, 4) x0, y0, x1, y1 (thin
    lines); circles (C, 3) x, y, r; exclude (R,) index of a circle each ray ignores (−1: none).
    Returns (R,). Vectorised over rays × segments and rays × circles.
    """
    origins = np.asarray(origins, dtype=float).reshape(-1, 2)
    ang = np.asarray(directions, dtype=float).reshape(-1)
    ox, oy = origins[:, 0], origins[:, 1]
    dx, dy = np.cos(ang), np.sin(ang)
    best = np.full(len(ang), np.inf)
    if len(segments):
        best = np.minimum(best, _ray_segment_hits(ox, oy, dx, dy, segments).min(axis=1))
    if len(circles):
        hits = _ray_circle_hits(ox, oy, dx, dy, np.asarray(circles, dtype=float), exclude)
        best = np.minimum(best, hits.min(axis=1))
    return np.where(best <= max_range, best, np.inf)


class RangeSensor:
    """The fixed beams of every robot: ``measure`` returns (N, n_beams) noisy ranges."""

    def __init__(self, config: RangeSensorConfig) -> None:
        self.config = config
        self.angles = np.asarray(config.angles, dtype=float)  # (B,) beam angles β_i

    @property
    def num_beams(self) -> int:
        return len(self.angles)

    def true_ranges(
        self, poses: np.ndarray, segments: np.ndarray, circles: np.ndarray, robot_radius: float
    ) -> np.ndarray:
        """Noiseless ranges (N, B) for poses (N, 3); circles (C, 3) are pillars only.

        When ``hit_robots`` is set, the other robots (radius ``robot_radius``) are appended to
        the circles, and each robot's beams skip its own body.
        """
        n, nb = len(poses), self.num_beams
        origins = np.repeat(poses[:, :2], nb, axis=0)  # (N·B, 2)
        dirs = (poses[:, 2:3] + self.angles[None, :]).reshape(-1)  # (N·B,)
        exclude = None
        if self.config.hit_robots and n > 0:
            bodies = np.column_stack([poses[:, :2], np.full(n, robot_radius)])  # (N, 3)
            circles = np.vstack([np.asarray(circles, dtype=float).reshape(-1, 3), bodies])
            exclude = len(circles) - n + np.repeat(np.arange(n), nb)  # (N·B,) own body
        d = cast_rays(origins, dirs, segments, circles, self.config.max_range, exclude)
        return d.reshape(n, nb)

    def measure(
        self,
        poses: np.ndarray,
        segments: np.ndarray,
        circles: np.ndarray,
        rng: np.random.Generator,
        robot_radius: float = 0.0,
    ) -> np.ndarray:
        """Noisy ranges (N, B): true + N(0, σ²), clipped to ≥ 0; no return stays ``inf``.

        A noisy hit near ``max_range`` may read slightly above it (the noise is not truncated).
        """
        return self.add_noise(self.true_ranges(poses, segments, circles, robot_radius), rng)

    def add_noise(self, true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy ranges from noiseless ones (N, B), as :meth:`measure` (one draw per beam)."""
        noise = rng.standard_normal(true.shape) * self.config.sigma  # drawn for every beam
        return np.maximum(true + noise, 0.0)


@dataclass(frozen=True)
class Detection:
    """One robot seen by another's camera: bearing relative to the robot axis, in (−π, π]."""

    target: int  # index of the detected robot
    distance: float  # m, centre to centre
    bearing: float  # rad


class Camera:
    """Detects other robots within range and field of view with a clear line of sight.

    Line of sight is the segment between the two centres; walls and pillars occlude, other
    robots do not (their bodies are small and the camera is assumed mounted above them).
    Failed (inactive) robots neither see nor are seen.
    """

    def __init__(self, config: CameraConfig) -> None:
        self.config = config
        self.half_fov = math.radians(config.fov_deg) / 2.0

    def visible(
        self, poses: np.ndarray, active: np.ndarray, segments: np.ndarray, circles: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noiseless (mask, distance, bearing), each (N, N): row = observer, column = target."""
        n = len(poses)
        rel = poses[None, :, :2] - poses[:, None, :2]  # (N, N, 2): target − observer
        dist = np.hypot(rel[..., 0], rel[..., 1])  # (N, N)
        bearing = wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - poses[:, None, 2])
        mask = active[:, None] & active[None, :] & ~np.eye(n, dtype=bool)
        mask &= dist <= self.config.range
        if self.config.fov_deg < 360.0:
            mask &= np.abs(bearing) <= self.half_fov
        obs, tgt = np.nonzero(mask)
        if len(obs):
            ang = np.arctan2(rel[obs, tgt, 1], rel[obs, tgt, 0])
            hit = cast_rays(poses[obs, :2], ang, segments, circles, np.inf)
            mask[obs[hit < dist[obs, tgt]], tgt[hit < dist[obs, tgt]]] = False
        return mask, dist, bearing

    def detect(
        self,
        poses: np.ndarray,
        active: np.ndarray,
        segments: np.ndarray,
        circles: np.ndarray,
        rng: np.random.Generator,
    ) -> list[list[Detection]]:
        """Per observer, its detections with noisy distance (≥ 0) and bearing (wrapped)."""
        n = len(poses)
        mask, dist, bearing = self.visible(poses, np.asarray(active, dtype=bool), segments, circles)
        noise = rng.standard_normal((n, n, 2))  # drawn for every pair, seen or not
        d = np.maximum(dist + noise[..., 0] * self.config.sigma_d, 0.0)
        b = wrap_angle(bearing + noise[..., 1] * self.config.sigma_bearing)
        out: list[list[Detection]] = [[] for _ in range(n)]
        for i, j in zip(*np.nonzero(mask), strict=True):
            out[int(i)].append(Detection(int(j), float(d[i, j]), float(b[i, j])))
        return out

"""Range beams and the robot-detecting camera: geometry on compiled kernels (no pymunk).

Sensing geometry is kept apart from the physics so it can be tested against brute force and
reused by metrics. The ray casting is :mod:`~polyslam_env.world.kernels` against the layout's
static :class:`~polyslam_env.world.nearby.WallIndex` (a bare (S, 4) array of segments is
indexed on the fly); the readable numpy version is the oracle in ``tests/world/reference.py``.
Conventions:

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
from typing import NamedTuple

import numpy as np

from polyslam_env.world import kernels
from polyslam_env.world.config import CameraConfig, RangeSensorConfig
from polyslam_env.world.nearby import WallIndex

Walls = np.ndarray | WallIndex  # segments (S, 4), or their static index
_FLOAT = np.dtype(float)


def _index(walls: Walls) -> WallIndex:
    """The static index of ``walls``: as given, or built for a bare (S, 4) array."""
    return walls if isinstance(walls, WallIndex) else WallIndex.build(walls)


def _rows3(a: np.ndarray) -> np.ndarray:  # (M, 3)
    """``a`` (poses or circles) as a C-contiguous float array of rows of 3: itself when it is
    one already (the common case, checked without numpy calls)."""
    if type(a) is np.ndarray and a.dtype == _FLOAT and a.ndim == 2 and a.shape[1] == 3:
        if a.flags.c_contiguous:
            return a
    return np.ascontiguousarray(np.asarray(a, dtype=float).reshape(-1, 3))


def cast_rays(
    origins: np.ndarray,
    directions: np.ndarray,
    walls: Walls,
    circles: np.ndarray,
    max_range: float,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Distance along each ray to the first segment or circle, ``inf`` beyond ``max_range``.

    origins (R, 2); directions (R,) angles in radians; walls the segments (S, 4) x0, y0, x1, y1
    (thin lines) or their :class:`WallIndex`; circles (C, 3) x, y, r; exclude (R,) index of a
    circle each ray ignores (−1: none). Returns (R,). A ray starting inside a circle is blocked
    at once (0); rays parallel to a segment (within 1e-12) never hit it.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 2)
    ang = np.asarray(directions, dtype=float).reshape(-1)
    poses = np.ascontiguousarray(np.column_stack([o, ang]))  # each ray a "robot" with one beam
    ex = np.full(len(ang), -1, dtype=np.int64) if exclude is None else np.asarray(exclude)
    out = np.empty((len(ang), 1))
    kernels.beam_ranges(
        poses, np.zeros(1), float(max_range), *_index(walls).arrays, _rows3(circles),
        ex.astype(np.int64), out,
    )  # fmt: skip
    return out.reshape(-1)


class RangeSensor:
    """The fixed beams of every robot: ``measure`` returns (N, n_beams) noisy ranges."""

    def __init__(self, config: RangeSensorConfig) -> None:
        self.config = config
        self.angles = np.asarray(config.angles, dtype=float)  # (B,) beam angles β_i

    @property
    def num_beams(self) -> int:
        return len(self.angles)

    def true_ranges(
        self, poses: np.ndarray, walls: Walls, circles: np.ndarray, robot_radius: float
    ) -> np.ndarray:
        """Noiseless ranges (N, B) for poses (N, 3); walls (S, 4) or their index; circles
        (C, 3) are pillars only.

        When ``hit_robots`` is set, the other robots (radius ``robot_radius``) are appended to
        the circles, and each robot's beams skip its own body.
        """
        p = _rows3(poses)
        n = len(p)
        circ = _rows3(circles)
        exclude = np.full(n, -1, dtype=np.int64)
        if self.config.hit_robots and n > 0:
            bodies = np.column_stack([p[:, :2], np.full(n, robot_radius)])  # (N, 3)
            circ = np.ascontiguousarray(np.vstack([circ, bodies]))
            exclude = len(circ) - n + np.arange(n, dtype=np.int64)  # own body
        out = np.empty((n, self.num_beams))
        kernels.beam_ranges(
            p, self.angles, float(self.config.max_range), *_index(walls).arrays, circ,
            exclude, out,
        )  # fmt: skip
        return out

    def measure(
        self,
        poses: np.ndarray,
        walls: Walls,
        circles: np.ndarray,
        rng: np.random.Generator,
        robot_radius: float = 0.0,
    ) -> np.ndarray:
        """Noisy ranges (N, B): true + N(0, σ²), clipped to ≥ 0; no return stays ``inf``.

        A noisy hit near ``max_range`` may read slightly above it (the noise is not truncated).
        """
        return self.add_noise(self.true_ranges(poses, walls, circles, robot_radius), rng)

    def add_noise(self, true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy ranges from noiseless ones (N, B), as :meth:`measure` (one draw per beam)."""
        noise = rng.standard_normal(true.shape)  # drawn for every beam
        out = np.empty(true.shape)
        kernels.noisy_ranges(true, noise, self.config.sigma, out)
        return out


@dataclass(frozen=True)
class Detection:
    """One robot seen by another's camera: bearing relative to the robot axis, in (−π, π]."""

    target: int  # index of the detected robot
    distance: float  # m, centre to centre
    bearing: float  # rad


class CameraFrame(NamedTuple):
    """One camera frame of the whole team as arrays: row = observer, column = target."""

    seen: np.ndarray  # (N, N) bool
    distance: np.ndarray  # (N, N) noisy distance, m (meaningful where seen)
    bearing: np.ndarray  # (N, N) noisy bearing, rad, wrapped (meaningful where seen)

    @classmethod
    def empty(cls, n: int) -> CameraFrame:
        """A frame in which nobody sees anybody (camera off)."""
        return cls(np.zeros((n, n), dtype=bool), np.zeros((n, n)), np.zeros((n, n)))

    def lists(self) -> list[list[Detection]]:
        """Per observer, its :class:`Detection` s in target order."""
        out: list[list[Detection]] = [[] for _ in range(len(self.seen))]
        if not np.count_nonzero(self.seen):  # (a C call; .any() is a ufunc reduction)
            return out
        obs, tgt = np.nonzero(self.seen)
        d, b = self.distance[self.seen].tolist(), self.bearing[self.seen].tolist()
        for i, j, dj, bj in zip(obs.tolist(), tgt.tolist(), d, b, strict=True):
            out[i].append(Detection(j, dj, bj))
        return out


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
        self, poses: np.ndarray, active: np.ndarray, walls: Walls, circles: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noiseless (mask, distance, bearing), each (N, N): row = observer, column = target;
        walls (S, 4) or their index, circles (C, 3) the pillars."""
        return self._visible(poses, active, walls, circles)[:3]

    def _visible(
        self, poses: np.ndarray, active: np.ndarray, walls: Walls, circles: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """:meth:`visible` and how many pairs are seen."""
        p = _rows3(poses)
        n = len(p)
        mask, dist, bearing = np.empty((n, n), dtype=bool), np.empty((n, n)), np.empty((n, n))
        seen = kernels.camera_visible(
            p, np.asarray(active, dtype=bool), float(self.config.range),
            self.half_fov, self.config.fov_deg < 360.0, *_index(walls).arrays,
            _rows3(circles), mask, dist, bearing,
        )  # fmt: skip
        return mask, dist, bearing, seen

    def detect(
        self,
        poses: np.ndarray,
        active: np.ndarray,
        walls: Walls,
        circles: np.ndarray,
        rng: np.random.Generator,
    ) -> list[list[Detection]]:
        """Per observer, its detections with noisy distance (≥ 0) and bearing (wrapped)."""
        return self.frame(poses, active, walls, circles, rng).lists()

    def frame(
        self,
        poses: np.ndarray,
        active: np.ndarray,
        walls: Walls,
        circles: np.ndarray,
        rng: np.random.Generator,
    ) -> CameraFrame:
        """:meth:`detect` as arrays: who sees whom, with noisy distance (≥ 0) and bearing
        (wrapped) where seen (the same draws: one pair of normals per robot pair)."""
        n = len(poses)
        mask, dist, bearing, seen = self._visible(poses, active, walls, circles)
        noise = rng.standard_normal((n, n, 2))  # drawn for every pair, seen or not
        if not seen:
            return CameraFrame(mask, np.zeros((n, n)), np.zeros((n, n)))
        d, b = np.empty((n, n)), np.empty((n, n))
        cfg = self.config
        kernels.camera_noise(dist, bearing, noise, cfg.sigma_d, cfg.sigma_bearing, d, b)
        return CameraFrame(mask, d, b)

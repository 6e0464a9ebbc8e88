"""Readable numpy versions of the world's compiled kernels: the oracles of the kernel tests.

These were the production code before the kernels (``polyslam_env/world/kernels.py``) replaced
them; the kernels do the same float operations in the same order, so the tests ask for
bit-identical results.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.world.layout import point_segment_distance

#: Rays and segments more parallel than this (|sin| of the angle between them) never hit.
PARALLEL_EPS = 1e-12


def ray_segment_hits(
    ox: np.ndarray, oy: np.ndarray, dx: np.ndarray, dy: np.ndarray, segments: np.ndarray
) -> np.ndarray:
    """Ray parameter t of each ray (R,) against each segment (S, 4): shape (R, S), inf if none."""
    ax, ay = segments[:, 0], segments[:, 1]  # (S,)
    ex, ey = segments[:, 2] - ax, segments[:, 3] - ay  # (S,)
    wx, wy = ax[None, :] - ox[:, None], ay[None, :] - oy[:, None]  # (R, S): origin → a
    denom = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]  # (R, S): cross(d, e)
    parallel = np.abs(denom) <= PARALLEL_EPS
    safe = np.where(parallel, 1.0, denom)
    t = (wx * ey[None, :] - wy * ex[None, :]) / safe  # cross(w, e) / cross(d, e)
    u = (wx * dy[:, None] - wy * dx[:, None]) / safe  # cross(w, d) / cross(d, e)
    ok = ~parallel & (t >= 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.where(ok, t, np.inf)


def ray_circle_hits(
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    circles: np.ndarray,
    exclude: np.ndarray | None,
) -> np.ndarray:
    """Ray parameter t of each ray (R,) against each circle (C, 3): shape (R, C), inf if none.

    A ray starting inside a circle is blocked at once (t = 0). ``exclude`` (R,) names one circle
    per ray to ignore (−1 for none).
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
    """Distance along each ray (R,) to the first segment or circle, ``inf`` beyond range."""
    origins = np.asarray(origins, dtype=float).reshape(-1, 2)
    ang = np.asarray(directions, dtype=float).reshape(-1)
    ox, oy = origins[:, 0], origins[:, 1]
    dx, dy = np.cos(ang), np.sin(ang)
    best = np.full(len(ang), np.inf)
    if len(segments):
        best = np.minimum(best, ray_segment_hits(ox, oy, dx, dy, segments).min(axis=1))
    if len(circles):
        hits = ray_circle_hits(ox, oy, dx, dy, np.asarray(circles, dtype=float), exclude)
        best = np.minimum(best, hits.min(axis=1))
    return np.where(best <= max_range, best, np.inf)


def true_ranges(
    poses: np.ndarray,
    angles: np.ndarray,
    max_range: float,
    segments: np.ndarray,
    circles: np.ndarray,
    robot_radius: float,
    hit_robots: bool,
) -> np.ndarray:
    """Noiseless ranges (N, B) of the beams at ``angles`` (B,) from ``poses`` (N, 3)."""
    n, nb = len(poses), len(angles)
    origins = np.repeat(poses[:, :2], nb, axis=0)  # (N·B, 2)
    dirs = (poses[:, 2:3] + angles[None, :]).reshape(-1)  # (N·B,)
    exclude = None
    if hit_robots and n > 0:
        bodies = np.column_stack([poses[:, :2], np.full(n, robot_radius)])  # (N, 3)
        circles = np.vstack([np.asarray(circles, dtype=float).reshape(-1, 3), bodies])
        exclude = len(circles) - n + np.repeat(np.arange(n), nb)  # (N·B,) own body
    return cast_rays(origins, dirs, segments, circles, max_range, exclude).reshape(n, nb)


def camera_visible(
    poses: np.ndarray,
    active: np.ndarray,
    segments: np.ndarray,
    circles: np.ndarray,
    cam_range: float,
    fov_deg: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noiseless (mask, distance, bearing), each (N, N): row = observer, column = target."""
    n = len(poses)
    half_fov = np.radians(fov_deg) / 2.0
    rel = poses[None, :, :2] - poses[:, None, :2]  # (N, N, 2): target − observer
    dist = np.hypot(rel[..., 0], rel[..., 1])  # (N, N)
    bearing = wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - poses[:, None, 2])
    mask = active[:, None] & active[None, :] & ~np.eye(n, dtype=bool)
    mask &= dist <= cam_range
    if fov_deg < 360.0:
        mask &= np.abs(bearing) <= half_fov
    obs, tgt = np.nonzero(mask)
    if len(obs):
        ang = np.arctan2(rel[obs, tgt, 1], rel[obs, tgt, 0])
        hit = cast_rays(poses[obs, :2], ang, segments, circles, np.inf)
        mask[obs[hit < dist[obs, tgt]], tgt[hit < dist[obs, tgt]]] = False
    return mask, dist, bearing


def segments_cross(p0: np.ndarray, p1: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Whether each path p0→p1 (N, 2) properly intersects any segment (S, 4): (N,) bool."""
    if len(segments) == 0:
        return np.zeros(len(p0), dtype=bool)
    a, e = segments[:, 0:2], segments[:, 2:4] - segments[:, 0:2]  # (S, 2)
    d = p1 - p0  # (N, 2)
    w = a[None, :, :] - p0[:, None, :]  # (N, S, 2)
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (N, S)
    t = w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]  # path parameter · denom
    u = w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]  # segment parameter · denom
    sign = np.sign(denom)
    t, u, denom = t * sign, u * sign, denom * sign
    hit = (denom > 0) & (t > 0) & (t < denom) & (u > 0) & (u < denom)
    return np.asarray(hit.any(axis=1))


def too_deep(
    centres: np.ndarray,
    segments: np.ndarray,
    pillars: np.ndarray,
    radius: float,
    wall_radius: float,
    tolerance: float,
) -> np.ndarray:
    """Whether each centre (N, 2) overlaps a wall or pillar by more than ``tolerance``."""
    deep = np.zeros(len(centres), dtype=bool)
    if len(segments):
        wall = point_segment_distance(centres, segments).min(axis=1)
        deep |= wall < radius + wall_radius - tolerance
    if len(pillars):
        rel = centres[:, None, :] - pillars[None, :, :2]  # (N, P, 2)
        gap = np.hypot(rel[..., 0], rel[..., 1]) - pillars[None, :, 2]
        deep |= gap.min(axis=1) < radius - tolerance
    return deep


def drive_forces(
    heading: np.ndarray, cmd: np.ndarray, h: float, substeps: int, mass: float
) -> np.ndarray:
    """Drive force (N, substeps, 2) of each robot in each sub-step (``World._integrate``)."""
    mid = heading[:, None] + cmd[:, 1:2] * h * (np.arange(substeps)[None, :] + 0.5)  # (N, n)
    half = cmd[:, 1:2] * (h / 2)  # (N, 1): half the turn of one sub-step
    safe = np.where(half == 0.0, 1.0, half)
    chord = np.where(half == 0.0, 1.0, np.sin(safe) / safe)  # (N, 1): sinc(ω h / 2)
    gain = cmd[:, 0:1] * chord * mass / h  # (N, 1)
    return np.stack([gain * np.cos(mid), gain * np.sin(mid)], axis=-1)


def noisy_ranges(true: np.ndarray, noise: np.ndarray, sigma: float) -> np.ndarray:  # (N, B)
    """Noisy ranges from noiseless ones and standard normal noise (N, B), clipped to ≥ 0."""
    return np.maximum(true + noise * sigma, 0.0)


def camera_noise(
    dist: np.ndarray, bearing: np.ndarray, noise: np.ndarray, sigma_d: float, sigma_bearing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy distances (≥ 0) and wrapped bearings (N, N) from noise (N, N, 2)."""
    d = np.maximum(dist + noise[..., 0] * sigma_d, 0.0)
    b = wrap_angle(bearing + noise[..., 1] * sigma_bearing)
    return d, b


def clip_commands(
    cmd: np.ndarray, lo: np.ndarray, hi: np.ndarray, active: np.ndarray
) -> np.ndarray:  # (N, 2)
    """``World.clip_commands`` as numpy wrote it: clipped per column, 0 for failed robots."""
    out = cmd.clip(lo, hi)
    out[~active] = 0.0
    return out

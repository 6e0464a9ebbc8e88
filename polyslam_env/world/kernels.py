"""Compiled kernels of the world: beams, the camera's line of sight, the guard, drive forces.

Plain loops over arrays, compiled by :func:`polyslam_env.core.jit.njit`. Each kernel does the
same floating-point operations in the same order as the readable numpy version it replaced
(kept in ``tests/world/reference.py`` as the oracle), so results are bit-identical. Walls are
looked up in the static :class:`~polyslam_env.world.nearby.WallIndex`: a query visits the cells
overlapped by a box and tests the segments they list (some more than once, which changes no
minimum and no "any").

The index is passed as its arrays, in this order: ``segments (S, 4), origin (2,), cell, rows,
cols, starts (rows·cols + 1,), items (K,)``.
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import njit

#: Rays and segments more parallel than this (|sin| of the angle between them) never hit.
PARALLEL_EPS = 1e-12
#: Growth of query boxes, m (the index grows segment boxes by the same).
MARGIN = 1e-6


@njit
def _cell_range(lo: float, hi: float, origin: float, cell: float, n: int) -> tuple[int, int]:
    """First and last cell (clamped to 0…n−1) overlapped by lo…hi grown by MARGIN; first >
    last when none."""
    a = math.floor((lo - MARGIN - origin) / cell)
    b = math.floor((hi + MARGIN - origin) / cell)
    return max(a, 0), min(b, n - 1)


@njit
def segment_hit(ox: float, oy: float, dx: float, dy: float, segments: np.ndarray, s: int) -> float:
    """Ray parameter t of the ray o + t·d (d a unit vector) at segment ``s``; inf if none."""
    ax, ay = segments[s, 0], segments[s, 1]
    ex, ey = segments[s, 2] - ax, segments[s, 3] - ay
    wx, wy = ax - ox, ay - oy  # origin → a
    denom = dx * ey - dy * ex  # cross(d, e)
    if abs(denom) <= PARALLEL_EPS:
        return math.inf
    t = (wx * ey - wy * ex) / denom  # cross(w, e) / cross(d, e)
    u = (wx * dy - wy * dx) / denom  # cross(w, d) / cross(d, e)
    if t >= 0.0 and u >= 0.0 and u <= 1.0:
        return t
    return math.inf


@njit
def circle_hit(ox: float, oy: float, dx: float, dy: float, circles: np.ndarray, c: int) -> float:
    """Ray parameter t of the ray o + t·d at circle ``c`` (x, y, r); 0 from inside; inf if none."""
    fx, fy = ox - circles[c, 0], oy - circles[c, 1]
    b = fx * dx + fy * dy  # unit direction, so a = 1
    cc = fx * fx + fy * fy - circles[c, 2] * circles[c, 2]
    disc = b * b - cc
    if not disc >= 0.0:
        return math.inf
    root = math.sqrt(max(disc, 0.0))
    if -b - root >= 0.0:
        return -b - root
    if -b + root >= 0.0:
        return 0.0
    return math.inf


@njit
def first_hit(
    ox: float,
    oy: float,
    dx: float,
    dy: float,
    reach: float,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
    circles: np.ndarray,
    exclude: int,
) -> float:
    """Smallest t of the ray o + t·d over the segments listed in the cells of the ray's box up
    to ``reach`` and over all circles but ``exclude`` (−1: none). Exact for every t ≤ reach; a
    larger result only says there is no hit up to ``reach``."""
    best = math.inf
    if reach < math.inf:
        ex, ey = ox + reach * dx, oy + reach * dy
        c0, c1 = _cell_range(min(ox, ex), max(ox, ex), origin[0], cell, cols)
        r0, r1 = _cell_range(min(oy, ey), max(oy, ey), origin[1], cell, rows)
    else:  # unbounded: every cell
        c0, c1, r0, r1 = 0, cols - 1, 0, rows - 1
    for row in range(r0, r1 + 1):
        for col in range(c0, c1 + 1):
            k = row * cols + col
            for j in range(starts[k], starts[k + 1]):
                t = segment_hit(ox, oy, dx, dy, segments, items[j])
                if t < best:
                    best = t
    for c in range(circles.shape[0]):
        if c != exclude:
            t = circle_hit(ox, oy, dx, dy, circles, c)
            if t < best:
                best = t
    return best


@njit
def beam_ranges(
    poses: np.ndarray,
    angles: np.ndarray,
    max_range: float,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
    circles: np.ndarray,
    exclude: np.ndarray,
    out: np.ndarray,
) -> None:
    """Noiseless ranges ``out`` (N, B) of the beams at ``angles`` (B,) from ``poses`` (N, 3):
    the first wall or circle along each beam, inf beyond ``max_range``; robot i's beams ignore
    circle ``exclude[i]`` (−1: none)."""
    for i in range(poses.shape[0]):
        ox, oy = poses[i, 0], poses[i, 1]
        for b in range(angles.shape[0]):
            phi = poses[i, 2] + angles[b]
            dx, dy = math.cos(phi), math.sin(phi)
            t = first_hit(
                ox, oy, dx, dy, max_range, segments, origin, cell, rows, cols, starts, items,
                circles, exclude[i],
            )  # fmt: skip
            out[i, b] = t if t <= max_range else math.inf


@njit
def in_view(
    ox: float,
    oy: float,
    heading: float,
    d: float,
    a: float,
    eligible: bool,
    reach: float,
    half_fov: float,
    limit_fov: bool,
    clear: float,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
    circles: np.ndarray,
    exclude: int,
) -> tuple[float, bool]:
    """The bearing, wrapped to (−π, π], of a target at distance ``d`` and absolute direction
    ``a`` from an observer at (``ox``, ``oy``) heading ``heading``, and whether it is seen:
    ``eligible``, within ``reach``, within the field of view when ``limit_fov``, and no wall
    and no circle (but circle ``exclude``, −1: none) on the first ``clear`` metres of the line
    of sight. The camera's and the pillar sensor's visibility test."""
    turn = a - heading
    bearing = math.pi - np.mod(math.pi - turn, 2.0 * math.pi)
    seen = eligible and d <= reach
    if seen and limit_fov:
        seen = abs(bearing) <= half_fov
    if seen:
        hit = first_hit(
            ox, oy, math.cos(a), math.sin(a), clear, segments, origin, cell, rows, cols,
            starts, items, circles, exclude,
        )  # fmt: skip
        seen = not hit < clear
    return bearing, seen


@njit
def camera_visible(
    poses: np.ndarray,
    active: np.ndarray,
    cam_range: float,
    half_fov: float,
    limit_fov: bool,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
    circles: np.ndarray,
    mask: np.ndarray,
    dist: np.ndarray,
    bearing: np.ndarray,
) -> int:
    """Which robot (column) each robot (row) sees: ``mask`` (N, N), and the distance ``dist``
    and ``bearing`` (N, N) of every pair, from the offset target − observer and its absolute
    direction (atan2, the C library's, as numpy's arctan2); returns how many pairs are seen.
    Seen: both active, not itself, within ``cam_range``, within the field of view when
    ``limit_fov``, and no wall or circle on the line of sight before the target."""
    n = poses.shape[0]
    seen = 0
    for o in range(n):
        for g in range(n):
            rx, ry = poses[g, 0] - poses[o, 0], poses[g, 1] - poses[o, 1]
            d = math.hypot(rx, ry)
            dist[o, g] = d
            bearing[o, g], mask[o, g] = in_view(
                poses[o, 0], poses[o, 1], poses[o, 2], d, math.atan2(ry, rx),
                active[o] and active[g] and o != g, cam_range, half_fov, limit_fov, d,
                segments, origin, cell, rows, cols, starts, items, circles, -1,
            )  # fmt: skip
            seen += mask[o, g]
    return seen


@njit
def pillar_visible(
    poses: np.ndarray,
    active: np.ndarray,
    max_range: float,
    half_fov: float,
    limit_fov: bool,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
    circles: np.ndarray,
    mask: np.ndarray,
    dist: np.ndarray,
    bearing: np.ndarray,
) -> None:
    """Which pillar (column of ``mask`` (N, P)) each robot (row) sees, and the distance and
    bearing (N, P) of every robot-pillar pair to the pillar's centre. Seen: the robot is
    active, the centre within ``max_range`` and the field of view when ``limit_fov``, and no
    wall and no other pillar (``circles`` (P, 3)) on the line from the robot's centre to the
    pillar's surface."""
    for o in range(poses.shape[0]):
        ox, oy = poses[o, 0], poses[o, 1]
        for c in range(circles.shape[0]):
            rx, ry = circles[c, 0] - ox, circles[c, 1] - oy
            d = math.hypot(rx, ry)
            r = circles[c, 2]
            dist[o, c] = d
            bearing[o, c], mask[o, c] = in_view(
                ox, oy, poses[o, 2], d, math.atan2(ry, rx), active[o] and d > r, max_range,
                half_fov, limit_fov, d - r, segments, origin, cell, rows, cols, starts, items,
                circles, c,
            )  # fmt: skip


@njit
def noisy_ranges(true: np.ndarray, noise: np.ndarray, sigma: float, out: np.ndarray) -> None:
    """Noisy ranges ``out`` (N, B): ``true`` (N, B) + standard normal ``noise`` (N, B) ·
    ``sigma``, clipped to ≥ 0 as ``np.maximum(v, 0.0)`` (NaN stays, −0 becomes 0)."""
    for i in range(true.shape[0]):
        for b in range(true.shape[1]):
            v = true[i, b] + noise[i, b] * sigma
            out[i, b] = v if v > 0.0 or v != v else 0.0


@njit
def camera_noise(
    dist: np.ndarray,
    bearing: np.ndarray,
    noise: np.ndarray,
    sigma_d: float,
    sigma_bearing: float,
    d: np.ndarray,
    b: np.ndarray,
) -> None:
    """Noisy distances ``d`` (≥ 0) and bearings ``b`` (wrapped to (−π, π]), each (N, N), from
    the noiseless ones and standard normal ``noise`` (N, N, 2)."""
    for o in range(dist.shape[0]):
        for g in range(dist.shape[1]):
            v = dist[o, g] + noise[o, g, 0] * sigma_d
            d[o, g] = v if v >= 0.0 or v != v else 0.0  # np.maximum(v, 0): NaN stays
            a = bearing[o, g] + noise[o, g, 1] * sigma_bearing
            b[o, g] = math.pi - np.mod(math.pi - a, 2.0 * math.pi)


@njit
def _crosses(px: float, py: float, qx: float, qy: float, segments: np.ndarray, s: int) -> bool:
    """Whether the path p → q properly intersects segment ``s`` (ends and touching excluded)."""
    ax, ay = segments[s, 0], segments[s, 1]
    ex, ey = segments[s, 2] - ax, segments[s, 3] - ay
    dx, dy = qx - px, qy - py
    wx, wy = ax - px, ay - py
    denom = dx * ey - dy * ex
    t = wx * ey - wy * ex  # path parameter · denom
    u = wx * dy - wy * dx  # segment parameter · denom
    if denom > 0.0:
        return t > 0.0 and t < denom and u > 0.0 and u < denom
    if denom < 0.0:  # both sides times −1, exactly
        return -t > 0.0 and -t < -denom and -u > 0.0 and -u < -denom
    return False


@njit
def _segment_distance(px: float, py: float, segments: np.ndarray, s: int) -> float:
    """Distance from point p to segment ``s``."""
    ax, ay = segments[s, 0], segments[s, 1]
    abx, aby = segments[s, 2] - ax, segments[s, 3] - ay
    denom = max(abx * abx + aby * aby, 1e-300)
    t = min(max(((px - ax) * abx + (py - ay) * aby) / denom, 0.0), 1.0)
    dx, dy = px - (ax + t * abx), py - (ay + t * aby)
    return math.sqrt(dx * dx + dy * dy)


@njit
def guard_violations(
    start: np.ndarray,
    end: np.ndarray,
    active: np.ndarray,
    wall_clearance: float,
    pillar_clearance: float,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
    pillars: np.ndarray,
    bad: np.ndarray,
) -> None:
    """``bad`` (N,): active robots whose centre path start → end (N, ≥2) properly crossed a
    wall, or whose end lies closer than ``wall_clearance`` to a wall or than
    ``pillar_clearance`` to a pillar's surface."""
    for i in range(start.shape[0]):
        bad[i] = False
        if not active[i]:
            continue
        px, py, qx, qy = start[i, 0], start[i, 1], end[i, 0], end[i, 1]
        c0, c1 = _cell_range(
            min(px, qx) - wall_clearance, max(px, qx) + wall_clearance, origin[0], cell, cols
        )
        r0, r1 = _cell_range(
            min(py, qy) - wall_clearance, max(py, qy) + wall_clearance, origin[1], cell, rows
        )
        for row in range(r0, r1 + 1):
            for col in range(c0, c1 + 1):
                k = row * cols + col
                for j in range(starts[k], starts[k + 1]):
                    s = items[j]
                    if _crosses(px, py, qx, qy, segments, s) or (
                        _segment_distance(qx, qy, segments, s) < wall_clearance
                    ):
                        bad[i] = True
        for p in range(pillars.shape[0]):
            gap = math.hypot(qx - pillars[p, 0], qy - pillars[p, 1]) - pillars[p, 2]
            if gap < pillar_clearance:
                bad[i] = True


@njit
def clip_commands(
    cmd: np.ndarray, lo: np.ndarray, hi: np.ndarray, active: np.ndarray, out: np.ndarray
) -> int:
    """Commands (N, 2) clipped per column to [lo, hi] (2,) into ``out`` (N, 2) as ``np.clip``
    does (max with lo, then min with hi, each keeping the first operand unless the second is
    strictly beyond it), 0 for robots not ``active`` (N,). Returns the first row holding a value
    that is not finite (``out`` then unfinished), −1 when there is none."""
    for i in range(cmd.shape[0]):
        for k in range(2):
            if not math.isfinite(cmd[i, k]):
                return i
    for i in range(cmd.shape[0]):
        for k in range(2):
            v = cmd[i, k] if cmd[i, k] > lo[k] else lo[k]
            out[i, k] = (v if v < hi[k] else hi[k]) if active[i] else 0.0
    return -1


@njit
def drive_forces(
    heading: np.ndarray, cmd: np.ndarray, h: float, substeps: int, mass: float, out: np.ndarray
) -> None:
    """Drive force ``out`` (N, substeps, 2) of each robot in each sub-step of length ``h``: along
    the sub-step's mid heading, of size m·v·sinc(ω h / 2)/h (see ``World._integrate``)."""
    for i in range(heading.shape[0]):
        v, w = cmd[i, 0], cmd[i, 1]
        half = w * (h / 2)  # half the turn of one sub-step
        chord = 1.0 if half == 0.0 else math.sin(half) / half  # sinc(ω h / 2)
        gain = v * chord * mass / h
        for k in range(substeps):
            mid = heading[i] + w * h * (k + 0.5)
            out[i, k, 0] = gain * math.cos(mid)
            out[i, k, 1] = gain * math.sin(mid)


@njit
def motion_end(
    pose: np.ndarray,
    cmd: np.ndarray,
    dt: float,
    force: np.ndarray,
    drift: float,
    tolerance: float,
    end: np.ndarray,
    touched: np.ndarray,
) -> None:
    """The end of a control period (``World._integrate``): ``end`` (N, 3) holds the robots'
    end positions (x, y, read from chipmunk); writes each end heading θ + ω dt and ``touched``
    (N,): whether the end is off the free end, the start moved by the sub-steps' drive forces
    ``force`` (N, substeps, 2) times ``drift`` = h²/m, by more than ``tolerance``."""
    for i in range(pose.shape[0]):
        end[i, 2] = pose[i, 2] + cmd[i, 1] * dt
        fx = 0.0
        fy = 0.0
        for k in range(force.shape[1]):  # in order, as numpy sums along a middle axis
            fx += force[i, k, 0]
            fy += force[i, k, 1]
        ox = end[i, 0] - pose[i, 0] - fx * drift
        oy = end[i, 1] - pose[i, 1] - fy * drift
        touched[i] = ox * ox + oy * oy > tolerance * tolerance

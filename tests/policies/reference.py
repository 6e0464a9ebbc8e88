"""Readable oracles of the frontier policy's compiled pieces: the planner and controller as they
were written with numpy and scipy, before they were compiled (issue 41).

Each function is the readable version of one kernel; the tests compare them cell for cell
(the kernels do the same float operations in the same order, so the results are equal, not
close).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

#: 8-neighbour offsets (row, col) used for the graph edges (the other four are their reverses).
EDGE_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))


def frontier_and_cost(
    free: np.ndarray, obstacles: np.ndarray, inflate: float, close_cells: int, res: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frontier cells, passable cells, cell costs and clearances (m) of a window whose own-map
    grids are ``free`` and ``obstacles`` (H, W): the readable planner's ``_frontier_and_cost``
    (scipy on the window, with its border rules)."""
    obst = obstacles
    free = free & ~obst
    clearance = ndimage.distance_transform_edt(~obst) * res  # (H, W) m
    passable = free & (clearance > inflate)
    ball = ndimage.generate_binary_structure(2, 1)
    known = ndimage.binary_closing(
        free | obst, structure=ball, iterations=close_cells, border_value=1
    )
    unknown = ndimage.binary_opening(~known, structure=ball)
    frontier = passable & ndimage.binary_dilation(unknown, structure=np.ones((3, 3)))
    soft = 3.0 * inflate
    cost = 1.0 + 4.0 * np.clip((soft - clearance) / soft, 0.0, 1.0)
    return frontier, passable, cost, clearance


def grid_path(
    passable: np.ndarray, cost: np.ndarray, start: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Dijkstra from ``start`` over passable cells (8-connected), edge = length × mean cost,
    with scipy's ``dijkstra`` on a sparse graph: distances (H, W), predecessors (H·W,)."""
    h, w = passable.shape
    idx = np.arange(h * w).reshape(h, w)
    src, dst, wt = [], [], []
    for dr, dc in EDGE_OFFSETS:
        r0, r1 = 0, h - dr
        c0, c1 = max(0, -dc), w - max(0, dc)
        a = (slice(r0, r1), slice(c0, c1))
        b = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
        ok = passable[a] & passable[b]
        src.append(idx[a][ok])
        dst.append(idx[b][ok])
        wt.append(math.hypot(dr, dc) * 0.5 * (cost[a][ok] + cost[b][ok]))
    graph = coo_matrix(
        (np.concatenate(wt), (np.concatenate(src), np.concatenate(dst))), shape=(h * w, h * w)
    ).tocsr()
    dist, pred = dijkstra(
        graph, directed=False, indices=start[0] * w + start[1], return_predecessors=True
    )
    return np.asarray(dist).reshape(h, w), np.asarray(pred)


def free_start(
    passable: np.ndarray, clearance: np.ndarray, start: tuple[int, int], reach: float
) -> None:
    """Within ``reach`` cells of ``start``, every cell at least as clear as the start (and not
    an obstacle) becomes passable, and the start itself (in place)."""
    r, c = start
    k = math.ceil(reach)
    near = (slice(max(r - k, 0), r + k + 1), slice(max(c - k, 0), c + k + 1))
    rows, cols = np.ogrid[near]
    disc = (rows - r) ** 2 + (cols - c) ** 2 <= reach * reach
    passable[near] |= disc & (clearance[near] >= clearance[r, c]) & (clearance[near] > 0)
    passable[r, c] = True


def search(
    free: np.ndarray,
    obstacles: np.ndarray,
    start: tuple[int, int],
    inflate: float,
    close_cells: int,
    res: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The readable planner's search of a window (grids (H, W)): its frontier, the path
    lengths in cells from ``start`` and the predecessors."""
    frontier, passable, cost, clearance = frontier_and_cost(
        free, obstacles, inflate, close_cells, res
    )
    free_start(passable, clearance, start, inflate / res + 1.0)
    dist, pred = grid_path(passable, cost, start)
    return frontier, dist, pred


def square_gain(known: np.ndarray, gain_cells: int) -> np.ndarray:  # (H, W) float32
    """The unknown fraction of the square within ``gain_cells`` of each cell of a window."""
    size = 2 * gain_cells + 1
    return ndimage.uniform_filter((~known).astype(np.float32), size, mode="constant")


def whole_map_layers(
    free: np.ndarray,
    occ: np.ndarray,
    hit: np.ndarray,
    inflate: float,
    close_cells: int,
    res: float,
    pad: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Squared clearance (cells²), passable and frontier cells of the whole map (n, n), the
    grids padded by ``pad`` unknown cells on every side for scipy (so that its border rules
    reach none of the map's cells but the outer ``pad``-wide band)."""
    obst = occ | hit
    big = [np.pad(g, pad) for g in (free, obst)]
    frontier, passable, _, _ = frontier_and_cost(big[0], big[1], inflate, close_cells, res)
    inner = (slice(pad, -pad), slice(pad, -pad))
    d2 = np.rint(np.square(ndimage.distance_transform_edt(~big[1])[inner]))
    return d2, passable[inner], frontier[inner]


# -- the controller --------------------------------------------------------------------------
def clearance(
    obstacles: np.ndarray, origin: float, res: float, points: np.ndarray, offsets: np.ndarray
) -> float:
    """Distance (m) from the nearest of ``points`` (P, 2) to the nearest obstacle cell (its
    square) among those holding a point + one of ``offsets`` (D, 2); inf for none."""
    n = obstacles.shape[0]
    ij = np.floor(((points[:, None, :] + offsets).reshape(-1, 2) - origin) / res).astype(np.intp)
    ok = np.all((ij >= 0) & (ij < n), axis=1)
    hit = np.zeros(len(ij), dtype=bool)
    hit[ok] = obstacles[ij[ok, 1], ij[ok, 0]]
    if not hit.any():
        return math.inf
    centre = (ij[hit] + 0.5) * res + origin
    gap = np.abs(np.repeat(points, len(offsets), axis=0)[hit] - centre) - 0.5 * res
    return float(np.hypot(*np.maximum(gap, 0.0).T).min())


def safe_speed(
    obstacles: np.ndarray,
    origin: float,
    res: float,
    disk: np.ndarray,
    dt: float,
    pose: np.ndarray,
    v: float,
    omega: float,
) -> float:
    """``v``, halved until the arc driven in one step keeps the robot's ``disk`` off mapped
    obstacles or no closer to them than now (else 0 after four tries)."""
    now = clearance(obstacles, origin, res, pose[None, :2], disk)
    t = np.linspace(0.25, 1.0, 4) * dt  # (T,) s
    for _ in range(4):
        th = pose[2] + omega * t  # (T,)
        if abs(omega) > 1e-6:
            x = pose[0] + v / omega * (np.sin(th) - math.sin(pose[2]))
            y = pose[1] - v / omega * (np.cos(th) - math.cos(pose[2]))
        else:
            x, y = pose[0] + v * t * math.cos(pose[2]), pose[1] + v * t * math.sin(pose[2])
        if clearance(obstacles, origin, res, np.stack([x, y], axis=1), disk) >= now - 1e-9:
            return v
        v *= 0.5
    return 0.0


def speed_cap(
    angles: np.ndarray, ranges: np.ndarray, radius: float, v_max: float, dt: float
) -> float:
    """Fastest safe forward speed given the beams within 60° of straight ahead."""
    cap = v_max
    for angle, r in zip(angles, ranges, strict=True):
        if abs(angle) < math.radians(60) and math.isfinite(r):
            ahead = r * math.cos(angle) - radius - 0.1
            side = abs(r * math.sin(angle))
            if side < radius + 0.2:
                cap = min(cap, max(ahead, 0.0) / dt)
    return cap


def lookahead_target(path: np.ndarray, pose: np.ndarray, lookahead: float) -> np.ndarray:
    """The pure-pursuit target on ``path`` (P, 2): the first waypoint from the nearest on at
    least ``lookahead`` m away, else the last."""
    d = np.hypot(*(path - pose[:2]).T)  # (P,)
    nearest = int(np.argmin(d))
    ahead = np.flatnonzero(d[nearest:] >= lookahead)
    return path[nearest + ahead[0]] if len(ahead) else path[-1]


def team_discount(points: np.ndarray, goals: np.ndarray, reach: float) -> np.ndarray:  # (F,)
    """Burgard et al.'s discount of each point (F, 2) by the team-mates' goals (K, 2): the
    product over goals of 1 − P(d), P(d) = max(0, 1 − d / reach), written out point by point
    (the readable version of ``planner_kernels.team_discount``, which writes 1 − P(d) as
    d / reach: equal up to the rounding of 1 − (1 − x), an ulp per factor)."""
    out = []
    for point in points:
        share = 1.0
        for goal in goals:
            d = math.hypot(point[0] - goal[0], point[1] - goal[1])
            seen = max(0.0, 1.0 - d / reach)  # P(d)
            share *= 1.0 - seen
        out.append(share)
    return np.array(out, dtype=float)

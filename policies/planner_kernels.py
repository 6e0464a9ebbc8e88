"""Compiled kernels of the frontier planner's path search (:mod:`policies.planner`): the
passable cells and their soft cost in the search window, the way out of the inflated zone, and
Dijkstra's cheapest paths, bit-identical to the readable planner's scipy search (the oracles in
``tests/policies/reference.py``); the path walked back, and the test of a path's cells.

Flat grids are (n·n,) arrays of the own map; window arrays are (H, W) (or flat (H·W,)),
cells (row, col) in the window, the window's cell (0, 0) being the map's (r0, c0).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from policies.ownmap_kernels import Layers
from policies.window_kernels import any_obstacle
from polyslam_env.core.jit import njit

#: Length factor of a diagonal edge times the half of the two cells' mean (as
#: ``math.hypot(1, 1) * 0.5`` in Python).
_DIAGONAL = math.hypot(1, 1) * 0.5
#: scipy's predecessor of a cell with none.
NO_PRED = -9999
#: The dearest cell of the planner: 1, plus 4 at an obstacle (the soft cost).
MAX_COST = 5.0


# -- path search --------------------------------------------------------------------------------
@njit
def _first(da: float, ia: int, db: float, ib: int) -> bool:
    """Whether queue entry (da, ia) is scanned before (db, ib): shorter first, then the larger
    cell id (scipy's ``dijkstra`` pops the greatest (−distance, id) pair of a C++ max-heap)."""
    return da < db or (da == db and ia > ib)


#: The 8 neighbours (row, col offsets); a step is diagonal when both are non-zero.
_DR = np.array([-1, -1, -1, 0, 0, 1, 1, 1])
_DC = np.array([-1, 0, 1, -1, 1, -1, 0, 1])
#: Buckets per unit of path cost in the search's queue (a power of two: the bucket of a cost
#: is exact). A cell costs at least 1 / BUCKETS, so an edge's end never falls into the bucket
#: being emptied.
BUCKETS = 16


class Queue(NamedTuple):
    """Room for the search queue's entries: (E,) arrays, E ≥ 8 × the cells searched + 1
    (every cell is scanned once and queues at most its 8 neighbours)."""

    keys: np.ndarray  # float64: path cost
    ids: np.ndarray  # int32: cell
    after: np.ndarray  # int32: the next entry of the same bucket (−1: none)
    order: np.ndarray  # int32: one bucket's entries, sorted


class Goals(NamedTuple):
    """The goal candidates the search may stop at: once the best utility among those reached
    (gain discounted by path length, :mod:`policies.planner`) beats what any cell farther away
    could reach, the rest cannot change the best goal (module planner's doc)."""

    cells: np.ndarray  # (F,) int64: the candidates' flat window cells
    gain: np.ndarray  # (F,) float32: their gains
    preferred: np.ndarray  # (F,) bool: candidates not excluded (another robot's side)
    res: float  # m per cell
    decay: float  # m: the utility's path-length discount
    min_goal: float  # m: goals nearer than this are not preferred


#: The most a frontier's gain term can be: float32(1 + 1e-3), the utility's (gain + 1e-3)
#: with a gain of 1 in float32.
MOST_GAIN = float(np.float32(1.0) + np.float32(1e-3))
#: Relative slack of the early stop's test: the kernel's exp may differ from numpy's by ulps.
STOP_SLACK = 1e-6


@njit
def no_goals() -> Goals:
    """No goal candidates (a search that runs to the end)."""
    return Goals(
        np.zeros(0, dtype=np.int64), np.zeros(0, np.float32), np.zeros(0, np.bool_), 1.0, 1.0, 0.0
    )


def queue(cells: int) -> Queue:
    """Room for the search of a padded grid of ``cells`` cells."""
    size = 8 * cells + 1
    return Queue(np.empty(size), *(np.empty(size, dtype=np.int32) for _ in range(3)))


@njit
def _dijkstra(
    ok: np.ndarray,
    level: np.ndarray,
    cost_of: np.ndarray,
    max_cost: float,
    wp: int,
    start: int,
    dist: np.ndarray,
    came: np.ndarray,
    room: Queue,
    goals: Goals,
    at: np.ndarray,
    stop: bool,
) -> tuple[int, float]:
    """:func:`dijkstra` on a flat grid with rows ``wp`` wide whose passable cells ``ok`` are
    all at least one cell from its edge (a window padded by an impassable cell, or the own
    map), ids row-major as the window's, so ties break the same way; a cell a costs
    ``cost_of[level[a]]``, in [1 / :data:`BUCKETS`, ``max_cost``] (the map's clearance
    levels and their soft cost; or cells and their costs). ``dist`` must hold inf and
    ``came`` −1; they get the path costs and the neighbour (index into ``_DR``, ``_DC``) each
    cell was reached from.
    Returns how many queue entries it made (``room.ids[:count]`` are all the cells it set)
    and the path cost it stopped at: with ``stop``, at the first bucket where the best
    preferred utility of the ``goals`` reached (``at``: a cell's candidate index, −1 for
    none) beats :data:`MOST_GAIN` discounted by the bucket's cost (every cell from there on is
    unsettled: its ``dist`` is not final); inf when it ran to the end.

    Cells are scanned in the order of scipy's heap — shortest path first, ties to the larger
    cell id — from a bucket queue (Dial's): entries fall into buckets of 1 / BUCKETS path
    cost, a circle of them spanning the dearest edge; a bucket, complete when it is reached,
    is sorted and scanned. Stale entries (a cell reached again, cheaper) are skipped."""
    keys, ids, after, order = room
    offsets = _DR * wp + _DC
    span = 1
    while span < _DIAGONAL * 2.0 * max_cost * BUCKETS + 2:
        span *= 2
    mask = span - 1
    head = np.full(span, -1, dtype=np.int32)
    dist[start] = 0.0
    keys[0], ids[0], after[0], head[0] = 0.0, start, -1, 0
    count, pending, bucket = 1, 1, 0
    best = -1.0  # the best preferred utility of the goals reached
    while pending > 0:
        while head[bucket & mask] < 0:
            bucket += 1
        if best > 0.0:
            reach = bucket / BUCKETS * goals.res
            if best > MOST_GAIN * math.exp(-reach / goals.decay) * (1.0 + STOP_SLACK):
                return count, bucket / BUCKETS
        m, e = 0, head[bucket & mask]
        head[bucket & mask] = -1
        while e >= 0:  # insertion sort: cost ascending, then cell id descending
            j, key, cell = m, keys[e], ids[e]
            while j > 0 and _first(key, cell, keys[order[j - 1]], ids[order[j - 1]]):
                order[j] = order[j - 1]
                j -= 1
            order[j] = e
            m += 1
            e = after[e]
        pending -= m
        for t in range(m):
            d, v = keys[order[t]], ids[order[t]]
            if dist[v] < d or not ok[v]:
                continue  # a stale entry, or a start off the passable cells (it has no edges)
            if stop and at[v] >= 0:
                i, metres = at[v], d * goals.res
                if goals.preferred[i] and metres >= goals.min_goal:
                    gain = float(goals.gain[i] + np.float32(1e-3))
                    best = max(best, gain * math.exp(-metres / goals.decay))
            for k in range(8):
                u = v + offsets[k]
                if not ok[u]:
                    continue
                a, b = (u, v) if u < v else (v, u)  # the weight as built from the edge's lower end
                if _DR[k] != 0 and _DC[k] != 0:
                    nd = d + _DIAGONAL * (cost_of[level[a]] + cost_of[level[b]])
                else:
                    nd = d + 0.5 * (cost_of[level[a]] + cost_of[level[b]])
                if nd < dist[u]:
                    dist[u], came[u] = nd, k
                    q = int(nd * BUCKETS) & mask
                    keys[count], ids[count], after[count], head[q] = nd, u, head[q], count
                    count += 1
                    pending += 1
        bucket += 1
    return count, math.inf


@njit
def _settled(
    dist_s: np.ndarray,
    came: np.ndarray,
    first: int,
    stride: int,
    w: int,
    scale: float,
    stop_at: float,
    room: Queue,
    count: int,
    dist: np.ndarray,
    pred: np.ndarray,
) -> None:
    """Path costs × ``scale`` and predecessors (H·W,) of the cells :func:`_dijkstra` settled
    (below ``stop_at``; ``room.ids[:count]`` holds every cell it reached) on a grid where
    window cell (r, c) is ``first + r · stride + c``, into ``dist`` and ``pred`` (which hold
    inf and :data:`NO_PRED` elsewhere)."""
    for e in range(count):
        v = room.ids[e]
        if dist_s[v] < stop_at:
            r, c = (v - first) // stride, (v - first) % stride
            k = came[v]
            dist[r * w + c] = dist_s[v] * scale
            pred[r * w + c] = NO_PRED if k < 0 else (r - _DR[k]) * w + c - _DC[k]


@njit
def dijkstra(
    passable: np.ndarray, cost: np.ndarray, start: int, dist: np.ndarray, pred: np.ndarray
) -> None:
    """Cheapest paths from flat cell ``start`` over the ``passable`` cells of an (H, W) grid,
    8-connected, an edge costing its length (1 or √2 cells) times the mean ``cost`` of its two
    cells (each ≥ 1 / :data:`BUCKETS`); ``dist`` (H·W,) gets the path costs (inf where
    unreachable), ``pred`` (H·W,) the predecessors (:data:`NO_PRED` where none).

    The result is scipy's ``dijkstra(directed=False)`` on the graph of :func:`grid_path`'s
    readable version bit for bit: the same sums in the same order, and ties between equal
    path costs broken as its heap breaks them, which fixes the predecessors.
    """
    h, w = passable.shape
    wp = w + 2
    ok = np.zeros((h + 2) * wp, dtype=np.bool_)
    padded = np.ones((h + 2) * wp)
    for r in range(h):
        for c in range(w):
            ok[(r + 1) * wp + c + 1] = passable[r, c]
            padded[(r + 1) * wp + c + 1] = cost[r, c]
    dist_p = np.full((h + 2) * wp, np.inf)
    came = np.full((h + 2) * wp, -1, dtype=np.int8)
    start_p = (start // w + 1) * wp + start % w + 1
    room = Queue(
        np.empty(8 * ok.shape[0] + 1),
        np.empty(8 * ok.shape[0] + 1, dtype=np.int32),
        np.empty(8 * ok.shape[0] + 1, dtype=np.int32),
        np.empty(8 * ok.shape[0] + 1, dtype=np.int32),
    )
    none = np.full(1, -1, dtype=np.int32)
    cells = np.arange(ok.shape[0])
    count, _ = _dijkstra(
        ok, cells, padded, padded.max(), wp, start_p, dist_p, came, room, no_goals(), none, False
    )
    dist[:], pred[:] = np.inf, NO_PRED
    _settled(dist_p, came, wp + 1, wp, w, 1.0, math.inf, room, count, dist, pred)


@njit
def free_start(
    passable: np.ndarray,
    clearance: np.ndarray,
    top: int,
    left: int,
    row: int,
    col: int,
    reach: float,
) -> None:
    """Within ``reach`` cells of the start (row, col) of the (H, W) ``passable`` grid, make
    every cell passable that is at least as clear of obstacles as the start and not an
    obstacle, and the start itself. ``clearance`` (m) covers the rows from ``top`` and the
    columns from ``left`` of the grid, at least that disc."""
    h, w = passable.shape
    k = math.ceil(reach)
    here = clearance[row - top, col - left]
    for r in range(max(row - k, 0), min(row + k + 1, h)):
        for c in range(max(col - k, 0), min(col + k + 1, w)):
            near = clearance[r - top, c - left]
            if (r - row) ** 2 + (c - col) ** 2 <= reach * reach and near >= here and near > 0:
                passable[r, c] = True
    passable[row, col] = True


@njit
def _exact_d2(
    obst: np.ndarray, n: int, r0: int, r1: int, c0: int, c1: int, row: int, col: int
) -> int:
    """Squared distance (cells²) from map cell (row, col) to the nearest obstacle of the
    window rows r0…r1 − 1, columns c0…c1 − 1, searched ring by ring (one must exist)."""
    best = -1
    s = 0
    while best < 0 or s * s < best:
        for r in range(max(row - s, r0), min(row + s + 1, r1)):
            step = 1 if abs(r - row) == s else 2 * s
            for c in range(col - s, col + s + 1, max(step, 1)):
                if c0 <= c < c1 and obst[r * n + c]:
                    d = (r - row) ** 2 + (c - col) ** 2
                    if best < 0 or d < best:
                        best = d
        s += 1
    return best


@njit
def search(
    layers: Layers,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    row: int,
    col: int,
    escape: float,
    on_map: bool,
    room: Queue,
    dist_map: np.ndarray,
    came_map: np.ndarray,
    goal_map: np.ndarray,
    goals: Goals,
    stop: bool,
    scale: float,
    dist: np.ndarray,
    pred: np.ndarray,
) -> float:
    """The planner's path search on window rows r0…r1 − 1, columns c0…c1 − 1 of the own map
    ``layers`` from window cell (row, col): the passable cells (free, not obstacles,
    clearance above the inflation radius), their soft cost near obstacles, the way out of the
    inflated zone (:func:`free_start` within ``escape`` cells), then :func:`dijkstra` (in
    ``room``): path costs × ``scale`` into ``dist`` and predecessors into ``pred`` (H·W,),
    which must hold inf and :data:`NO_PRED`; with ``stop``, until the best of the ``goals``
    (window cells) is settled (:func:`_dijkstra`). Returns the path cost (cells) it stopped at
    (inf: the end); cells from there on are left unreached.

    Clearances are the window's distance transform, as the readable planner's: ``d2`` where
    exact (a far start's disc is searched exactly), which needs every obstacle within the
    soft radius of a window cell inside the window (the planner's windows hold every known
    cell); in a window without obstacles, the distance to the virtual cell (−1, 0) scipy's
    transform measures then.

    ``on_map``: every free cell and the start's disc lie inside the window, one cell from its
    edge, and the window one cell inside the map; then (unless the window has no obstacle) the
    search runs on the map's own ``passable`` and ``d2`` layers, in ``dist_map``,
    ``came_map`` and ``goal_map`` (inf, −1 and −1, left so), else on padded copies of the
    window. ``room`` holds :func:`queue` of (H + 2)(W + 2) cells either way."""
    free, obst, d2, n, res = layers.free, layers.obst, layers.d2, layers.n, layers.res
    passable_d2, cost_d2 = layers.passable_d2, layers.cost_d2
    inflate, soft = layers.inflate, layers.soft
    h, w = r1 - r0, c1 - c0
    empty = not any_obstacle(obst, n, r0, r1, c0, c1)
    far = passable_d2.shape[0] - 1  # d2 of "beyond the exact reach"
    k = math.ceil(escape)
    top, left = max(row - k, 0), max(col - k, 0)
    patch = np.empty((min(row + k + 1, h) - top, min(col + k + 1, w) - left))
    start_far = not empty and d2[(row + r0) * n + col + c0] >= far
    for r in range(patch.shape[0]):
        for c in range(patch.shape[1]):
            wr, wc = r + top, c + left
            if empty:
                patch[r, c] = math.sqrt(float((wr + 1) ** 2 + wc * wc)) * res
            else:
                e = d2[(wr + r0) * n + wc + c0]
                if e >= far:
                    e = _exact_d2(obst, n, r0, r1, c0, c1, wr + r0, wc + c0) if start_far else -1
                patch[r, c] = math.sqrt(float(e)) * res if e >= 0 else math.inf
    if on_map and not empty:
        layer = layers.passable.reshape(n, n)[r0:r1, c0:c1]
        before = layer[top : top + patch.shape[0], left : left + patch.shape[1]].copy()
        count, stop_at = _run(
            layers.passable, layer, d2, cost_d2, patch, top, left, row, col, escape,
            r0 * n + c0, n, w, dist_map, came_map, goal_map, room, goals, stop, scale, dist, pred,
        )  # fmt: skip
        for e in range(count):  # leave the map's layers and scratch as they were
            dist_map[room.ids[e]], came_map[room.ids[e]] = np.inf, -1
        layer[top : top + patch.shape[0], left : left + patch.shape[1]] = before
        return stop_at
    first, stride = w + 3, w + 2  # a copy of the window, padded by an impassable cell
    ok = np.zeros((h + 2) * stride, dtype=np.bool_)
    level = np.full((h + 2) * stride, far, dtype=d2.dtype)
    costs = np.ones((h + 2) * stride)  # without obstacles: each cell its own cost
    for r in range(h):
        for c in range(w):
            x, p = (r + r0) * n + c + c0, first + r * stride + c
            if empty:
                clear = math.sqrt(float((r + 1) ** 2 + c * c)) * res
                ok[p] = free[x] and not obst[x] and clear > inflate
                costs[p] = 1.0 + 4.0 * min(max((soft - clear) / soft, 0.0), 1.0)
            else:
                ok[p] = free[x] and not obst[x] and passable_d2[d2[x]]
                level[p] = d2[x]
    layer = ok.reshape(h + 2, stride)[1:-1, 1:-1]
    scratch_d = np.full(ok.shape[0], np.inf)
    scratch_c = np.full(ok.shape[0], -1, dtype=np.int8)
    at = np.full(ok.shape[0], -1, dtype=np.int32)
    if empty:
        return _run(
            ok, layer, np.arange(ok.shape[0]), costs, patch, top, left, row, col, escape, first,
            stride, w, scratch_d, scratch_c, at, room, goals, stop, scale, dist, pred,
        )[1]  # fmt: skip
    return _run(
        ok, layer, level, cost_d2, patch, top, left, row, col, escape, first, stride, w,
        scratch_d, scratch_c, at, room, goals, stop, scale, dist, pred,
    )[1]  # fmt: skip


@njit
def _run(
    ok: np.ndarray,
    layer: np.ndarray,
    level: np.ndarray,
    cost_of: np.ndarray,
    patch: np.ndarray,
    top: int,
    left: int,
    row: int,
    col: int,
    escape: float,
    first: int,
    stride: int,
    w: int,
    dist_s: np.ndarray,
    came: np.ndarray,
    at: np.ndarray,
    room: Queue,
    goals: Goals,
    stop: bool,
    scale: float,
    dist: np.ndarray,
    pred: np.ndarray,
) -> tuple[int, float]:
    """:func:`search`'s way out of the inflated zone and path search on a grid of passable
    cells ``ok`` whose window cell (r, c) is ``first + r · stride + c`` (``layer``: ``ok`` as
    the window's (H, W) view): :func:`free_start` with the clearances ``patch``, then
    :func:`_dijkstra` in ``dist_s``, ``came``, ``at``, the settled cells into ``dist`` and
    ``pred``. Returns :func:`_dijkstra`'s entries made and cost stopped at."""
    free_start(layer, patch, top, left, row, col, escape)
    for i in range(goals.cells.shape[0]):  # the goal candidates' cells on the searched grid
        at[first + (goals.cells[i] // w) * stride + goals.cells[i] % w] = i
    count, stop_at = _dijkstra(
        ok, level, cost_of, MAX_COST, stride, first + row * stride + col, dist_s, came, room,
        goals, at, stop,
    )  # fmt: skip
    _settled(dist_s, came, first, stride, w, scale, stop_at, room, count, dist, pred)
    for i in range(goals.cells.shape[0]):
        at[first + (goals.cells[i] // w) * stride + goals.cells[i] % w] = -1
    return count, stop_at


@njit
def walk_back(
    pred: np.ndarray, goal: int, start: int, width: int, r0: int, c0: int, origin: float, res: float
) -> np.ndarray:  # (P, 2)
    """Own-frame centres of the cells of the path to window cell ``goal`` (flat) along the
    predecessors ``pred``, the start excluded (the start alone when the goal is the start)."""
    count, node = 0, goal
    while node >= 0 and node != start:
        count += 1
        node = pred[node]
    if count == 0:
        count, goal = 1, start
    path = np.empty((count, 2))
    node = goal
    for i in range(count - 1, -1, -1):
        path[i, 0] = (node % width + c0 + 0.5) * res + origin
        path[i, 1] = (node // width + r0 + 0.5) * res + origin
        node = pred[node]
    return path


@njit
def path_blocked(path: np.ndarray, obst: np.ndarray, origin: float, res: float, n: int) -> bool:
    """Whether an obstacle cell lies under one of the own-frame points ``path`` (P, 2)."""
    for i in range(path.shape[0]):
        col = math.floor((path[i, 0] - origin) / res)
        row = math.floor((path[i, 1] - origin) / res)
        if 0 <= row < n and 0 <= col < n and obst[row * n + col]:
            return True
    return False


# -- goal scoring: the team's announced goals ---------------------------------------------------
@njit
def team_discount(points: np.ndarray, goals: np.ndarray, reach: float) -> np.ndarray:  # (F,)
    """Per own-frame point (F, 2), the share of its utility no team-mate is expected to take:
    ``Π_k (1 − P(|point − goals[k]|))`` over the team-mates' goals (K, 2), with Burgard et al.
    (2005)'s visibility probability ``P(d) = 1 − d / reach`` within ``reach`` m, 0 beyond (a
    team-mate that reaches its goal sees a frontier at distance d with that probability; the
    product is the chance that none of them does, the robots' views taken as independent).
    """
    out = np.ones(points.shape[0])
    for f in range(points.shape[0]):
        for k in range(goals.shape[0]):
            d = math.hypot(points[f, 0] - goals[k, 0], points[f, 1] - goals[k, 1])
            if d < reach:
                out[f] *= d / reach  # 1 − P(d)
    return out

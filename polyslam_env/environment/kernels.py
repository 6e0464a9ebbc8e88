"""Compiled kernels of the observations: a map sampler's cache brought up to date with its
table (:func:`resample_map`) and its points shifted by the c0s, the egocentric local map's
occupied and free cells, and the vector observation's parts.

Plain loops compiled by :func:`polyslam_env.core.jit.njit`, with the same float operations in
the same order as the numpy version they replaced (the oracle in
``tests/environment/reference.py``), so the cells are identical. The two small matrix products
that place points (``points @ R``) are computed as numpy's gemm computed them on OpenBLAS's FMA
kernels (:func:`placed_centre`, :func:`ego_point`: a chain of fused multiply-adds along the inner
index, from 0).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import fma, njit
from polyslam_env.core.raster import cell_id
from polyslam_env.metrics.kernels import sample_rows
from polyslam_env.slam import columns as col

# Fields (rows) of a map sampler's int64 cache (fields × capacity): per landmark in state order,
# its stable id and stamp when sampled, its dependent coordinate (0 or 1), and where its points
# are in the pool
CACHE_ID = 0
CACHE_STAMP = 1
CACHE_AXIS = 2
CACHE_START = 3
CACHE_COUNT = 4
N_CACHE = 5


@njit
def resample_map(
    cache: np.ndarray,
    cache_c0: np.ndarray,
    cached: int,
    index: np.ndarray,
    real: np.ndarray,
    shape: np.ndarray,
    mean: np.ndarray,
    n: int,
    step: float,
    dense: int,
    pool: np.ndarray,
    used: int,
) -> tuple[np.ndarray, int, int]:
    """A map sampler's cache (``cache`` (N_CACHE, capacity ≥ n) int64 and ``cache_c0``
    (capacity,), its first ``cached`` rows in use) brought up to date with the ``n`` landmarks
    of a table (its buffers ``index``, ``real``, ``shape``, c0s in the state ``mean``), rows
    rewritten in the table's order; returns the pool (``pool`` (P, 2), or a larger one), the
    rows of it in use and the live points (Σ count).

    A landmark keeps its cached row (found by id) while its stamp is the one it was sampled at;
    the others (stale or new) are sampled every ``step`` of arc length at their c0 now
    (:func:`~polyslam_env.metrics.kernels.sample_rows` with ``dense``, in row order) and
    appended to the pool from row ``used`` on. When they do not fit, the live rows' points are
    first copied, in row order, to the front of a new pool of twice the live points (64 at
    least): the pool never holds more than twice what it must, and a change touches only the
    stale rows."""
    old = cache[:, :cached].copy()
    old_c0 = cache_c0[:cached].copy()
    stale = np.empty(n, dtype=np.int64)
    q = 0
    hint = 0  # where the search for the next id starts: rows keep their order
    for r in range(n):
        found = -1
        for t in range(cached):
            o = hint + t
            if o >= cached:
                o -= cached
            if old[CACHE_ID, o] == index[col.ID, r]:
                found = o
                break
        cache[CACHE_ID, r] = index[col.ID, r]
        cache[CACHE_STAMP, r] = index[col.STAMP, r]
        if found >= 0:
            hint = found + 1
        if found >= 0 and old[CACHE_STAMP, found] == index[col.STAMP, r]:
            cache[CACHE_AXIS, r] = old[CACHE_AXIS, found]
            cache[CACHE_START, r] = old[CACHE_START, found]
            cache[CACHE_COUNT, r] = old[CACHE_COUNT, found]
            cache_c0[r] = old_c0[found]
        else:
            cache[CACHE_COUNT, r] = 0  # its old points, if any, are dropped
            stale[q] = r
            q += 1
    if q:
        coeffs = shape[:n].copy()  # (n, M+1) [0, b_1, …]: c0 from the state
        coeffs[:, 0] = mean[3 : 3 + n]
        points, starts = sample_rows(
            index[col.VARIATE, :n], coeffs, real[col.LO, :n], real[col.HI, :n], stale[:q],
            step, dense,
        )  # fmt: skip
        if used + points.shape[0] > pool.shape[0]:
            live = 0
            for r in range(n):
                live += cache[CACHE_COUNT, r]
            room = np.empty((max(2 * (live + points.shape[0]), 64), 2))
            at = 0
            for r in range(n):
                a, k = cache[CACHE_START, r], cache[CACHE_COUNT, r]
                if k > 0:
                    room[at : at + k] = pool[a : a + k]
                    cache[CACHE_START, r] = at
                    at += k
            pool, used = room, at
        for j in range(q):
            r = stale[j]
            cache[CACHE_AXIS, r] = 1 if index[col.VARIATE, r] == 1 else 0
            cache[CACHE_START, r] = starts[j] + used
            cache[CACHE_COUNT, r] = starts[j + 1] - starts[j]
            cache_c0[r] = mean[3 + r]
        pool[used : used + points.shape[0]] = points
        used += points.shape[0]
    total = 0
    for r in range(n):
        total += cache[CACHE_COUNT, r]
    return pool, used, total


@njit
def shifted_points(
    pool: np.ndarray,
    cache: np.ndarray,
    cache_c0: np.ndarray,
    n: int,
    mean: np.ndarray,
    out: np.ndarray,
) -> None:
    """A map sampler's cached points (:func:`resample_map`: landmark o's ``cache[CACHE_COUNT,
    o]`` rows of ``pool`` (P, 2) from ``cache[CACHE_START, o]``, at the c0 they were sampled
    with, ``cache_c0[o]``), moved to the c0s of the state ``mean`` (its ``3 + o`` entry) and
    written one landmark after the other into ``out`` (Σ count, 2): each point's dependent
    coordinate ``cache[CACHE_AXIS, o]`` (0 or 1) gains ``mean[3 + o] − cache_c0[o]`` (as
    ``points[m, axis] + (c0s − c0)[owner]``)."""
    m = 0
    for o in range(n):
        shift = mean[3 + o] - cache_c0[o]
        a = cache[CACHE_AXIS, o]
        first = cache[CACHE_START, o]
        for p in range(first, first + cache[CACHE_COUNT, o]):
            out[m, 0] = pool[p, 0]
            out[m, 1] = pool[p, 1]
            out[m, a] += shift
            m += 1


@njit
def team_status(
    covs: np.ndarray,
    last: np.ndarray,
    step_count: int,
    never: int,
    stds: np.ndarray,
    since: np.ndarray,
    step: np.ndarray,
) -> None:
    """A team view's small fields of K robots: the pose standard deviations ``stds`` (K, 3),
    the square roots of the covariances' ``covs`` (K, 3, 3) diagonals clipped at 0 as
    ``np.maximum(v, 0.0)`` (NaN stays, −0 becomes 0); the steps ``since`` (K,) the last
    rendezvous at step ``last`` (K,) (``never`` where it is ``never``); and ``step`` (K,), the
    env step ``step_count`` of every robot."""
    for k in range(covs.shape[0]):
        for j in range(3):
            v = covs[k, j, j]
            stds[k, j] = math.sqrt(v if v > 0.0 or v != v else 0.0)
        since[k] = never if last[k] == never else step_count - last[k]
        step[k] = step_count


@njit
def placed_centre(
    a: float, b: float, c: float, s: float, x: float, y: float
) -> tuple[float, float]:
    """An egocentric cell centre (a, b) in the frame of a robot at (x, y) heading θ (c, s =
    cos θ, sin θ): (a, b) R(θ)ᵀ + (x, y), each product entry a chain of fused multiply-adds
    along the inner index from 0, as numpy's gemm computed ``@`` (module docstring)."""
    return fma(b, -s, fma(a, c, 0.0)) + x, fma(b, c, fma(a, s, 0.0)) + y


@njit
def ego_point(px: float, py: float, c: float, s: float, x: float, y: float) -> tuple[float, float]:
    """A map point (px, py) of a robot at (x, y) heading θ (c, s = cos θ, sin θ) in its
    egocentric frame: (p − (x, y)) R(θ), as :func:`placed_centre` computes its product."""
    dx, dy = px - x, py - y
    return fma(dy, s, fma(dx, c, 0.0)), fma(dy, c, fma(dx, -s, 0.0))


@njit
def local_cells(
    cell_centres: np.ndarray,
    map_points: np.ndarray,
    map_starts: np.ndarray,
    poses: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    lone: np.ndarray,
    g: int,
    cell: float,
    belief_free: np.ndarray,
    belief_hit: np.ndarray,
    rows: np.ndarray,
    origin: float,
    resolution: float,
    n: int,
    use_hits: bool,
    occ: np.ndarray,
    free: np.ndarray,
) -> None:
    """Occupied ``occ`` and free ``free`` (K, G²) cells of K robots' G × G egocentric grids of
    side ``cell``. Robot k at ``poses[k]`` (x, y, θ), ``cos[k]``, ``sin[k]`` of θ: occupied
    where one of its map points ``map_points[map_starts[k]:map_starts[k + 1]]`` falls, placed
    in its egocentric frame (:func:`ego_point`; a robot with one point uses ``lone[k]``
    (K, 2), its ego point as the caller computed it: numpy sends a (1, 2) product to gemv,
    which rounds otherwise), and, with ``use_hits``, where its belief grid saw a hit; free
    where its belief grid is free at the cell's centre (``cell_centres`` (G², 2) placed by
    :func:`placed_centre`) and not occupied. Belief grids: flat rows ``rows[k]`` of
    ``belief_free``, ``belief_hit`` (R, n·n), lower-left corner (origin, origin), cell side
    ``resolution``."""
    half = g // 2 + 0.5
    for k in range(poses.shape[0]):
        c, s = cos[k], sin[k]
        x, y = poses[k, 0], poses[k, 1]
        own_free, own_hit = belief_free[rows[k]], belief_hit[rows[k]]
        for i in range(g * g):
            occ[k, i] = False
        first, last = map_starts[k], map_starts[k + 1]
        for m in range(first, last):
            if last - first == 1:
                ex, ey = lone[k, 0], lone[k, 1]
            else:
                ex, ey = ego_point(map_points[m, 0], map_points[m, 1], c, s, x, y)
            col = math.floor(ex / cell + half)
            row = math.floor(ey / cell + half)
            if 0 <= col < g and 0 <= row < g:
                occ[k, row * g + col] = True
        for i in range(g * g):
            cx, cy = placed_centre(cell_centres[i, 0], cell_centres[i, 1], c, s, x, y)
            cid = cell_id(cx, cy, origin, origin, resolution, n, n)
            if cid >= 0 and use_hits and own_hit[cid]:
                occ[k, i] = True
            free[k, i] = cid >= 0 and own_free[cid] and not occ[k, i]


@njit
def _clip(v: float, lo: float, hi: float) -> float:
    """``min(max(v, lo), hi)`` with Python's builtins' semantics (the first argument wins ties
    and NaN comparisons)."""
    v = lo if lo > v else v
    return hi if hi < v else v


@njit
def vector_head(
    ranges: np.ndarray,
    max_range: float,
    poses: np.ndarray,
    scale: float,
    stds: np.ndarray,
    caps: np.ndarray,
    occ: np.ndarray,
    free: np.ndarray,
    codes: np.ndarray,
    out: np.ndarray,
) -> None:
    """The first parts of K robots' vector observations, row k of ``out`` (K, D) float32 from
    ``ranges[k]`` (B,), ``poses[k]`` (3,), ``stds[k]`` (3,): ranges / max_range (no return →
    1), a no-return flag per beam, the pose (x/scale, y/scale clipped to ±1, cos θ, sin θ), the
    pose standard deviations / caps clipped to 0…1, then, when ``occ`` (K, G²) has columns, the
    local map coded ``codes`` = (free, unknown, occupied) per cell."""
    nb = ranges.shape[1]
    for k in range(ranges.shape[0]):
        for b in range(nb):
            v = ranges[k, b] / max_range
            out[k, b] = v if v < 1.0 else 1.0  # fmin: inf and nan → 1
            out[k, nb + b] = 0.0 if math.isfinite(ranges[k, b]) else 1.0
        p = 2 * nb
        out[k, p] = _clip(poses[k, 0] / scale, -1.0, 1.0)
        out[k, p + 1] = _clip(poses[k, 1] / scale, -1.0, 1.0)
        out[k, p + 2] = math.cos(poses[k, 2])
        out[k, p + 3] = math.sin(poses[k, 2])
        for j in range(3):
            out[k, p + 4 + j] = _clip(stds[k, j] / caps[j], 0.0, 1.0)
        m = p + 7
        for i in range(occ.shape[1]):
            out[k, m + i] = codes[0] if free[k, i] else (codes[2] if occ[k, i] else codes[1])


@njit
def vector_tail(
    seen: np.ndarray,
    distance: np.ndarray,
    bearing: np.ndarray,
    cam_range: float,
    slots: int,
    since: np.ndarray,
    rendezvous: np.ndarray,
    cap: int,
    step: np.ndarray,
    max_steps: int,
    first: int,
    out: np.ndarray,
) -> None:
    """The last parts of K robots' vector observations, written into row k of ``out`` (K, D)
    float32 from column ``first`` on: ``slots`` camera slots, nearest first (ties: the lower
    target index), each ``(1, min(d / cam_range, 1), cos b, sin b)`` of a robot seen
    (``seen[k, t]``, (K, T), at ``distance`` and ``bearing`` (K, T)) and zeros when empty;
    then ``since`` (K,) steps since the last rendezvous / ``max_steps`` clipped to 1 (1 for
    −1, never), min(``rendezvous`` (K,), ``cap``) / ``cap`` and ``step`` (K,) / ``max_steps``
    clipped to 1."""
    targets = seen.shape[1]
    order = np.empty(targets, dtype=np.int64)
    for k in range(seen.shape[0]):
        n = 0
        for t in range(targets):  # insertion by (distance, target): a stable sort
            if seen[k, t]:
                m = n
                while m > 0 and distance[k, t] < distance[k, order[m - 1]]:
                    order[m] = order[m - 1]
                    m -= 1
                order[m] = t
                n += 1
        c = first
        for j in range(slots):
            if j < n:
                t = order[j]
                d = distance[k, t] / cam_range
                out[k, c] = 1.0
                out[k, c + 1] = 1.0 if 1.0 < d else d  # min(d, 1.0)
                out[k, c + 2] = math.cos(bearing[k, t])
                out[k, c + 3] = math.sin(bearing[k, t])
            else:
                for i in range(4):
                    out[k, c + i] = 0.0
            c += 4
        if since[k] < 0:
            out[k, c] = 1.0
        else:
            s = since[k] / max_steps
            out[k, c] = 1.0 if 1.0 < s else s
        out[k, c + 1] = min(rendezvous[k], cap) / cap
        p = step[k] / max_steps
        out[k, c + 2] = 1.0 if 1.0 < p else p


@njit
def encode_vectors(
    cell_centres: np.ndarray,
    map_points: np.ndarray,
    map_starts: np.ndarray,
    poses: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    lone: np.ndarray,
    g: int,
    cell: float,
    belief_free: np.ndarray,
    belief_hit: np.ndarray,
    rows: np.ndarray,
    origin: float,
    resolution: float,
    n: int,
    use_hits: bool,
    ranges: np.ndarray,
    max_range: float,
    scale: float,
    stds: np.ndarray,
    caps: np.ndarray,
    codes: np.ndarray,
    seen: np.ndarray,
    distance: np.ndarray,
    bearing: np.ndarray,
    cam_range: float,
    slots: int,
    since: np.ndarray,
    rendezvous: np.ndarray,
    cap: int,
    step: np.ndarray,
    max_steps: int,
    first: int,
    out: np.ndarray,
) -> None:
    """K robots' vector observations with their local maps in one call: the cells of
    :func:`local_cells`, then :func:`vector_head` and :func:`vector_tail` into ``out`` (K, D)
    float32 (the arguments of the three in their order, each once)."""
    occ = np.empty((poses.shape[0], g * g), dtype=np.bool_)
    free = np.empty((poses.shape[0], g * g), dtype=np.bool_)
    local_cells(
        cell_centres, map_points, map_starts, poses, cos, sin, lone, g, cell, belief_free,
        belief_hit, rows, origin, resolution, n, use_hits, occ, free,
    )  # fmt: skip
    vector_head(ranges, max_range, poses, scale, stds, caps, occ, free, codes, out)
    vector_tail(
        seen, distance, bearing, cam_range, slots, since, rendezvous, cap, step, max_steps,
        first, out,
    )  # fmt: skip

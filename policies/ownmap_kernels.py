"""Compiled kernels of :class:`policies.ownmap.OwnMap`: folding a step's cells into the grids,
and keeping the obstacle clearance and the frontier layers up to date where cells changed.

All grids are flat (n·n,) arrays of one square grid, cell ``row · n + col``. The layers are
defined on the infinite plane (outside the grid is unknown, never an obstacle), so that a
cell's value depends only on the cells around it; :mod:`policies.planner_kernels` corrects the
cells near a search window's edge, where the planner's window-bounded operations differ.

Layers (what ``tests/policies/reference.py`` computes with scipy on the whole grid):

* ``d2``: squared distance (cells²) from a cell's centre to the nearest obstacle cell's
  centre, exact up to ``r2``; ``r2 + 1`` ("far") beyond it.
* ``passable``: free, not an obstacle, and clearance √d2 · res above the inflation radius.
* ``known_near``: known cells within L1 distance ``rad`` (the gap closing's diamond);
  a cell with none is *open* (unknown after closing's dilation).
* ``open_near``: open cells within L1 distance ``rad``; a cell with none is *closed-known*
  (known after the closing: ``binary_closing`` by the cross, ``rad`` iterations).
* ``closed_near``: closed-known cells in the cross; a cell with none is *eroded-unknown*
  (``binary_opening``'s erosion of the unknown).
* ``eroded_near``: eroded-unknown cells in the cross; a cell with any is *unknown* (the
  opening's dilation).
* ``unknown_near``: unknown cells in the 3 × 3 block; a passable cell with any is a frontier.

Known cells only ever grow (free is never cleared, a cleared occupied cell is free), so the
counts change one way and each transition is propagated once, where it happens. Obstacles
come and go (occupied cells follow the robot's own map), so ``d2`` is lowered around a new
obstacle and recomputed around a removed one.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from polyslam_env.core.jit import njit
from polyslam_env.core.raster import cell_id, scan_cells_into


class Layers(NamedTuple):
    """An own map's grids and layers as the kernels take them: flat (n·n,) arrays of one square
    grid of n × n cells of ``res`` m, cell ``row · n + col`` (module doc)."""

    free: np.ndarray  # bool: swept by a beam, or visited
    occ: np.ndarray  # bool: last seen occupied in the local grid
    hit: np.ndarray  # bool: a beam ended here
    obst: np.ndarray  # bool: occ | hit
    known: np.ndarray  # bool: free | occ | hit
    d2: np.ndarray  # int16: squared clearance (cells²), exact up to reach², reach² + 1 beyond
    passable: np.ndarray  # bool
    frontier: np.ndarray  # bool: on the whole map
    frontier_cells: np.ndarray  # int64: the frontier cells, first frontier_count[0] of them
    frontier_at: np.ndarray  # int32: a cell's index in frontier_cells (−1: not a frontier)
    frontier_count: np.ndarray  # (1,) int64
    known_near: np.ndarray  # uint16: known cells within L1 rad
    open_near: np.ndarray  # uint16: open cells within L1 rad
    closed_near: np.ndarray  # uint8: closed-known cells in the cross
    eroded_near: np.ndarray  # uint8: eroded-unknown cells in the cross
    unknown_near: np.ndarray  # uint8: unknown cells in the 3 × 3 block
    passable_d2: np.ndarray  # (reach² + 2,) bool: a clearance of √d2 cells above inflate
    cost_d2: np.ndarray  # (reach² + 2,) float64: its soft cost
    bbox: np.ndarray  # (4,) int64: the known cells' first and last row, first and last column
    n: int
    reach: int  # cells: clearance is exact up to here
    rad: int  # cells: the gap closing's radius
    res: float  # m per cell
    origin: float  # m: x and y of the grid's lower-left corner
    inflate: float  # m: clearance a passable cell needs
    soft: float  # m: clearance from which a cell costs 1


def diamond_cells(rad: int) -> int:
    """Cells within L1 distance ``rad`` of a cell (itself included)."""
    return 2 * rad * (rad + 1) + 1


@njit
def fold(
    layers: Layers,
    turned: np.ndarray,
    lattice_cell: np.ndarray,
    local_free: np.ndarray,
    local_occ: np.ndarray,
    pose: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    fractions: np.ndarray,
    disc: np.ndarray,
    touched: np.ndarray,
) -> None:
    """Fold one step seen from ``pose`` (3,) into the grids of ``layers``, in the order of the
    readable map, then bring the layers up to date (:func:`update_layers`):

    * the egocentric local grid: points ``turned`` (L, 2) (its lattice turned to the own
      frame, the pose's position yet to add), each in local cell ``lattice_cell`` (L,) of the
      flat ``local_free`` and ``local_occ`` (G·G,) bool; the free cells' points set free and
      clear occupied, then the occupied cells' points occupied;
    * the beams at ``angles`` (B,) reading ``ranges`` (B,) up to ``max_range``: free at the
      ``fractions`` (S,) of their length, and the hit cells
      (:func:`polyslam_env.core.raster.scan_cells_into`, as the env's belief grids);
    * the robot's own ``disc`` (P, 2) of offsets around the pose, free.

    ``touched`` must hold 2 L + B·(S + 1) + P cell ids (scratch: the cells that change)."""
    free, occ, hit = layers.free, layers.occ, layers.hit
    origin, res, n = layers.origin, layers.res, layers.n
    k = 0  # cells whose grids change (some maybe back again), for update_layers
    for j in range(turned.shape[0]):
        if local_free[lattice_cell[j]]:
            c = cell_id(turned[j, 0] + pose[0], turned[j, 1] + pose[1], origin, origin, res, n, n)
            if c >= 0 and (occ[c] or not free[c]):
                free[c], occ[c], touched[k] = True, False, c
                k += 1
    for j in range(turned.shape[0]):
        if local_occ[lattice_cell[j]]:
            c = cell_id(turned[j, 0] + pose[0], turned[j, 1] + pose[1], origin, origin, res, n, n)
            if c >= 0 and not occ[c]:
                occ[c], touched[k] = True, c
                k += 1
    beam_free = np.empty((1, angles.shape[0], fractions.shape[0]), dtype=np.int64)
    beam_hit = np.empty((1, angles.shape[0]), dtype=np.int64)
    scan_cells_into(
        pose.reshape(1, 3), angles, ranges.reshape(1, -1), max_range, fractions, origin, origin,
        res, n, n, beam_free, beam_hit,
    )  # fmt: skip
    for swept in beam_free.reshape(-1):
        if swept >= 0 and not free[swept]:
            free[swept], touched[k] = True, swept
            k += 1
    for ended in beam_hit.reshape(-1):
        if ended >= 0 and not hit[ended]:
            hit[ended], touched[k] = True, ended
            k += 1
    for j in range(disc.shape[0]):
        c = cell_id(pose[0] + disc[j, 0], pose[1] + disc[j, 1], origin, origin, res, n, n)
        if c >= 0 and not free[c]:
            free[c], touched[k] = True, c
            k += 1
    update_layers(touched[:k], layers)


@njit
def _nearest(obst: np.ndarray, n: int, row: int, col: int, reach: int, r2: int) -> int:
    """Squared distance from (row, col) to the nearest obstacle within ``reach`` cells (and
    within √r2), ``r2 + 1`` for none."""
    best = r2 + 1
    for dr in range(-reach, reach + 1):
        r = row + dr
        if r < 0 or r >= n:
            continue
        for dc in range(-reach, reach + 1):
            c = col + dc
            d = dr * dr + dc * dc
            if 0 <= c < n and d < best and obst[r * n + c]:
                best = d
    return best


@njit
def _set_frontier(
    x: int, on: bool, frontier: np.ndarray, cells: np.ndarray, at: np.ndarray, count: np.ndarray
) -> None:
    """Make cell x a frontier cell or not, in the grid ``frontier`` and in the list of frontier
    cells ``cells`` (``count[0]`` of them; ``at``: a cell's place in it, −1 for none)."""
    if frontier[x] == on:
        return
    frontier[x] = on
    if on:
        cells[count[0]], at[x] = x, count[0]
        count[0] += 1
    else:  # the last one takes its place
        count[0] -= 1
        last = cells[count[0]]
        cells[at[x]], at[last], at[x] = last, at[x], -1


@njit
def _recheck(
    x: int,
    free: np.ndarray,
    obst: np.ndarray,
    d2: np.ndarray,
    passable_d2: np.ndarray,
    passable: np.ndarray,
    unknown_near: np.ndarray,
    listed: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    """Cell x's passable and frontier layers from its free, obstacle and clearance cells
    (``listed``: the frontier grid and list, :func:`_set_frontier`)."""
    ok = free[x] and not obst[x] and passable_d2[d2[x]]
    passable[x] = ok
    _set_frontier(x, ok and unknown_near[x] > 0, *listed)


@njit
def _count_down_open(
    cell: int,
    n: int,
    rad: int,
    open_near: np.ndarray,
    closed_near: np.ndarray,
    eroded_near: np.ndarray,
    unknown_near: np.ndarray,
    listed: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    """Cell ``cell`` stopped being open: propagate the change through the layers, down to
    the frontier cells that no unknown cell touches any more (``listed``: the frontier grid
    and list, :func:`_set_frontier`)."""
    row, col = cell // n, cell % n
    for dr in range(-rad, rad + 1):
        span = rad - abs(dr)
        r = row + dr
        if r < 0 or r >= n:
            continue
        for dc in range(-span, span + 1):
            c = col + dc
            if c < 0 or c >= n:
                continue
            x = r * n + c
            open_near[x] -= 1
            if open_near[x] == 0:  # x is closed-known now: its cross is no longer eroded
                for yr, yc in ((r, c), (r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                    if yr < 0 or yr >= n or yc < 0 or yc >= n:
                        continue
                    y = yr * n + yc
                    closed_near[y] += 1
                    if closed_near[y] == 1:  # y stopped being eroded-unknown
                        for ur, uc in (
                            (yr, yc),
                            (yr - 1, yc),
                            (yr + 1, yc),
                            (yr, yc - 1),
                            (yr, yc + 1),
                        ):
                            if ur < 0 or ur >= n or uc < 0 or uc >= n:
                                continue
                            u = ur * n + uc
                            eroded_near[u] -= 1
                            if eroded_near[u] == 0:  # u stopped being unknown
                                for vr in range(max(ur - 1, 0), min(ur + 2, n)):
                                    for vc in range(max(uc - 1, 0), min(uc + 2, n)):
                                        v = vr * n + vc
                                        unknown_near[v] -= 1
                                        if unknown_near[v] == 0:
                                            _set_frontier(v, False, *listed)


@njit
def update_layers(touched: np.ndarray, layers: Layers) -> None:
    """Bring the ``layers`` (module doc) up to date after the cells ``touched`` changed in
    their ``free``, ``occ``, ``hit`` grids (the known box too).

    A cell's passable and frontier layers are recomputed whenever one of their inputs
    changes, so the last recomputation sees the final inputs."""
    free, occ, hit, obst, known = layers.free, layers.occ, layers.hit, layers.obst, layers.known
    d2, known_near = layers.d2, layers.known_near
    passable_d2, bbox = layers.passable_d2, layers.bbox
    passable, unknown_near = layers.passable, layers.unknown_near
    open_near, closed_near, eroded_near = layers.open_near, layers.closed_near, layers.eroded_near
    listed = layers.frontier, layers.frontier_cells, layers.frontier_at, layers.frontier_count
    n, reach, rad = layers.n, layers.reach, layers.rad
    checked = free, obst, d2, passable_d2, passable, unknown_near, listed
    r2 = passable_d2.shape[0] - 2
    m = touched.shape[0]
    added = np.empty(m, dtype=np.int64)
    removed = np.empty(m, dtype=np.int64)
    fresh = np.empty(m, dtype=np.int64)
    na = nr = nf = 0
    for c in touched:
        o = occ[c] or hit[c]
        if o != obst[c]:
            obst[c] = o
            if o:
                added[na] = c
                na += 1
            else:
                removed[nr] = c
                nr += 1
        if (free[c] or o) and not known[c]:
            known[c] = True
            fresh[nf] = c
            nf += 1
        _recheck(c, *checked)
    # clearance: lower around new obstacles, recompute around removed ones
    for i in range(na):
        row, col = added[i] // n, added[i] % n
        for r in range(max(row - reach, 0), min(row + reach + 1, n)):
            for cc in range(max(col - reach, 0), min(col + reach + 1, n)):
                d = (r - row) ** 2 + (cc - col) ** 2
                x = r * n + cc
                if d < d2[x]:
                    d2[x] = d
                    _recheck(x, *checked)
    for i in range(nr):
        row, col = removed[i] // n, removed[i] % n
        for r in range(max(row - reach, 0), min(row + reach + 1, n)):
            for cc in range(max(col - reach, 0), min(col + reach + 1, n)):
                d = (r - row) ** 2 + (cc - col) ** 2
                x = r * n + cc
                if d <= r2 and d2[x] == d:  # its nearest obstacle may have been this one
                    d2[x] = _nearest(obst, n, r, cc, reach, r2)
                    _recheck(x, *checked)
    # the gap closing and the frontier's unknown
    for i in range(nf):
        c = fresh[i]
        row, col = c // n, c % n
        bbox[0], bbox[1] = min(bbox[0], row), max(bbox[1], row)
        bbox[2], bbox[3] = min(bbox[2], col), max(bbox[3], col)
        for dr in range(-rad, rad + 1):
            span = rad - abs(dr)
            r = row + dr
            if r < 0 or r >= n:
                continue
            for dc in range(-span, span + 1):
                cc = col + dc
                if cc < 0 or cc >= n:
                    continue
                x = r * n + cc
                known_near[x] += 1
                if known_near[x] == 1:  # x stopped being open
                    _count_down_open(
                        x, n, rad, open_near, closed_near, eroded_near, unknown_near, listed
                    )

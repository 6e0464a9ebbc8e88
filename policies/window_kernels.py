"""Compiled kernels of the frontier planner's window (:mod:`policies.planner`): its frontier,
exactly as the readable planner computed it on the window, and the gain of its frontier cells.

The readable planner ran scipy's morphology on the search window (the known cells' box grown by
a margin), whose operations treat the outside in their own ways: the gap closing as known, the
opening and the dilation as not unknown. The own map keeps the same layers on the whole map
(:mod:`policies.ownmap_kernels`); deep enough inside the window they agree with the window's,
and :func:`window_frontier` copies them there. Nearer the edge (within ``2 rad + 3`` cells,
``rad`` the closing's radius) it evaluates each cell with the window's rules, from the known-cell
counts, going down the chain frontier ← unknown ← eroded ← closed only as far as it must: at a
depth where a layer cannot see the edge, the whole map's layer answers.

Window cells are (r, c), the window's (0, 0) being map cell (r0, c0); the map's flat grids are
(n·n,). The readable versions are the oracles in ``tests/policies/reference.py``.
"""

from __future__ import annotations

import math

import numpy as np

from policies.ownmap_kernels import Layers
from polyslam_env.core.jit import njit


@njit
def _ring(r: int, c: int, h: int, w: int) -> int:
    """How many cells (r, c) lies inside the edge of an (h, w) window (0: on the edge)."""
    return min(r, c, h - 1 - r, w - 1 - c)


@njit
def any_obstacle(obst: np.ndarray, n: int, r0: int, r1: int, c0: int, c1: int) -> bool:
    """Whether the window rows r0…r1 − 1, columns c0…c1 − 1 hold an obstacle."""
    for r in range(r0, r1):
        for c in range(c0, c1):
            if obst[r * n + c]:
                return True
    return False


@njit
def _open_in_diamond(
    r: int, c: int, g: int, h: int, w: int, n: int, rad: int, known_near: np.ndarray
) -> bool:
    """Whether a cell within L1 ``rad`` of window cell (r, c) (map cell g) is "open" for the
    window's closing: at least ``rad`` from the window's edge (nearer, and outside, the
    closing's border counts as known) and with no known cell within L1 ``rad``."""
    top, bottom = max(r - rad, rad), min(r + rad, h - 1 - rad)
    for y in range(top, bottom + 1):
        span = rad - abs(y - r)
        row = g + (y - r) * n - c
        for x in range(max(c - span, rad), min(c + span, w - 1 - rad) + 1):
            if known_near[row + x] == 0:
                return True
    return False


@njit
def _columns(r: int, h: int, w: int, depth: int, deep: bool) -> int:
    """The cells of row r within ``depth`` of the window's edge are its columns [0, k) and
    [w − k, w): k (w for the whole row; every cell when not ``deep``)."""
    if not deep or r <= depth or r >= h - 1 - depth:
        return w
    return min(depth + 1, w)


@njit
def frontier_cells(layers: Layers, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """The frontier cells (flat ids, row-major order) of window rows r0…r1 − 1, columns
    c0…c1 − 1 of the own map ``layers``, as the readable planner computed them on the window:
    passable cells next (3 × 3) to unknown space after closing the gaps between beam stripes
    (``rad`` cross iterations) and opening the unknown (module doc). Passable cells need every
    obstacle within the inflation radius of a window cell inside the window.

    Near the window's edge each layer is computed, each one ring deeper than the next needs,
    and read from the whole map's counts from the depth where the edge is out of its reach:
    closed-known from 2 rad, eroded from 2 rad + 1, unknown from 2 rad + 2, frontier from
    2 rad + 3; deeper, the whole map's list of frontier cells answers. Near the map's edge
    (not ``deep``) every cell is computed."""
    free, obst, d2 = layers.free, layers.obst, layers.d2
    passable_d2, known_near, open_near = layers.passable_d2, layers.known_near, layers.open_near
    closed_near, eroded_near = layers.closed_near, layers.eroded_near
    n, rad, res, inflate = layers.n, layers.rad, layers.res, layers.inflate
    h, w = r1 - r0, c1 - c0
    band = 2 * rad + 3
    deep = min(r0, c0, n - r1, n - c1) >= band  # far enough from the map's edge
    empty = not any_obstacle(obst, n, r0, r1, c0, c1)
    closed = np.empty((h, w), dtype=np.bool_)
    eroded = np.empty((h, w), dtype=np.bool_)
    unknown = np.empty((h, w), dtype=np.bool_)
    found = np.empty(h * w if not deep else min(h * w, 2 * band * (h + w)), dtype=np.int64)
    count = 0
    for depth, layer in ((band - 2, 0), (band - 1, 1), (band, 2), (band - 1, 3)):
        for r in range(h):
            k = _columns(r, h, w, depth, deep)
            c = -1
            while c + 1 < w:
                c = max(k, w - k) if c + 1 == k else c + 1  # the row's deep middle skipped
                if c >= w:
                    break
                g = (r + r0) * n + c + c0
                ring = _ring(r, c, h, w)
                if layer == 0:  # closed-known after the window's gap closing
                    if deep and ring >= 2 * rad:
                        closed[r, c] = open_near[g] == 0
                    else:
                        closed[r, c] = not _open_in_diamond(r, c, g, h, w, n, rad, known_near)
                elif layer == 1:  # eroded-unknown: none of its cross closed, inside the edge
                    if ring < 1:
                        eroded[r, c] = False
                    elif deep and ring >= 2 * rad + 1:
                        eroded[r, c] = closed_near[g] == 0
                    else:
                        eroded[r, c] = not (
                            closed[r, c] or closed[r - 1, c] or closed[r + 1, c]
                            or closed[r, c - 1] or closed[r, c + 1]
                        )  # fmt: skip
                elif layer == 2:  # unknown: an eroded cell in its cross
                    if deep and ring >= 2 * rad + 2:
                        unknown[r, c] = eroded_near[g] > 0
                    else:
                        unknown[r, c] = eroded[r, c] or (
                            (r > 0 and eroded[r - 1, c]) or (r < h - 1 and eroded[r + 1, c])
                            or (c > 0 and eroded[r, c - 1]) or (c < w - 1 and eroded[r, c + 1])
                        )  # fmt: skip
                elif free[g] and not obst[g]:  # the frontier: passable, an unknown cell near
                    if empty:
                        clear_ok = math.sqrt(float((r + 1) ** 2 + c * c)) * res > inflate
                    else:
                        clear_ok = passable_d2[d2[g]]
                    if clear_ok and _any_unknown(unknown, r, c, h, w):
                        found[count] = r * w + c
                        count += 1
    out = found[:count]
    if deep:  # the middle, from the whole map's list of frontier cells
        middle = np.empty(layers.frontier_count[0], dtype=np.int64)
        m = 0
        for cell in layers.frontier_cells[: layers.frontier_count[0]]:
            r, c = cell // n - r0, cell % n - c0
            if band <= r < h - band and band <= c < w - band:
                middle[m] = r * w + c
                m += 1
        out = np.concatenate((out, middle[:m]))
    return np.sort(out)


@njit
def goal_cells(
    layers: Layers,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    black: np.ndarray,
    near: int,
    size: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The goal candidates of window rows r0…r1 − 1, columns c0…c1 − 1: its
    :func:`frontier_cells` (flat, row-major) but those within ``near`` cells (Chebyshev) of a
    map cell of ``black`` (K, 2) (rows, cols), and their :func:`square_gain` over ``size``
    cells (zeros for ``size`` 0)."""
    cells = frontier_cells(layers, r0, r1, c0, c1)
    w = c1 - c0
    keep = np.ones(cells.shape[0], dtype=np.bool_)
    for i in range(cells.shape[0]):
        r, c = cells[i] // w + r0, cells[i] % w + c0
        for k in range(black.shape[0]):
            if abs(r - black[k, 0]) <= near and abs(c - black[k, 1]) <= near:
                keep[i] = False
    cells = cells[keep]
    if size == 0:
        return cells, np.zeros(cells.shape[0], dtype=np.float32)
    rows, cols = cells // w, cells % w
    return cells, square_gain(layers.known, layers.n, r0, r1, c0, c1, size, rows, cols)


@njit
def _any_unknown(unknown: np.ndarray, r: int, c: int, h: int, w: int) -> bool:
    """Whether the 3 × 3 block around (r, c) (inside the window) holds an unknown cell."""
    for y in range(max(r - 1, 0), min(r + 2, h)):
        for x in range(max(c - 1, 0), min(c + 2, w)):
            if unknown[y, x]:
                return True
    return False


@njit
def window_frontier(layers: Layers, r0: int, r1: int, c0: int, c1: int, out: np.ndarray) -> None:
    """:func:`frontier_cells` as an (H, W) bool grid ``out``."""
    flat = out.reshape(-1)
    flat[:] = False
    for cell in frontier_cells(layers, r0, r1, c0, c1):
        flat[cell] = True


@njit
def frontier_at(layers: Layers, r0: int, r1: int, c0: int, c1: int, row: int, col: int) -> bool:
    """Whether map cell (row, col) is in :func:`window_frontier` of that window (obstacles
    anywhere: only the cell's own clearance counts, and it is inside the window)."""
    h, w, n = r1 - r0, c1 - c0, layers.n
    band = 2 * layers.rad + 3
    if min(r0, c0, n - r1, n - c1) >= band and _ring(row - r0, col - c0, h, w) >= band:
        return layers.frontier[row * n + col]
    cells = frontier_cells(layers, r0, r1, c0, c1)
    i = np.searchsorted(cells, (row - r0) * w + col - c0)
    return i < cells.shape[0] and cells[i] == (row - r0) * w + col - c0


@njit
def frontier_near(layers: Layers, half: int, row: int, col: int, reach: int) -> bool:
    """Whether a map cell within ``reach`` cells (Chebyshev) of map cell (row, col) is a
    frontier cell by :func:`frontier_at` on the window of ``half`` cells around it (clipped to
    the map), the cells in row-major order until one is."""
    n = layers.n
    for r in range(max(row - reach, 0), min(row + reach + 1, n)):
        for c in range(max(col - reach, 0), min(col + reach + 1, n)):
            r0, c0 = max(r - half, 0), max(c - half, 0)
            if frontier_at(layers, r0, min(r + half + 1, n), c0, min(c + half + 1, n), r, c):
                return True
    return False


# -- the gain ----------------------------------------------------------------------------------
@njit
def square_gain(
    known: np.ndarray,
    n: int,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    size: int,
    rows: np.ndarray,
    cols: np.ndarray,
) -> np.ndarray:  # (K,) float32
    """At window cells (rows[k], cols[k]), the mean unknown fraction of the ``size`` × ``size``
    square around them, zero outside the window: the readable planner's
    ``uniform_filter((~known).astype(float32), size, mode="constant")`` over the window, to the
    bit. scipy filters along columns, then rows, each pass a running sum in double divided by
    ``size`` and stored as float32. The first pass sums 0s and 1s; the second sums at most
    ``size`` float32 values k / size, all multiples of 2⁻³⁰ below ``size`` (for a size below
    2¹⁰), so both sums are exact in double whatever their order: each cell's gain is computed
    from its own square alone."""
    h, w = r1 - r0, c1 - c0
    half = size // 2
    below = np.zeros((h + 1, w), dtype=np.int64)  # unknown cells of rows < r, per column
    for r in range(h):
        for c in range(w):
            below[r + 1, c] = below[r, c] + (0 if known[(r + r0) * n + c + c0] else 1)
    out = np.empty(rows.shape[0], dtype=np.float32)
    column = np.empty(w, dtype=np.float32)  # the first pass along one row
    last = -1
    for k in range(rows.shape[0]):
        r = rows[k]
        if r != last:
            top, bottom = max(r - half, 0), min(r + half + 1, h)
            for c in range(w):
                column[c] = np.float32(float(below[bottom, c] - below[top, c]) / size)
            last = r
        total = 0.0
        for c in range(max(cols[k] - half, 0), min(cols[k] + half + 1, w)):
            total += float(column[c])
        out[k] = np.float32(total / size)
    return out

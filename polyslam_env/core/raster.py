"""Range beams rasterised on square-celled grids: the cells their samples fall in.

Grid convention shared by every grid that beams are swept into (the coverage grid of the
metrics, the robots' belief grids, the frontier policy's own map): cell ``(row, col)`` covers
``x ∈ [ox + col·res, ox + (col+1)·res)``, ``y ∈ [oy + row·res, oy + (row+1)·res)`` with
``origin = (ox, oy)`` the grid's lower-left corner, and its flat id is ``row · W + col`` for a
grid of ``shape = (H, W)``. A sample at distance t along a beam of absolute angle φ from
(x0, y0) is the point ``(x0 + t·cos φ, y0 + t·sin φ)``; the distances are every ≤ res/2, so a
cell a beam crosses over at least res/2 is always hit.

Two sampling rules, both compiled kernels (:func:`polyslam_env.core.jit.njit`):

* :func:`scan_cells` (kernel :func:`scan_cells_into`) / :func:`mark_scans` (belief grids,
  frontier map): fixed ``fractions`` (:func:`beam_fractions`) of each beam's length, which
  stops half a cell short of a hit, plus the hit cell;
* :func:`even_beam_cells` (coverage): each scan's beams sampled ``linspace(0, 1, n)`` of their
  length, with ``n`` set by the scan's longest beam, both ends included.

:func:`count_new` and :func:`mark_cells` count and mark cells of a boolean grid. The readable
numpy versions are the oracles in ``tests/core/reference.py``; the kernels do the same float
operations in the same order, so cells are identical. Nothing of the package but ``core``.
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import njit

__all__ = [
    "beam_fractions",
    "cell_id",
    "count_new",
    "even_beam_cells",
    "mark_cells",
    "mark_scans",
    "point_cells",
    "scan_cells",
    "scan_cells_into",
    "sweep_team",
]


# -- kernels ----------------------------------------------------------------------------------
@njit
def cell_id(x: float, y: float, ox: float, oy: float, res: float, h: int, w: int) -> int:
    """Flat id of the cell holding (x, y) in a grid of origin (ox, oy), cell side ``res`` and
    shape (h, w); −1 outside the grid. A kernel: callable from other kernels."""
    col = math.floor((x - ox) / res)
    row = math.floor((y - oy) / res)
    if 0 <= row < h and 0 <= col < w:
        return row * w + col
    return -1


@njit
def _point_cells(
    x: np.ndarray, y: np.ndarray, ox: float, oy: float, res: float, h: int, w: int, out: np.ndarray
) -> None:
    for i in range(x.shape[0]):
        out[i] = cell_id(x[i], y[i], ox, oy, res, h, w)


@njit
def _beam(
    theta: float, angle: float, r_raw: float, max_range: float, res: float
) -> tuple[bool, float, float, float, float]:
    """One beam of a scan: (returned, range r clipped to ``max_range`` (inf and nan → it), the
    free length swept (r less half a cell when it returned), cos and sin of its direction)."""
    returned = math.isfinite(r_raw)
    r = r_raw if r_raw < max_range else max_range  # fmin: inf and nan → max_range
    length = max(r - 0.5 * res, 0.0) if returned else r
    phi = theta + angle
    return returned, r, length, math.cos(phi), math.sin(phi)


@njit
def scan_cells_into(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    fractions: np.ndarray,
    ox: float,
    oy: float,
    res: float,
    h: int,
    w: int,
    free: np.ndarray,
    hit: np.ndarray,
) -> None:
    """Free ids ``free`` (K, B, S) and hit ids ``hit`` (K, B) of K scans (−1: outside the grid,
    or no return for a hit); see :func:`scan_cells`. A kernel: callable from other kernels."""
    for k in range(poses.shape[0]):
        for b in range(angles.shape[0]):
            returned, r, length, c, s = _beam(poses[k, 2], angles[b], ranges[k, b], max_range, res)
            for j in range(fractions.shape[0]):
                t = length * fractions[j]
                free[k, b, j] = cell_id(poses[k, 0] + t * c, poses[k, 1] + t * s, ox, oy, res, h, w)
            end = cell_id(poses[k, 0] + r * c, poses[k, 1] + r * s, ox, oy, res, h, w)
            hit[k, b] = end if returned else -1


@njit
def _mark_scans(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    fractions: np.ndarray,
    ox: float,
    oy: float,
    res: float,
    h: int,
    w: int,
    free: np.ndarray,
    hit: np.ndarray,
    rows: np.ndarray,
) -> None:
    """Set the free and hit cells of K scans, scan k in the flat grids ``free[rows[k]]``,
    ``hit[rows[k]]``; see :func:`mark_scans`."""
    for k in range(poses.shape[0]):
        own_free, own_hit = free[rows[k]], hit[rows[k]]
        for b in range(angles.shape[0]):
            returned, r, length, c, s = _beam(poses[k, 2], angles[b], ranges[k, b], max_range, res)
            for j in range(fractions.shape[0]):
                t = length * fractions[j]
                cell = cell_id(poses[k, 0] + t * c, poses[k, 1] + t * s, ox, oy, res, h, w)
                if cell >= 0:
                    own_free[cell] = True
            if returned:
                cell = cell_id(poses[k, 0] + r * c, poses[k, 1] + r * s, ox, oy, res, h, w)
                if cell >= 0:
                    own_hit[cell] = True


@njit
def _linspace_fraction(i: int, n: int) -> float:
    """``numpy.linspace(0.0, 1.0, n)[i]``, computed as numpy does."""
    if n == 1:
        return 0.0
    if i == n - 1:
        return 1.0
    return i * (1.0 / (n - 1)) + 0.0


@njit
def _even_scan(
    ox: np.ndarray,
    oy: np.ndarray,
    phi: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    gx: float,
    gy: float,
    res: float,
    h: int,
    w: int,
    out: np.ndarray,
) -> None:
    """Ids ``out`` (R, width) of the cells under the samples of one scan's R beams from
    (``ox``, ``oy``) (R,) at angles ``phi`` (R,) (−1: outside the grid or past the scan's
    sample count); see :func:`even_beam_cells`."""
    spacing = 0.5 * res
    longest = 0.0
    for b in range(phi.shape[0]):
        length = ranges[b] if ranges[b] < max_range else max_range  # fmin: inf, nan → max
        longest = max(longest, length)
    n = math.ceil(max(longest, 0.0) / spacing) + 1
    for b in range(phi.shape[0]):
        length = ranges[b] if ranges[b] < max_range else max_range
        c, s = math.cos(phi[b]), math.sin(phi[b])
        for j in range(out.shape[1]):
            if j < n:
                t = length * _linspace_fraction(j, n)
                out[b, j] = cell_id(ox[b] + t * c, oy[b] + t * s, gx, gy, res, h, w)
            else:
                out[b, j] = -1


@njit
def _even_beam_cells(
    ox: np.ndarray,
    oy: np.ndarray,
    phi: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    gx: float,
    gy: float,
    res: float,
    h: int,
    w: int,
    out: np.ndarray,
) -> None:
    """:func:`_even_scan` of K scans: ``out`` (K, R, width)."""
    for k in range(phi.shape[0]):
        _even_scan(ox[k], oy[k], phi[k], ranges[k], max_range, gx, gy, res, h, w, out[k])


@njit
def _count_new(cells: np.ndarray, mask: np.ndarray, marked: np.ndarray) -> int:
    """How many distinct ids among ``cells`` (−1 skipped) are in ``mask`` and not ``marked``
    (flat grids); ``marked`` is left as it was."""
    fresh = np.empty(cells.shape[0], dtype=np.int64)
    n = 0
    for c in cells:
        if c >= 0 and mask[c] and not marked[c]:
            marked[c] = True  # counted once; undone below
            fresh[n] = c
            n += 1
    for i in range(n):
        marked[fresh[i]] = False
    return n


@njit
def _mark_cells(cells: np.ndarray, mask: np.ndarray, marked: np.ndarray, mine: np.ndarray) -> int:
    """Mark ``cells`` (−1 skipped) in ``marked`` and ``mine`` (flat grids; ``mine`` may be
    empty: not marked); return how many were in ``mask`` and not ``marked`` before."""
    own = mine.shape[0] > 0
    n = 0
    for c in cells:
        if c >= 0:
            if mask[c] and not marked[c]:
                n += 1
            marked[c] = True
            if own:
                mine[c] = True
    return n


@njit
def _count_and_mark(
    ids: np.ndarray,
    mask: np.ndarray,
    marked: np.ndarray,
    mines: np.ndarray,
    rows: np.ndarray,
    gains: np.ndarray,
) -> tuple[int, int]:
    """K sets of cells ``ids`` (K, M) (−1 skipped) at once: first :func:`_count_new` of each
    against ``marked`` as it is into ``gains`` (K,), then :func:`_mark_cells` of each in
    order, in ``marked`` and its own grid ``mines[rows[k]]`` (flat grids). Returns the total
    newly marked cells of ``mask`` and those of the last set."""
    for k in range(ids.shape[0]):
        gains[k] = _count_new(ids[k], mask, marked)
    total = last = 0
    for k in range(ids.shape[0]):
        last = _mark_cells(ids[k], mask, marked, mines[rows[k]])
        total += last
    return total, last


@njit
def _sweep_team(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    active: np.ndarray,
    max_range: float,
    gx: float,
    gy: float,
    res: float,
    h: int,
    w: int,
    mask: np.ndarray,
    marked: np.ndarray,
    mines: np.ndarray,
    rows: np.ndarray,
    gains: np.ndarray,
) -> tuple[int, int]:
    """:func:`sweep_team` on flat grids; ``gains`` (N,) of inactive robots are left alone."""
    width = math.ceil(max(max_range, 0.0) / (0.5 * res)) + 1
    nb = angles.shape[0]
    robots = np.flatnonzero(active)
    ids = np.empty((robots.shape[0], nb * width), dtype=np.int64)
    phi = np.empty(nb)
    for k in range(robots.shape[0]):
        i = robots[k]
        for b in range(nb):
            phi[b] = poses[i, 2] + angles[b]
        ox, oy = np.full(nb, poses[i, 0]), np.full(nb, poses[i, 1])
        out = ids[k].reshape((nb, width))
        _even_scan(ox, oy, phi, ranges[i], max_range, gx, gy, res, h, w, out)
    team = np.empty(robots.shape[0], dtype=np.int64)
    total, last = _count_and_mark(ids, mask, marked, mines, rows[robots], team)
    for k in range(robots.shape[0]):
        gains[robots[k]] = team[k]
    return total, last


# -- wrappers -------------------------------------------------------------------------------
def point_cells(
    x: np.ndarray,
    y: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Flat ids and whether each point lies inside the grid, for coordinates ``x``, ``y``
    (same shape). Ids of points outside are −1."""
    xs = np.ascontiguousarray(x, dtype=float).reshape(-1)
    ys = np.ascontiguousarray(y, dtype=float).reshape(-1)
    out = np.empty(xs.shape, dtype=np.int64)
    _point_cells(xs, ys, float(origin[0]), float(origin[1]), float(resolution), *shape, out)
    flat = out.reshape(np.shape(x))
    return flat, flat >= 0


def beam_fractions(max_range: float, resolution: float) -> np.ndarray:  # (S,)
    """Sample positions 0…1 along a beam of at most ``max_range``, ≤ res/2 apart."""
    return np.linspace(0.0, 1.0, math.ceil(max_range / (0.5 * resolution)) + 1)


def scan_cells(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    fractions: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cells of K scans from ``poses`` (K, 3), beams at ``angles`` (B,) relative to the
    heading, ``ranges`` (K, B) (inf or nan: no return; beyond ``max_range``: cut there).

    Free: each beam sampled at ``fractions`` (S,) (:func:`beam_fractions`) of its length, which
    stops half a cell short of a hit (so the hit cell is not cleared) or runs to ``max_range``
    without a return. Hit: the cell of the end point of each beam with a return.
    Returns free ids and inside mask (K, B, S), hit ids (K, B) and hit mask (K, B).
    """
    p = np.ascontiguousarray(poses, dtype=float).reshape(-1, 3)
    a = np.ascontiguousarray(angles, dtype=float).reshape(-1)
    r = np.ascontiguousarray(ranges, dtype=float).reshape(len(p), len(a))
    f = np.ascontiguousarray(fractions, dtype=float)
    free = np.empty((len(p), len(a), len(f)), dtype=np.int64)
    hit = np.empty((len(p), len(a)), dtype=np.int64)
    ox, oy = float(origin[0]), float(origin[1])
    scan_cells_into(p, a, r, float(max_range), f, ox, oy, float(resolution), *shape, free, hit)
    return free, free >= 0, hit, hit >= 0


def mark_scans(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    fractions: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    free: np.ndarray,
    hit: np.ndarray,
    rows: np.ndarray,
) -> None:
    """Set (in place) the free and hit cells of K scans from ``poses`` (K, 3) (beams at
    ``angles`` (B,), ``ranges`` (K, B)) in stacks of boolean grids ``free`` and ``hit``
    (R, H, W), C-contiguous: scan k in grids ``rows[k]`` (K,). The cells of
    :func:`scan_cells`."""
    r, h, w = free.shape
    _mark_scans(
        np.ascontiguousarray(poses, dtype=float), np.ascontiguousarray(angles, dtype=float),
        np.ascontiguousarray(ranges, dtype=float), float(max_range), fractions,
        float(origin[0]), float(origin[1]), float(resolution), h, w, free.reshape(r, -1),
        hit.reshape(r, -1), rows,
    )  # fmt: skip


def even_beam_cells(
    ox: np.ndarray,
    oy: np.ndarray,
    phi: np.ndarray,
    ranges: np.ndarray,
    max_range: float,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
) -> np.ndarray:  # (K, R, width) int64, −1 for no cell
    """Cells under the samples of K scans of R beams from (``ox``, ``oy``) (K, R) at absolute
    angles ``phi`` (K, R), ``ranges`` (K, R) (inf, nan: no return, the beam runs to
    ``max_range``; longer ranges are cut there). Each scan's beams are sampled at
    ``linspace(0, 1, n)`` of their length, ``n = ⌈longest / (res/2)⌉ + 1`` from the scan's
    longest beam (so samples are ≤ res/2 apart, both ends included); ``width`` is ``n`` of a
    beam of ``max_range``, and slots past a scan's ``n`` are −1."""
    width = math.ceil(max(float(max_range), 0.0) / (0.5 * resolution)) + 1
    out = np.empty((*np.shape(phi), width), dtype=np.int64)
    _even_beam_cells(
        ox, oy, phi, ranges, float(max_range), float(origin[0]), float(origin[1]),
        float(resolution), *shape, out,
    )  # fmt: skip
    return out


def count_new(cells: np.ndarray, mask: np.ndarray, marked: np.ndarray) -> int:
    """Distinct ids among ``cells`` (any shape; −1 skipped) that are in ``mask`` and not in
    ``marked`` (boolean grids of one shape, C-contiguous; ``marked`` is not changed)."""
    flat = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
    return int(_count_new(flat, mask.reshape(-1), marked.reshape(-1)))


def mark_cells(
    cells: np.ndarray, mask: np.ndarray, marked: np.ndarray, mine: np.ndarray | None = None
) -> int:
    """Mark ``cells`` (any shape; −1 skipped) in ``marked`` and, if given, ``mine`` (boolean
    grids of ``mask``'s shape, C-contiguous, changed in place); return how many distinct cells
    were in ``mask`` and not ``marked`` before."""
    flat = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
    own = np.zeros(0, dtype=bool) if mine is None else mine.reshape(-1)
    return int(_mark_cells(flat, mask.reshape(-1), marked.reshape(-1), own))


def sweep_team(
    poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    active: np.ndarray,
    max_range: float,
    origin: tuple[float, float],
    resolution: float,
    mask: np.ndarray,
    marked: np.ndarray,
    mines: np.ndarray,
    rows: np.ndarray,
) -> tuple[np.ndarray, int, int]:
    """Count, then mark the :func:`even_beam_cells` of the ``active`` (N,) robots' scans, in
    one kernel call. Robot i stands at ``poses[i]`` (3,), its beams at ``angles`` (B,)
    relative to its heading read ``ranges[i]`` (B,), its own grid is ``mines[rows[i]]``.
    First each scan's distinct cells of ``mask`` not yet ``marked`` are counted (before any
    of this call's marks), then its cells are marked in ``marked`` and its own grid, in
    order. Returns the counts (N,) (0 for inactive robots), the total newly marked cells of
    ``mask`` and those of the last active robot."""
    gains = np.zeros(len(poses), dtype=np.int64)
    h, w = mask.shape
    total, last = _sweep_team(
        poses, angles, ranges, active, float(max_range), float(origin[0]), float(origin[1]),
        float(resolution), h, w, mask.reshape(-1), marked.reshape(-1),
        mines.reshape(len(mines), -1), rows, gains,
    )  # fmt: skip
    return gains, int(total), int(last)

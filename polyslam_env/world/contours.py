"""Walls from rasters: the boundary of a sampled free space traced into closed polylines.

Used by the contour-drawn generators (caves, curved floors: a scalar field sampled on a grid,
free where it exceeds a level) and by the occupancy-map import (a binary grid: free 1,
occupied 0, level ½).

* :func:`trace_rings` — marching squares over the samples with linear interpolation on the
  grid edges, free on the left of every ring (counter-clockwise around a free region,
  clockwise around a hole). A cell whose four corners alternate (a saddle) joins its two free
  corners when the mean of the four samples exceeds the level, else keeps them apart; on a
  binary grid (mean exactly ½) two free samples that touch only diagonally stay apart, so
  free space is 4-connected, as a robot needs.
* :func:`main_region` — the largest free region: its outer ring and its holes (islands).
* :func:`simplify_rings` — Douglas–Peucker on every ring to a tolerance, then re-simplified
  with half the tolerance where two rings (or two pieces of one) would touch or cross, so the
  result keeps the traced topology.
* :func:`sharpen_corners` — a corner of two straight walls, which a grid cuts off by up to one
  cell, put back at the intersection of the two walls.

Sample ``(row, col)`` sits at ``(ox + col·res, oy + row·res)``: rows grow with y.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "main_region",
    "ring_area",
    "rings_touching",
    "sharpen_corners",
    "simplify_ring",
    "simplify_rings",
    "trace_rings",
]

# The four sides of a cell in counter-clockwise order (bottom, right, top, left); corner k is
# where side k starts: corners (0, 0), (0, 1), (1, 1), (1, 0) as (row, col) offsets.
_CORNERS = ((0, 0), (0, 1), (1, 1), (1, 0))


def _segment_table() -> dict[tuple[int, bool], tuple[tuple[int, int], ...]]:
    """For each corner pattern (bit k set: corner k free) and saddle choice (free corners
    joined), the cell's directed segments as (from side, to side), free on the left.

    Walking the cell's sides counter-clockwise, a crossing is an exit (free to occupied) or
    an entry. A segment from an exit to the next entry cuts off the occupied corner between
    them; from an exit to the previous entry, the free corner. Two crossings: one segment,
    both rules agree. Four (a saddle): cutting off the occupied corners joins the free ones."""
    table: dict[tuple[int, bool], tuple[tuple[int, int], ...]] = {}
    for case in range(16):
        free = [bool(case >> k & 1) for k in range(4)]
        sides = [k for k in range(4) if free[k] != free[(k + 1) % 4]]
        exits = [k for k in sides if free[k]]
        for joined in (False, True):
            segs = []
            for x in exits:
                i = sides.index(x)
                step = 1 if joined or len(sides) == 2 else -1
                segs.append((x, sides[(i + step) % len(sides)]))
            table[case, joined] = tuple(segs)
    return table


_TABLE = _segment_table()


def trace_rings(
    field: np.ndarray, level: float, origin: tuple[float, float], resolution: float
) -> list[np.ndarray]:
    """The closed rings (k+1, 2) (first == last) bounding ``{field > level}``, free on the left.

    ``field`` (H, W) is sampled at ``(ox + col·res, oy + row·res)``; its border samples must
    not exceed the level (pad it), so that every ring closes inside the grid. Crossings lie on
    the grid edges where the linear interpolation of the two samples equals the level."""
    f = np.asarray(field, dtype=float)
    if f.ndim != 2 or min(f.shape) < 2:
        raise ValueError(f"field: expected a 2-D grid of at least 2 × 2 samples, got {f.shape}")
    free = f > level
    if free[0].any() or free[-1].any() or free[:, 0].any() or free[:, -1].any():
        raise ValueError("field: the border samples must not exceed the level (pad the field)")
    h, w = f.shape
    ox, oy = origin
    # Crossing coordinates per grid edge, ids: horizontal edge (r, c)-(r, c+1) is r·w + c,
    # vertical edge (r, c)-(r+1, c) is h·w + r·w + c.
    n_edges = 2 * h * w
    xs = np.full(n_edges, np.nan)
    ys = np.full(n_edges, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (level - f[:, :-1]) / (f[:, 1:] - f[:, :-1])  # (H, W-1)
        r, c = np.nonzero(free[:, :-1] != free[:, 1:])
        ids = r * w + c
        xs[ids] = ox + (c + t[r, c]) * resolution
        ys[ids] = oy + r * resolution
        t = (level - f[:-1, :]) / (f[1:, :] - f[:-1, :])  # (H-1, W)
        r, c = np.nonzero(free[:-1, :] != free[1:, :])
        ids = h * w + r * w + c
        xs[ids] = ox + c * resolution
        ys[ids] = oy + (r + t[r, c]) * resolution
    # Each cell's sides as edge ids: bottom, right, top, left.
    rr, cc = np.meshgrid(np.arange(h - 1), np.arange(w - 1), indexing="ij")
    side_ids = np.stack(
        [rr * w + cc, h * w + rr * w + cc + 1, (rr + 1) * w + cc, h * w + rr * w + cc], axis=-1
    )  # (H-1, W-1, 4)
    case = sum(free[dr : h - 1 + dr, dc : w - 1 + dc].astype(np.int64) << k
               for k, (dr, dc) in enumerate(_CORNERS))  # fmt: skip
    corners = [f[dr : h - 1 + dr, dc : w - 1 + dc] for dr, dc in _CORNERS]
    joined = (corners[0] + corners[1] + corners[2] + corners[3]) / 4.0 > level
    nxt = np.full(n_edges, -1, dtype=np.int64)
    for (kind, join), segs in _TABLE.items():
        if not segs:
            continue
        cells = (case == kind) & (joined == join)
        if not cells.any():
            continue
        sides = side_ids[cells]  # (n, 4)
        for a, b in segs:
            nxt[sides[:, a]] = sides[:, b]
    return _link(nxt, xs, ys)


def _link(nxt: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> list[np.ndarray]:
    """Follow ``nxt`` (edge id → next edge id, −1 none) into closed rings of coordinates."""
    rings = []
    todo = nxt >= 0
    for start in np.flatnonzero(todo):
        if not todo[start]:
            continue
        ids = [int(start)]
        todo[start] = False
        k = int(nxt[start])
        while k != start:
            ids.append(k)
            todo[k] = False
            k = int(nxt[k])
        ids.append(int(start))
        pts = np.column_stack([xs[ids], ys[ids]])
        keep = np.ones(len(pts), dtype=bool)  # drop repeats (a sample exactly at the level)
        keep[1:] = np.any(pts[1:] != pts[:-1], axis=1)
        pts = pts[keep]
        if len(pts) >= 4:
            rings.append(pts)
    return rings


def ring_area(ring: np.ndarray) -> float:
    """Signed area of a closed ring (> 0 counter-clockwise)."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))


def _inside(point: np.ndarray, ring: np.ndarray) -> bool:
    """Even-odd test of one point against a closed ring."""
    x0, y0, x1, y1 = ring[:-1, 0], ring[:-1, 1], ring[1:, 0], ring[1:, 1]
    px, py = float(point[0]), float(point[1])
    crosses = (y0 > py) != (y1 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
    return bool(np.count_nonzero(crosses & (px < x_at)) % 2)


def main_region(
    rings: list[np.ndarray], min_hole_area: float = 0.0
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The largest free region of traced ``rings`` (free on the left): its outer ring (the
    counter-clockwise ring of largest area) and its holes (clockwise rings directly inside it,
    each of area at least ``min_hole_area`` m²). Other free regions (outside it, or in pockets
    inside its holes) are left out."""
    outers = [r for r in rings if ring_area(r) > 0]
    if not outers:
        raise ValueError("no free region")
    outer = max(outers, key=ring_area)
    holes = [r for r in rings if ring_area(r) < 0 and _inside(r[0], outer)]
    lo = np.array([h.min(axis=0) for h in holes]).reshape(-1, 2)
    hi = np.array([h.max(axis=0) for h in holes]).reshape(-1, 2)
    kept = []
    for i, hole in enumerate(holes):
        if -ring_area(hole) < min_hole_area:
            continue
        around = np.flatnonzero(np.all((lo <= hole[0]) & (hole[0] <= hi), axis=1))
        if any(_inside(hole[0], holes[j]) for j in around if j != i):
            continue  # a hole in a pocket of free space inside another hole
        kept.append(hole)
    return outer, kept


# -- simplification ------------------------------------------------------------------------------
def _douglas_peucker(points: np.ndarray, tol: float) -> np.ndarray:
    """Indices of the points of an open chain (n, 2) that Douglas–Peucker keeps at ``tol``:
    every dropped point is within ``tol`` of the chord between the kept points around it."""
    keep = np.zeros(len(points), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(points) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        a, b = points[i], points[j]
        mid = points[i + 1 : j]
        ab = b - a
        length = math.hypot(ab[0], ab[1])
        if length == 0.0:
            d = np.hypot(mid[:, 0] - a[0], mid[:, 1] - a[1])
        else:
            d = np.abs(ab[0] * (mid[:, 1] - a[1]) - ab[1] * (mid[:, 0] - a[0])) / length
            # beyond the chord's ends the distance is to the nearer end
            s = ((mid - a) @ ab) / (length * length)
            before, after = s < 0, s > 1
            d[before] = np.hypot(*(mid[before] - a).T)
            d[after] = np.hypot(*(mid[after] - b).T)
        k = int(np.argmax(d))
        if d[k] > tol:
            m = i + 1 + k
            keep[m] = True
            stack += [(i, m), (m, j)]
    return np.flatnonzero(keep)


def simplify_ring(ring: np.ndarray, tol: float) -> np.ndarray:
    """A closed ring simplified by Douglas–Peucker to ``tol`` (m): split at its first point and
    the point farthest from it, each half simplified; at least a triangle is kept."""
    if tol <= 0 or len(ring) <= 4:
        return ring.copy()
    pts = ring[:-1]
    far = int(np.argmax(np.hypot(*(pts - pts[0]).T)))
    first = _douglas_peucker(ring[: far + 1], tol)
    second = far + _douglas_peucker(ring[far:], tol)
    idx = np.concatenate([first, second[1:]])  # ends with the closing point (index len-1)
    if len(idx) < 4:  # a triangle at least: add the point farthest from both kept ones
        d = np.hypot(*(pts - pts[0]).T) + np.hypot(*(pts - pts[far]).T)
        idx = np.array([*sorted({0, far, int(np.argmax(d))}), len(ring) - 1])
    return ring[idx].copy()


def simplify_rings(rings: list[np.ndarray], tol: float) -> list[np.ndarray]:
    """Every ring simplified to ``tol`` (:func:`simplify_ring`); rings that would then touch or
    cross (each other or themselves, :func:`rings_touching`) are simplified again from the
    traced ring at half the tolerance, until none does (at tolerance 0 the traced rings,
    which never touch)."""
    tols = [tol] * len(rings)
    out = [simplify_ring(r, tol) for r in rings]
    while True:
        bad = rings_touching(out)
        if not bad:
            return out
        for i in bad:
            tols[i] = tols[i] / 2 if tols[i] > tol / 64 else 0.0
            out[i] = simplify_ring(rings[i], tols[i])


def rings_touching(rings: list[np.ndarray]) -> set[int]:
    """Indices of the closed rings that touch or cross another ring or themselves (segments
    that are not neighbours on one ring). Segments are bucketed on a grid of cells about the
    mean segment length, and only pairs sharing a cell are tested."""
    if not rings:
        return set()
    segs = np.vstack([np.hstack([r[:-1], r[1:]]) for r in rings])  # (S, 4)
    owner = np.concatenate([np.full(len(r) - 1, i) for i, r in enumerate(rings)])  # (S,)
    index = np.concatenate([np.arange(len(r) - 1) for r in rings])  # (S,) position in ring
    count = np.array([len(r) - 1 for r in rings])[owner]  # (S,) segments of the owning ring
    lo = np.minimum(segs[:, :2], segs[:, 2:])
    hi = np.maximum(segs[:, :2], segs[:, 2:])
    cell = max(float(np.mean(np.hypot(*(hi - lo).T))), 1e-9) * 2.0
    origin = lo.min(axis=0)
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    span = c1 - c0 + 1
    n_cells = span[:, 0] * span[:, 1]
    seg_of = np.repeat(np.arange(len(segs)), n_cells)
    k = np.arange(len(seg_of)) - np.repeat(np.cumsum(n_cells) - n_cells, n_cells)
    cx = c0[seg_of, 0] + k % span[seg_of, 0]
    cy = c0[seg_of, 1] + k // span[seg_of, 0]
    key = cx * (int(c1[:, 1].max()) + 2) + cy
    order = np.argsort(key, kind="stable")
    key, seg_of = key[order], seg_of[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], len(key)]
    bad: set[int] = set()
    for a, b in zip(starts, ends, strict=True):
        if b - a < 2:
            continue
        s = seg_of[a:b]
        i, j = np.triu_indices(len(s), 1)
        si, sj = s[i], s[j]
        same = owner[si] == owner[sj]
        gap = np.abs(index[si] - index[sj])
        neighbours = same & ((gap == 1) | (gap == count[si] - 1))
        si, sj = si[~neighbours], sj[~neighbours]
        hit = _segments_touch(segs[si], segs[sj])
        bad.update(owner[si[hit]].tolist())
        bad.update(owner[sj[hit]].tolist())
    return bad


def _segments_touch(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether segments p (n, 4) and q (n, 4) touch or cross (closed segments)."""

    def orient(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray,
               cx: np.ndarray, cy: np.ndarray) -> np.ndarray:  # fmt: skip
        return np.sign((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))

    o1 = orient(p[:, 0], p[:, 1], p[:, 2], p[:, 3], q[:, 0], q[:, 1])
    o2 = orient(p[:, 0], p[:, 1], p[:, 2], p[:, 3], q[:, 2], q[:, 3])
    o3 = orient(q[:, 0], q[:, 1], q[:, 2], q[:, 3], p[:, 0], p[:, 1])
    o4 = orient(q[:, 0], q[:, 1], q[:, 2], q[:, 3], p[:, 2], p[:, 3])
    lo_p, hi_p = np.minimum(p[:, :2], p[:, 2:]), np.maximum(p[:, :2], p[:, 2:])
    lo_q, hi_q = np.minimum(q[:, :2], q[:, 2:]), np.maximum(q[:, :2], q[:, 2:])
    boxes = np.all((lo_p <= hi_q) & (lo_q <= hi_p), axis=1)
    return np.asarray(boxes & (o1 * o2 <= 0) & (o3 * o4 <= 0))


def sharpen_corners(
    ring: np.ndarray, size: float, min_turn: float = math.radians(20)
) -> np.ndarray:
    """A closed ring with its cut corners put back: a run of segments each shorter than
    ``size`` between two longer segments that turn by at least ``min_turn`` is replaced by the
    intersection of the two long segments' lines, when that point lies within the run's length
    (at least ``size``) of every vertex of the run. A grid cuts a corner of two straight walls
    within a cell or two, so ``size`` is about one and a half cells."""
    pts = ring[:-1]
    n = len(pts)
    long = np.hypot(*(np.roll(pts, -1, axis=0) - pts).T) >= size  # segment k: pts[k] → pts[k+1]
    if long.all() or not long.any():
        return ring.copy()
    shift = int(np.flatnonzero(long)[0])
    pts, long = np.roll(pts, -shift, axis=0), np.roll(long, -shift)  # segment 0 is long
    out: list[np.ndarray] = []
    replaced = -1  # a long segment whose start is replaced by the corner before it
    k = 0
    while k < n:
        if long[k]:
            if k != replaced:
                out.append(pts[k])
            k += 1
            continue
        m = k
        while m < n and not long[m]:
            m += 1  # segments k … m−1 are short; segment m (mod n) is long
        end, after = pts[m % n], pts[(m + 1) % n]
        corner = _line_intersection(pts[k - 1], pts[k], end, after, min_turn)
        run = pts[k : m + 1] if m < n else np.vstack([pts[k:], pts[:1]])
        reach = max(size, float(np.hypot(*np.diff(run, axis=0).T).sum()))
        if corner is not None and bool(np.all(np.hypot(*(run - corner).T) <= reach)):
            if m < n:
                out.append(corner)
                replaced = m
            else:
                out[0] = corner  # the run wraps to segment 0: its start is the corner
        else:
            out.extend(pts[k:m])
        k = m
    verts = np.array(out)
    keep = np.any(verts != np.roll(verts, 1, axis=0), axis=1)  # a corner on its neighbour: once
    if keep.sum() < 3:
        return ring.copy()
    sharp = np.vstack([verts[keep], verts[keep][:1]])
    # Corners only add the small triangles they cut off: a ring that turned inside out or
    # changed by more than a strip of ``size`` along its length was no pair of straight walls.
    before, after = ring_area(ring), ring_area(sharp)
    perimeter = float(np.hypot(*np.diff(ring, axis=0).T).sum())
    if before * after <= 0 or abs(after - before) > size * perimeter:
        return ring.copy()
    return sharp


def _line_intersection(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray, min_turn: float
) -> np.ndarray | None:
    """Where the lines a0→a1 and b0→b1 meet, if they turn by at least ``min_turn``."""
    u, v = a1 - a0, b1 - b0
    cross = float(u[0] * v[1] - u[1] * v[0])
    if math.atan2(abs(cross), float(u @ v)) < min_turn:
        return None
    s = float((b0 - a0)[0] * v[1] - (b0 - a0)[1] * v[0]) / cross
    return np.asarray(a0 + s * u)

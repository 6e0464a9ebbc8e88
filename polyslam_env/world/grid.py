"""Free-space rasters of a layout: which grid cells a robot centre may occupy.

Used by the procedural generators (to check connectivity), by tests, and by the coverage
metric, which takes a boolean mask plus its origin and resolution.

Conventions: cell ``(row, col)`` covers ``[ox + col·res, ox + (col+1)·res) ×
[oy + row·res, oy + (row+1)·res)``, so rows grow with y and columns with x; a cell's state is
decided at its centre. A cell is free when its centre is

* inside the outer boundary (the bounding box when the layout has no closed wall),
* outside every other closed wall polyline — those are solid islands (rocks, furniture),
* farther than ``max(inflate, resolution / 2)`` from every wall segment and pillar surface
  (:func:`blocking_distance`).

The half-cell floor gives every wall a thickness of at least one cell, so two 4-adjacent free
cells never lie on opposite sides of a wall: connectivity (4-neighbourhood) cannot leak
through a zero-thickness wall, whatever ``inflate`` is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from polyslam_env.world.layout import Layout

#: Cell–segment pairs measured per vectorised chunk (bounds the temporary arrays).
_PAIRS_PER_CHUNK = 200_000


@dataclass(frozen=True, eq=False)
class FreeGrid:
    """A boolean free-space raster with its placement in the world."""

    mask: np.ndarray  # (H, W) bool, True = free
    origin: tuple[float, float]  # (x, y) of the lower-left corner of cell (0, 0), m
    resolution: float  # cell side, m

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.mask.shape[0]), int(self.mask.shape[1]))

    @property
    def free_area(self) -> float:
        """Area of the free cells (m²)."""
        return float(np.count_nonzero(self.mask)) * self.resolution**2

    def xs(self) -> np.ndarray:  # (W,)
        """x of the cell centres of each column."""
        return self.origin[0] + (np.arange(self.mask.shape[1]) + 0.5) * self.resolution

    def ys(self) -> np.ndarray:  # (H,)
        """y of the cell centres of each row."""
        return self.origin[1] + (np.arange(self.mask.shape[0]) + 0.5) * self.resolution

    def centres(self) -> np.ndarray:  # (H, W, 2)
        """World coordinates of every cell centre."""
        gx, gy = np.meshgrid(self.xs(), self.ys())
        return np.stack([gx, gy], axis=-1)

    def cell_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, in_grid) of the cells holding points (…, 2); indices clipped."""
        pts = np.asarray(points, dtype=float)
        col = np.floor((pts[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((pts[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        h, w = self.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        return np.clip(row, 0, h - 1), np.clip(col, 0, w - 1), inside

    def free_at(self, points: np.ndarray) -> np.ndarray:
        """Whether each point (…, 2) falls in a free cell (False off the grid)."""
        row, col, inside = self.cell_of(points)
        return np.asarray(inside & self.mask[row, col])


def free_space_grid(layout: Layout, resolution: float, inflate: float = 0.0) -> FreeGrid:
    """Rasterise the free space of ``layout`` at ``resolution`` with walls grown by ``inflate``.

    ``inflate`` is usually the robot radius, so free cells are where the robot centre fits.
    """
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution: must be a finite number > 0, got {resolution!r}")
    if not (math.isfinite(inflate) and inflate >= 0):
        raise ValueError(f"inflate: must be a finite number >= 0, got {inflate!r}")
    x0, y0, x1, y1 = layout.bounds
    origin = (x0 - resolution, y0 - resolution)
    width = math.ceil((x1 - x0) / resolution) + 2
    height = math.ceil((y1 - y0) / resolution) + 2
    grid = FreeGrid(np.zeros((height, width), dtype=bool), origin, resolution)
    xs, ys = grid.xs(), grid.ys()

    mask = _inside_outer(layout, xs, ys)
    for poly in _islands(layout):
        mask &= ~polygon_mask(poly, xs, ys)
    threshold = blocking_distance(resolution, inflate)
    mask &= ~_near_segments(layout.segments, grid.shape, origin, resolution, threshold)
    mask &= ~_near_pillars(layout.pillars, xs, ys, threshold)
    return FreeGrid(mask, origin, resolution)


def blocking_distance(resolution: float, inflate: float) -> float:
    """Distance from a wall within which a cell centre is blocked: ``max(inflate, res/2)``.

    The half cell is padded by one part in a million so that a wall lying exactly on a cell
    border (centres exactly half a cell away on both sides) still blocks one side despite
    round-off.
    """
    return max(inflate, 0.5 * resolution * (1.0 + 1e-6))


def label_components(grid: FreeGrid) -> tuple[np.ndarray, int]:
    """4-connected components of the free cells: labels (H, W) int (0 = blocked), count."""
    labels, count = ndimage.label(grid.mask)
    return np.asarray(labels), int(count)


def is_connected(grid: FreeGrid) -> bool:
    """Whether the free cells form exactly one 4-connected component."""
    return label_components(grid)[1] == 1


def connected_up_to_slivers(grid: FreeGrid, max_cells: int = 2) -> bool:
    """Whether the free cells form one 4-connected component, up to raster slivers: other
    components of at most ``max_cells`` cells that touch the largest one diagonally.

    Where two walls meet at an angle to the raster, a cell just beyond the inflation from
    both can have its only free neighbour on the diagonal: a separate 4-component of one or
    two cells although the robot's centre reaches it through the corner's free wedge. A
    region the robot really cannot reach (behind a door narrower than the robot) is a room
    of free cells, not a sliver touching the rest at a corner."""
    labels, count = label_components(grid)
    if count <= 1:
        return count == 1
    sizes = np.bincount(labels.ravel())[1:]  # (count,)
    main = int(np.argmax(sizes)) + 1
    near = ndimage.binary_dilation(labels == main, structure=np.ones((3, 3), dtype=bool))
    for k in range(1, count + 1):
        if k == main:
            continue
        if sizes[k - 1] > max_cells or not near[labels == k].all():
            return False
    return True


def component_at(grid: FreeGrid, points: np.ndarray) -> np.ndarray:
    """Component label (…,) of the cell holding each point; 0 when blocked or off the grid."""
    labels, _ = label_components(grid)
    row, col, inside = grid.cell_of(points)
    return np.where(inside, labels[row, col], 0)


def polygon_mask(poly: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Even-odd inside test of the grid points (xs × ys) against a closed polyline: (H, W).

    Scan-line form of :func:`~polyslam_env.world.layout.points_in_polygon`: the crossings of
    each row with the edges are binned into columns and a cumulative sum gives, for every
    cell, the parity of the crossings to its left. O(H·E + H·W) instead of O(H·W·E).
    """
    ax, ay, bx, by = poly[:-1, 0], poly[:-1, 1], poly[1:, 0], poly[1:, 1]
    y = ys[:, None]  # (H, 1)
    crosses = (ay > y) != (by > y)  # (H, E)
    rows, edges = np.nonzero(crosses)
    yr = ys[rows]
    x_at = ax[edges] + (yr - ay[edges]) * (bx[edges] - ax[edges]) / (by[edges] - ay[edges])
    # First column whose centre lies strictly right of the crossing.
    first = np.searchsorted(xs, x_at, side="right")
    counts = np.zeros((len(ys), len(xs) + 1), dtype=np.int64)
    np.add.at(counts, (rows, first), 1)
    return np.asarray(np.cumsum(counts[:, :-1], axis=1) % 2 == 1)


def _inside_outer(layout: Layout, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    outer = layout.outer_boundary
    if outer is not None:
        return polygon_mask(outer, xs, ys)
    bx0, by0, bx1, by1 = layout.bounds
    in_x = (xs > bx0) & (xs < bx1)
    in_y = (ys > by0) & (ys < by1)
    return np.asarray(in_y[:, None] & in_x[None, :])


def _islands(layout: Layout) -> list[np.ndarray]:
    """Closed wall polylines other than the outer boundary (same rule as Layout)."""
    outer = layout.outer_boundary
    return [
        w for w in layout.walls if len(w) >= 4 and np.array_equal(w[0], w[-1]) and w is not outer
    ]


def _near_segments(
    segs: np.ndarray, shape: tuple[int, int], origin: tuple[float, float], res: float, thr: float
) -> np.ndarray:
    """(H, W) cells whose centre is within ``thr`` of a segment (S, 4).

    Segments are cut into pieces no longer than a few cells; each piece is measured only
    against the fixed k × k window of cells around it, all pieces at once (in chunks). The
    cost follows the wall length, not cells × segments. Cutting a segment does not change the
    distance to it, so the result is exact.
    """
    near = np.zeros(shape, dtype=bool)
    if len(segs) == 0:
        return near
    max_len = max(thr, 2.0 * res)
    pieces = _split_segments(segs, max_len)  # (P, 4)
    k = math.ceil((max_len + 2.0 * thr) / res) + 1
    lo = np.minimum(pieces[:, 0:2], pieces[:, 2:4]) - thr  # (P, 2)
    first = np.ceil((lo - np.asarray(origin)) / res - 0.5).astype(np.int64)  # (P, 2)
    steps = np.arange(k)
    chunk = max(1, _PAIRS_PER_CHUNK // (k * k))
    for c0 in range(0, len(pieces), chunk):
        sl = slice(c0, c0 + chunk)
        cols = first[sl, 0, None] + steps  # (p, k)
        rows = first[sl, 1, None] + steps  # (p, k)
        cx = (origin[0] + (cols + 0.5) * res)[:, None, :]  # (p, 1, k)
        cy = (origin[1] + (rows + 0.5) * res)[:, :, None]  # (p, k, 1)
        ax, ay, bx, by = (pieces[sl, i, None, None] for i in range(4))  # each (p, 1, 1)
        dx, dy = bx - ax, by - ay
        t = np.clip(((cx - ax) * dx + (cy - ay) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
        hit = (cx - ax - t * dx) ** 2 + (cy - ay - t * dy) ** 2 <= thr * thr  # (p, k, k)
        r = np.broadcast_to(rows[:, :, None], hit.shape)[hit]
        c = np.broadcast_to(cols[:, None, :], hit.shape)[hit]
        ok = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
        near[r[ok], c[ok]] = True
    return near


def _split_segments(segs: np.ndarray, max_len: float) -> np.ndarray:
    """Segments (S, 4) cut into equal pieces no longer than ``max_len``: (P, 4)."""
    length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    n = np.maximum(1, np.ceil(length / max_len).astype(np.int64))  # (S,)
    owner = np.repeat(np.arange(len(segs)), n)  # (P,)
    start = np.arange(len(owner)) - np.repeat(np.cumsum(n) - n, n)  # piece index in segment
    t0 = (start / n[owner])[:, None]
    t1 = ((start + 1) / n[owner])[:, None]
    a, b = segs[owner, 0:2], segs[owner, 2:4]
    return np.hstack([a + t0 * (b - a), a + t1 * (b - a)])


def _near_pillars(pillars: np.ndarray, xs: np.ndarray, ys: np.ndarray, thr: float) -> np.ndarray:
    """(H, W) cells whose centre is within ``thr`` of a pillar surface (or inside it)."""
    near = np.zeros((len(ys), len(xs)), dtype=bool)
    for px, py, pr in pillars:
        dx = xs[None, :] - px
        dy = ys[:, None] - py
        near |= np.hypot(dx, dy) <= pr + thr
    return near

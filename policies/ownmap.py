"""The frontier planner's own map: a robot's occupancy belief in its own start frame, with the
obstacle clearance and the frontier kept up to date where cells change.

Each step :meth:`OwnMap.fold` folds what the robot observes — the egocentric local grid
(occupied = its own polynomials, free = cells its beams swept), its beams and its own
footprint — into the grids in one compiled call, then brings the layers up to date in
another, touching only the cells that changed and their neighbourhoods
(:mod:`policies.ownmap_kernels`): the squared distance to the nearest obstacle (exact up to
the planner's soft-cost radius), the passable cells, and the frontier as the readable planner
defined it on the whole map (free cells next to unknown space after the gaps between the beams'
stripes are closed). ``tests/policies/reference.py`` computes the same layers with scipy on the
whole grid; the tests compare them at every step of real episodes.
"""

from __future__ import annotations

import math

import numpy as np

from policies import ownmap_kernels as kernels
from polyslam_env.core import raster

__all__ = ["OwnMap"]


class OwnMap:
    """A robot's occupancy belief in its own start frame: a square grid of ``size`` m with
    ``resolution`` m cells, rows = y, plus the planner's layers for a robot that keeps
    ``inflate`` m from obstacles and pays a soft cost within ``soft`` m of them, the gaps
    between beam stripes closed over ``close_cells`` cells (the defaults: the frontier
    policy's for the default robot, radius 0.065 m, at 0.1 m cells).

    ``free``, ``occ``, ``hit`` (n, n) bool are the grids (swept by a beam or visited; last
    seen occupied in the local grid; a beam ended here). Write them through :meth:`fold`;
    after writing them directly, call :meth:`rebuild`.
    """

    def __init__(
        self,
        size: float,
        resolution: float,
        inflate: float = 0.155,
        soft: float = 0.465,
        close_cells: int = 3,
    ) -> None:
        if not 0.0 <= inflate < soft:
            raise ValueError(f"own map: need 0 <= inflate < soft, got {inflate}, {soft}")
        if close_cells < 1:
            raise ValueError(f"own map: close_cells must be >= 1, got {close_cells}")
        self.close_cells = int(close_cells)
        self.res = float(resolution)
        self.n = math.ceil(size / resolution)
        self.origin = -0.5 * self.n * self.res  # x and y of the lower-left corner
        self.inflate, self.soft = float(inflate), float(soft)
        #: clearance is exact up to this many cells (then "far": beyond the soft radius)
        self.reach = math.ceil(self.soft / self.res)
        self.r2 = self.reach * self.reach
        if self.r2 + 1 > np.iinfo(np.int16).max:
            raise ValueError(f"own map: soft radius {soft} m is too wide for {resolution} m cells")
        d2 = np.arange(self.r2 + 2)
        clearance = np.sqrt(d2.astype(float)) * self.res  # m, as scipy's distance transform
        #: whether a clearance of √d2 cells is above the inflation radius (d2 = r2 + 1: far)
        self.passable_d2 = clearance > self.inflate
        self.passable_d2[-1] = True
        #: the soft cost near obstacles of a clearance of √d2 cells (1 from ``soft`` m on)
        self.cost_d2 = 1.0 + 4.0 * np.clip((self.soft - clearance) / self.soft, 0.0, 1.0)
        self.cost_d2[-1] = 1.0
        cells = self.n * self.n
        self._grids = tuple(np.zeros(cells, dtype=bool) for _ in range(3))  # free, occ, hit
        self._touched = np.empty(0, dtype=np.int64)
        self._lattice: tuple[np.ndarray, np.ndarray] | None = None  # local grid lattice
        self._fractions: np.ndarray | None = None  # beam sample positions
        self._footprint: np.ndarray | None = None  # (P, 2) offsets of the robot's disc
        self._clear_layers()

    def _clear_layers(self) -> None:
        cells = self.n * self.n
        free, occ, hit = self._grids
        self.layers = kernels.Layers(
            free,
            occ,
            hit,
            obst=np.zeros(cells, dtype=bool),
            known=np.zeros(cells, dtype=bool),
            d2=np.full(cells, self.r2 + 1, dtype=np.int16),
            passable=np.zeros(cells, dtype=bool),
            frontier=np.zeros(cells, dtype=bool),
            frontier_cells=np.empty(cells, dtype=np.int64),
            frontier_at=np.full(cells, -1, dtype=np.int32),
            frontier_count=np.zeros(1, dtype=np.int64),
            known_near=np.zeros(cells, dtype=np.uint16),
            open_near=np.full(cells, kernels.diamond_cells(self.close_cells), np.uint16),
            closed_near=np.zeros(cells, dtype=np.uint8),
            eroded_near=np.full(cells, 5, dtype=np.uint8),
            unknown_near=np.full(cells, 9, dtype=np.uint8),
            passable_d2=self.passable_d2,
            cost_d2=self.cost_d2,
            bbox=np.array([self.n, -1, self.n, -1], dtype=np.int64),
            n=self.n,
            reach=self.reach,
            rad=self.close_cells,
            res=self.res,
            origin=self.origin,
            inflate=self.inflate,
            soft=self.soft,
        )

    # -- the grids ---------------------------------------------------------------------------
    @property
    def free(self) -> np.ndarray:  # (n, n) bool
        return self.layers.free.reshape(self.n, self.n)

    @property
    def occ(self) -> np.ndarray:  # (n, n) bool
        return self.layers.occ.reshape(self.n, self.n)

    @property
    def hit(self) -> np.ndarray:  # (n, n) bool
        return self.layers.hit.reshape(self.n, self.n)

    @property
    def obstacles(self) -> np.ndarray:  # (n, n) bool
        return self.occ | self.hit

    @property
    def d2(self) -> np.ndarray:  # (n, n) int: squared clearance in cells², r2 + 1 beyond reach
        return self.layers.d2.reshape(self.n, self.n)

    @property
    def passable(self) -> np.ndarray:  # (n, n) bool
        return self.layers.passable.reshape(self.n, self.n)

    @property
    def frontier(self) -> np.ndarray:  # (n, n) bool, on the whole map
        return self.layers.frontier.reshape(self.n, self.n)

    def cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) (M,) of points (M, 2), only for points inside the grid."""
        ij, ok = self.index(points)
        return ij[ok, 1], ij[ok, 0]

    def index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(col, row) (M, 2) of every point (M, 2), and whether it lies inside the grid (M,)."""
        ij = np.floor((points - self.origin) / self.res).astype(np.intp)
        return ij, np.all((ij >= 0) & (ij < self.n), axis=1)

    def cell(self, x: float, y: float) -> tuple[int, int] | None:
        """(row, col) of the own-frame point (x, y), None outside the grid."""
        col, row = (
            math.floor((x - self.origin) / self.res),
            math.floor((y - self.origin) / self.res),
        )
        return (row, col) if 0 <= row < self.n and 0 <= col < self.n else None

    def centre(self, row: int, col: int) -> np.ndarray:  # (2,)
        return np.array([col + 0.5, row + 0.5]) * self.res + self.origin

    # -- folding observations in -------------------------------------------------------------
    def fold(
        self,
        pose: np.ndarray,
        local_occ: np.ndarray,
        local_free: np.ndarray,
        cell: float,
        angles: np.ndarray,
        ranges: np.ndarray,
        max_range: float,
        radius: float,
    ) -> None:
        """Fold one step seen from ``pose`` (3,) in: the egocentric local grid's occupied and
        free cells ``local_occ``, ``local_free`` (G, G) bool of ``cell`` m; the beams at
        ``angles`` (B,) reading ``ranges`` (B,) (inf: no return) up to ``max_range``: free up
        to half a cell short of a hit, and the hit cells
        (:func:`polyslam_env.core.raster.scan_cells`, as the env's belief grids); and the
        robot's own disc of ``radius`` m, free (it has been there). Then the layers."""
        lattice, lattice_cell = self._local_lattice(local_occ.shape[0], cell)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        turned = lattice @ np.array([[c, s], [-s, c]])  # (L, 2), the position added in fold
        if self._fractions is None:
            self._fractions = raster.beam_fractions(max_range, self.res)
        disc = self._disc(radius)
        most = 2 * len(turned) + len(angles) * (len(self._fractions) + 1) + len(disc)
        if len(self._touched) < most:
            self._touched = np.empty(most, dtype=np.int64)
        kernels.fold(
            self.layers, turned, lattice_cell, local_free.reshape(-1), local_occ.reshape(-1),
            pose, angles, ranges, max_range, self._fractions, disc, self._touched,
        )  # fmt: skip

    def integrate_local(self, pose: np.ndarray, local: np.ndarray, cell: float) -> None:
        """Fold an egocentric (3, G, G) bool grid (occupied, free, unknown) of ``cell`` m
        cells seen from ``pose`` (3,) in, alone (:meth:`fold` does it with the beams)."""
        lattice, lattice_cell = self._local_lattice(local.shape[1], cell)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        turned = lattice @ np.array([[c, s], [-s, c]])  # (L, 2)
        if len(self._touched) < 2 * len(turned):
            self._touched = np.empty(2 * len(turned), dtype=np.int64)
        kernels.fold(
            self.layers, turned, lattice_cell, local[1].reshape(-1), local[0].reshape(-1), pose,
            np.zeros(0), np.zeros(0), 1.0, np.zeros(1), np.zeros((0, 2)), self._touched,
        )  # fmt: skip

    def rebuild(self) -> None:
        """Recompute every layer from the grids (after they were written directly)."""
        self._clear_layers()
        free, occ, hit = self._grids
        kernels.update_layers(np.flatnonzero(free | occ | hit), self.layers)

    def _local_lattice(self, g: int, cell: float) -> tuple[np.ndarray, np.ndarray]:
        """Points (L, 2) sampling a (g, g) egocentric grid of ``cell`` m cells on a k × k
        lattice per cell, finer than our cells' side / √2 (so any rotation of a cell covers
        all our cells it overlaps), and the local cell (L,) of each point (flat id)."""
        if self._lattice is None:
            k = max(1, math.ceil(cell * math.sqrt(2) / self.res))
            sub = (np.arange(k) + 0.5) / k - 0.5  # (k,) offsets in cells
            q = (np.arange(g) - g // 2)[:, None] + sub[None, :]  # (G, k)
            qs = q.reshape(-1) * cell  # (G·k,)
            xs, ys = np.meshgrid(qs, qs)  # columns x, rows y: (G·k, G·k)
            ego = np.stack([xs.reshape(-1), ys.reshape(-1)], axis=1)  # (G²k², 2)
            idx = np.arange(g * k) // k  # lattice row or column → local row or column
            owner = (idx[:, None] * g + idx[None, :]).reshape(-1)  # (G²k²,)
            self._lattice = (ego, owner)
        return self._lattice

    def _disc(self, radius: float) -> np.ndarray:  # (P, 2)
        """Offsets sampling the robot's disc of ``radius`` m (half-cell spacing)."""
        if self._footprint is None:
            rr = radius + 0.5 * self.res
            offs = np.mgrid[-rr : rr + 1e-9 : self.res / 2, -rr : rr + 1e-9 : self.res / 2]
            pts = offs.reshape(2, -1).T  # (M, 2)
            self._footprint = pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius]
        return self._footprint

    # -- the planner's view ------------------------------------------------------------------
    def bbox(self, pose: np.ndarray, margin: int) -> tuple[slice, slice]:
        """The window of known cells plus the robot, grown by ``margin`` cells."""
        r0, r1, c0, c1 = self.layers.bbox.tolist()
        robot = self.cell(pose[0], pose[1])
        if robot is not None:
            r0, r1 = min(r0, robot[0]), max(r1, robot[0])
            c0, c1 = min(c0, robot[1]), max(c1, robot[1])
        if r1 < 0:
            return slice(0, self.n), slice(0, self.n)
        return (
            slice(max(r0 - margin, 0), min(r1 + margin + 1, self.n)),
            slice(max(c0 - margin, 0), min(c1 + margin + 1, self.n)),
        )

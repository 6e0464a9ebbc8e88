"""On-board observations (SPEC §6): what one robot could know, encoded for a policy.

Nothing here reads ground truth. Each robot keeps

* a :class:`BeliefGrid` in its own start frame: cells its beams swept (free) and, in
  ground-truth-pose mode, cells its beams ended in (hit), both placed with its *estimated* pose;
* a :class:`MapSampler`: its polynomials sampled as points, cached per landmark and shifted
  when only c0 moved (a c0 change shifts every point of the curve along its dependent axis).

:class:`ObservationEncoder` turns these, the ranges, the pose estimate, camera detections and
channel state into the vector (or grid + vector) observation, and owns the spaces.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from polyslam_env.core import raster
from polyslam_env.environment import kernels
from polyslam_env.environment.config import EnvConfig, ObservationConfig
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.sensors import Detection

__all__ = [
    "BeliefGrid",
    "MapSampler",
    "ObservationEncoder",
    "RobotView",
    "belief_grids",
    "sweep_beliefs",
]

#: Values of the one-channel local map in vector mode.
FREE, UNKNOWN, OCCUPIED = 0.0, 0.5, 1.0
#: Caps of the reported pose standard deviations (x m, y m, θ rad); std/cap is clipped to 1.
STD_CAPS = np.array([1.0, 1.0, math.pi])
_NO_POINTS = np.zeros((0, 2))
_NO_CELLS = np.zeros((1, 0), dtype=bool)  # (1, 0): no local map
_CODES = np.array([FREE, UNKNOWN, OCCUPIED])


def _cells_a_side(size: float, resolution: float) -> int:
    return math.ceil(round(size / resolution, 9))  # no float noise


class BeliefGrid:
    """A robot's own square grid centred on its start (its frame's origin), rows = y.

    ``free`` marks cells its beams crossed, ``hit`` cells where a beam ended on something.
    Both are views of row ``row`` of a stack of grids (``stack``: free and hit, each (R, n, n);
    its own stack of one by default), so that the compiled kernels sweep and read the grids of
    a whole team (:func:`belief_grids`) in one call.
    """

    def __init__(
        self,
        size: float,
        resolution: float,
        max_range: float,
        stack: tuple[np.ndarray, np.ndarray] | None = None,
        row: int = 0,
    ) -> None:
        self.resolution = float(resolution)
        self.n = _cells_a_side(size, resolution)  # cells a side
        self.origin = -0.5 * self.n * self.resolution  # x and y of the lower-left corner
        if stack is None:
            stack = (np.zeros((1, self.n, self.n), bool), np.zeros((1, self.n, self.n), bool))
        self.stack, self.row = stack, row
        self.free = stack[0][row]  # (n, n) view
        self.hit = stack[1][row]  # (n, n) view
        self.max_range = float(max_range)
        #: (origin, resolution, shape) in the arguments' order of polyslam_env.core.raster
        self._grid = ((self.origin, self.origin), self.resolution, (self.n, self.n))
        self._t = raster.beam_fractions(max_range, self.resolution)  # (S,) beam samples

    def __getstate__(self) -> dict[str, object]:
        """Pickled without the views (a pickled view is a copy): rebuilt from the stack."""
        state = self.__dict__.copy()
        del state["free"], state["hit"]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self.free, self.hit = self.stack[0][self.row], self.stack[1][self.row]

    def _flat_cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat cell index (M,) of points (M, 2) (0 where outside) and whether each is inside."""
        flat, inside = raster.point_cells(points[:, 0], points[:, 1], *self._grid)
        return np.where(inside, flat, 0), inside

    def sweep(self, pose: np.ndarray, angles: np.ndarray, ranges: np.ndarray) -> None:
        """Mark the beams of one scan from ``pose`` (3,): free up to half a cell short of each
        hit (or to ``max_range`` without return), and the hit cells."""
        sweep_beliefs([self], pose[None], angles, ranges[None])

    def inside(self, points: np.ndarray) -> np.ndarray:  # (M,) bool
        """Whether each of the points (M, 2) falls in a cell of the grid."""
        return self._flat_cells(points)[1]

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(free, hit) (M,) at points (M, 2); False outside the grid."""
        flat, inside = self._flat_cells(points)
        return self.free.reshape(-1)[flat] & inside, self.hit.reshape(-1)[flat] & inside


def belief_grids(
    config: ObservationConfig,
    bounds: tuple[float, float, float, float],
    max_range: float,
    n: int,
) -> list[BeliefGrid]:
    """``n`` empty belief grids for a map of ``bounds`` (x0, y0, x1, y1) m, each of side
    :meth:`~polyslam_env.environment.config.ObservationConfig.belief_side`, so the grid
    centred on any start holds the whole map."""
    x0, y0, x1, y1 = bounds
    side = config.belief_side((x1 - x0, y1 - y0), max_range)
    cells = _cells_a_side(side, config.belief_resolution)
    stack = (np.zeros((n, cells, cells), bool), np.zeros((n, cells, cells), bool))
    return [BeliefGrid(side, config.belief_resolution, max_range, stack, i) for i in range(n)]


def sweep_beliefs(
    grids: Sequence[BeliefGrid], poses: np.ndarray, angles: np.ndarray, ranges: np.ndarray
) -> None:
    """:meth:`BeliefGrid.sweep` of several robots' scans into their own grids (the grids share
    size, resolution and range): poses (K, 3), ranges (K, B); the compiled
    :func:`~polyslam_env.core.raster.mark_scans`, in one call when the grids share a stack."""
    g = grids[0]
    if any((h.n, h.resolution, h.max_range) != (g.n, g.resolution, g.max_range) for h in grids):
        raise ValueError("sweep_beliefs needs grids of the same size, resolution and range")
    origin, res, _ = g._grid
    if all(h.stack is g.stack for h in grids):  # one kernel call for the team
        rows = np.array([h.row for h in grids], dtype=np.int64)
        raster.mark_scans(poses, angles, ranges, g.max_range, g._t, origin, res, *g.stack, rows)
        return
    for h, pose, r in zip(grids, poses, ranges, strict=True):
        rows = np.array([h.row], dtype=np.int64)
        raster.mark_scans(
            pose[None], angles, r[None], h.max_range, h._t, origin, res, *h.stack, rows
        )


class MapSampler:
    """A robot's polynomials as points every ``step`` of arc length, in its own frame.

    A landmark is resampled only when its shape object changed (created, refit, merged or
    extended: shapes are immutable, so a change is a new object); a c0 change alone shifts the
    cached points along the polynomial's dependent axis, which is exact.
    """

    def __init__(self, step: float) -> None:
        self.step = float(step)
        self._shapes: list[Polynomial] = []  # cached shape objects, in state order
        self._ids: list[int] = []
        self._c0 = np.zeros(0)  # (n,) c0 of each landmark when its points were sampled
        self._points = np.zeros((0, 2))  # (M, 2) all points at the cached c0s
        self._owner = np.zeros(0, dtype=np.intp)  # (M,) landmark (state order) of each point
        self._axis = np.zeros(0, dtype=np.intp)  # (M,) the dependent coordinate (0 or 1)
        self._per_id: dict[int, tuple[Polynomial, float, np.ndarray]] = {}

    def _stale(self, slam: PolySlam) -> bool:
        ids = slam.table.ids
        if list(ids) != self._ids:
            return True
        return any(slam.shapes[lid] is not shp for lid, shp in zip(ids, self._shapes, strict=True))

    def _rebuild(self, slam: PolySlam) -> None:
        """Resample the landmarks whose shape changed; keep the others' points."""
        ids = list(slam.table.ids)
        c0s = slam.c0s
        per_id: dict[int, tuple[Polynomial, float, np.ndarray]] = {}
        for lid, c0 in zip(ids, c0s, strict=True):
            shape = slam.shapes[lid]
            old = self._per_id.get(lid)
            if old is None or old[0] is not shape:
                old = (shape, float(c0), shape.with_c0(float(c0)).sample_arclength(self.step))
            per_id[lid] = old
        self._per_id, self._ids = per_id, ids
        self._shapes = [per_id[lid][0] for lid in ids]
        self._c0 = np.array([per_id[lid][1] for lid in ids])
        pts = [per_id[lid][2] for lid in ids]
        counts = [len(p) for p in pts]
        self._points = np.vstack(pts) if pts else np.zeros((0, 2))
        self._owner = np.repeat(np.arange(len(ids)), counts)
        axes = [1 if shp.variate == 1 else 0 for shp in self._shapes]
        self._axis = np.repeat(np.array(axes, dtype=np.intp), counts)

    def points(self, slam: PolySlam) -> np.ndarray:  # (M, 2)
        """All map points of ``slam`` in its frame."""
        if self._stale(slam):
            self._rebuild(slam)
        out = self._points.copy()
        if len(out):
            shift = (slam.c0s - self._c0)[self._owner]  # (M,)
            out[np.arange(len(out)), self._axis] += shift
        return out


@dataclass(frozen=True)
class RobotView:
    """Everything one robot knows at the end of a step (its own frame)."""

    ranges: np.ndarray  # (B,) noisy ranges, inf = no return
    pose: np.ndarray  # (3,) estimated pose in its start frame
    pose_std: np.ndarray  # (3,) standard deviations of the pose estimate
    map_points: np.ndarray  # (M, 2) its polynomials' points in its frame
    belief: BeliefGrid
    detections: list[Detection]
    steps_since_rendezvous: int | None  # None: never met anyone
    rendezvous: int
    step: int


class ObservationEncoder:
    """Builds the observation space once and encodes :class:`RobotView` s into it."""

    def __init__(self, config: EnvConfig, map_size: tuple[float, float]) -> None:
        """``map_size``: (width, height) m of the map's bounding box; it sets the pose scale
        (:meth:`~polyslam_env.environment.config.ObservationConfig.position_scale`) and is
        checked against the belief grid's size limit now rather than at the first reset."""
        oc = config.observation
        self.config = config
        self.mode = oc.mode
        self.g = oc.grid_size
        self.res = oc.grid_resolution
        self.k = config.num_detections
        self.beams = len(config.world.range_sensor.angles_deg)
        self.max_range = config.world.range_sensor.max_range
        self.pose_scale = oc.position_scale(map_size, self.max_range)  # m
        oc.belief_side(map_size, self.max_range)  # raises if the derived grid is too large
        self.use_hits = not config.slam_enabled
        h = self.g // 2
        q, r = np.meshgrid(np.arange(self.g) - h, np.arange(self.g) - h)  # columns x, rows y
        self.cell_centres = np.stack([q, r], axis=-1).reshape(-1, 2) * self.res  # (G², 2) ego
        self._layout = self.vector_layout
        low, high = self._vector_bounds()
        self.vector_space = spaces.Box(low, high, dtype=np.float32)
        self.space: spaces.Space[object]
        if self.mode == "grid":
            grid = spaces.Box(0.0, 1.0, (3, self.g, self.g), dtype=np.float32)
            self.space = spaces.Dict({"grid": grid, "vector": self.vector_space})
        else:
            self.space = self.vector_space

    # -- layout of the vector -------------------------------------------------------------
    def _vector_parts(self) -> list[tuple[str, int, float]]:
        """(name, length, low) of each part, in order; every high is 1."""
        parts = [
            ("ranges", self.beams, 0.0),
            ("no_return", self.beams, 0.0),
            ("pose", 4, -1.0),
            ("pose_std", 3, 0.0),
        ]
        if self.mode == "vector":
            parts.append(("local_map", self.g * self.g, 0.0))
        parts += [("detections", 4 * self.k, -1.0), ("channel", 2, 0.0), ("progress", 1, 0.0)]
        return parts

    def _vector_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        parts = self._vector_parts()
        low = np.concatenate([np.full(n, lo, dtype=np.float32) for _, n, lo in parts])
        return low, np.ones_like(low)

    @property
    def vector_layout(self) -> dict[str, slice]:
        """Where each named part sits in the vector (for policies and tests)."""
        out, start = {}, 0
        for name, n, _ in self._vector_parts():
            out[name] = slice(start, start + n)
            start += n
        return out

    # -- encoding -------------------------------------------------------------------------
    def local_cells(self, view: RobotView) -> tuple[np.ndarray, np.ndarray]:
        """Occupied and free cells (G²,) bool of the egocentric grid (x forward = columns,
        row-major); a cell is never both, and neither means unknown. Occupied: the robot's map
        points (and, with ``use_hits``, the belief grid's hits); free: the belief grid's free
        cells."""
        occ, free = self._local_cells([view])
        return occ[0], free[0]

    def _local_cells(self, views: Sequence[RobotView]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`local_cells` of K views (K, G²) each, by the compiled
        :func:`~polyslam_env.environment.kernels.local_cells`: in one call when the views'
        belief grids share a stack (a team's do), else one call per view."""
        k, gg = len(views), self.g * self.g
        poses = np.array([v.pose for v in views])  # (K, 3)
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        # R(θ)ᵀ (core.geometry.rotation, transposed) of each heading, C-contiguous: numpy's
        # batched product then equals the products of one robot at a time (the same BLAS
        # kernel, bit for bit) at half their cost.
        rots_t = np.empty((k, 2, 2))
        rots_t[:, 0, 0], rots_t[:, 0, 1], rots_t[:, 1, 0], rots_t[:, 1, 1] = c, s, -s, c
        centres = self.cell_centres @ rots_t + poses[:, None, :2]  # (K, G², 2) own frames
        ego = [
            (v.map_points - v.pose[:2]) @ np.ascontiguousarray(rots_t[j].T)  # @ R(θ): ego
            if len(v.map_points)
            else _NO_POINTS
            for j, v in enumerate(views)
        ]
        starts = np.zeros(k + 1, dtype=np.int64)
        starts[1:] = np.cumsum([len(e) for e in ego])
        points = np.concatenate(ego) if starts[-1] else _NO_POINTS  # (M, 2) ego frames
        occ, free = np.empty((k, gg), dtype=bool), np.empty((k, gg), dtype=bool)
        b = views[0].belief
        if all(v.belief.stack is b.stack for v in views):
            groups = [(slice(0, k), b, np.array([v.belief.row for v in views], dtype=np.int64))]
        else:
            groups = [
                (slice(j, j + 1), v.belief, np.array([v.belief.row])) for j, v in enumerate(views)
            ]
        for sl, grid, rows in groups:
            free_stack, hit_stack = grid.stack
            kernels.local_cells(
                centres[sl], points, starts[sl.start : sl.stop + 1],
                self.g, self.res, free_stack.reshape(len(free_stack), -1),
                hit_stack.reshape(len(hit_stack), -1), rows, grid.origin, grid.resolution,
                grid.n, self.use_hits, occ[sl], free[sl],
            )  # fmt: skip
        return occ, free

    def local_map(self, view: RobotView) -> np.ndarray:  # (3, G, G) float32
        """Occupied / free / unknown channels of the egocentric grid (x forward = columns)."""
        occ, free = self.local_cells(view)
        out = np.empty((3, self.g * self.g), dtype=np.float32)
        out[0], out[1], out[2] = occ, free, ~(occ | free)
        return out.reshape(3, self.g, self.g)

    def _detections(self, detections: list[Detection]) -> list[float]:  # (4K,)
        """Slots nearest first, ``(seen, d/range, cos α, sin α)``, zeros for empty slots."""
        cam_range = self.config.world.camera.range
        out: list[float] = []
        for det in sorted(detections, key=lambda d: (d.distance, d.target))[: self.k]:
            d = min(det.distance / cam_range, 1.0)
            out += (1.0, d, math.cos(det.bearing), math.sin(det.bearing))
        return out + [0.0] * (4 * self.k - len(out))

    def vector(
        self, view: RobotView, cells: tuple[np.ndarray, np.ndarray] | None
    ) -> np.ndarray:  # (D,) float32
        """The flat vector; the local map's (occupied, free) ``cells`` (G²,) are folded in as
        one coded channel if given."""
        if cells is None:
            return self._vectors([view], _NO_CELLS, _NO_CELLS)[0]
        return self._vectors([view], cells[0][None], cells[1][None])[0]

    def _vectors(
        self, views: Sequence[RobotView], occ: np.ndarray, free: np.ndarray
    ) -> np.ndarray:  # (K, D) float32
        """:meth:`vector` of K views, the local maps' cells ``occ``, ``free`` (K, G²) or
        (K, 0) for none. Ranges, pose, standard deviations and local map are written by the
        compiled :func:`~polyslam_env.environment.kernels.vector_head` (one call), the rest
        as Python floats."""
        oc = self.config.observation
        lay = self._layout
        out = np.empty((len(views), *self.vector_space.shape), dtype=np.float32)
        kernels.vector_head(
            np.array([v.ranges for v in views]), self.max_range, np.array([v.pose for v in views]),
            self.pose_scale, np.array([v.pose_std for v in views]), STD_CAPS, occ, free,
            _CODES, out,
        )  # fmt: skip
        t = self.config.max_steps
        tail = slice(lay["detections"].start, lay["progress"].stop)
        for row, view in zip(out, views, strict=True):
            since = view.steps_since_rendezvous
            # detections, channel and progress are adjacent: one assignment
            row[tail] = [
                *self._detections(view.detections),
                1.0 if since is None else min(since / t, 1.0),
                min(view.rendezvous, oc.rendezvous_cap) / oc.rendezvous_cap,
                min(view.step / t, 1.0),
            ]
        return out

    def encode(self, view: RobotView) -> np.ndarray | dict[str, np.ndarray]:
        """The observation of one robot in :attr:`space`."""
        return self.encode_team([view])[0]

    def encode_team(self, views: Sequence[RobotView]) -> list[np.ndarray | dict[str, np.ndarray]]:
        """The observations of K robots (:meth:`encode` of each), the vectors' numerical
        parts computed for all robots in one call of each kernel."""
        if self.mode == "grid":
            return [{"grid": self.local_map(v), "vector": self.vector(v, None)} for v in views]
        if not views:
            return []
        occ, free = self._local_cells(views)
        return [row.copy() for row in self._vectors(views, occ, free)]

"""On-board observations (SPEC §6): what one robot could know, encoded for a policy.

Nothing here reads ground truth. Each robot keeps

* a :class:`BeliefGrid` in its own start frame: cells its beams swept (free) and, in
  ground-truth-pose mode, cells its beams ended in (hit), both placed with its *estimated* pose;
* a :class:`MapSampler`: its polynomials sampled as points, cached per landmark and shifted
  when only c0 moved (a c0 change shifts every point of the curve along its dependent axis).

:class:`ObservationEncoder` turns these, the ranges, the pose estimate, camera detections and
channel state into the vector (or grid + vector) observation, and owns the spaces. The env
encodes the whole team at once from one :class:`TeamView` (arrays over the robots) with two
compiled calls; :class:`RobotView` is one robot's view, for encoding a single robot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from gymnasium import spaces

from polyslam_env.core import raster
from polyslam_env.environment import kernels
from polyslam_env.environment.config import EnvConfig, ObservationConfig
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.sensors import Detection

__all__ = [
    "BeliefGrid",
    "MapSampler",
    "ObservationEncoder",
    "RobotView",
    "TeamView",
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
# The arguments of kernels.local_cells before its outputs, and of kernels.vector_tail before
# its output (ObservationEncoder._cell_args, _tail_args)
_A = np.ndarray
_CellArgs = tuple[_A, _A, _A, _A, _A, _A, _A, int, float, _A, _A, _A, float, float, int, bool]
_TailArgs = tuple[_A, _A, _A, float, int, _A, _A, int, _A, int, int]
#: Points per curve a map sampler measures its arc length on (``Polynomial.sample_arclength``'s).
_DENSE = 512


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
        #: the stack with each grid flat: free and hit, each (R, n·n) views
        self.flat_stack = (stack[0].reshape(len(stack[0]), -1), stack[1].reshape(len(stack[1]), -1))
        self.max_range = float(max_range)
        #: (origin, resolution, shape) in the arguments' order of polyslam_env.core.raster
        self._grid = ((self.origin, self.origin), self.resolution, (self.n, self.n))
        self._t = raster.beam_fractions(max_range, self.resolution)  # (S,) beam samples

    def __getstate__(self) -> dict[str, object]:
        """Pickled without the views (a pickled view is a copy): rebuilt from the stack."""
        state = self.__dict__.copy()
        del state["free"], state["hit"], state["flat_stack"]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        free, hit = self.stack
        self.free, self.hit = free[self.row], hit[self.row]
        self.flat_stack = (free.reshape(len(free), -1), hit.reshape(len(hit), -1))

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
    shared = True  # one stack: one kernel call for the team
    for h in grids:
        if h.n != g.n or h.resolution != g.resolution or h.max_range != g.max_range:
            raise ValueError("sweep_beliefs needs grids of the same size, resolution and range")
        shared = shared and h.stack is g.stack
    origin, res, _ = g._grid
    if shared:
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

    Nothing is looked at while the map's table keeps its ``version`` (only c0s moved); after
    a change, a landmark is resampled only when its ``stamp`` moved (created, refit, merged
    or extended: the table bumps it with every change of shape or extent). A c0 change alone
    shifts the cached points along the polynomial's dependent axis, which is exact.

    The cache is one int64 array (:data:`~polyslam_env.environment.kernels.N_CACHE` fields ×
    capacity: per landmark in state order, its id, its stamp, its dependent axis and where its
    points are) and the c0s they were sampled at; the points live in an append-only pool. A
    change is one compiled call (:func:`~polyslam_env.environment.kernels.resample_map`: the
    stale rows resampled and appended, the others kept where they are), and :meth:`write`
    another (:func:`~polyslam_env.environment.kernels.shifted_points`).
    """

    def __init__(self, step: float) -> None:
        self.step = float(step)
        self._table: object | None = None  # the table the cache was built on
        self._version = -1  # its version then
        self._cache = np.zeros((kernels.N_CACHE, 16), dtype=np.int64)  # (fields, capacity)
        self._c0 = np.zeros(16)  # (capacity,) c0 of each landmark when sampled
        self._cached = 0  # rows of the cache in use: the table's landmarks then
        self._pool = np.zeros((0, 2))  # (capacity, 2): points at the cached c0s
        self._used = 0  # rows of the pool in use (live or dropped)
        self._total = 0  # live points: Σ count

    def _rebuild(self, slam: PolySlam) -> None:
        """Bring the cache up to date with the map's table (the stale rows resampled)."""
        table = slam.table
        n = len(table.ids)
        if n > self._c0.shape[0]:  # more room, the rows in use kept
            cache = np.zeros((kernels.N_CACHE, 2 * n), dtype=np.int64)
            c0 = np.zeros(2 * n)
            cache[:, : self._cached] = self._cache[:, : self._cached]
            c0[: self._cached] = self._c0[: self._cached]
            self._cache, self._c0 = cache, c0
        real, index, shape = table.buffers  # the table's columns (capacity ≥ n), read whole
        self._pool, self._used, self._total = kernels.resample_map(
            self._cache, self._c0, self._cached, index, real, shape, slam.mean, n, self.step,
            _DENSE, self._pool, self._used,
        )  # fmt: skip
        self._cached = n
        self._table, self._version = table, table.version

    def count(self, slam: PolySlam) -> int:
        """How many points :meth:`points` of ``slam`` gives (resampling first if the map's
        table changed)."""
        table = slam.table
        if table is not self._table or table.version != self._version:
            self._rebuild(slam)
        return self._total

    def write(self, slam: PolySlam, out: np.ndarray) -> None:
        """:meth:`points` of ``slam`` written into ``out`` (:meth:`count`, 2), which must be
        called first (its resampling is not repeated here)."""
        kernels.shifted_points(self._pool, self._cache, self._c0, self._cached, slam.mean, out)

    def points(self, slam: PolySlam) -> np.ndarray:  # (M, 2)
        """All map points of ``slam`` in its frame."""
        out = np.empty((self.count(slam), 2))
        self.write(slam, out)
        return out


@dataclass(frozen=True)
class RobotView:
    """Everything one robot knows at the end of a step (its own frame); for encoding one robot
    (the env encodes the team from a :class:`TeamView`)."""

    ranges: np.ndarray  # (B,) noisy ranges, inf = no return
    pose: np.ndarray  # (3,) estimated pose in its start frame
    pose_std: np.ndarray  # (3,) standard deviations of the pose estimate
    map_points: np.ndarray  # (M, 2) its polynomials' points in its frame
    belief: BeliefGrid
    detections: list[Detection]
    steps_since_rendezvous: int | None  # None: never met anyone
    rendezvous: int
    step: int


#: ``TeamView.since`` of a robot that never met anyone.
NEVER = -1


class TeamView(NamedTuple):
    """What K robots know at the end of a step, each in its own frame, as arrays."""

    ranges: np.ndarray  # (K, B) noisy ranges, inf = no return
    poses: np.ndarray  # (K, 3) estimated poses in their start frames
    pose_stds: np.ndarray  # (K, 3) standard deviations of the pose estimates
    map_points: np.ndarray  # (M, 2): robot k's map points are rows starts[k]:starts[k + 1]
    map_starts: np.ndarray  # (K + 1,) int64
    belief: BeliefGrid  # the grid of one of them: the stack of their grids, its geometry
    belief_rows: np.ndarray  # (K,) int64: robot k's belief grid is row belief_rows[k] of it
    seen: np.ndarray  # (K, T) bool: robot k's camera sees robot t
    distance: np.ndarray  # (K, T) m, as the camera measured it (where seen)
    bearing: np.ndarray  # (K, T) rad, ditto
    since: np.ndarray  # (K,) int64 steps since the last rendezvous, NEVER (−1) for none
    rendezvous: np.ndarray  # (K,) int64 rendezvous so far
    step: np.ndarray  # (K,) int64 the env step each observation is of

    @classmethod
    def of(cls, views: Sequence[RobotView]) -> TeamView:
        """The team view of single-robot views (their belief grids in one stack, as
        :func:`belief_grids` makes a team's)."""
        if not views:
            raise ValueError("TeamView.of: no views")
        belief = views[0].belief
        if any(v.belief.stack is not belief.stack for v in views):
            raise ValueError("TeamView.of: the views' belief grids are not in one stack")
        points = [v.map_points.reshape(-1, 2) for v in views]
        starts = np.zeros(len(views) + 1, dtype=np.int64)
        starts[1:] = np.cumsum([len(p) for p in points])
        targets = 1 + max((d.target for v in views for d in v.detections), default=-1)
        seen = np.zeros((len(views), targets), dtype=bool)
        distance, bearing = np.zeros((len(views), targets)), np.zeros((len(views), targets))
        for k, view in enumerate(views):
            for d in view.detections:
                seen[k, d.target] = True
                distance[k, d.target], bearing[k, d.target] = d.distance, d.bearing
        since = [NEVER if v.steps_since_rendezvous is None else v.steps_since_rendezvous
                 for v in views]  # fmt: skip
        return cls(
            ranges=np.array([v.ranges for v in views], dtype=float),
            poses=np.array([v.pose for v in views], dtype=float),
            pose_stds=np.array([v.pose_std for v in views], dtype=float),
            map_points=np.concatenate(points) if points else _NO_POINTS,
            map_starts=starts,
            belief=belief,
            belief_rows=np.array([v.belief.row for v in views], dtype=np.int64),
            seen=seen,
            distance=distance,
            bearing=bearing,
            since=np.array(since, dtype=np.int64),
            rendezvous=np.array([v.rendezvous for v in views], dtype=np.int64),
            step=np.array([v.step for v in views], dtype=np.int64),
        )

    def __len__(self) -> int:  # robots, not fields
        return len(self.poses)


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
        occ, free = self.team_cells(TeamView.of([view]))
        return occ[0], free[0]

    def team_cells(self, team: TeamView) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`local_cells` of K robots (K, G²) each, in one call of the compiled
        :func:`~polyslam_env.environment.kernels.local_cells` (which places the cells and
        the map points itself)."""
        k, gg = len(team), self.g * self.g
        occ, free = np.empty((k, gg), dtype=bool), np.empty((k, gg), dtype=bool)
        kernels.local_cells(*self._cell_args(team), occ, free)
        return occ, free

    def _cell_args(self, team: TeamView) -> _CellArgs:
        """The arguments of :func:`~polyslam_env.environment.kernels.local_cells` before its
        outputs."""
        poses = team.poses
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        grid = team.belief
        free_stack, hit_stack = grid.flat_stack
        return (
            self.cell_centres, team.map_points, team.map_starts, poses, c, s,
            self._lone_points(team, c, s), self.g, self.res, free_stack, hit_stack,
            team.belief_rows, grid.origin, grid.resolution, grid.n, self.use_hits,
        )  # fmt: skip

    @staticmethod
    def _lone_points(team: TeamView, c: np.ndarray, s: np.ndarray) -> np.ndarray:  # (K, 2)
        """Row k: the ego point of robot k if its map is one point, as numpy computes
        (p − xy) R(θ) for one row (BLAS's gemv, which rounds otherwise than the kernel's gemm
        chain); rows of the other robots are not read (left unset)."""
        starts = team.map_starts.tolist()  # K + 1 ints: a Python loop, no numpy calls
        lone = np.empty((len(starts) - 1, 2))
        for j in range(len(starts) - 1):
            a = starts[j]
            if starts[j + 1] - a != 1:
                continue
            rot = np.array([[c[j], -s[j]], [s[j], c[j]]])  # R(θ) = (R(θ)ᵀ)ᵀ, C-contiguous
            lone[j] = ((team.map_points[a : a + 1] - team.poses[j, :2]) @ rot)[0]
        return lone

    def local_map(self, view: RobotView) -> np.ndarray:  # (3, G, G) float32
        """Occupied / free / unknown channels of the egocentric grid (x forward = columns)."""
        occ, free = self.local_cells(view)
        return self._channels(occ[None], free[None])[0]

    def _channels(self, occ: np.ndarray, free: np.ndarray) -> np.ndarray:  # (K, 3, G, G)
        out = np.empty((len(occ), 3, self.g * self.g), dtype=np.float32)
        out[:, 0], out[:, 1], out[:, 2] = occ, free, ~(occ | free)
        return out.reshape(len(occ), 3, self.g, self.g)

    def vector(
        self, view: RobotView, cells: tuple[np.ndarray, np.ndarray] | None
    ) -> np.ndarray:  # (D,) float32
        """The flat vector; the local map's (occupied, free) ``cells`` (G²,) are folded in as
        one coded channel if given."""
        team = TeamView.of([view])
        if cells is None:
            return self.team_vectors(team, _NO_CELLS, _NO_CELLS)[0]
        return self.team_vectors(team, cells[0][None], cells[1][None])[0]

    def team_vectors(
        self, team: TeamView, occ: np.ndarray, free: np.ndarray
    ) -> np.ndarray:  # (K, D) float32
        """:meth:`vector` of K robots, the local maps' cells ``occ``, ``free`` (K, G²) or
        (K, 0) for none, written by two compiled calls: ranges, pose, standard deviations and
        local map (:func:`~polyslam_env.environment.kernels.vector_head`), then detections,
        channel and progress (:func:`~polyslam_env.environment.kernels.vector_tail`)."""
        out = np.empty((len(team), *self.vector_space.shape), dtype=np.float32)
        kernels.vector_head(
            team.ranges, self.max_range, team.poses, self.pose_scale, team.pose_stds, STD_CAPS,
            occ, free, _CODES, out,
        )  # fmt: skip
        kernels.vector_tail(*self._tail_args(team), out)
        return out

    def _tail_args(self, team: TeamView) -> _TailArgs:
        """The arguments of :func:`~polyslam_env.environment.kernels.vector_tail` before its
        output."""
        oc = self.config.observation
        return (
            team.seen, team.distance, team.bearing, self.config.world.camera.range, self.k,
            team.since, team.rendezvous, oc.rendezvous_cap, team.step, self.config.max_steps,
            self._layout["detections"].start,
        )  # fmt: skip

    def encode(self, view: RobotView) -> np.ndarray | dict[str, np.ndarray]:
        """The observation of one robot in :attr:`space`."""
        return self.encode_team(TeamView.of([view]))[0]

    def encode_team(self, team: TeamView) -> list[np.ndarray | dict[str, np.ndarray]]:
        """The observations of K robots (:meth:`encode` of each), the numerical parts computed
        for all robots in one call of each kernel (vector mode: one call of
        :func:`~polyslam_env.environment.kernels.encode_vectors` in all)."""
        if not len(team):
            return []
        if self.mode == "grid":
            occ, free = self.team_cells(team)
            grids = self._channels(occ, free)
            none = np.zeros((len(team), 0), dtype=bool)  # no local map in the vector
            vectors = self.team_vectors(team, none, none)
            return [{"grid": g, "vector": v} for g, v in zip(grids, vectors, strict=True)]
        out = np.empty((len(team), *self.vector_space.shape), dtype=np.float32)
        kernels.encode_vectors(
            *self._cell_args(team), team.ranges, self.max_range, self.pose_scale, team.pose_stds,
            STD_CAPS, _CODES, *self._tail_args(team), out,
        )  # fmt: skip
        return list(out)

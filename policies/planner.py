"""The frontier planner: own map → frontiers, cheapest paths and utilities (SPEC §7).

Pure planning, no policy state: :class:`FrontierPlanner` reads an :class:`~policies.ownmap.OwnMap`
and a pose and returns what a goal can be picked from.

1. :meth:`FrontierPlanner.paths`: the search window (the known cells' box grown by
   :data:`MARGIN` cells), its frontier cells (free cells next to unknown space once the gaps
   between the beams' swept stripes are closed; else every beam line would be a frontier), and
   the cheapest paths from the robot (Dijkstra, 8-connected) over the passable cells (free,
   clear of obstacles by the robot radius plus a margin) with a soft cost near obstacles. A
   robot inside the inflated zone may leave it the way it came (:func:`free_start`).
2. :meth:`FrontierPlanner.rank`: each reachable frontier cell's gain, the unknown area within
   ``gain_radius`` of it (``gain="visible"``: only what rays from it reach before an obstacle,
   :func:`visible_gain`), and its utility, the gain discounted by ``exp(−path length / decay)``
   (a room's worth of unknown space beats a sliver next door), goals at least ``min_goal`` away
   and not excluded preferred. A per-cell ``discount`` (F,) multiplies the utility: the hook
   for coordinated exploration; :func:`team_discount` is Burgard et al.'s (a team-mate's
   announced goal discounts the frontiers it will see, ``policies.team``).

Every numerical piece is a compiled kernel (:mod:`policies.planner_kernels`), bit-identical to
the readable scipy planner kept as the oracle in ``tests/policies/reference.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from policies import planner_kernels as kernels
from policies import window_kernels
from policies.ownmap import OwnMap

__all__ = [
    "GAINS",
    "GAIN_RAYS",
    "MARGIN",
    "FrontierPlanner",
    "Paths",
    "Search",
    "free_start",
    "grid_path",
    "team_discount",
    "visible_gain",
]

#: Cells the search window reaches beyond the known cells.
MARGIN = 4
#: How a frontier cell's gain counts the unknown space around it: ``square``, the unknown
#: fraction of the square within ``gain_radius`` (walls and all: space behind a wall counts);
#: ``visible``, the unknown fraction along :data:`GAIN_RAYS` rays of ``gain_radius`` that stop
#: at the first obstacle (:func:`visible_gain`).
GAINS = ("square", "visible")
GAIN_RAYS = 16

#: Own-frame points (F, 2) → a per-point mask or factor (F,).
PointFn = Callable[[np.ndarray], np.ndarray]


def grid_path(
    passable: np.ndarray, cost: np.ndarray, start: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Dijkstra from ``start`` over passable cells (8-connected), edge = length × mean cost.

    Returns the distance (H, W) (inf where unreachable) and the predecessor (H·W,) flat index
    of every cell (−9999 where none).
    """
    h, w = passable.shape
    dist = np.empty(h * w)
    pred = np.empty(h * w, dtype=np.int32)
    kernels.dijkstra(
        np.ascontiguousarray(passable, dtype=bool), np.ascontiguousarray(cost, dtype=float),
        int(start[0]) * w + int(start[1]), dist, pred,
    )  # fmt: skip
    return dist.reshape(h, w), pred


def free_start(
    passable: np.ndarray, clearance: np.ndarray, start: tuple[int, int], reach: float
) -> None:
    """Let the robot leave the inflated zone when it is inside it (pushed there by a turn,
    a teammate or its own pose correction): within ``reach`` cells of its cell, every cell
    at least as clear of the obstacles as its own becomes passable (``passable`` (H, W) is
    changed in place; ``clearance`` (H, W) m). It can then back out of a corner the way it
    came, but never squeeze closer to an obstacle than it already is (the soft cost near
    obstacles still steers it outwards)."""
    kernels.free_start(passable, np.asarray(clearance, dtype=float), 0, 0, *start, float(reach))


def visible_gain(
    known: np.ndarray, obstacles: np.ndarray, rows: np.ndarray, cols: np.ndarray, reach: int
) -> np.ndarray:
    """Per cell (rows[k], cols[k]) of the grids ``known`` and ``obstacles`` (H, W) bool, the
    fraction of the cells along :data:`GAIN_RAYS` rays of ``reach`` cells from it (evenly
    spaced directions, the k-th cell of a ray the one nearest to k cells out) that are unknown
    and that the ray reaches before an obstacle or the grid's edge: what its beams might reveal,
    not the space behind a wall. (K,) float32."""
    h, w = known.shape
    seen = np.zeros(len(rows))
    for angle in np.linspace(0.0, 2.0 * np.pi, GAIN_RAYS, endpoint=False):
        alive = np.ones(len(rows), dtype=bool)
        for k in range(1, reach + 1):
            r = np.round(rows + k * np.sin(angle)).astype(np.intp)
            c = np.round(cols + k * np.cos(angle)).astype(np.intp)
            alive &= (r >= 0) & (r < h) & (c >= 0) & (c < w)
            r, c = np.where(alive, r, 0), np.where(alive, c, 0)
            alive &= ~obstacles[r, c]
            seen += alive & ~known[r, c]
    return (seen / (GAIN_RAYS * reach)).astype(np.float32)


def team_discount(points: np.ndarray, goals: np.ndarray, reach: float) -> np.ndarray:  # (F,)
    """The share of each frontier point's (F, 2) utility that no team-mate heading to
    ``goals`` (K, 2) is expected to take: ``Π_k (1 − P(d_k))`` with Burgard et al. (2005)'s
    visibility probability ``P(d) = max(0, 1 − d / reach)``
    (:func:`policies.planner_kernels.team_discount`); all ones without goals."""
    if not reach > 0:
        raise ValueError(f"team_discount: reach must be > 0, got {reach!r}")
    return kernels.team_discount(
        np.ascontiguousarray(points, dtype=float).reshape(-1, 2),
        np.ascontiguousarray(goals, dtype=float).reshape(-1, 2),
        float(reach),
    )


@dataclass(frozen=True, eq=False)
class Paths:
    """The cheapest paths from the robot over a window of its own map: arrays are (H, W) over
    the window, cells are (row, col) in it."""

    window: tuple[slice, slice]
    start: tuple[int, int]  # the robot's cell
    frontier: np.ndarray  # bool: frontier cells (reachable or not)
    dist: np.ndarray  # m: path length from the robot (inf where unreachable)
    pred: np.ndarray  # (H·W,) flat predecessor on the shortest path (−9999 where none)


@dataclass(frozen=True, eq=False)
class Search:
    """One planning search, on a window of the own map: its goal candidates (reachable
    frontier cells, blacklisted ones out), their gain and utility; arrays are (H, W) over the
    window, cells are (row, col) in it."""

    window: tuple[slice, slice]
    start: tuple[int, int]  # the robot's cell
    dist: np.ndarray  # m: path length from the robot (inf where unreached)
    pred: np.ndarray  # (H·W,) flat predecessor on the shortest path (−9999 where none)
    cells: np.ndarray  # (F,) the candidates' flat cells, row-major
    cell_gain: np.ndarray  # (F,) float32: unknown fraction within gain_radius
    cell_utility: np.ndarray  # (F,) gain discounted by path length; −inf if not preferred

    @classmethod
    def of_grids(
        cls,
        window: tuple[slice, slice],
        start: tuple[int, int],
        candidates: np.ndarray,
        dist: np.ndarray,
        pred: np.ndarray,
        utility: np.ndarray,
    ) -> Search:
        """The search whose goal ``candidates`` (H, W) bool have ``utility`` (H, W) (gain 0)."""
        cells = np.flatnonzero(candidates)
        gain = np.zeros(len(cells), dtype=np.float32)
        return cls(window, start, dist, pred, cells, gain, utility.reshape(-1)[cells])

    def _grid(self, values: np.ndarray, fill: float, dtype: type) -> np.ndarray:
        out: np.ndarray = np.full(self.dist.shape, fill, dtype=dtype)
        out.reshape(-1)[self.cells] = values
        return out

    @cached_property
    def frontier(self) -> np.ndarray:  # (H, W) bool: the goal candidates
        return self._grid(np.ones(len(self.cells), dtype=bool), False, bool)

    @cached_property
    def gain(self) -> np.ndarray:  # (H, W) float32, 0 off the candidates
        return self._grid(self.cell_gain, 0.0, np.float32)

    @cached_property
    def utility(self) -> np.ndarray:  # (H, W), −inf off the (preferred) candidates
        return self._grid(self.cell_utility, -np.inf, float)

    def best(self) -> tuple[int, int]:
        """The cell of best utility (the first in row-major order among ties)."""
        r, c = divmod(int(self.cells[int(np.argmax(self.cell_utility))]), self.dist.shape[1])
        return r, c


class FrontierPlanner:
    """Frontiers, paths and utilities on ``own`` (module doc) for a robot that leaves the
    inflated zone within ``escape`` cells, with gains over ``gain_cells`` cells (``gain`` one of
    :data:`GAINS`), utilities discounted over ``decay`` m, goals preferred ``min_goal`` m away.
    """

    def __init__(
        self,
        own: OwnMap,
        escape: float,
        gain: str,
        gain_cells: int,
        decay: float,
        min_goal: float,
    ) -> None:
        self.own = own
        self.escape = float(escape)
        self.gain, self.gain_cells = gain, int(gain_cells)
        self.decay, self.min_goal = float(decay), float(min_goal)
        self._room = kernels.queue(0)  # the search's queue, grown with the window
        cells = own.n * own.n
        # the search's scratch on the map (inf, −1, −1: it leaves them so)
        self._scratch = (
            np.full(cells, np.inf),
            np.full(cells, -1, dtype=np.int8),
            np.full(cells, -1, dtype=np.int32),
        )
        self.reruns = 0  # early-stopped searches that had to run to the end (module doc)

    def paths(self, pose: np.ndarray) -> Paths | None:
        """The window's frontier and the cheapest paths from the robot at ``pose`` (3,) to
        every cell (None when it is off its own map)."""
        window = self._window(pose)
        if window is None:
            return None
        (rows, cols), start = window
        frontier = np.empty((rows.stop - rows.start, cols.stop - cols.start), dtype=bool)
        window_kernels.window_frontier(
            self.own.layers, rows.start, rows.stop, cols.start, cols.stop, frontier
        )
        dist, pred, _ = self._search(window, kernels.no_goals(), False)
        return Paths(window[0], start, frontier, dist, pred)

    def search(
        self,
        pose: np.ndarray,
        blacklist: list[tuple[int, int]],
        near: int,
        exclude: PointFn | None = None,
        discount: PointFn | None = None,
        complete: bool = False,
    ) -> Search | None:
        """The goal search from the robot at ``pose`` (3,): the reachable frontier cells not
        within ``near`` cells of a ``blacklist`` map cell (row, col), their gain and utility
        (module doc), or None when none is left (or the robot is off its own map).
        ``exclude`` marks the own-frame cell centres (F, 2) to prefer not to go to (another
        robot's side); ``discount`` (F,) multiplies the utilities.

        Unless ``complete`` (or with a ``discount``), the path search stops once the best goal
        is certain (module doc): the search then covers the cells nearer than that."""
        window = self._window(pose)
        if window is None:
            return None
        m, (box, start) = self.own, window
        w = box[1].stop - box[1].start
        black = np.array(blacklist, dtype=np.int64).reshape(-1, 2)  # (K, 2) map cells
        size = 0 if self.gain == "visible" else 2 * self.gain_cells + 1
        cells, gain = window_kernels.goal_cells(
            m.layers, box[0].start, box[0].stop, box[1].start, box[1].stop, black, near, size
        )  # (F,) row-major
        if len(cells) == 0:
            return None
        rows, cols = np.divmod(cells, w)
        if size == 0:
            obstacles = m.layers.obst.reshape(m.n, m.n)[box]
            gain = visible_gain(m.free[box] | obstacles, obstacles, rows, cols, self.gain_cells)
        pts = np.zeros((len(cells), 0))  # (F, 2) own-frame cell centres, when a hook needs them
        if exclude is not None or discount is not None:
            pts = (np.column_stack([cols + box[1].start, rows + box[0].start]) + 0.5) * m.res
            pts += m.origin
        preferred = np.ones(len(cells), dtype=bool) if exclude is None else ~exclude(pts)
        goals = kernels.Goals(cells, gain, preferred, m.res, self.decay, self.min_goal)
        stop = not complete and discount is None
        dist, pred, stop_at = self._search(window, goals, stop)
        d = dist.reshape(-1)[cells]
        reached = np.isfinite(d)
        if not reached.all():
            if not reached.any():
                return None
            cells, gain, d, preferred = (
                cells[reached],
                gain[reached],
                d[reached],
                preferred[reached],
            )
            pts = pts[reached]
        value = (gain + 1e-3) * np.exp(-d / self.decay)  # (F,) the readable planner's utility
        if discount is not None:
            value = value * discount(pts)
        preferred &= d >= self.min_goal
        if preferred.any() and not preferred.all():
            value[~preferred] = -np.inf
        if math.isfinite(stop_at) and not self._certain(value, preferred, stop_at):
            self.reruns += 1
            return self.search(pose, blacklist, near, exclude, discount, complete=True)
        return Search(box, start, dist, pred, cells, gain, value)

    def _certain(self, value: np.ndarray, preferred: np.ndarray, stop_at: float) -> bool:
        """Whether the best utility ``value`` of the preferred cells settled beats the most a
        cell at path cost ``stop_at`` (cells) or more can have (then the search's early stop
        kept the best goal): checked with numpy's own exp, with room for its rounding."""
        if not preferred.any():
            return False
        most = kernels.MOST_GAIN * np.exp(-(stop_at * self.own.res) / self.decay)
        return bool(value[preferred].max() > most * (1.0 + 1e-9))

    def _window(self, pose: np.ndarray) -> tuple[tuple[slice, slice], tuple[int, int]] | None:
        """The search window and the robot's cell (row, col) in it (None: off the map)."""
        m = self.own
        cell = m.cell(pose[0], pose[1])
        if cell is None:
            return None
        box = m.bbox(pose, MARGIN)
        return box, (cell[0] - box[0].start, cell[1] - box[1].start)

    def _search(
        self,
        window: tuple[tuple[slice, slice], tuple[int, int]],
        goals: kernels.Goals,
        stop: bool,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Path lengths (H, W) m and predecessors (H·W,) from the robot over ``window``, and
        the cost it stopped at (:func:`policies.planner_kernels.search`)."""
        m, ((rows, cols), start) = self.own, window
        (r0, r1), (c0, c1) = (rows.start, rows.stop), (cols.start, cols.stop)
        h, w = r1 - r0, c1 - c0
        dist = np.full(h * w, np.inf)
        pred = np.full(h * w, kernels.NO_PRED, dtype=np.int32)
        if len(self._room.keys) < 8 * (h + 2) * (w + 2) + 1:
            self._room = kernels.queue((h + 2) * (w + 2))
        # the window holds the known cells and the robot's way out, a cell from its edge, and
        # lies a cell inside the map: search on the map's own layers
        on_map = min(r0, c0, m.n - r1, m.n - c1) >= 1 and MARGIN > math.ceil(self.escape)
        stop_at = kernels.search(
            m.layers, r0, r1, c0, c1, *start, self.escape, on_map, self._room, *self._scratch,
            goals, stop, m.res, dist, pred,
        )  # fmt: skip
        return dist.reshape(h, w), pred, stop_at

    def still_frontier(self, cell: tuple[int, int]) -> bool:
        """Whether map ``cell`` (row, col) is a frontier, computed on a window around it: wide
        enough that every operation of the window's frontier at the cell (closing, opening,
        dilation, clearance up to the inflation radius) sees the same cells as on the whole
        map."""
        return self.frontier_near(cell, 0)

    def frontier_near(self, cell: tuple[int, int], reach: int) -> bool:
        """Whether a map cell within ``reach`` cells (Chebyshev) of map ``cell`` (row, col) is a
        frontier by :meth:`still_frontier`."""
        m = self.own
        half = 2 * m.close_cells + 4 + math.ceil(m.inflate / m.res)
        return bool(window_kernels.frontier_near(m.layers, half, cell[0], cell[1], int(reach)))

    def path_to(self, search: Search, goal: tuple[int, int]) -> np.ndarray:  # (P, 2)
        """Own-frame waypoints (cell centres) of the path of ``search`` to ``goal`` (row, col
        in its window), the robot's cell left out (the robot's cell alone for its own)."""
        m, window = self.own, search.window
        width = search.dist.shape[1]
        return kernels.walk_back(
            search.pred, goal[0] * width + goal[1], search.start[0] * width + search.start[1],
            width, window[0].start, window[1].start, m.origin, m.res,
        )  # fmt: skip

    def blocked(self, path: np.ndarray) -> bool:
        """Whether an obstacle now lies under one of the waypoints ``path`` (P, 2)."""
        m = self.own
        return bool(kernels.path_blocked(path, m.layers.obst, m.origin, m.res, m.n))

"""Frontier exploration on the robot's own estimated map (SPEC §7).

Each step the policy folds the observation's egocentric local grid (occupied = the robot's
own polynomials, free = cells its beams swept) and its current beams into an :class:`OwnMap`
in the robot's own start frame, placed with the pose estimate from the observation — no
ground truth. The own map is sized from the public map size (its bounding box) so that it holds
the whole map from any start, as the env's belief grid does. It then

1. finds frontiers: known free cells next to unknown space, after closing the gaps between the
   five beams' swept stripes (else every beam line would be a frontier);
2. plans the cheapest paths (Dijkstra, 8-connected) on the grid with obstacles inflated by the
   robot radius plus a margin and a soft cost near obstacles, and picks the frontier of best
   utility: the unknown area within ``gain_radius`` of it (``gain="visible"``: only what rays
   from it reach before an obstacle, not the space behind a wall) discounted by
   ``exp(−path length / decay)`` (rather than the nearest: a room's worth of unknown space
   beats a sliver next door), preferring goals at least ``min_goal`` away;
3. follows the path by pure pursuit within the (v, ω) limits, slowing down or turning away
   when a front beam is short;
4. replans when the goal is reached, stops being a frontier, the path gets blocked, the robot
   stalls, a robot is seen near the goal, or every ``replan_every`` steps; a goal it could not
   reach is blacklisted for a while;
5. backs off when it stalls against another robot: two robots that meet too close to pass
   (round a corner, where the camera saw neither in time) would each turn away, turn back to
   their paths and stop again for ever; each drives ``BACK_OFF_STEPS`` steps directly away
   from the other, then plans again with that goal blacklisted.

**Active loop closing** (``close_loops``, off by default; the policy ``frontier_closing`` turns
it on; after Stachniss, Hähnel & Burgard's active loop closing, on the EKF's own numbers):
the policy keeps the places where the robot's pose was well known relative to its map (its
filter's own position σ, :meth:`~policies.base.PolicyContext.relative_pose_std`, below
``anchor_below``). When that σ grows past ``close_above`` while it maps new ground, it drives
back to the nearest such place by path (no farther than ``close_reach``), re-observes the walls
it mapped there, and returns to exploring once the σ is below ``close_below`` (or the place
is reached; it then rests ``close_rest`` steps). The EKF's correlations carry the correction
to the walls mapped on the way out. It corrects position drift, not heading drift: README
"SLAM on large floor plans" has the measurements.

Team coordination uses only what a robot sees: when its camera detects another robot, the
frontiers nearer to where that robot was seen than to where this one stood (within
``claim_radius``, for ``claim_steps`` steps) are left to it, so two robots that meet split the
map between them and head apart. When no frontier is left it falls back to right-hand wall
following.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from policies.base import Policy, PolicyContext, PolicyError
from policies.scripted import avoid_robots, beam_index, contact_gap, wall_follow_command
from polyslam_env.core import raster

__all__ = [
    "GAINS",
    "FrontierPolicy",
    "OwnMap",
    "Search",
    "frontier_closing",
    "grid_path",
    "visible_gain",
]

#: Steps a robot stalled against another drives away from it before it plans again.
BACK_OFF_STEPS = 8
#: rad: a robot further than this off its heading turns on the spot before it drives on.
TURN_FIRST = 0.7

#: 8-neighbour offsets (row, col) used for the graph edges (the other four are their reverses).
_EDGE_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))


class OwnMap:
    """A robot's occupancy belief in its own start frame: a square grid, rows = y."""

    def __init__(self, size: float, resolution: float) -> None:
        self.res = float(resolution)
        self.n = math.ceil(size / resolution)
        self.origin = -0.5 * self.n * self.res  # x and y of the lower-left corner
        self.free = np.zeros((self.n, self.n), dtype=bool)  # (n, n) swept by a beam / visited
        self.occ = np.zeros((self.n, self.n), dtype=bool)  # (n, n) last seen occupied (map)
        self.hit = np.zeros((self.n, self.n), dtype=bool)  # (n, n) a beam ended here

    def cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) (M,) of points (M, 2), only for points inside the grid."""
        ij, ok = self.index(points)
        return ij[ok, 1], ij[ok, 0]

    def index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(col, row) (M, 2) of every point (M, 2), and whether it lies inside the grid (M,)."""
        ij = np.floor((points - self.origin) / self.res).astype(np.intp)
        return ij, np.all((ij >= 0) & (ij < self.n), axis=1)

    def clearance(self, points: np.ndarray, offsets: np.ndarray) -> float:
        """Distance (m) from the nearest of ``points`` (P, 2) to the nearest obstacle cell
        (its square) among those holding a point + one of ``offsets`` (D, 2); inf for none."""
        ij, ok = self.index((points[:, None, :] + offsets).reshape(-1, 2))
        hit = np.zeros(len(ij), dtype=bool)
        hit[ok] = self.obstacles[ij[ok, 1], ij[ok, 0]]
        if not hit.any():
            return math.inf
        centre = (ij[hit] + 0.5) * self.res + self.origin
        gap = np.abs(np.repeat(points, len(offsets), axis=0)[hit] - centre) - 0.5 * self.res
        return float(np.hypot(*np.maximum(gap, 0.0).T).min())

    def centre(self, row: int, col: int) -> np.ndarray:  # (2,)
        return np.array([col + 0.5, row + 0.5]) * self.res + self.origin

    def integrate_local(self, pose: np.ndarray, local: np.ndarray, cell: float) -> None:
        """Fold an egocentric (3, G, G) bool grid of ``cell`` m cells seen from ``pose``.

        Each local cell is sampled on a k × k lattice finer than our cells' side / √2, so any
        rotation of it covers all our cells it overlaps.
        """
        g = local.shape[1]
        k = max(1, math.ceil(cell * math.sqrt(2) / self.res))
        sub = (np.arange(k) + 0.5) / k - 0.5  # (k,) offsets in cells
        q = (np.arange(g) - g // 2)[:, None] + sub[None, :]  # (G, k)
        qs = q.reshape(-1) * cell  # (G·k,)
        xs, ys = np.meshgrid(qs, qs)  # columns x, rows y: (G·k, G·k)
        ego = np.stack([xs.reshape(-1), ys.reshape(-1)], axis=1)  # (G²k², 2)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        own = ego @ np.array([[c, s], [-s, c]]) + pose[:2]  # (G²k², 2)

        def up(mask: np.ndarray) -> np.ndarray:  # (G, G) → (G²k²,) per lattice point
            return np.repeat(np.repeat(mask, k, axis=0), k, axis=1).reshape(-1)

        rows, cols = self.cells(own[up(local[1])])
        self.free[rows, cols] = True
        self.occ[rows, cols] = False
        rows, cols = self.cells(own[up(local[0])])
        self.occ[rows, cols] = True

    def integrate_beams(
        self, pose: np.ndarray, angles: np.ndarray, ranges: np.ndarray, max_range: float
    ) -> None:
        """Free along each beam up to half a cell short of its hit, and the hit cells
        (:func:`polyslam_env.core.raster.scan_cells`, as the env's belief grids)."""
        free, free_in, hit, hit_in = raster.scan_cells(
            pose[None],
            angles,
            ranges[None],
            max_range,
            raster.beam_fractions(max_range, self.res),
            (self.origin, self.origin),
            self.res,
            (self.n, self.n),
        )
        self.free.reshape(-1)[free[free_in]] = True
        self.hit.reshape(-1)[hit[hit_in]] = True

    def mark_visited(self, pose: np.ndarray, radius: float) -> None:
        """The robot's own footprint is free (it has been there)."""
        rr = radius + 0.5 * self.res
        offs = np.mgrid[-rr : rr + 1e-9 : self.res / 2, -rr : rr + 1e-9 : self.res / 2]
        pts = offs.reshape(2, -1).T  # (M, 2)
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius]
        self.free[self.cells(pose[:2] + pts)] = True

    @property
    def obstacles(self) -> np.ndarray:  # (n, n) bool
        return self.occ | self.hit

    def bbox(self, pose: np.ndarray, margin: int) -> tuple[slice, slice]:
        """The window of known cells plus the robot, grown by ``margin`` cells."""
        known = self.free | self.obstacles
        rows = np.flatnonzero(known.any(axis=1))
        cols = np.flatnonzero(known.any(axis=0))
        r, c = self.cells(pose[None, :2])
        rr = np.concatenate([rows, r])
        cc = np.concatenate([cols, c])
        if len(rr) == 0:
            return slice(0, self.n), slice(0, self.n)
        r0, r1 = max(int(rr.min()) - margin, 0), min(int(rr.max()) + margin + 1, self.n)
        c0, c1 = max(int(cc.min()) - margin, 0), min(int(cc.max()) + margin + 1, self.n)
        return slice(r0, r1), slice(c0, c1)


def grid_path(
    passable: np.ndarray, cost: np.ndarray, start: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Dijkstra from ``start`` over passable cells (8-connected), edge = length × mean cost.

    Returns the distance (H, W) (inf where unreachable) and the predecessor (H·W,) flat index
    of every cell (−9999 where none).
    """
    h, w = passable.shape
    idx = np.arange(h * w).reshape(h, w)
    src, dst, wt = [], [], []
    for dr, dc in _EDGE_OFFSETS:
        r0, r1 = 0, h - dr
        c0, c1 = max(0, -dc), w - max(0, dc)
        a = (slice(r0, r1), slice(c0, c1))
        b = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
        ok = passable[a] & passable[b]
        src.append(idx[a][ok])
        dst.append(idx[b][ok])
        wt.append(math.hypot(dr, dc) * 0.5 * (cost[a][ok] + cost[b][ok]))
    graph = coo_matrix(
        (np.concatenate(wt), (np.concatenate(src), np.concatenate(dst))), shape=(h * w, h * w)
    ).tocsr()
    dist, pred = dijkstra(
        graph, directed=False, indices=start[0] * w + start[1], return_predecessors=True
    )
    return np.asarray(dist).reshape(h, w), np.asarray(pred)


@dataclass(frozen=True, eq=False)
class Search:
    """One planning search of :class:`FrontierPolicy`, on a window of its own map: arrays are
    (H, W) over the window, cells are (row, col) in it."""

    window: tuple[slice, slice]
    start: tuple[int, int]  # the robot's cell
    frontier: np.ndarray  # bool: reachable frontier cells, blacklisted goals removed
    dist: np.ndarray  # m: path length from the robot (inf where unreachable)
    pred: np.ndarray  # (H·W,) flat predecessor on the shortest path (−9999 where none)
    gain: np.ndarray  # unknown fraction within gain_radius
    utility: np.ndarray  # gain discounted by path length; −inf off the (preferred) frontier

    def best(self) -> tuple[int, int]:
        """The cell of best utility (the first in row-major order among ties)."""
        r, c = np.unravel_index(int(np.argmax(self.utility)), self.utility.shape)
        return int(r), int(c)


class FrontierPolicy(Policy):
    """Nearest-frontier exploration with pure pursuit on the robot's own map (module doc)."""

    def __init__(
        self,
        context: PolicyContext,
        resolution: float = 0.1,
        map_size: float | None = None,
        margin: float = 0.09,
        lookahead: float = 0.4,
        min_goal: float = 0.8,
        replan_every: int = 8,
        close_gaps: float = 0.3,
        gain_radius: float = 1.0,
        decay: float = 8.0,
        claim_radius: float = 8.0,
        claim_steps: int = 150,
        close_loops: bool = False,
        close_above: float = 0.035,
        close_below: float = 0.02,
        anchor_below: float = 0.012,
        close_rest: int = 40,
        close_reach: float = math.inf,
        gain: str = "square",
    ) -> None:
        super().__init__(context)
        if map_size is None:  # the map seen from any start, as the env's belief grid
            map_size = 2.0 * (math.hypot(*context.map_size) + context.max_range)
        for name, value in (
            ("resolution", resolution),
            ("map_size", map_size),
            ("lookahead", lookahead),
            ("replan_every", replan_every),
            ("gain_radius", gain_radius),
            ("decay", decay),
            ("claim_radius", claim_radius),
            ("claim_steps", claim_steps),
            ("close_above", close_above),
            ("close_below", close_below),
            ("anchor_below", anchor_below),
            ("close_reach", close_reach),
        ):
            if not value > 0:
                raise PolicyError(f"frontier: {name} must be > 0, got {value!r}")
        if "local_map" not in context.vector_layout and context.obs_mode != "grid":
            raise PolicyError("frontier: the observation has no local map")
        self.resolution, self.map_size = float(resolution), float(map_size)
        self.inflate = context.robot_radius + margin  # m
        self.lookahead, self.min_goal = float(lookahead), float(min_goal)
        self.replan_every = int(replan_every)
        self.close_cells = max(1, round(close_gaps / resolution))
        self.gain_cells = max(1, round(gain_radius / resolution))
        self.decay = float(decay)
        self.claim_radius, self.claim_steps = float(claim_radius), int(claim_steps)
        if not anchor_below <= close_below <= close_above:
            raise PolicyError(
                "frontier: need anchor_below <= close_below <= close_above, got"
                f" {anchor_below}, {close_below}, {close_above}"
            )
        if gain not in GAINS:
            raise PolicyError(f"frontier: gain must be one of {', '.join(GAINS)}, got {gain!r}")
        self.gain = gain
        if close_rest < 0:
            raise PolicyError(f"frontier: close_rest must be >= 0, got {close_rest!r}")
        self.close_loops = bool(close_loops) and context.p0_sigma is not None
        self.close_above, self.close_below = float(close_above), float(close_below)
        self.anchor_below, self.close_rest = float(anchor_below), int(close_rest)
        self.close_reach = float(close_reach)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.map = OwnMap(self.map_size, self.resolution)
        self.path: np.ndarray | None = None  # (P, 2) own-frame waypoints
        self.goal: tuple[int, int] | None = None  # (row, col) in the own map
        self._since_plan = 0
        self._blacklist: dict[tuple[int, int], int] = {}  # goal cell → step it expires
        self._step = 0
        self._trail: list[np.ndarray] = []  # recent positions, for stall detection
        #: own-frame direction (rad) to drive while backing off from a robot, and until when
        self._back_off: tuple[float, int] | None = None
        self._wall_error = 0.0
        #: (other robot's position, own position, step it expires) in the own frame, from
        #: camera sightings: frontiers nearer the other robot are left to it (module doc)
        self._claims: list[tuple[np.ndarray, np.ndarray, int]] = []
        #: own-map cells where the pose was well known (active loop closing, module doc)
        self._anchors = np.zeros((self.map.n, self.map.n), dtype=bool)
        self._closing = False
        self._resume: tuple[int, int] | None = None  # the frontier goal a closing left
        self._rest_until = 0  # no new loop closing before this step
        self.closings = 0  # loop closings started this episode (for reports)

    # -- act -------------------------------------------------------------------------------
    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        pose, ranges, detections = self._sense(observation)
        claimed = self._claim(pose, detections)
        if self.close_loops and self._closing_now(pose, observation):
            if self._needs_anchor_plan(pose):
                self._plan_anchor(pose)
        elif claimed or self._needs_plan(pose):
            self._plan(pose)
        return self._follow(pose, ranges, detections)

    # -- active loop closing ---------------------------------------------------------------
    def _closing_now(self, pose: np.ndarray, observation: Any) -> bool:
        """Record an anchor, start or end a loop closing (module doc); whether one is on."""
        std = self.context.relative_pose_std(observation)
        if std is None:
            return self._closing
        sigma = float(np.hypot(std[0], std[1]))  # m
        if sigma < self.anchor_below:
            self._anchors[self.map.cells(pose[None, :2])] = True
        if self._closing and sigma < self.close_below:
            self._stop_closing()
        elif (
            not self._closing
            and sigma > self.close_above
            and self._step >= self._rest_until
            and self._anchors.any()
        ):
            self._resume = self.goal
            self._closing, self.path, self.goal = True, None, None
            self.closings += 1
        return self._closing

    def _stop_closing(self) -> None:
        self._closing, self.path, self.goal = False, None, None
        self._rest_until = self._step + self.close_rest

    def _needs_anchor_plan(self, pose: np.ndarray) -> bool:
        """Whether to plan the way to an anchor again (as :meth:`_needs_plan`, without the
        frontier test); reaching the anchor ends the loop closing."""
        self._since_plan += 1
        if self.path is None or self.goal is None or self._since_plan >= self.replan_every:
            return True
        if np.hypot(*(self.path[-1] - pose[:2])) < 0.25:
            self._stop_closing()  # there, and still uncertain: explore again
            return False
        if self._stalled():
            return True
        rows, cols = self.map.cells(self.path)
        return bool(np.any(self.map.obstacles[rows, cols]))

    def _plan_anchor(self, pose: np.ndarray) -> None:
        """Path to the anchor nearest by path at least ``min_goal`` away; none reachable ends
        the loop closing (the frontier plan then takes over)."""
        paths = self._paths(pose)
        if paths is None:
            self._stop_closing()
            return
        window, start, _, dist, pred = paths
        dist = dist * self.map.res
        candidate = self._anchors[window] & (dist >= self.min_goal) & (dist <= self.close_reach)
        if not candidate.any():
            self._stop_closing()
            self._plan(pose)
            return
        # a search whose goals are the anchors, the nearest one best
        utility = np.where(candidate, -dist, -np.inf)
        search = Search(window, start, candidate, dist, pred, np.zeros_like(dist), utility)
        self._go(search, search.best())

    def _sense(self, observation: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fold ``observation`` into the own map and count the step; the pose (3,), ranges
        (B,) and detections (k, 2) it holds."""
        ctx = self.context
        pose = ctx.pose(observation)
        ranges = ctx.ranges(observation)
        self._update_map(pose, ranges, ctx.local_grid(observation))
        self._step += 1
        self._trail = [*self._trail[-7:], pose[:2].copy()]
        return pose, ranges, ctx.detections(observation)

    def _follow(self, pose: np.ndarray, ranges: np.ndarray, detections: np.ndarray) -> Any:
        """The action that follows the path (the walls when there is none), kept clear of
        mapped obstacles and of the robots the camera sees."""
        ctx = self.context
        if self._backing_off(pose, detections):
            assert self._back_off is not None
            v, omega = self._head(pose, self._back_off[0], ranges)
            v = self._safe_speed(pose, v, omega)
        elif self.path is None:
            v, omega, self._wall_error = wall_follow_command(
                ranges, ctx, prev_error=self._wall_error
            )
        else:
            v, omega = self._pursue(pose, ranges)
            v = self._safe_speed(pose, v, omega)
        v, omega = avoid_robots(v, omega, detections, ctx)
        return ctx.action(v, omega)

    def _backing_off(self, pose: np.ndarray, detections: np.ndarray) -> bool:
        """Whether to back off from a robot now: one is, or was until the last
        ``BACK_OFF_STEPS``, too close ahead to pass (no free travel left, within ±80°: what
        :func:`~policies.scripted.avoid_robots` stops for) while this robot stalled. Ending a
        back-off drops the path and rests its goal, as a stall does."""
        if self._back_off is not None:
            if self._step < self._back_off[1]:
                return True
            self._back_off = None
            if self.goal is not None:
                self._blacklist[self.goal] = self._step + 60
            self.path = self.goal = None
            return False
        if not self._stalled() or len(detections) == 0:
            return False
        gap = contact_gap(detections[:, 0], self.context)
        blocking = (gap <= 0.0) & (np.abs(detections[:, 1]) <= math.radians(80))
        if not blocking.any():
            return False
        nearest = int(np.argmin(np.where(blocking, detections[:, 0], np.inf)))
        away = pose[2] + float(detections[nearest, 1]) + math.pi
        self._back_off = (away, self._step + BACK_OFF_STEPS)
        return True

    def _stalled(self) -> bool:
        """Whether the robot moved less than 0.1 m over its last 8 positions."""
        return len(self._trail) >= 8 and bool(np.hypot(*(self._trail[-1] - self._trail[0])) < 0.1)

    def _head(self, pose: np.ndarray, direction: float, ranges: np.ndarray) -> tuple[float, float]:
        """(v, ω) that drive toward the own-frame ``direction`` (rad): on the spot while it
        is more than :data:`TURN_FIRST` off, then forward within the front beams' cap."""
        alpha = math.remainder(direction - pose[2], 2 * math.pi)
        if abs(alpha) > TURN_FIRST:
            return 0.0, self._turn_rate(alpha)
        return min(0.5 * self.context.v_max, self._speed_cap(ranges)), self._turn_rate(alpha)

    def _turn_rate(self, alpha: float) -> float:
        """ω (rad/s) that turns by ``alpha`` (rad) in one step, within ±ω_max."""
        ctx = self.context
        return float(np.clip(alpha / ctx.dt, -ctx.omega_max, ctx.omega_max))

    def _claim(self, pose: np.ndarray, detections: np.ndarray) -> bool:
        """Remember the robots the camera sees (k, 2: distance m, bearing rad) as claims;
        True when the current goal now lies in a new claim (time to replan)."""
        self._claims = [c for c in self._claims if c[2] > self._step]
        if len(detections) == 0:
            return False
        phi = pose[2] + detections[:, 1]
        others = pose[:2] + detections[:, :1] * np.column_stack([np.cos(phi), np.sin(phi)])
        fresh = [(o, pose[:2].copy(), self._step + self.claim_steps) for o in others]
        self._claims = [*self._claims, *fresh][-8:]
        if self.goal is None:
            return False
        goal = self.map.centre(*self.goal)[None]  # (1, 2)
        return bool(self._claimed(goal, fresh)[0])

    def _claimed(
        self, points: np.ndarray, claims: list[tuple[np.ndarray, np.ndarray, int]]
    ) -> np.ndarray:  # (M,) bool
        """Points (M, 2) left to another robot: within ``claim_radius`` of where it was seen
        and nearer to it than to where this robot stood then (its side of the bisector)."""
        out = np.zeros(len(points), dtype=bool)
        for other, own, _ in claims:
            d_other = np.hypot(*(points - other).T)
            out |= (d_other < self.claim_radius) & (d_other < np.hypot(*(points - own).T))
        return out

    def _update_map(self, pose: np.ndarray, ranges: np.ndarray, local: np.ndarray) -> None:
        ctx = self.context
        self.map.integrate_local(pose, local, ctx.grid_resolution)
        self.map.integrate_beams(pose, ctx.beam_angles, ranges, ctx.max_range)
        self.map.mark_visited(pose, ctx.robot_radius)

    # -- planning --------------------------------------------------------------------------
    def _frontier_and_cost(
        self, window: tuple[slice, slice]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Frontier cells, passable cells, cell costs and clearances (m) (H, W) inside
        ``window``."""
        m = self.map
        obst = m.obstacles[window]
        free = m.free[window] & ~obst
        clearance = ndimage.distance_transform_edt(~obst) * m.res  # (H, W) m
        passable = free & (clearance > self.inflate)
        ball = ndimage.generate_binary_structure(2, 1)
        known = ndimage.binary_closing(
            free | obst, structure=ball, iterations=self.close_cells, border_value=1
        )
        unknown = ndimage.binary_opening(~known, structure=ball)
        frontier = passable & ndimage.binary_dilation(unknown, structure=np.ones((3, 3)))
        soft = 3.0 * self.inflate
        cost = 1.0 + 4.0 * np.clip((soft - clearance) / soft, 0.0, 1.0)
        return frontier, passable, cost, clearance

    def _needs_plan(self, pose: np.ndarray) -> bool:
        self._since_plan += 1
        if self.path is None or self.goal is None or self._since_plan >= self.replan_every:
            return True
        if np.hypot(*(self.path[-1] - pose[:2])) < 0.25:
            return True
        if self._stalled():
            self._blacklist[self.goal] = self._step + 60  # stalled: give this goal a rest
            return True
        if not self._still_frontier(self.goal):
            return True
        rows, cols = self.map.cells(self.path)
        return bool(np.any(self.map.obstacles[rows, cols]))

    def _still_frontier(self, cell: tuple[int, int]) -> bool:
        """Whether ``cell`` is a frontier, computed on a window around it: wide enough that
        every operation of :meth:`_frontier_and_cost` at the cell (closing, opening, dilation,
        clearance up to the inflation radius) sees the same cells as on the whole map."""
        m = self.map
        half = 2 * self.close_cells + 4 + math.ceil(self.inflate / m.res)
        r0, c0 = max(cell[0] - half, 0), max(cell[1] - half, 0)
        window = (slice(r0, min(cell[0] + half + 1, m.n)), slice(c0, min(cell[1] + half + 1, m.n)))
        frontier = self._frontier_and_cost(window)[0]
        return bool(frontier[cell[0] - r0, cell[1] - c0])

    def _plan(self, pose: np.ndarray) -> None:
        """Path to the frontier of best utility (:meth:`_search`), or None when none is left;
        after a loop closing, to the frontier it left if that still is one."""
        search = self._search(pose)
        resume, self._resume = self._resume, None
        if search is None:
            return
        goal = search.best()
        if resume is not None:
            r, c = resume[0] - search.window[0].start, resume[1] - search.window[1].start
            h, w = search.utility.shape
            if 0 <= r < h and 0 <= c < w and np.isfinite(search.utility[r, c]):
                goal = (r, c)
        self._go(search, goal)

    def _search(self, pose: np.ndarray) -> Search | None:
        """Frontiers, path lengths and utilities around the robot (None when no frontier is
        reachable). Clears the plan, which :meth:`_go` then sets."""
        paths = self._paths(pose)
        if paths is None:
            return None
        window, start, frontier, dist, pred = paths
        m = self.map
        frontier &= np.isfinite(dist)
        self._drop_blacklisted(frontier, window)
        if not frontier.any():
            return None
        dist = dist * m.res
        gain, utility = self._utility(frontier, dist, window)
        return Search(window, start, frontier, dist, pred, gain, utility)

    def _paths(
        self, pose: np.ndarray
    ) -> tuple[tuple[slice, slice], tuple[int, int], np.ndarray, np.ndarray, np.ndarray] | None:
        """Clear the plan and find the cheapest paths from the robot over the known window:
        (window, the robot's cell, frontier cells, path lengths in cells (inf where
        unreachable), flat predecessors), or None when the robot is off its own map."""
        self._since_plan = 0
        self.path, self.goal = None, None
        m = self.map
        window = m.bbox(pose, 4)
        frontier, passable, cost, clearance = self._frontier_and_cost(window)
        rows, cols = m.cells(pose[None, :2])
        if len(rows) == 0:
            return None
        start = (int(rows[0]) - window[0].start, int(cols[0]) - window[1].start)
        self._free_start(passable, clearance, start, self.inflate / m.res + 1.0)
        dist, pred = grid_path(passable, cost, start)
        return window, start, frontier, dist, pred

    def _go(self, search: Search, goal: tuple[int, int]) -> None:
        """Plan the path of ``search`` to ``goal`` (row, col in its window)."""
        m, window = self.map, search.window
        width = search.frontier.shape[1]
        cells = self._walk_back(search.pred, goal[0] * width + goal[1], search.start, width)
        self.path = np.array([m.centre(r + window[0].start, c + window[1].start) for r, c in cells])
        self.goal = (int(goal[0]) + window[0].start, int(goal[1]) + window[1].start)

    def _utility(
        self, frontier: np.ndarray, dist: np.ndarray, window: tuple[slice, slice]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The gain and the utility (H, W) of the cells of ``window``: the gain is the unknown
        fraction of the square within ``gain_radius`` of a cell (what its beams may reveal;
        with ``gain="visible"`` on frontier cells only, along rays that stop at obstacles:
        :func:`visible_gain`),
        the utility, on frontier cells only (−inf elsewhere), that gain discounted by
        ``exp(−path length / decay)``, ``dist`` (H, W) m being the path lengths. Cells at
        least ``min_goal`` away and not claimed by another robot are preferred whenever any
        exist: the others' utility is −inf then."""
        m = self.map
        known = m.free[window] | m.obstacles[window]
        rows, cols = np.nonzero(frontier)
        if self.gain == "visible":
            gain = np.zeros(known.shape, dtype=np.float32)
            gain[rows, cols] = visible_gain(known, m.obstacles[window], rows, cols, self.gain_cells)
        else:
            size = 2 * self.gain_cells + 1
            gain = ndimage.uniform_filter((~known).astype(np.float32), size, mode="constant")
        utility = np.where(frontier, (gain + 1e-3) * np.exp(-dist / self.decay), -np.inf)
        preferred = dist[rows, cols] >= self.min_goal
        if self._claims:
            pts = np.column_stack([cols + window[1].start, rows + window[0].start])
            pts = (pts + 0.5) * m.res + m.origin  # (F, 2) own-frame cell centres
            preferred &= ~self._claimed(pts, self._claims)
        if preferred.any() and not preferred.all():
            utility[rows[~preferred], cols[~preferred]] = -np.inf
        return gain, utility

    @staticmethod
    def _free_start(
        passable: np.ndarray, clearance: np.ndarray, start: tuple[int, int], reach: float
    ) -> None:
        """Let the robot leave the inflated zone when it is inside it (pushed there by a turn,
        a teammate or its own pose correction): within ``reach`` cells of its cell, every cell
        at least as clear of the obstacles as its own becomes passable. It can then back out of
        a corner the way it came, but never squeeze closer to an obstacle than it already is
        (the soft cost near obstacles still steers it outwards)."""
        r, c = start
        k = math.ceil(reach)
        near = (slice(max(r - k, 0), r + k + 1), slice(max(c - k, 0), c + k + 1))
        rows, cols = np.ogrid[near]
        disc = (rows - r) ** 2 + (cols - c) ** 2 <= reach * reach
        passable[near] |= disc & (clearance[near] >= clearance[r, c]) & (clearance[near] > 0)
        passable[r, c] = True

    def _drop_blacklisted(self, frontier: np.ndarray, window: tuple[slice, slice]) -> None:
        near = max(1, round(0.3 / self.map.res))
        for (r, c), until in list(self._blacklist.items()):
            if until <= self._step:
                del self._blacklist[(r, c)]
                continue
            r0, c0 = r - window[0].start, c - window[1].start
            frontier[max(r0 - near, 0) : r0 + near + 1, max(c0 - near, 0) : c0 + near + 1] = False

    @staticmethod
    def _walk_back(
        pred: np.ndarray, goal: int, start: tuple[int, int], width: int
    ) -> list[tuple[int, int]]:
        out, node, first = [], goal, start[0] * width + start[1]
        while node >= 0 and node != first:
            out.append(divmod(int(node), width))
            node = int(pred[node])
        out.reverse()
        return out or [start]

    # -- following -------------------------------------------------------------------------
    def _pursue(self, pose: np.ndarray, ranges: np.ndarray) -> tuple[float, float]:
        """Pure pursuit to the look-ahead point, then limited by the front beams."""
        ctx = self.context
        assert self.path is not None
        d = np.hypot(*(self.path - pose[:2]).T)  # (P,)
        nearest = int(np.argmin(d))
        ahead = np.flatnonzero(d[nearest:] >= self.lookahead)
        target = self.path[nearest + ahead[0]] if len(ahead) else self.path[-1]
        dx, dy = target - pose[:2]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        fx, fy = c * dx + s * dy, -s * dx + c * dy  # target in the robot frame
        dist, alpha = math.hypot(fx, fy), math.atan2(fy, fx)
        if abs(alpha) > TURN_FIRST:
            return 0.0, self._turn_rate(alpha)
        v = min(ctx.v_max, 0.8 * dist / ctx.dt)
        v = min(v, self._speed_cap(ranges))
        omega = 2.0 * math.sin(alpha) / max(dist, 1e-6) * v + 0.3 * alpha / ctx.dt
        if v < 0.02:  # blocked ahead: turn toward the roomier side
            left = ranges[beam_index(ctx.beam_angles, math.pi / 4)]
            right = ranges[beam_index(ctx.beam_angles, -math.pi / 4)]
            omega = 0.8 * ctx.omega_max * (1.0 if left >= right else -1.0)
            self.path = None  # replan next step with the new hits in the map
        return v, float(np.clip(omega, -ctx.omega_max, ctx.omega_max))

    def _safe_speed(self, pose: np.ndarray, v: float, omega: float) -> float:
        """``v``, halved until the arc driven in one step keeps the robot off mapped obstacles:
        no obstacle cell within its radius + 4 cm of any point of the arc, or, when one already
        is that close, none closer than now (a robot that came within the margin of a wall
        beside or behind it may drive on, away or along; refusing every arc there left one
        standing for 15 steps while each replanned path led straight on)."""
        ctx = self.context
        keep = ctx.robot_radius + 0.04
        r = np.arange(-keep, keep + 1e-9, 0.5 * self.map.res)
        disk = np.stack(np.meshgrid(r, r), axis=-1).reshape(-1, 2)  # (D, 2)
        disk = disk[np.hypot(disk[:, 0], disk[:, 1]) <= keep]
        now = self.map.clearance(pose[None, :2], disk)
        t = np.linspace(0.25, 1.0, 4) * ctx.dt  # (T,) s
        for _ in range(4):
            th = pose[2] + omega * t  # (T,)
            if abs(omega) > 1e-6:
                x = pose[0] + v / omega * (np.sin(th) - math.sin(pose[2]))
                y = pose[1] - v / omega * (np.cos(th) - math.cos(pose[2]))
            else:
                x, y = pose[0] + v * t * math.cos(pose[2]), pose[1] + v * t * math.sin(pose[2])
            # inf: no obstacle within keep; 1e-9 m: the rounding of an arc along a wall
            if self.map.clearance(np.stack([x, y], axis=1), disk) >= now - 1e-9:
                return v
            v *= 0.5
        return 0.0

    def _speed_cap(self, ranges: np.ndarray) -> float:
        """Fastest safe forward speed given the beams within 60° of straight ahead."""
        ctx = self.context
        cap = ctx.v_max
        for angle, r in zip(ctx.beam_angles, ranges, strict=True):
            if abs(angle) < math.radians(60) and math.isfinite(r):
                ahead = r * math.cos(angle) - ctx.robot_radius - 0.1
                side = abs(r * math.sin(angle))
                if side < ctx.robot_radius + 0.2:
                    cap = min(cap, max(ahead, 0.0) / ctx.dt)
        return cap


#: How a frontier cell's gain counts the unknown space around it: ``square``, the unknown
#: fraction of the square within ``gain_radius`` (walls and all: space behind a wall counts);
#: ``visible``, the unknown fraction along :data:`GAIN_RAYS` rays of ``gain_radius`` that stop
#: at the first obstacle (:func:`visible_gain`).
GAINS = ("square", "visible")
GAIN_RAYS = 16


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


def frontier_closing(context: PolicyContext, **kwargs: Any) -> FrontierPolicy:
    """The policy ``frontier_closing``: :class:`FrontierPolicy` with active loop closing on
    (module doc); keyword arguments as for :class:`FrontierPolicy`."""
    return FrontierPolicy(context, **{"close_loops": True, **kwargs})

"""Frontier exploration on the robot's own estimated map (SPEC §7).

Each step the policy folds the observation's egocentric local grid (occupied = the robot's
own polynomials, free = cells its beams swept) and its current beams into an
:class:`~policies.ownmap.OwnMap` in the robot's own start frame, placed with the pose estimate
from the observation — no ground truth. The own map is sized from the public map size (its
bounding box) so that it holds the whole map from any start, as the env's belief grid does; it
keeps the obstacle clearance and the frontier up to date where cells change. Then

1. the planner (:class:`~policies.planner.FrontierPlanner`) finds the frontiers, the cheapest
   paths to them and their utility: the unknown area within ``gain_radius`` of a frontier
   (``gain="visible"``: only what rays from it reach before an obstacle) discounted by
   ``exp(−path length / decay)``, goals at least ``min_goal`` away preferred;
2. the controller (:class:`~policies.controller.Controller`) follows the path by pure pursuit
   within the (v, ω) limits, slowing down or turning away when a front beam is short and
   keeping off mapped obstacles;
3. the policy replans when the goal is reached, stops being a frontier, the path gets blocked,
   the robot stalls, a robot is seen near the goal, or every ``replan_every`` steps; a goal it
   could not reach is blacklisted for a while;
4. it backs off when it stalls against another robot (:attr:`~policies.modes.Mode.BACK_OFF`):
   two robots that meet too close to pass (round a corner, where the camera saw neither in
   time) would each turn away, turn back to their paths and stop again for ever; each drives
   ``BACK_OFF_STEPS`` steps directly away from the other, then plans again with that goal
   blacklisted.

**Active loop closing** (``close_loops``, off by default; the policy ``frontier_closing`` turns
it on; after Stachniss, Hähnel & Burgard's active loop closing, on the EKF's own numbers):
the policy keeps the places where the robot's pose was well known relative to its map (its
filter's own position σ, :meth:`~policies.base.PolicyContext.relative_pose_std`, below
``anchor_below``). When that σ grows past ``close_above`` while it maps new ground, it drives
back to the nearest such place by path (no farther than ``close_reach``)
(:attr:`~policies.modes.Mode.CLOSE_LOOP`), re-observes the walls it mapped there, and returns to
exploring once the σ is below ``close_below`` (or the place is reached; it then rests
``close_rest`` steps). Two optional bounds keep it exploring (both off by default: on Willow
they cost ``frontier_closing``'s map gains with the default shape shift, see
``docs/results/floors.md``): a closing starts only while the steps spent closing are at most
``close_share`` of the steps so far, and one that has not ended after ``close_timeout``
steps (a stall on the way) is given up and its anchor forgotten.
The EKF's correlations carry the correction to the walls mapped on the way out. It corrects
position drift, not heading drift: README "SLAM on large floor plans" has the measurements.

Team coordination uses only what a robot sees: when its camera detects another robot, the
frontiers nearer to where that robot was seen than to where this one stood (within
``claim_radius``, for ``claim_steps`` steps) are left to it, so two robots that meet split the
map between them and head apart. :meth:`FrontierPolicy.frontier_discount` is the hook for
coordination by announced goals. When no frontier is left it falls back to right-hand wall
following.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from policies.base import Policy, PolicyContext, PolicyError
from policies.controller import TURN_FIRST, Controller
from policies.modes import BACK_OFF_STEPS, BackOff, Mode, ModeState
from policies.ownmap import OwnMap
from policies.planner import (
    GAIN_RAYS,
    GAINS,
    FrontierPlanner,
    Search,
    free_start,
    grid_path,
    visible_gain,
)
from policies.reading import read
from policies.scripted import avoid_robots, contact_gap, wall_follow_command

__all__ = [
    "BACK_OFF_STEPS",
    "GAINS",
    "GAIN_RAYS",
    "TURN_FIRST",
    "FrontierPolicy",
    "OwnMap",
    "Search",
    "frontier_closing",
    "grid_path",
    "visible_gain",
]

#: Steps a goal the robot stalled on (or backed off from) stays blacklisted.
REST_GOAL = 60


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
        close_share: float = 1.0,
        close_timeout: int | None = None,
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
            ("robot_radius + margin", context.robot_radius + margin),
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
        if not 0.0 <= close_share <= 1.0:
            raise PolicyError(f"frontier: close_share must be in [0, 1], got {close_share!r}")
        self.close_share = float(close_share)
        if close_timeout is not None and close_timeout < 1:
            raise PolicyError(f"frontier: close_timeout must be >= 1, got {close_timeout!r}")
        self.close_timeout = None if close_timeout is None else int(close_timeout)
        if close_rest < 0:
            raise PolicyError(f"frontier: close_rest must be >= 0, got {close_rest!r}")
        self.close_loops = bool(close_loops) and context.p0_sigma is not None
        self.close_above, self.close_below = float(close_above), float(close_below)
        self.anchor_below, self.close_rest = float(anchor_below), int(close_rest)
        self.close_reach = float(close_reach)
        self.controller = Controller(context, self.resolution, self.lookahead)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.map = OwnMap(
            self.map_size, self.resolution, self.inflate, 3.0 * self.inflate, self.close_cells
        )
        self.planner = FrontierPlanner(
            self.map, self.inflate / self.map.res + 1.0, self.gain, self.gain_cells,
            self.decay, self.min_goal,
        )  # fmt: skip
        self.path: np.ndarray | None = None  # (P, 2) own-frame waypoints
        self.goal: tuple[int, int] | None = None  # (row, col) in the own map
        self.modes = ModeState()
        self._since_plan = 0
        self._blacklist: dict[tuple[int, int], int] = {}  # goal cell → step it expires
        self._step = 0
        self._trail: list[np.ndarray] = []  # recent positions, for stall detection
        self._wall_error = 0.0
        #: (other robot's position, own position, step it expires) in the own frame, from
        #: camera sightings: frontiers nearer the other robot are left to it (module doc)
        self._claims: list[tuple[np.ndarray, np.ndarray, int]] = []
        #: own-map cells where the pose was well known (active loop closing, module doc)
        self._anchors = np.zeros((self.map.n, self.map.n), dtype=bool)

    @property
    def mode(self) -> Mode:
        """What the robot is doing now (explore, close a loop or back off)."""
        return self.modes.mode

    @property
    def closings(self) -> int:
        """Loop closings started this episode (for reports)."""
        return self.modes.closings

    @property
    def _closing(self) -> bool:
        return self.modes.closing

    @_closing.setter
    def _closing(self, on: bool) -> None:
        self.modes.heading = Mode.CLOSE_LOOP if on else Mode.EXPLORE

    @property
    def _back_off(self) -> tuple[float, int] | None:
        b = self.modes.back_off
        return None if b is None else (b.direction, b.until)

    def metrics(self) -> dict[str, float]:
        """With active loop closing: the loop closings started and the steps spent closing
        loops this episode (none without)."""
        if not self.close_loops:
            return {}
        return {"closings": float(self.closings), "closing_steps": float(self.modes.closing_steps)}

    def frontier_discount(self, points: np.ndarray) -> np.ndarray | None:
        """Factors (F,) in [0, 1] multiplying the utility of the frontier cells whose
        own-frame centres are ``points`` (F, 2), or None for none (here): the hook for
        coordinated exploration (a team-mate's announced goal discounts what it will see)."""
        return None

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
            self._closing
            and self.close_timeout is not None
            and self._step - self.modes.closing_since >= self.close_timeout
        ):
            self._give_up_closing()
        elif (
            not self._closing
            and sigma > self.close_above
            and self._step >= self.modes.rest_until
            and self.modes.closing_steps <= self.close_share * self._step
            and self._anchors.any()
        ):
            self.modes.start_closing(self.goal, self._step)
            self.path, self.goal = None, None
        self.modes.closing_steps += self._closing
        return self._closing

    def _stop_closing(self) -> None:
        self.modes.stop_closing(self._step, self.close_rest)
        self.path, self.goal = None, None

    def _give_up_closing(self) -> None:
        """End a loop closing that took ``close_timeout`` steps without reaching its anchor
        or its σ (a stall, a path that keeps being blocked): the anchors within 1 m of its
        goal are forgotten, so the next closing does not head for the same place."""
        if self.goal is not None:
            r, c = self.goal
            k = max(1, round(1.0 / self.map.res))
            self._anchors[max(0, r - k) : r + k + 1, max(0, c - k) : c + k + 1] = False
        self._stop_closing()

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
        return self.planner.blocked(self.path)

    def _plan_anchor(self, pose: np.ndarray) -> None:
        """Path to the anchor nearest by path at least ``min_goal`` away; none reachable ends
        the loop closing (the frontier plan then takes over)."""
        self._clear_plan()
        paths = self.planner.paths(pose)
        if paths is None:
            self._stop_closing()
            return
        window, dist = paths.window, paths.dist
        # reachable (finite path length: with close_reach unbounded, ``dist <= close_reach``
        # alone let walled-off anchors through, each "path" its goal cell alone)
        reach = np.isfinite(dist) & (dist >= self.min_goal) & (dist <= self.close_reach)
        candidate = self._anchors[window] & reach
        if not candidate.any():
            self._stop_closing()
            self._plan(pose)
            return
        # a search whose goals are the anchors, the nearest one best
        utility = np.where(candidate, -dist, -np.inf)
        self._go(Search.of_grids(window, paths.start, candidate, dist, paths.pred, utility), None)

    # -- sensing ---------------------------------------------------------------------------
    def _sense(self, observation: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fold ``observation`` into the own map and count the step; the pose (3,), ranges
        (B,) and detections (k, 2) it holds."""
        ctx = self.context
        seen = read(ctx, observation)
        self.map.fold(
            seen.pose, seen.occ, seen.free, ctx.grid_resolution, ctx.beam_angles, seen.ranges,
            ctx.max_range, ctx.robot_radius,
        )  # fmt: skip
        self._step += 1
        self._trail = [*self._trail[-7:], seen.pose[:2].copy()]
        return seen.pose, seen.ranges, seen.detections

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
        if not claims:
            return np.zeros(len(points), dtype=bool)
        other = np.array([c[0] for c in claims])  # (K, 2)
        own = np.array([c[1] for c in claims])  # (K, 2)
        d_other = np.hypot(points[:, None, 0] - other[:, 0], points[:, None, 1] - other[:, 1])
        d_own = np.hypot(points[:, None, 0] - own[:, 0], points[:, None, 1] - own[:, 1])
        return np.any((d_other < self.claim_radius) & (d_other < d_own), axis=1)  # (M,)

    # -- planning --------------------------------------------------------------------------
    def _needs_plan(self, pose: np.ndarray) -> bool:
        self._since_plan += 1
        if self.path is None or self.goal is None or self._since_plan >= self.replan_every:
            return True
        if np.hypot(*(self.path[-1] - pose[:2])) < 0.25:
            return True
        if self._stalled():
            self._blacklist[self.goal] = self._step + REST_GOAL  # stalled: give it a rest
            return True
        if not self.planner.still_frontier(self.goal):
            return True
        return self.planner.blocked(self.path)

    def _plan(self, pose: np.ndarray) -> None:
        """Path to the frontier of best utility (:meth:`_search`), or None when none is left;
        after a loop closing, to the frontier it left if that still is one."""
        search = self._search(pose)
        resume = self.modes.take_resume()
        if search is None:
            return
        goal = search.best()
        if resume is not None:
            r, c = resume[0] - search.window[0].start, resume[1] - search.window[1].start
            h, w = search.utility.shape
            if 0 <= r < h and 0 <= c < w and np.isfinite(search.utility[r, c]):
                goal = (r, c)
        self._go(search, goal)

    def _search(self, pose: np.ndarray, complete: bool = False) -> Search | None:
        """Frontiers, path lengths and utilities around the robot (None when no frontier is
        reachable; ``complete``: of every reachable frontier, else the search may stop once
        the best is certain). Clears the plan, which :meth:`_go` then sets."""
        self._clear_plan()
        if self.map.cell(pose[0], pose[1]) is None:
            return None
        exclude = (lambda pts: self._claimed(pts, self._claims)) if self._claims else None
        near = max(1, round(0.3 / self.map.res))
        return self.planner.search(
            pose, self._blacklisted(), near, exclude, self._discount(), complete
        )

    def _discount(self) -> Any:
        """:meth:`frontier_discount` as the planner's hook (None when not overridden)."""
        if type(self).frontier_discount is FrontierPolicy.frontier_discount:
            return None
        return self.frontier_discount

    def _clear_plan(self) -> None:
        self._since_plan = 0
        self.path, self.goal = None, None

    def _go(self, search: Search, goal: tuple[int, int] | None) -> None:
        """Plan the path of ``search`` to ``goal`` (row, col in its window; None: its best)."""
        goal = search.best() if goal is None else goal
        self.path = self.planner.path_to(search, goal)
        self.goal = (int(goal[0]) + search.window[0].start, int(goal[1]) + search.window[1].start)

    @staticmethod
    def _free_start(
        passable: np.ndarray, clearance: np.ndarray, start: tuple[int, int], reach: float
    ) -> None:
        """:func:`policies.planner.free_start` (the robot leaves the inflated zone)."""
        free_start(passable, clearance, start, reach)

    def _blacklisted(self) -> list[tuple[int, int]]:
        """The goal cells still resting (expired ones dropped): no goal within 0.3 m of them."""
        for cell, until in list(self._blacklist.items()):
            if until <= self._step:
                del self._blacklist[cell]
        return list(self._blacklist)

    # -- following -------------------------------------------------------------------------
    def _follow(self, pose: np.ndarray, ranges: np.ndarray, detections: np.ndarray) -> Any:
        """The action that follows the path (the walls when there is none), kept clear of
        mapped obstacles and of the robots the camera sees."""
        ctx, control = self.context, self.controller
        if self._backing_off(pose, ranges, detections):
            assert self.modes.back_off is not None
            v, omega = control.head(pose, self.modes.back_off.direction, ranges)
            v = self._safe_speed(pose, v, omega)
        elif self.path is None:
            v, omega, self._wall_error = wall_follow_command(
                ranges, ctx, prev_error=self._wall_error
            )
        else:
            v, omega, blocked = control.pursue(self.path, pose, ranges)
            if blocked:
                self.path = None  # replan next step with the new hits in the map
            v = self._safe_speed(pose, v, omega)
        v, omega = avoid_robots(v, omega, detections, ctx)
        return ctx.action(v, omega)

    def _safe_speed(self, pose: np.ndarray, v: float, omega: float) -> float:
        """:meth:`~policies.controller.Controller.safe_speed` on the own map."""
        m = self.map
        return self.controller.safe_speed(pose, v, omega, m.layers.obst, m.origin, m.res)

    def _head(self, pose: np.ndarray, direction: float, ranges: np.ndarray) -> tuple[float, float]:
        """:meth:`~policies.controller.Controller.head`."""
        return self.controller.head(pose, direction, ranges)

    def _backing_off(self, pose: np.ndarray, ranges: np.ndarray, detections: np.ndarray) -> bool:
        """Whether to back off now, for ``BACK_OFF_STEPS``: from a robot that is too close ahead
        to pass (no free travel left, within ±80°: what
        :func:`~policies.scripted.avoid_robots` stops for) while this robot stalled; or, stalled
        with no path (no frontier reachable: wall following), out of its pocket
        (:meth:`_escape`). Ending a back-off drops the path and rests its goal, as a stall
        does."""
        modes = self.modes
        if modes.back_off is not None:
            if self._step < modes.back_off.until:
                return True
            modes.back_off = None
            if self.goal is not None:
                self._blacklist[self.goal] = self._step + REST_GOAL
            self.path = self.goal = None
            return False
        if not self._stalled():
            return False
        if len(detections) == 0:
            return self._escape(pose, ranges)
        gap = contact_gap(detections[:, 0], self.context)
        blocking = (gap <= 0.0) & (np.abs(detections[:, 1]) <= math.radians(80))
        if not blocking.any():
            return self._escape(pose, ranges)
        nearest = int(np.argmin(np.where(blocking, detections[:, 0], np.inf)))
        away = pose[2] + float(detections[nearest, 1]) + math.pi
        modes.back_off = BackOff(away, self._step + BACK_OFF_STEPS)
        return True

    def _escape(self, pose: np.ndarray, ranges: np.ndarray) -> bool:
        """A stalled robot with no path (wall following, which in a pocket of clutter turns
        on the spot one way for the wall on its left and back for the one ahead, step after
        step) backs off: toward its longest beam if its own map lets it drive that way as fast
        as any way, else toward the heading (of ``ESCAPE_HEADINGS`` round it) the own map lets
        it drive fastest, which may lie behind it, where no beam reaches."""
        if self.path is not None:
            return False
        beam = pose[2] + float(self.context.beam_angles[int(np.argmax(ranges))])
        headings = [beam, *(pose[2] + np.linspace(-np.pi, np.pi, ESCAPE_HEADINGS, False))]
        v_max = self.context.v_max
        speeds = [self._safe_speed(np.array([pose[0], pose[1], h]), v_max, 0.0) for h in headings]
        toward = float(headings[int(np.argmax(speeds))])  # the first of the fastest: the beam's
        self.modes.back_off = BackOff(toward, self._step + BACK_OFF_STEPS)
        return True

    def _stalled(self) -> bool:
        """Whether the robot moved less than 0.1 m over its last 8 positions."""
        return len(self._trail) >= 8 and bool(np.hypot(*(self._trail[-1] - self._trail[0])) < 0.1)


#: Headings (evenly round the robot) an escape weighs on the own map (:meth:`_escape`).
ESCAPE_HEADINGS = 16


def frontier_closing(context: PolicyContext, **kwargs: Any) -> FrontierPolicy:
    """The policy ``frontier_closing``: :class:`FrontierPolicy` with active loop closing on
    (module doc); keyword arguments as for :class:`FrontierPolicy`."""
    return FrontierPolicy(context, **{"close_loops": True, **kwargs})

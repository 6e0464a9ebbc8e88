"""Goal choice: the frontier planner, with the goal picked among its candidates.

:class:`GoalPolicy` is :class:`~policies.frontier.FrontierPolicy` with one change. Every
``decide_every`` steps it lists up to ``CANDIDATES`` frontier regions of its own map (the
connected groups of frontier cells, each represented by its cell of best utility, ordered by
that utility, so slot 0 is what the frontier policy itself would pick) and describes them in a
fixed-size feature vector (:meth:`GoalPolicy.features`, layout in :data:`FEATURES`).
:meth:`GoalPolicy.choose` picks one — slot 0 here; the learned network in
:class:`policies.ppo.LearnedGoalPolicy` — and the planner drives there. Between decisions it
replans as the frontier policy does when the goal is reached, blocked, claimed by a robot it
saw or no longer a frontier, then to its own best goal.

Everything the features hold comes from the robot's observation (its pose estimate, its own
map, its camera sightings): no ground truth. The decision loop is split so that a training
wrapper can stand between :meth:`GoalPolicy.observe` and :meth:`GoalPolicy.commit` (see
:mod:`polyslam_env.apps.goal_env`); :meth:`GoalPolicy.act` runs the same sequence with
:meth:`GoalPolicy.choose`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from policies.base import PolicyContext, PolicyError
from policies.frontier import FrontierPolicy, Search

__all__ = ["CANDIDATES", "FEATURES", "GLOBALS", "GoalPolicy", "feature_size", "region_best"]

#: Candidate slots per decision.
CANDIDATES = 6
#: Features of one candidate slot, in order (all zero for an empty slot).
FEATURES = (
    "valid",  # 1 for a candidate, 0 for an empty slot
    "path",  # path length / 10 m (clipped at 3)
    "distance",  # straight-line distance / 10 m (clipped at 3)
    "cos_bearing",  # direction in the robot frame
    "sin_bearing",
    "gain",  # unknown fraction within gain_radius of the goal cell
    "size",  # log(1 + frontier cells of the region) / 5
    "utility",  # utility / the best candidate's (1 for slot 0)
    "other_robot",  # distance to the nearest recent sighting of another robot / 10 m (1: none)
    "current",  # 1 if the current goal lies in this region
)
#: Features of the whole decision, after the slots.
GLOBALS = (
    "time",  # step / max_steps
    "regions",  # frontier regions / 10 (clipped at 3)
    "claims",  # 1 if another robot was seen recently
    "no_frontier",  # 1 if no frontier is reachable (the robot follows walls)
)
#: A sighting older than this many steps is not counted in ``other_robot``.
_SIGHTING_STEPS = 150


def feature_size() -> int:
    """Length of the feature vector."""
    return CANDIDATES * len(FEATURES) + len(GLOBALS)


def region_best(labels: np.ndarray, values: np.ndarray) -> tuple[list[int], list[float]]:
    """The flat index and value of the best cell of each region ``1 … labels.max()`` of
    ``labels`` (M,) (0: no region; every label present, as ``ndimage.label`` numbers them):
    its largest value in ``values`` (M,), the first in index order among ties. Sorts only the
    regions' cells, not the whole grid as ``ndimage.maximum_position`` does (whose unstable
    sort also leaves ties to chance)."""
    cells = np.flatnonzero(labels)  # (C,) ascending
    region = labels[cells]
    order = np.lexsort((-values[cells], region))  # by region, best first; stable: index order
    _, first = np.unique(region[order], return_index=True)  # (n,) each region's first row
    best = cells[order[first]]
    return best.tolist(), values[best].tolist()


class GoalPolicy(FrontierPolicy):
    """Frontier exploration whose goals :meth:`choose` picks (module doc).

    ``decide_every`` is the decision period in steps; the other keyword arguments are
    :class:`FrontierPolicy`'s.
    """

    def __init__(self, context: PolicyContext, decide_every: int = 8, **frontier: Any) -> None:
        if decide_every < 1:
            raise PolicyError(f"goals: decide_every must be >= 1, got {decide_every!r}")
        self.decide_every = int(decide_every)
        super().__init__(context, replan_every=self.decide_every, **frontier)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._pose = np.zeros(3)
        self._ranges = np.full(len(self.context.beam_angles), np.inf)
        self._detections = np.zeros((0, 2))
        self._previous_goal: tuple[int, int] | None = None
        self._replan = False
        self._search_now: Search | None = None
        self._goals: list[tuple[int, int]] = []  # (row, col) in the search window, by slot
        self._sightings: list[tuple[np.ndarray, int]] = []  # (own-frame position, step)

    # -- the decision loop -------------------------------------------------------------------
    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        if self.observe(observation):
            self.commit(self.choose(self.features(), rng))
        return self.drive()

    def choose(self, features: np.ndarray, rng: np.random.Generator) -> int:
        """The slot to drive to, from the features (:func:`feature_size`,): here slot 0, the
        frontier policy's own goal."""
        return 0

    def observe(self, observation: Any) -> bool:
        """Fold ``observation`` into the own map; True when a decision is due (then call
        :meth:`features` and :meth:`commit` before :meth:`drive`)."""
        pose, ranges, detections = self._sense(observation)
        self._pose, self._ranges, self._detections = pose, ranges, detections
        self._remember(pose, detections)
        claimed = self._claim(pose, detections)
        if (self._step - 1) % self.decide_every == 0:
            self._previous_goal = self.goal
            self._search_now = self._search(pose, complete=True)
            return True
        self._replan = claimed or self._needs_plan(pose)
        return False

    def features(self) -> np.ndarray:  # (feature_size(),) float32
        """The candidates of the due decision (module doc, :data:`FEATURES`)."""
        out = np.zeros(feature_size(), dtype=np.float32)
        search = self._search_now
        regions = 0
        self._goals = []
        if search is not None:
            regions, slots = self._candidates(search)
            self._goals = [goal for goal, _ in slots]
            for k, (_, values) in enumerate(slots):
                out[k * len(FEATURES) : (k + 1) * len(FEATURES)] = values
        g = CANDIDATES * len(FEATURES)
        out[g:] = (
            self._step / max(self.context.max_steps, 1),
            min(regions / 10.0, 3.0),
            float(bool(self._claims)),
            float(search is None),
        )
        return out

    def commit(self, slot: int) -> None:
        """Drive to the candidate in ``slot`` (slot 0 when that slot is empty)."""
        search = self._search_now
        if search is None or not self._goals:
            return  # no frontier: drive() follows walls
        slot = int(slot) if 0 <= int(slot) < len(self._goals) else 0
        self._go(search, self._goals[slot])

    def drive(self) -> Any:
        """The action for this step: replan first if an event asked for it (after
        :meth:`observe` without a decision), then follow the path (or the walls)."""
        if self._replan:
            self._replan = False
            self._plan(self._pose)
        return self._follow(self._pose, self._ranges, self._detections)

    # -- candidates --------------------------------------------------------------------------
    def _candidates(self, search: Search) -> tuple[int, list[tuple[tuple[int, int], np.ndarray]]]:
        """The number of frontier regions with a finite utility, and up to ``CANDIDATES``
        (goal cell, feature row) for the best of them."""
        labels, n = ndimage.label(search.frontier, structure=np.ones((3, 3)))
        if n == 0:
            return 0, []
        flat_l = labels.reshape(-1)
        sizes = np.bincount(flat_l, minlength=n + 1)[1:]  # (n,)
        order = []
        cells, best = region_best(flat_l, search.utility.reshape(-1))
        for k, (flat, u) in enumerate(zip(cells, best, strict=True)):
            if math.isfinite(u):
                order.append((-u, flat, k))
        order.sort()  # best utility first, then row-major: slot 0 is search.best()
        rows = []
        top = -order[0][0] if order else 1.0
        for neg_u, flat, k in order[:CANDIDATES]:
            r, c = divmod(flat, labels.shape[1])
            rows.append(
                ((r, c), self._describe(search, (r, c), int(sizes[k]), -neg_u / top, k + 1, labels))
            )
        return len(order), rows

    def _describe(
        self,
        search: Search,
        cell: tuple[int, int],
        size: int,
        utility: float,
        label: int,
        labels: np.ndarray,
    ) -> np.ndarray:
        m, window = self.map, search.window
        goal = m.centre(cell[0] + window[0].start, cell[1] + window[1].start)
        dx, dy = goal - self._pose[:2]
        distance = math.hypot(dx, dy)
        bearing = math.atan2(dy, dx) - self._pose[2]
        near = 10.0
        for where, _ in self._sightings:
            near = min(near, math.hypot(*(goal - where)))
        current = 0.0
        if self._previous_goal is not None:
            r = self._previous_goal[0] - window[0].start
            c = self._previous_goal[1] - window[1].start
            inside = 0 <= r < labels.shape[0] and 0 <= c < labels.shape[1]
            current = float(inside and labels[r, c] == label)
        return np.array(
            [
                1.0,
                min(float(search.dist[cell]) / 10.0, 3.0),
                min(distance / 10.0, 3.0),
                math.cos(bearing),
                math.sin(bearing),
                float(search.gain[cell]),
                math.log1p(size) / 5.0,
                utility,
                near / 10.0,
                current,
            ],
            dtype=np.float32,
        )

    def _remember(self, pose: np.ndarray, detections: np.ndarray) -> None:
        """Keep the own-frame positions of the robots the camera saw in the last
        ``_SIGHTING_STEPS`` steps."""
        keep = self._step - _SIGHTING_STEPS
        self._sightings = [s for s in self._sightings if s[1] > keep]
        for distance, bearing in detections:
            phi = pose[2] + bearing
            where = pose[:2] + distance * np.array([math.cos(phi), math.sin(phi)])
            self._sightings.append((where, self._step))
        self._sightings = self._sightings[-8:]

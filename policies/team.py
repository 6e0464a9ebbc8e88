"""Coordinated frontier exploration (``--policy frontier_team``): Burgard et al. (2005) on what
each robot knows (SPEC §7).

:class:`TeamFrontierPolicy` is the frontier policy (:mod:`policies.frontier`: own map, planner,
controller, camera claims) plus goal messages (:mod:`policies.radio`). Each robot

1. **announces** its goal while it sees another robot: a message with its goal and the last
   ``history − 1`` goals it had (where it has been exploring), in its body frame, and what its
   camera sees; when the goal changed, the robots in view changed, or ``resend`` steps passed
   since the last one (every message is counted in bytes);
2. **listens**: a team-mate's message of the last step that it can pair with its own sighting
   of that robot (a mutual sighting) gives the team-mate's goals in its own frame; it keeps the
   last goals of each team-mate for ``goal_steps`` steps;
3. **discounts** the utility of every frontier by the team-mates' goals it knows
   (:func:`policies.planner.team_discount`): ``Π_k (1 − P(d_k))``, ``P(d) = 1 − d / team_range``
   within ``team_range`` m — Burgard's ``U(t) − β P(t)`` with the utility a product rather
   than a difference, as the planner's utility is gain × exp(−path / decay) (the chance that
   no team-mate sees the frontier's unknown space first);
4. **replans** when a team-mate with a lower index announces a goal that discounts its own
   (Burgard's sequential assignment: robot i yields to robots 0 … i−1, so two robots never
   swap goals back and forth).

**Explored area** (``share_area``, on by default): a message also carries, every
``area_resend`` steps of a meeting and whenever the robots in view change, the area its sender
knows explored — the free cells of its own map and the area its team-mates told it of — as a
grid of ``area_cell`` m cells in its own frame (:class:`~policies.radio.Area`, deflated, counted
in the message's bytes). A receiver places it with the mutual sighting as it places the goals
(:func:`~policies.radio.area_in_own_frame`) and keeps it for the episode (its frame and the
sender's do not move; the error is the sighting's and the pose drift since). Its discount then
has a second factor: the share of a frontier's unknown gain square (the planner's
``square`` gain: ``2 · gain_radius`` a side) that no team-mate explored
(:meth:`TeamFrontierPolicy.area_discount`), so a robot stops treating a team-mate's rooms as
frontiers; a goal whose square lost half its unknown so replans at once, whatever the sender's
index (an explored area is a fact, not a claim: nothing to swap back and forth).

**A radio longer than the camera** (the env's ``channel.range`` above the camera's; the radio
then has the env's distance test, :class:`~policies.radio.Radio`): every message also carries
its sender's own-frame pose, and a receiver keeps, from its first mutual sighting of a
team-mate, the transform between their two start frames (:func:`~policies.radio.own_frame_of`).
A robot that has met a team-mate so sends its goal (and, every ``radio_area_resend`` steps, its
area) also while it sees nobody, every ``radio_resend`` steps (a goal changed meanwhile waits:
frontier goals change every few steps, and the bytes count), and
a receiver within radio range whose transform to the sender it holds places the message
through it, with no sighting, and takes it as one heard over a sighting. With the default env
(``channel.range`` = the camera's 1.5 m) nothing changes.

The camera claims of plain frontier (a seen robot's side is left to it, ``claim_radius`` for
``claim_steps``) stay: they are what a robot knows of where a team-mate was last seen heading.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from policies.base import PolicyContext, PolicyError
from policies.frontier import FrontierPolicy
from policies.planner import team_discount
from policies.radio import (
    Area,
    GoalMessage,
    Links,
    Radio,
    area_in_frame,
    decode,
    encode,
    mate_in_own_frame,
    mutual_sighting,
    own_frame_of,
    team_radio,
)
from polyslam_env.core.geometry import compose, inverse, transform_points

__all__ = ["TeamFrontierPolicy", "frontier_team"]


class TeamFrontierPolicy(FrontierPolicy):
    """The frontier policy with announced goals and Burgard's discount (module doc).

    ``radio`` is the team's shared :class:`~policies.radio.Radio` (a private one, with nobody
    to talk to, if None); ``team_range`` m is the reach of a team-mate's goal's discount,
    ``goal_steps`` how long a heard goal counts, ``history`` how many goals a message holds
    (the current one and the last ones), ``resend`` the steps between two messages of an
    unchanged goal, ``match_tol`` m how far two distance readings of one mutual sighting
    may differ (default 0.06 m: four σ of the difference of two readings of the default
    camera, σ_d = 0.01 m each); ``share_area`` sends and takes the explored area (module doc)
    on a grid of ``area_cell`` m, again every ``area_resend`` steps of a meeting; over a radio
    longer than the camera (module doc) a robot that sees nobody sends its goal every
    ``radio_resend`` steps and its area every ``radio_area_resend``; other
    keywords go to :class:`FrontierPolicy`."""

    def __init__(
        self,
        context: PolicyContext,
        radio: Radio | None = None,
        team_range: float = 4.0,
        goal_steps: int = 100,
        history: int = 4,
        resend: int = 10,
        match_tol: float = 0.06,
        share_area: bool = True,
        area_cell: float = 0.2,
        area_resend: int = 20,
        radio_resend: int = 20,
        radio_area_resend: int = 100,
        **kwargs: Any,
    ) -> None:
        for name, value in (
            ("team_range", team_range),
            ("goal_steps", goal_steps),
            ("history", history),
            ("resend", resend),
            ("match_tol", match_tol),
            ("area_cell", area_cell),
            ("area_resend", area_resend),
            ("radio_resend", radio_resend),
            ("radio_area_resend", radio_area_resend),
        ):
            if not value > 0:
                raise PolicyError(f"frontier_team: {name} must be > 0, got {value!r}")
        self.radio = Radio(context.num_robots) if radio is None else radio
        self.team_range, self.goal_steps = float(team_range), int(goal_steps)
        self.history = min(int(history), 255)
        self.resend, self.match_tol = int(resend), float(match_tol)
        if not 0.01 <= area_cell <= 2.55:
            raise PolicyError(f"frontier_team: area_cell must be 0.01 … 2.55 m, got {area_cell!r}")
        self.share_area = bool(share_area)
        self.area_cell, self.area_resend = round(float(area_cell), 2), int(area_resend)
        self.radio_resend, self.radio_area_resend = int(radio_resend), int(radio_area_resend)
        super().__init__(context, **kwargs)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.radio.reset(self.context.index)
        #: team-mate → (its goals (g, 2) in the own frame, step they expire)
        self.heard: dict[int, tuple[np.ndarray, int]] = {}
        #: the pose (3,) and detections (k, 2) of the last step (the next step's messages
        #: were sent then)
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self._sent: tuple[tuple[int, int], int, int] | None = None  # goal, k seen, step
        self._goals: list[tuple[int, int]] = []  # the last goals (own-map cells), newest first
        #: own-map cells a team-mate told it it explored (module doc)
        self.team_area = np.zeros((self.map.n, self.map.n), dtype=bool)
        self._area_sent: tuple[int, int] | None = None  # k seen, step of the last area sent
        self._areas_received = 0
        #: team-mate → its own (start) frame (3,) in this robot's, from the first mutual
        #: sighting whose message carried its pose (a radio longer than the camera only)
        self.frames: dict[int, np.ndarray] = {}
        self._radio_received = 0

    def metrics(self) -> dict[str, float]:
        """The goal messages of the episode so far: sent, their bytes, received (of which
        over the radio's range, without a sighting), and the explored areas received."""
        i = self.context.index
        return {
            "goal_messages_sent": float(self.radio.messages_sent[i]),
            "goal_bytes_sent": float(self.radio.bytes_sent[i]),
            "goal_messages_received": float(self.radio.messages_received[i]),
            "goal_messages_unseen": float(self._radio_received),
            "goal_areas_received": float(self._areas_received),
        }

    def frontier_discount(self, points: np.ndarray) -> np.ndarray:
        """Burgard's discount of the frontier points (F, 2) by the team-mates' goals heard,
        times the share of their gain square no team-mate explored (:meth:`area_discount`)."""
        goals = np.concatenate([np.zeros((0, 2)), *(g for g, _ in self.heard.values())])
        return team_discount(points, goals, self.team_range) * self.area_discount(points)

    def area_discount(self, points: np.ndarray) -> np.ndarray:  # (F,)
        """At own-frame points (F, 2), the share of the unknown cells of the square of
        ``2 · gain_cells + 1`` cells around each (the planner's ``square`` gain) that lies
        outside :attr:`team_area` (1 where the square has no unknown cell or the point lies
        off the map)."""
        m, half = self.map, self.gain_cells
        out = np.ones(len(points))
        ij, inside = m.index(points)
        if not inside.any() or not self.team_area.any():
            return out
        cols, rows = ij[inside, 0], ij[inside, 1]
        r0, c0 = max(int(rows.min()) - half, 0), max(int(cols.min()) - half, 0)
        r1, c1 = min(int(rows.max()) + half + 1, m.n), min(int(cols.max()) + half + 1, m.n)
        unknown = ~m.layers.known.reshape(m.n, m.n)[r0:r1, c0:c1]
        told = unknown & self.team_area[r0:r1, c0:c1]
        lo_r, hi_r = np.maximum(rows - half, r0) - r0, np.minimum(rows + half + 1, r1) - r0
        lo_c, hi_c = np.maximum(cols - half, c0) - c0, np.minimum(cols + half + 1, c1) - c0
        counts = []
        for grid in (unknown, told):
            s = np.zeros((r1 - r0 + 1, c1 - c0 + 1), dtype=np.int64)  # summed-area table
            s[1:, 1:] = grid.cumsum(axis=0).cumsum(axis=1)
            counts.append(s[hi_r, hi_c] - s[lo_r, hi_c] - s[hi_r, lo_c] + s[lo_r, lo_c])
        total, gone = counts
        out[inside] = np.where(total > 0, 1.0 - gone / np.maximum(total, 1), 1.0)
        return out

    def _discount(self) -> Any:
        """:meth:`frontier_discount` while a team-mate's goal or area is known, else None
        (then the planner may stop its search early, as plain frontier's)."""
        return self.frontier_discount if self.heard or self.team_area.any() else None

    # -- the frontier policy's step, with messages ------------------------------------------
    def _claim(self, pose: np.ndarray, detections: np.ndarray) -> bool:
        """The camera claims (:class:`FrontierPolicy`), then the messages heard; True when
        either asks for a new plan."""
        claimed = super()._claim(pose, detections)
        return self._listen() or claimed

    def _follow(self, pose: np.ndarray, ranges: np.ndarray, detections: np.ndarray) -> Any:
        """Announce the goal just planned (or kept), then follow it."""
        self._announce(pose, detections)
        return super()._follow(pose, ranges, detections)

    def _listen(self) -> bool:
        """Take in the team-mates' messages of the last step that came over a mutual sighting
        or, with a radio longer than the camera, over its range from a team-mate met before
        (module doc); whether one of a lower-index team-mate discounts the current goal."""
        step, me = self._step, self.context.index
        self.heard = {k: v for k, v in self.heard.items() if v[1] > step}
        if self._last is None:
            return False
        pose, seen = self._last
        replan = False
        for data in self.radio.heard(me):
            message = decode(data)
            if message.step != step - 1:
                continue  # not sent at the last step: out of range then, or old
            body = self._place(message, pose, seen)
            if body is None:
                continue
            goals = np.asarray(transform_points(message.goals, body))
            self.heard[message.sender] = (goals, step + self.goal_steps)
            self.radio.messages_received[me] += 1
            if message.area is not None and self.share_area:
                self._take_area(own_frame_of(body, message.area.pose), message.area)
                if self.goal is not None:
                    mine = self.map.centre(*self.goal)[None]  # (1, 2)
                    replan |= bool(self.area_discount(mine)[0] < 0.5)
            if message.sender < me and self.goal is not None:
                mine = self.map.centre(*self.goal)[None]  # (1, 2)
                replan |= bool(team_discount(mine, goals[:1], self.team_range)[0] < 1.0)
        return replan

    def _place(self, message: GoalMessage, pose: np.ndarray, seen: np.ndarray) -> Any:
        """The sender's body pose (3,) in the own frame when ``message`` reached this robot,
        else None: over a mutual sighting (this robot at ``pose`` saw ``seen`` then; keeps the
        sender's frame at the first one that carries its pose), or over the radio's range
        from a team-mate whose frame it keeps."""
        pair = mutual_sighting(seen, message.detections, self.match_tol)
        if pair is not None:
            j, k = pair
            body = mate_in_own_frame(pose, seen[j], message.detections[k, 1])
            if message.pose is not None and message.sender not in self.frames:
                self.frames[message.sender] = own_frame_of(body, message.pose)
            return body
        frame = self.frames.get(message.sender)
        if frame is None or message.pose is None:
            return None
        if not self.radio.reached(message.sender, self.context.index):
            return None
        self._radio_received += 1
        return np.asarray(compose(frame, message.pose))

    def _take_area(self, frame: np.ndarray, area: Area) -> None:
        """Mark a team-mate's explored ``area`` in :attr:`team_area`, its own frame being
        ``frame`` (3,) in this robot's."""
        self.team_area[self.map.cells(area_in_frame(area, frame))] = True
        self._areas_received += 1

    def explored_area(self, pose: np.ndarray) -> Area:
        """The area this robot knows explored (its own map's free cells and :attr:`team_area`)
        on the ``area_cell`` lattice of its own frame, a cell explored where any own-map cell
        whose centre lies in it is; ``pose`` (3,) is its own."""
        m = self.map
        rows, cols = np.nonzero(m.free | self.team_area)
        if len(rows) == 0:
            return Area(pose.copy(), (0, 0), np.zeros((0, 0), dtype=bool), self.area_cell)
        centres = (np.column_stack([cols, rows]) + 0.5) * m.res + m.origin
        lattice = np.floor(centres / self.area_cell).astype(np.int64)  # (M, 2) col, row
        corner = lattice.min(axis=0)
        w, h = lattice.max(axis=0) - corner + 1
        cells = np.zeros((h, w), dtype=bool)
        cells[lattice[:, 1] - corner[1], lattice[:, 0] - corner[0]] = True
        return Area(pose.copy(), (int(corner[0]), int(corner[1])), cells, self.area_cell)

    def _announce(self, pose: np.ndarray, detections: np.ndarray) -> None:
        """Send the goal while a robot is in view, or over a radio longer than the camera once
        it has met a team-mate (module doc); remember this step's pose and detections for the
        messages the next step brings."""
        self._last = (pose.copy(), detections.copy())
        if self.goal is not None and self.goal not in self._goals[:1]:
            self._goals = [self.goal, *self._goals][: self.history]
        far = self.radio.links is not None  # a radio longer than the camera
        k = len(detections)
        if self.goal is None or (k == 0 and not (far and self.frames)):
            return
        resend, area_resend = (
            (self.resend, self.area_resend) if k else (self.radio_resend, self.radio_area_resend)
        )
        if self._sent is not None:
            goal, k_sent, step = self._sent
            if self._step - step < resend and (k == 0 or (goal == self.goal and k_sent == k)):
                return  # over the radio alone, at most every radio_resend steps
        me = self.context.index
        goals = [self.goal, *(g for g in self._goals if g != self.goal)][: self.history]
        body = transform_points(np.array([self.map.centre(*g) for g in goals]), inverse(pose))
        area = None
        if self.share_area and (
            self._area_sent is None
            or (k and self._area_sent[0] != k)
            or self._step - self._area_sent[1] >= area_resend
        ):
            area = self.explored_area(pose)
            self._area_sent = (k, self._step)
        own = pose.copy() if far and area is None else None
        self.radio.send(me, encode(GoalMessage(me, self._step, detections, body, area, own)))
        self._sent = (self.goal, k, self._step)


def frontier_team(context: PolicyContext, **kwargs: Any) -> TeamFrontierPolicy:
    """The policy ``frontier_team`` for one robot (a radio of its own: nobody hears it)."""
    return TeamFrontierPolicy(context, **kwargs)


def _team(
    contexts: list[PolicyContext], links: Links | None = None, **kwargs: Any
) -> dict[str, TeamFrontierPolicy]:
    """The policies ``frontier_team`` of a whole team, sharing one radio (reaching as far as
    the env's channel with its ``links``: :func:`~policies.radio.team_radio`)."""
    radio = team_radio(contexts, links)
    return {c.agent: TeamFrontierPolicy(c, radio=radio, **kwargs) for c in contexts}


frontier_team.team = _team  # type: ignore[attr-defined]
frontier_team.takes_links = True  # type: ignore[attr-defined]

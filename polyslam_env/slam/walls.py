"""The wall graph of one robot's map: pieces of one wall linked across gaps, walls tied square
(:class:`WallGraph`; the geometry and the rows are :mod:`~polyslam_env.slam.links`').

Two partitions of the landmarks: *wall groups* (pieces linked across gaps, directly or through
others, or merged from linked pieces) and *direction groups* (walls tied square or parallel,
as pieces of one wall are). A fact may be used once: pieces of one wall group are never
linked again among themselves, and each square tie joins two direction groups. The graph
follows the map's lineage (:mod:`~polyslam_env.slam.lineage`): a new landmark starts its own
groups, a refit or merge inherits its parents' (joined), a removed landmark leaves.

``link_age`` steps after a landmark is created, refit or merged, :meth:`WallGraph.link_changed`
links it to the straight pieces of its wall across gaps and ties it square, each a
pseudo-measurement update that estimates the two lines' turns and turns the stored lines by
them (:meth:`WallGraph.update_pair`). Received landmarks take no part
(:mod:`~polyslam_env.slam.links` says why).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from polyslam_env.slam import ekf
from polyslam_env.slam.landmarks import EXTENT_MARGIN
from polyslam_env.slam.lineage import MERGED, REMOVED, REPLACED, LineageEvent
from polyslam_env.slam.links import (
    SQUARE_MIN_LENGTH,
    chord_bias,
    evidence_gap,
    junction,
    junction_rows,
    line_angle,
    link_rows,
    off_square,
    pair_supported,
    rectilinear,
    turned_line,
)
from polyslam_env.slam.map_kernels import GAP_SPLIT
from polyslam_env.slam.polynomial import polyval

if TYPE_CHECKING:
    from polyslam_env.slam.robot import PolySlam


#: m: a curve is linked only to pieces whose evidence meets its own, a gap no wider than the
#: beams' sampling along a wall (``map_kernels.GAP_SPLIT``, wider is a doorway): the junction
#: rows extrapolate each shape to the junction, and beyond its evidence a curve's order-m fit
#: misses the wall's next terms, which its frozen variance does not hold (linked across
#: ``link_gap``, the curved floors' maps got worse: docs/notes/curved.md)
CURVE_LINK_GAP = GAP_SPLIT


class WallGraph:
    """Wall and direction groups of one :class:`~polyslam_env.slam.robot.PolySlam`'s
    landmarks, and the links and square ties between them (module docstring)."""

    def __init__(self, slam: PolySlam) -> None:
        self.slam = slam
        self.config = slam.config
        self.wall_of: dict[int, int] = {}  # landmark id → its wall group
        self.direction_of: dict[int, int] = {}  # landmark id → its direction group
        slam.lineage.listen(self.follow)

    def follow(self, event: LineageEvent) -> None:
        """Keep the groups with a lineage event: a new landmark starts its own; a refit or
        merge puts its parents' groups into its own (what they share is in the state now,
        and must not be used again) and they leave; a removed landmark leaves."""
        landmark_id = event.landmark_id
        if event.kind == REMOVED:
            self.wall_of.pop(landmark_id, None)
            self.direction_of.pop(landmark_id, None)
            return
        self.wall_of[landmark_id] = landmark_id
        self.direction_of[landmark_id] = landmark_id
        if event.kind in (REPLACED, MERGED):
            for parent in event.parents:
                self.join_walls(landmark_id, parent)
                self.wall_of.pop(parent, None)
                self.direction_of.pop(parent, None)

    def join_walls(self, keep: int, other: int) -> None:
        """Put landmark ``other``'s wall group into landmark ``keep``'s (a link or a merge),
        and so their direction groups (one wall is parallel to itself)."""
        join_groups(self.wall_of, keep, other)
        join_groups(self.direction_of, keep, other)

    # -- links and square ties --------------------------------------------------------------
    def link_changed(self) -> int:
        """Link the landmarks created, refit or merged ``config.link_age`` steps ago to the
        straight pieces of their walls across gaps (:meth:`link_walls`) and tie them square
        (:meth:`square_wall`); a linked landmark is then checked for merges again (pieces a
        few cm apart that no join fit could explain may now be one polynomial). Returns the
        number of links and ties."""
        cfg, slam = self.config, self.slam
        if cfg.link_gap <= 0.0 and not cfg.square_walls:
            return 0
        table = slam.table
        made_at = slam.step_count - cfg.link_age
        fresh = [table.ids[j] for j in np.flatnonzero(table.changed_at == made_at).tolist()]
        links = 0
        for landmark_id in fresh:
            made = self.link_walls(landmark_id) + self.square_wall(landmark_id)
            if made:
                links += made
                slam.maintenance.merge_into_map(landmark_id)
        if cfg.square_pair_evidence and fresh:
            links += self.square_loners()
        return links

    def square_loners(self) -> int:
        """With the evidence per pair (``config.square_pair_evidence``) a wall's tie may have
        lacked its third wall when it was tried: once new walls have matured, try again every
        own straight wall still alone in its direction group and ``config.link_age`` steps old.
        Returns the number of ties."""
        table = self.slam.table
        matured = self.slam.step_count - self.config.link_age
        sizes: dict[int, int] = {}
        for group in self.direction_of.values():
            sizes[group] = sizes.get(group, 0) + 1
        alone = [
            lid
            for j, lid in enumerate(table.ids)
            if table.order[j] == 1
            and table.changed_at[j] <= matured
            and sizes[self.direction_of[lid]] == 1
        ]
        return sum(self.square_wall(lid) for lid in alone if lid in table)

    def link_walls(self, landmark_id: int) -> int:
        """Link a straight landmark to every straight piece of another wall group, made at
        least ``config.link_age`` steps ago, whose evidence lies at most ``config.link_gap``
        from its own along their common axis, nearest first, when the collinearity
        pseudo-measurement passes its χ²(2) gate (:mod:`~polyslam_env.slam.links`); returns
        the number of links made."""
        cfg, slam = self.config, self.slam
        table, maintenance = slam.table, slam.maintenance
        if cfg.link_gap <= 0.0 or landmark_id not in table:
            return 0
        idx = table.index_of(landmark_id)
        if table.received[idx] or not self.linkable(int(table.order[idx])):
            return 0
        evidence = maintenance.evidence(idx)
        reach = cfg.link_gap * (1.0 + 1e-9) + EXTENT_MARGIN
        candidates = []
        matured = slam.step_count - cfg.link_age  # partners at least as old (link_changed)
        near = table.near(maintenance.box(idx), slam.c0s, reach)
        variate, order = table.variate, table.order
        near = near[
            (near != idx)
            & (variate[near] == variate[idx])
            & ((order[near] == 1) | self.linkable(2))
            & (table.changed_at[near] <= matured)
            & (table.received[near] == 0)
        ]
        for j in near.tolist():
            gap = evidence_gap(evidence, maintenance.evidence(j))
            reach_j = cfg.link_gap if order[idx] == order[j] == 1 else CURVE_LINK_GAP
            if -2.0 * EXTENT_MARGIN <= gap <= reach_j:
                candidates.append((gap, table.ids[j]))
        links = 0
        for _, other_id in sorted(candidates):
            if self.wall_of[other_id] != self.wall_of[landmark_id]:
                links += self.link_pair(landmark_id, other_id)
        return links

    def linkable(self, order: int) -> bool:
        """Whether a landmark of ``order`` may be linked: a line, or with
        ``config.curve_links`` and rotation states a curve too."""
        return order == 1 or (self.config.curve_links and self.config.rotation_states)

    def link_pair(self, first: int, second: int) -> bool:
        """The collinearity update of two straight landmarks (rows at the middle of each one's
        evidence, noise each fit's variance beyond the range noise plus
        ``config.wall_straightness``²), estimating their two turns (:meth:`update_pair`);
        whether it passed the gate and was applied. A pair with a curve meets at its
        junction instead (:meth:`link_junction`)."""
        slam = self.slam
        table, maintenance = slam.table, slam.maintenance
        i, j = table.index_of(first), table.index_of(second)
        if table.order[i] != 1 or table.order[j] != 1:
            return self.link_junction(first, second)
        xis = np.array([0.5 * sum(maintenance.evidence(i)), 0.5 * sum(maintenance.evidence(j))])
        if self.direction_of[first] == self.direction_of[second]:
            xis = xis.mean(keepdims=True)  # parallel already: only the offset is new
        residual, H = link_rows(
            maintenance.polynomial(i), 3 + i, maintenance.turn_of(i),
            maintenance.polynomial(j), 3 + j, maintenance.turn_of(j),
            xis, slam.mean.size,
        )  # fmt: skip
        r = float(table.model_var[i] + table.model_var[j]) + self.config.wall_straightness**2
        if not self.update_pair(i, j, -residual, H, r * np.eye(xis.size)):
            return False
        self.join_walls(first, second)
        return True

    def link_junction(self, first: int, second: int) -> bool:
        """Two pieces of one wall, a curve among them (``config.curve_links``), meet at the
        junction of their evidence with one tangent (:func:`~polyslam_env.slam.links.
        junction_rows`; only the offset when they are in one direction group already). The
        noise of each row is what no state holds at the junction, the curve extrapolated
        there included: each piece's frozen error (:meth:`PolySlam.frozen_variance` on η,
        :meth:`PolySlam.frozen_slope_variance` on the slope) plus ``config.wall_straightness``²
        on η and ``config.wall_squareness_deg`` as a kink on the direction. Gated by χ²;
        the lines' turns are estimated, the curves' stay considered (:meth:`update_pair`)."""
        slam, cfg = self.slam, self.config
        table, maintenance = slam.table, slam.maintenance
        i, j = table.index_of(first), table.index_of(second)
        xi = junction(maintenance.evidence(i), maintenance.evidence(j))
        residual, H = junction_rows(
            maintenance.polynomial(i), 3 + i, maintenance.turn_of(i),
            maintenance.polynomial(j), 3 + j, maintenance.turn_of(j),
            xi, slam.mean.size,
        )  # fmt: skip
        value_var, slope_var = cfg.wall_straightness**2, 0.0
        for k, other in ((i, j), (j, i)):
            value_var += float(slam.frozen_variance(k, np.array([xi]))[0])
            slope_var += slam.frozen_slope_variance(k, xi)
            if table.order[k] == 1:  # a line on the other's curve: a chord, off at its end
                bend = float(polyval(xi, table.polys[other].coeffs, derivative=2))
                lo, hi = maintenance.evidence(k)
                value_bias, slope_bias = chord_bias(bend, xi - 0.5 * (lo + hi), 0.5 * (hi - lo))
                value_var += value_bias**2
                slope_var += slope_bias**2
        slope = float(polyval(xi, table.polys[i].coeffs, derivative=1))
        slope_var += (1.0 + slope * slope) ** 2 * math.radians(cfg.wall_squareness_deg) ** 2
        rows = 1 if self.direction_of[first] == self.direction_of[second] else 2
        R = np.diag([value_var, slope_var])[:rows, :rows]
        if not self.update_pair(i, j, -residual[:rows], H[:rows], R):
            return False
        self.join_walls(first, second)
        return True

    def square_wall(self, landmark_id: int) -> int:
        """Tie straight landmark ``landmark_id`` in direction to the straight landmark of
        another direction group, made at least ``config.link_age`` steps ago, whose angle to
        it the state knows best, by the pseudo-measurement that their angle is a multiple of
        90° (:func:`~polyslam_env.slam.links.off_square`), noise ``config.wall_squareness_deg``²
        plus each fit's direction variance beyond the range noise, gated by χ²(1); estimates
        the two lines' turns as a link does. Needs ``config.square_walls``, rotation
        states and (with ``config.square_evidence``) a rectilinear floor
        (:meth:`rectilinear`); received landmarks take no part. Returns 1 if tied, else 0."""
        cfg, slam = self.config, self.slam
        table = slam.table
        if not cfg.square_walls or not cfg.rotation_states or landmark_id not in table:
            return 0
        if cfg.square_evidence and not self.rectilinear():
            return 0
        i = table.index_of(landmark_id)
        if table.received[i] or table.order[i] != 1 or not self.long_enough(i):
            return 0
        group, ids = self.direction_of[landmark_id], table.ids
        others = np.array(
            [j for j in self.mature_lines().tolist() if self.direction_of[ids[j]] != group],
            dtype=np.int64,
        )
        if others.size == 0:
            return 0
        n = len(table)
        turn_index = slam.layout.turn_index
        t_i, t_others = turn_index(i, n), turn_index(0, n) + others
        cov = slam.cov
        relative = cov[t_i, t_i] + cov[t_others, t_others] - 2.0 * cov[t_i, t_others]
        j = int(others[int(np.argmin(relative))])
        t_j = turn_index(j, n)
        angle = line_angle(table.polys[i]) + slam.mean[t_i]
        angle -= line_angle(table.polys[j]) + slam.mean[t_j]
        H = np.zeros((1, slam.mean.size))
        H[0, t_i], H[0, t_j] = 1.0, -1.0
        r = math.radians(cfg.wall_squareness_deg) ** 2 + sum(
            float(table.model_var[k]) / float(table.fit_half[k]) ** 2 for k in (i, j)
        )
        if cfg.square_pair_evidence and not self.pair_supported(i, j):
            return 0
        if not self.update_pair(i, j, np.array([-off_square(angle)]), H, np.array([[r]])):
            return 0
        join_groups(self.direction_of, landmark_id, table.ids[j])
        return 1

    def rectilinear(self) -> bool:
        """Whether this robot's own map says its floor is rectilinear
        (:func:`~polyslam_env.slam.links.rectilinear`): its confident straight walls (own,
        ``config.link_age`` steps old, ``SQUARE_MIN_LENGTH`` long) are the evidence, each
        pair's relative direction variance that of a tie (the state's var(α_i − α_j) plus
        each fit's direction variance and ``config.wall_squareness_deg``²). Needs rotation
        states (False without)."""
        if not self.config.rotation_states:
            return False
        directions, relative, lengths = self.square_evidence(self.confident_walls())
        return rectilinear(directions, relative, lengths, self.config.gate_prob)

    def pair_supported(self, i: int, j: int) -> bool:
        """Whether straight landmarks ``i`` and ``j`` (rows) have a third confident straight
        wall (as :meth:`rectilinear`'s, no piece of either's wall) square to both
        (:func:`~polyslam_env.slam.links.pair_supported`; ``config.square_pair_evidence``)."""
        table = self.slam.table
        walls = {self.wall_of[table.ids[i]], self.wall_of[table.ids[j]]}
        others = [k for k in self.confident_walls() if self.wall_of[table.ids[k]] not in walls]
        directions, relative, _ = self.square_evidence([i, j, *others])
        return pair_supported(0, 1, directions, relative, self.config.gate_prob)

    def confident_walls(self) -> list[int]:
        """Rows of the straight walls that are square evidence: own, ``config.link_age``
        steps old, ``SQUARE_MIN_LENGTH`` long."""
        return self.mature_lines(SQUARE_MIN_LENGTH).tolist()

    def square_evidence(self, rows_list: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(directions, their pairwise relative variances, lengths) of straight walls
        ``rows_list`` (rows) as :func:`~polyslam_env.slam.links.rectilinear` takes them."""
        cfg, slam = self.config, self.slam
        table = slam.table
        rows = np.asarray(rows_list, dtype=np.int64)
        turns = slam.layout.turn_index(0, len(table)) + rows
        directions = np.array([line_angle(table.polys[j]) for j in rows.tolist()])
        directions += slam.mean[turns]
        fit = table.model_var[rows] / table.fit_half[rows] ** 2
        own = np.diag(slam.cov)[turns] + fit + 0.5 * math.radians(cfg.wall_squareness_deg) ** 2
        block = slam.cov[np.ix_(turns, turns)]
        relative = own[:, None] + own[None, :] - 2.0 * block
        lengths = table.hi[rows] - table.lo[rows]
        return directions, relative, lengths

    def update_pair(
        self, i: int, j: int, innovation: np.ndarray, H: np.ndarray, R: np.ndarray
    ) -> bool:
        """A pseudo-measurement tying straight landmarks ``i`` and ``j`` (rows):
        :func:`~polyslam_env.slam.ekf.update_rows` with every turn but the two lines' own
        considered, then both stored lines turned by their estimates (:meth:`apply_turn`) and
        the stored points carried with the pose; whether it passed its gate and was applied."""
        slam, cfg = self.slam, self.config
        considered = None
        n = len(slam.table)
        lines = [k for k in (i, j) if slam.table.order[k] == 1]
        if cfg.rotation_states:  # every turn but the two lines' own
            turns = slam.layout.turn_index(0, n) + np.arange(n)
            considered = np.delete(turns, lines)
        result = ekf.update_rows(slam.mean, slam.cov, innovation, H, R, cfg.gate_prob, considered)
        if result is None:
            return False
        before = slam.mean[:3].copy()
        slam.mean, slam.cov, _ = result
        if cfg.rotation_states:
            for k in lines:
                self.apply_turn(k)
        slam.state_moved(before)
        return True

    def apply_turn(self, row: int) -> None:
        """Turn straight landmark ``row``'s stored line by its estimated turn α̂ about its
        pivot and reset α̂ to 0: an error-state reset. Turns about one point add, and the
        offset at the pivot stays (:func:`~polyslam_env.slam.links.turned_line`), so the
        errors keep their meaning and the covariance stays."""
        slam = self.slam
        t = slam.layout.turn_index(row, len(slam.table))
        line = turned_line(
            slam.maintenance.polynomial(row), float(slam.table.pivot[row]), slam.mean[t]
        )
        slam.mean[3 + row], slam.mean[t] = line.c0, 0.0
        slam.table.set_shape(row, line)

    def mature_lines(self, min_length: float | None = None) -> np.ndarray:
        """Rows (ascending, int64) of the own straight landmarks made at least
        ``config.link_age`` steps ago and at least ``min_length`` long on ξ (default: long
        enough to update the pose, :meth:`long_enough`): those a square tie or the
        rectilinear test may use."""
        cfg, table = self.config, self.slam.table
        floor = cfg.min_update_extent if min_length is None else min_length
        matured = self.slam.step_count - cfg.link_age
        lines = (table.order == 1) & (table.received == 0) & (table.changed_at <= matured)
        if floor > 0.0 or min_length is not None:
            lines &= table.hi - table.lo >= floor
        return np.flatnonzero(lines)

    def long_enough(self, row: int) -> bool:
        """Whether landmark ``row`` is long enough to update the pose (``min_update_extent``)."""
        floor = self.config.min_update_extent
        if floor <= 0.0:
            return True
        table = self.slam.table
        return bool(table.hi[row] - table.lo[row] >= floor)


def join_groups(group_of: dict[int, int], keep: int, other: int) -> None:
    """Put landmark ``other``'s group of ``group_of`` into landmark ``keep``'s."""
    target, source = group_of[keep], group_of[other]
    if target == source:
        return
    for lid, group in group_of.items():
        if group == source:
            group_of[lid] = target

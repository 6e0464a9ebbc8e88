"""Map maintenance of one robot's SLAM: landmarks created, refit, merged, inserted and
removed (paper §3.1, §3.3; :class:`MapMaintenance`).

Each change augments or marginalises the state (:class:`~polyslam_env.slam.layout.
StateLayout`), changes the landmark table's rows, and records one lineage event
(:mod:`~polyslam_env.slam.lineage`): the wall graph and the map exchange follow those.
These are the step's rare events (a landmark made every few dozen steps); they run in Python
between the step's two compiled calls.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from polyslam_env.slam import map_kernels
from polyslam_env.slam.association import fit_cluster, qbad_refit_points
from polyslam_env.slam.fitting import (
    MAX_SLOPE,
    Fit,
    PointSet,
    centroid_xi,
    fit_polynomial,
    turn_gradient,
)
from polyslam_env.slam.landmarks import clip_to_evidence, evidence_on, hull
from polyslam_env.slam.layout import TurnSource
from polyslam_env.slam.lineage import CREATED, INSERTED, MERGED, REMOVED, REPLACED
from polyslam_env.slam.merging import (
    JOIN_GAP,
    face_normal,
    merge_fit,
    near_merge_gammas,
    pick_merge,
)
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.stored import PointArrays

if TYPE_CHECKING:
    from polyslam_env.slam.robot import PolySlam

#: The default turn of a new landmark: a clone of the current heading (layout.TurnSource).
CLONE = TurnSource()
#: A join (two pieces end to end) is kept only if the merged fit explains both within this
#: many σ of the range noise (RMS).
JOIN_RMS = 1.0


class MapMaintenance:
    """The map changes of one :class:`~polyslam_env.slam.robot.PolySlam` (module docstring):
    it reads and writes that SLAM's state, table and stored points."""

    def __init__(self, slam: PolySlam) -> None:
        self.slam = slam
        self.config = slam.config

    # -- landmarks in and out ---------------------------------------------------------------
    def add(
        self,
        fit: Fit,
        side: int = 0,
        evidence: tuple[float, float] | None = None,
        source: TurnSource = CLONE,
        points: PointSet | None = None,
        received: bool = False,
    ) -> int:
        """Append a fitted landmark to the state and the table; returns its new id (the caller
        records its lineage). ``side``: the face its beams saw (+1 from +η, −1 from −η, 0
        unknown; see :mod:`~polyslam_env.slam.merging`); ``evidence``: the ξ-interval of its
        supporting hits (default: the fit's extent, i.e. its points' — a received landmark
        keeps the sender's evidence so); the extent is cut to it ±
        ``landmarks.EXTENT_MARGIN``. With rotation states the shape's turn α goes in too,
        made as ``source`` says (:mod:`~polyslam_env.slam.layout`).

        The shape turns about its **pivot**, the point where its c0 measures the offset. A
        merge fits points sampled on its two landmarks, each set weighted 1/var(c0) (a refit,
        those of the old landmark and its Q_bad hits); its shape-fixed c0 is their weighted
        mean offset (∂c0/∂η_i = w_i/Σw), so with rotation states the pivot is the ξ of their
        weighted centroid (``points``: the point set the fit was made on). With the middle of
        the extent instead, a piece joined to a much more certain one put c0's offset and α's
        turn about different points: the turn then moved the wall where the model said it
        stayed, an error no state held (README "SLAM on large floor plans" has the measured
        effect). A landmark made from a cluster of hits
        (``points`` None) keeps the middle of its extent: its hits weigh 1/‖P_{k|k−1}‖ of
        their steps while the stored-point model hangs them all on the current pose, and
        their weighted centroid as pivot made the single-robot NEES rise in development runs
        (``scripts/nees_episodes.py``). The paper's filter (no rotation states) keeps the
        middle of the extent everywhere."""
        slam, cfg = self.slam, self.config
        pivot = None
        if points is not None and cfg.rotation_states:
            pivot = centroid_xi(points, fit.poly.variate)
        n = len(slam.table)
        evidence = (fit.poly.lo, fit.poly.hi) if evidence is None else evidence
        poly = clip_to_evidence(fit.poly, evidence)
        clone = cfg.rotation_states and source.gradient is None  # its fit's own slope error
        fit_var = self.rotation_fit_var(poly) if clone else 0.0
        xi_var = float(slam.cov[0, 0] if poly.variate == 1 else slam.cov[1, 1])
        # only the step's shape_shift "pose" model reads a landmark's shift slope
        shifted = cfg.shape_shift == "pose" and not received
        shift_slope = self.shift_slope(fit, n) if shifted else math.nan
        if not math.isnan(shift_slope):
            xi_var = self.shift_var(fit, n, xi_var)
        slam.mean, slam.cov = slam.layout.add(slam.mean, slam.cov, n, fit, source, fit_var)
        return slam.table.append(
            poly,
            pivot=0.5 * (poly.lo + poly.hi) if pivot is None else pivot,
            xi_var=xi_var,
            model_var=max(fit.rms**2 - cfg.range_sigma**2, 0.0),
            fit_half=max(0.5 * (poly.hi - poly.lo), 0.05),
            step=slam.step_count,
            side=side,
            evidence=evidence,
            received=received,
            shift_slope=shift_slope,
        )

    def shift_slope(self, fit: Fit, n: int) -> float:
        """The slope s̄ a new landmark's c0 moves by when the pose's error shifts its points
        along ξ (c0 changes by −s̄·δξ; ``SlamConfig.shape_shift`` "pose", the only reader:
        with "noise" :meth:`add` stores nan without computing it): from its G_x, the pose's
        column along ξ and, through the old landmarks it was fitted on (a refit, a merge),
        each one's own s̄ (they were shifted by the same error); nan when one of those has
        none, or lies along the other axis (its s̄ is a slope against the other ξ, and G_x on
        its c0 is no share of the new one's points: a merge across a corner of a curved
        wall, where carrying it anyway gave a slope far from the new shape's and the pose
        drifted along that wall at 4–6 σ; docs/notes/floors.md, Round 5)."""
        gx = fit.Gx[0]
        variate = fit.poly.variate
        slope = -float(gx[0 if variate == 1 else 1])
        table = self.slam.table
        for row in np.flatnonzero(gx[3 : 3 + n]).tolist():
            if int(table.variate[row]) != variate:
                return math.nan
            slope += float(gx[3 + row]) * float(table.shift_slope[row])
        return slope

    def shift_var(self, fit: Fit, n: int, pose_var: float) -> float:
        """The variance of the shift along ξ a new landmark's shape was fitted with
        (``SlamConfig.shape_shift`` "pose"): its points placed by the current pose (variance
        ``pose_var`` along ξ) carry that pose's error, those sampled on old landmarks (a refit,
        a merge) each one's own, and its shape is their weighted mean (the shares: G_x on the
        pose's η and on each old c0). Their correlation unknown, the standard deviations add
        (the bound). Taking the current pose's instead made a merge across a loop claim that
        the old piece's shape moved with today's pose: on a curved floor the pose then drifted
        along the wall at 3-4 σ (docs/notes/floors.md, Round 5)."""
        gx = np.abs(fit.Gx[0])
        rows = np.flatnonzero(gx[3 : 3 + n])
        if rows.size == 0:
            return pose_var
        sigma = float(gx[1 if fit.poly.variate == 1 else 0]) * math.sqrt(pose_var)
        sigma += float(gx[3 + rows] @ np.sqrt(self.slam.table.xi_var[rows]))
        return sigma * sigma

    def drop(self, *landmark_ids: int) -> None:
        """Take landmarks out of the state, the table and the stored points (a
        marginalisation: the rest of the covariance is unchanged; the caller records it). A
        merge's two leave together: one copy of the state, the same numbers as one by one."""
        slam = self.slam
        rows = [slam.table.index_of(landmark_id) for landmark_id in landmark_ids]
        slam.mean, slam.cov = slam.layout.remove(slam.mean, slam.cov, rows, len(slam.table))
        for row in sorted(rows, reverse=True):  # the rows after a removed one move up
            slam.table.remove(row)
        slam.points.drop_qbad(*landmark_ids)

    def remove(self, landmark_id: int) -> None:
        """:meth:`drop`, recorded as removed."""
        self.drop(landmark_id)
        self.slam.lineage.record(REMOVED, landmark_id, (), self.slam.step_count)

    def insert(self, fit: Fit, merge: bool, turn: tuple[np.ndarray, float] | None) -> int:
        """A received landmark (``PolySlam.insert_landmark``); the id that holds it after the
        merge check."""
        slam = self.slam
        landmark_id = self.add(fit, source=TurnSource(turn=turn), received=True)
        slam.lineage.record(INSERTED, landmark_id, (), slam.step_count)
        if merge and self.merge_into_map(landmark_id):
            return slam.table.ids[-1]
        return landmark_id

    def replace(
        self,
        old_ids: Sequence[int],
        fit: Fit,
        side: int = 0,
        evidence: tuple[float, float] | None = None,
        source: TurnSource = CLONE,
        points: PointSet | None = None,
    ) -> int:
        """Add the fit (its G_x may touch the old c0s; ``points``: what it was fitted on),
        then drop the old landmarks: a refit (one) or a merge (two). The new one holds
        received data when one of the old did."""
        slam = self.slam
        table = slam.table
        received = any(bool(table.received[table.index_of(lid)]) for lid in old_ids)
        new_id = self.add(fit, side, evidence, source, points, received)
        self.drop(*old_ids)
        kind = REPLACED if len(old_ids) == 1 else MERGED
        slam.lineage.record(kind, new_id, tuple(old_ids), slam.step_count)
        return new_id

    # -- from this robot's beams ------------------------------------------------------------
    def create(self, cluster: PointArrays, rho: float) -> int | None:
        """A new landmark from a full cluster; unused points go back to a cluster."""
        slam, cfg = self.slam, self.config
        result = fit_cluster(
            cluster,
            slam.mean[:3],
            slam.mean.size,
            max_rms=self.max_fit_rms(rho),
            order=cfg.order,
            shape_fixed=True,
            auto_order=cfg.auto_order,
            min_noise_var=cfg.range_sigma**2,
            curvature_test=cfg.curvature_test,
        )
        # the unused points go back as one cluster of the newest ≤ ε_Z: the next point then
        # refits the newest evidence instead of an ever-growing set every step
        leftover = result.leftover
        slam.points.add_cluster(leftover.subset(np.arange(len(leftover))[-cfg.eps_z :]))
        if result.fit is None:
            return None
        landmark_id = self.add(result.fit, observed_side(result.used, result.fit.poly.variate))
        slam.lineage.record(CREATED, landmark_id, (), slam.step_count)
        return landmark_id

    def refit(self, landmark_id: int, bad: PointArrays, rho: float) -> int:
        """Refit a landmark on Q_bad ∪ R; returns 1 if it was replaced."""
        slam = self.slam
        if landmark_id not in slam.table:
            return 0
        row = slam.table.index_of(landmark_id)
        poly = self.polynomial(row)
        pts = qbad_refit_points(
            bad,
            poly,
            3 + row,
            slam.c0_variance(landmark_id),
            self.config.eps_m,
            slam.mean[:3],
            slam.mean.size,
            self.turn_of(row),
        )
        fit = self.fit(pts)
        if fit is None or fit.rms > self.max_fit_rms(rho):
            return 0  # the bad points do not make one wall with p*: keep p* as it is
        side = side_in(int(slam.table.side[row]), poly, fit.poly)
        xi_bad = bad.xy[:, 0] if fit.poly.variate == 1 else bad.xy[:, 1]  # the bad hits' ξ
        evidence = hull(
            evidence_on(self.evidence(row), poly, fit.poly),
            (float(xi_bad.min()), float(xi_bad.max())),
        )
        rotation = [(row, length_weight(poly.hi - poly.lo, float(np.ptp(xi_bad))))]
        new_id = self.replace([landmark_id], fit, side, evidence, TurnSource(rotation), pts)
        self.merge_into_map(new_id)
        return 1

    def max_fit_rms(self, rho: float) -> float:
        """Largest RMS residual a new or refit polynomial may have: min(ρ_k, 2.5 σ_range).

        The paper accepts a fit within ρ_k (8 cm at first), four times the 2 cm range noise:
        a cubic across a straight wall and the start of a bulge passes that, and the robot
        then localises against a wall that is not there. A right shape leaves residuals at
        the noise level; 2.5σ leaves room for the drift between the points' steps.
        """
        return min(rho, 2.5 * self.config.range_sigma)

    # -- merges -----------------------------------------------------------------------------
    def merge_into_map(self, landmark_id: int) -> int:
        """Merge a new or changed landmark with overlapping or adjoining ones (paper §3.3 and
        the joins of :mod:`~polyslam_env.slam.merging` when ``config.join_pieces``); returns
        the number of merges.

        Only landmarks whose bounding box lies within γ_M of this one's are handed to
        :func:`choose_merge`: every approximation error of a farther one is at least the box
        distance, so its γ could not be below γ_M (same choice, in the same order), and a
        join needs end points within ``JOIN_GAP`` ≤ γ_M. A merged landmark is checked again
        (a wall seen in pieces becomes one landmark), at most once per landmark in the map.
        """
        merges = 0
        for _ in range(len(self.slam.table)):
            merged_id = self.merge_once(landmark_id)
            if merged_id is None:
                break
            landmark_id = merged_id
            merges += 1
        return merges

    def merge_once(self, landmark_id: int) -> int | None:
        """One merge of ``landmark_id`` with its best partner whose merged fit passes; the
        merged id, or None. Partners are tried in :func:`choose_merge`'s order (smallest γ
        first): a join to the next piece of a wall that one polynomial cannot follow must not
        hide an overlap with a landmark of the same stretch (a received wall was left beside
        the robot's own one, 2.4 cm apart over 6 m, when only the best was tried)."""
        slam, cfg = self.slam, self.config
        if landmark_id not in slam.table:
            return None
        idx = slam.table.index_of(landmark_id)
        c0s = slam.c0s
        reach = cfg.gamma_max * (1.0 + 1e-9) + 1e-12  # ≥ γ_M despite rounding
        boxes = slam.landmark_boxes()  # cached until the map or the state changes
        poly = self.polynomial(idx)
        table = slam.table
        near, gammas, joined = near_merge_gammas(
            poly, table, c0s, boxes, boxes[idx], reach, cfg.merge_min_overlap, exclude=idx,
            join_gap=JOIN_GAP if cfg.join_pieces else None,
        )  # fmt: skip
        sides = table.side[near].tolist()
        while len(near):
            choice = pick_merge(
                poly,
                gammas,
                joined,
                cfg.gamma_max,
                functools.partial(self._near_polynomial, near),
                new_side=int(table.side[idx]),
                sides=sides,
            )
            if choice is None:
                return None
            j = int(near[choice.partner])
            merged = self.merge_pair(
                landmark_id, idx, poly, j, self.polynomial(j), bool(choice.joined)
            )
            if merged is not None:
                return merged
            # the state is unchanged: the others' answers stand
            near, gammas, joined = (np.delete(a, choice.partner) for a in (near, gammas, joined))
            del sides[choice.partner]
        return None

    def _near_polynomial(self, rows: np.ndarray, k: int) -> Polynomial:
        """The landmark at ``rows[k]`` with its current c0 (a merge candidate)."""
        return self.polynomial(int(rows[k]))

    def merge_pair(
        self, landmark_id: int, idx: int, poly: Polynomial, j: int, other: Polynomial, joined: bool
    ) -> int | None:
        """Merge landmark ``landmark_id`` (index ``idx``, shape ``poly``) with the one at index
        ``j`` (shape ``other``) when one polynomial explains both; the merged id, or None (the
        state unchanged)."""
        slam, cfg = self.slam, self.config
        sides = slam.table.side
        other_id = slam.table.ids[j]
        pts, merged = merge_fit(
            poly,
            3 + idx,
            float(slam.cov[3 + idx, 3 + idx]),
            other,
            3 + j,
            float(slam.cov[3 + j, 3 + j]),
            cfg.eps_m,
            slam.mean.size,
            self.turn_of(idx),
            self.turn_of(j),
            (cfg.order, cfg.auto_order, cfg.range_sigma**2, cfg.curvature_test),
        )
        fit = usable(merged)
        if fit is None:
            return None
        # one polynomial must explain both pieces, else they are not one wall: a join within
        # JOIN_RMS σ and, with join_pieces (off in the paper preset), an overlap merge within
        # the acceptance RMS of any new landmark (the paper's γ < γ_M = 0.35 m alone paired
        # two faces of a shelf 0.33 m apart that a robot had received without their sides,
        # and their merged cubic ran 1.5 m off the map)
        if joined:
            limit = JOIN_RMS * cfg.range_sigma
        elif cfg.join_pieces:
            limit = self.max_fit_rms(cfg.rho_max)
        else:
            limit = np.inf
        if fit.rms > limit:
            return None
        side = combine_sides(
            side_in(int(sides[idx]), poly, fit.poly), side_in(int(sides[j]), other, fit.poly)
        )
        evidence = hull(
            evidence_on(self.evidence(idx), poly, fit.poly),
            evidence_on(self.evidence(j), other, fit.poly),
        )
        w = length_weight(poly.hi - poly.lo, other.hi - other.lo)
        gradient = None
        if cfg.rotation_states and cfg.merge_turn == "fit":
            gradient = turn_gradient(pts, fit, centroid_xi(pts, fit.poly.variate))
        source = TurnSource([(idx, w), (j, 1 - w)], gradient=gradient)
        return self.replace([landmark_id, other_id], fit, side, evidence, source, pts)

    # -- helpers ----------------------------------------------------------------------------
    def fit(self, points: PointSet) -> Fit | None:
        """The SLAM's fit of ``points`` (shape fixed, order by the χ² test), or None when it
        is not finite or curves away between its points (steeper than ``MAX_SLOPE``)."""
        cfg = self.config
        fit = fit_polynomial(
            points,
            cfg.order,
            None,
            shape_fixed=True,
            auto_order=cfg.auto_order,
            min_noise_var=cfg.range_sigma**2,
            curvature_test=cfg.curvature_test,
        )
        return usable(fit)

    def rotation_fit_var(self, poly: Polynomial) -> float:
        """Variance of a fitted shape's turn from its slope's fit error: the slope's
        σ²·M⁻¹[1, 1]/h² (N = ε_Z + 1 equally spaced points over the half-extent h, order ≥ 1:
        the kernels' frozen-shape model) over (1 + b'²)², the slope-to-angle factor at the
        centroid (:func:`~polyslam_env.slam.map_kernels.rotation_fit_var`)."""
        cfg = self.config
        used = np.flatnonzero(poly.coeffs[1:])  # the shape without its zero tail
        order = max(int(used[-1]) + 1 if used.size else 0, 1)
        shape = np.zeros(poly.order + 1)
        shape[1:] = poly.coeffs[1:]
        inverse = fit_inverse_table(cfg.eps_z + 1, cfg.order)
        return float(
            map_kernels.rotation_fit_var(
                shape, order, poly.lo, poly.hi, inverse, cfg.range_sigma**2, 2.0
            )
        )

    def turn_of(self, row: int) -> tuple[int, float] | None:
        """(state index of landmark ``row``'s turn α, its pivot ξ), None without rotation
        states (:meth:`StateLayout.turn_of`)."""
        table = self.slam.table
        return self.slam.layout.turn_of(row, len(table), float(table.pivot[row]))

    def evidence(self, row: int) -> tuple[float, float]:
        """ξ-interval (on its own axis) of the hits supporting landmark ``row``."""
        lo, hi = self.slam.table.evidence[row].tolist()
        return lo, hi

    def polynomial(self, row: int) -> Polynomial:
        """Landmark ``row`` (state 3 + row) with its current c0."""
        return self.slam.table.polys[row].with_c0(float(self.slam.mean[3 + row]))

    def box(self, row: int) -> np.ndarray:
        """(4,) bounding box (x_min, x_max, y_min, y_max) of landmark ``row``."""
        return self.slam.table.boxes(self.slam.c0s)[row]


def usable(fit: Fit) -> Fit | None:
    """``fit``, or None when it is not finite or curves away between its points (steeper than
    ``MAX_SLOPE``): not one wall (the map's fits, :meth:`MapMaintenance.fit`, and its merges)."""
    if not (math.isfinite(fit.c0) and np.isfinite(fit.Gx).all() and np.isfinite(fit.Gy).all()):
        return None
    if fit.poly.max_slope() > MAX_SLOPE:  # curves away between its points: not one wall
        return None
    return fit


@functools.lru_cache(maxsize=16)
def fit_inverse_table(n_points: int, max_order: int) -> np.ndarray:
    """(M+1, M+1, M+1): [m, :m+1, :m+1] is (AᵀA)⁻¹ for monomials of t up to order m at
    ``n_points`` points equally spaced over [−1, 1] (m = 1 … M; the rest zero)."""
    table = np.zeros((max_order + 1,) * 3)
    for order in range(1, max_order + 1):
        if n_points > order:  # else no fit of that order exists
            a = np.linspace(-1.0, 1.0, n_points)[:, None] ** np.arange(order + 1)
            table[order, : order + 1, : order + 1] = np.linalg.inv(a.T @ a)
    return table


def length_weight(first: float, second: float) -> float:
    """Weight of the first of two fitted pieces in the turn of one shape fitted over both: a
    slope's precision grows as N·L² for N points over a length L, and N with L: as L³."""
    a, b = max(first, 1e-6) ** 3, max(second, 1e-6) ** 3
    return a / (a + b)


def observed_side(points: PointArrays, variate: int) -> int:
    """The face the beams of ``points`` saw on a curve of ``variate``: beams travelling
    towards +η came from the −η side (−1), and vice versa; 0 if they cancel."""
    axis = 1 if variate == 1 else 0
    total = sum(points.direction[:, axis].tolist())  # in order, as Python adds
    return -1 if total > 0 else (1 if total < 0 else 0)


def combine_sides(a: int, b: int) -> int:
    """Face of a merge: the common one, the known one, or 0 (both faces: a thin wall)."""
    if a == b or b == 0:
        return a
    return b if a == 0 else 0


def side_in(side: int, old: Polynomial, new: Polynomial) -> int:
    """The face ``side`` of ``old`` expressed on ``new`` (their variates may differ)."""
    if side == 0:
        return 0
    normal = face_normal(old, 0.5 * (old.lo + old.hi), side)
    return 1 if float(normal @ face_normal(new, 0.5 * (new.lo + new.hi), 1)) >= 0 else -1

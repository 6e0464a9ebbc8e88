"""One robot's polynomial EKF SLAM: the stateful shell around the pure functions.

Each step follows SPEC §3's order: predict from odometry → extraction and data association
(creating and refitting landmarks) → merge check → batched, gated EKF update with the beams
associated to a landmark → end points follow from the updated c0s.

The robot works in its own start frame R_{j,0} and never sees ground truth.
"""

from __future__ import annotations

import functools
import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from polyslam_env.core.blas import blas_threads
from polyslam_env.slam import ekf, kernels
from polyslam_env.slam.association import (
    GAP_SPLIT,
    AssociationResult,
    MapBook,
    fit_cluster,
    qbad_refit_points,
)
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import (
    MAX_SLOPE,
    Fit,
    PointSet,
    StoredPoint,
    centroid_xi,
    fit_polynomial,
    polynomial_points,
    store_beams,
    turn_gradient,
)
from polyslam_env.slam.landmarks import (
    EXTENT_MARGIN,
    LandmarkTable,
    ShapesView,
    boxes_near,
    clip_to_evidence,
    evidence_on,
    hull,
)
from polyslam_env.slam.links import evidence_gap, line_angle, link_rows, off_square, turned_line
from polyslam_env.slam.merging import JOIN_GAP, choose_merge, face_normal, merge_points
from polyslam_env.slam.polynomial import Polynomial

#: The innovation screen of the divergence test (:meth:`PolySlam._is_diverging`): the last
#: SCREEN_WINDOW beams whose return (or lack of one) the map predicts, each an outlier when
#: its NIS exceeds the χ²(1) gate quantile (probability 1 − gate_prob for a consistent
#: filter). Besides, up to SCREEN_CONTAMINATION of the beams of a healthy robot are gross
#: outliers (occlusion by walls not yet mapped, polynomials reaching past their support: 6.5 %
#: of 6,785 beams over 40 healthy wall-following episodes, up to 17 % in one episode), so an
#: alarm needs the count that Bin(SCREEN_WINDOW, 1 − gate_prob + SCREEN_CONTAMINATION)
#: reaches with probability at most SCREEN_FALSE_ALARM (7 of 10 with the defaults).
SCREEN_WINDOW = 10
SCREEN_CONTAMINATION = 0.15
SCREEN_FALSE_ALARM = 1e-3
#: Slack (m) added to box distances when selecting the landmarks a beam can reach: covers
#: the root polishing and rounding of the hit point, which the exact test then decides.
REACH_MARGIN = 1e-3
JOIN_RMS = 1.0


@dataclass(frozen=True)
class SlamStepInfo:
    """What one SLAM step did (for logs, metrics and tests)."""

    step: int
    time_s: float  # wall time of the step
    n_landmarks: int
    beams_used: int  # beams that went into the EKF update
    created: int  # landmarks created from clusters
    refit: int  # landmarks refit from Q_bad
    merged: int  # merges performed
    rho: float  # this step's thresholds
    sigma: float
    divergence_f: float
    diverging: bool
    linked: int = 0  # pieces of one wall linked across a gap, walls tied square (links.py)


class PolySlam:
    """Polynomial-landmark EKF SLAM of one robot (paper §3.1, §3.3).

    The state is ``mean = [x¹, x², θ, c0_1 … c0_n, α_1 … α_n]`` with covariance ``cov``
    (the α, each landmark's shape rotation, only with ``shape_rotation="considered"``, the
    default; :attr:`c0s` is the c0 block); everything else about landmark ``i`` (stable id
    ``landmark_ids[i]``: shape, extent, Q_bad, …) is row i of :attr:`table`, the map's one
    record. ``mean`` and ``cov`` are working arrays
    (the prediction and the update write into them): copy to keep them.

    **Anchored at the true start.** The robot's frame is its nominal start pose, but where it
    really started differs by an unknown e₀ ~ N(0, P0), and nothing it senses can tell (no
    absolute reference). The filter therefore estimates everything relative to the true
    start, where the pose is known exactly (``cov`` starts at 0): the map lives in that
    frame, and no measurement can be mistaken for information about e₀ (the paper's form,
    P starting at P0, lets relinearisation shrink the pose covariance below what e₀ alone
    implies). :attr:`pose_cov` adds e₀'s share back for the pose as an estimate in the
    robot's frame; :attr:`pose_cov_relative` is the filter's own. The propagation uses
    first-estimates Jacobians (:func:`~polyslam_env.slam.ekf.predict_inplace`).

    **Shape rotations as considered states.** A shape is frozen when it is fitted, turned from
    the true wall by the heading error of that moment (and its slope's fit error). Taking that
    turn to be the *current* heading error (``shape_rotation="heading"``, the paper preset's)
    lets a wall seen again long after it was made correct nothing of the heading, and the
    same frozen error, repeated step after step, made the filter overconfident on loops.
    Each landmark therefore carries its turn α as a state: cloned from the heading when the
    shape is fitted (:meth:`_add_rotation`), never estimated by the beams (Schmidt–Kalman:
    zero gain, so the stored shape stays the estimate), its correlations updated by every
    beam on it (``kernels.update_sparse``).

    **Pieces of one wall linked.** A straight landmark made, refit or merged ``link_age``
    steps ago is linked to the straight pieces of its wall across gaps up to ``link_gap``
    (doorways) by a collinearity pseudo-measurement (:mod:`~polyslam_env.slam.links`,
    :meth:`_link_walls`); that update does estimate the two lines' turns, and turns the
    stored lines by them. With ``square_walls`` a straight landmark is also tied square to
    the straight wall of another direction group whose angle to it is best known
    (:meth:`_square_wall`).

    Set :attr:`profile` to a dict to collect per-stage wall times (s) of every step under
    the keys ``predict``, ``association``, ``map`` (extents, refits, new landmarks,
    merges) and ``update``; None (the default) skips the timing.
    """

    def __init__(
        self,
        config: SlamConfig,
        beam_angles: Sequence[float] | np.ndarray,
        max_range: float,
    ) -> None:
        self.config = config
        self.beam_angles = np.asarray(beam_angles, dtype=float)  # (B,)
        self._update_beams = update_beam_mask(self.beam_angles, config.update_spacing_deg)
        # the divergence screen tests the same beams: its count assumes independent beams
        self._screen_angles = np.ascontiguousarray(self.beam_angles[self._update_beams])
        self._range_var = float(config.range_sigma**2)
        self._n_fit = config.eps_z + 1  # points of the cluster a landmark is born from
        self._turn_var_per_step = float(config.odom_cov[2, 2])  # rad², see _turn_var
        self._outlier = np.empty(self._screen_angles.size, dtype=bool)  # the screen's flags
        self._min_sine = float(np.sin(np.deg2rad(config.tangent_min_deg)))
        self.max_range = float(max_range)
        self.mean = np.zeros(3)  # (3+n,) relative to the true start (see class docstring)
        self.cov = np.zeros((3, 3))  # (3+n, 3+n) ditto: the true start is known exactly
        self._first_xy: tuple[float, float] | None = None  # x̂_{k|k−1}'s position (FEJ)
        self.table = LandmarkTable()  # the map: ids, shapes, extents, Q_bad, … in state order
        self.book = MapBook(
            config.eps_m, config.eps_z, config.cluster_radius, self.table, config.link_clusters
        )
        self.step_count = 0
        self._wall_of: dict[int, int] = {}  # landmark id → its wall group (links.py)
        self._direction_of: dict[int, int] = {}  # landmark id → its direction group (ditto)
        self._received: set[int] = set()  # ids holding a received landmark (never linked)
        self.diverging = False
        self.divergence_f = 0.0
        self.profile: dict[str, list[float]] | None = None
        self._state_version = 0  # bumped by every update (map changes bump the table's version)
        kp0_eig = np.linalg.eigvalsh(config.k_divergence * config.p0)  # (3,) ascending
        self._kp0_norm = float(max(-kp0_eig[0], kp0_eig[-1]))  # ‖K P0‖
        self._kp0_min = float(kp0_eig[0])  # λ_min(K P0)
        self._gate = ekf.chi2_1dof_quantile(config.gate_prob)
        self._screen: deque[bool] = deque(maxlen=SCREEN_WINDOW)  # outlier flags, oldest first
        self._screen_alarm = ekf.outlier_count_threshold(
            SCREEN_WINDOW, 1.0 - config.gate_prob + SCREEN_CONTAMINATION, SCREEN_FALSE_ALARM
        )

    # -- read-only views ------------------------------------------------------------------
    @property
    def pose(self) -> np.ndarray:  # (3,)
        """The pose estimate (x, y, θ) in the robot's start frame (a copy)."""
        return self.mean[:3].copy()

    @property
    def pose_cov(self) -> np.ndarray:  # (3, 3)
        """Covariance of :attr:`pose` as an estimate of the pose in the robot's frame: the
        filter's P_S plus the unobservable start error's J P0 Jᵀ
        (:func:`~polyslam_env.slam.ekf.start_error_cov`)."""
        return self.cov[:3, :3] + ekf.start_error_cov(self.mean, self.config.p0)

    @property
    def pose_cov_relative(self) -> np.ndarray:  # (3, 3)
        """The filter's P_S: the pose's covariance relative to the robot's true start, the
        frame its map lives in (what a map exchange must use)."""
        return self.cov[:3, :3].copy()

    @property
    def landmark_ids(self) -> list[int]:
        return list(self.table.ids)

    @property
    def n_landmarks(self) -> int:
        """The number of landmarks (polynomials) in the map."""
        return len(self.table)

    @property
    def shapes(self) -> ShapesView:
        """Id → shape and extent (a :class:`Polynomial` whose c0 is the fit's: the current
        one is in the state); a new object whenever the landmark changes."""
        return self.table.shapes

    @property
    def c0s(self) -> np.ndarray:  # (n,)
        """Every landmark's c0, in state order (a view of the mean)."""
        return self.mean[3 : 3 + len(self.table)]

    def polynomials(self) -> list[Polynomial]:
        """The map: every landmark with its current c0, in state order."""
        return self.table.polynomials(self.c0s)

    @property
    def wall_groups(self) -> dict[int, int]:
        """Landmark id → its wall group: pieces linked across gaps, directly or through others,
        share one (:mod:`~polyslam_env.slam.links`); a copy."""
        return dict(self._wall_of)

    @property
    def direction_groups(self) -> dict[int, int]:
        """Landmark id → its direction group: straight walls tied square (or parallel, as
        pieces of one wall are) to each other, directly or through others (:mod:`~polyslam_env.
        slam.links`); a copy."""
        return dict(self._direction_of)

    def c0_variance(self, landmark_id: int) -> float:
        k = self.table.state_index(landmark_id)
        return float(self.cov[k, k])

    def turn_variance(self, landmark_id: int) -> float:
        """Variance (rad²) of the landmark's turn α (needs rotation states)."""
        if not self.config.rotation_states:
            raise ValueError("turn_variance: this filter has no turn states (shape_rotation)")
        k = self._turn_index(self.table.index_of(landmark_id))
        return float(self.cov[k, k])

    def map_error_jacobian(self, spacing: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
        """How the state's errors move the map: at points every ``spacing`` m of ξ along
        every landmark's extent, each point's arc length (M,) (m: the points weigh as
        :func:`~polyslam_env.metrics.mapping.map_precision`'s arc-length samples do) and the
        Jacobian (M, state size) of its offset along the curve's normal w.r.t. the state: 1/√(1
        + B'²) on its c0, and with rotation states its turn α about the pivot
        (:func:`~polyslam_env.slam.fitting.polynomial_points`' ∂π/∂α = J(π − π_c)). The state
        lives in the true-start frame (class docstring), so with :attr:`cov` it gives the
        filter's own distribution of the map's errors where the map metrics place the map
        (:func:`~polyslam_env.metrics.mapping.expected_precision`). What no state holds (a
        frozen shape's higher-order fit error) is not in it."""
        n_state = self.mean.size
        lengths, rows = [np.zeros(0)], [np.zeros((0, n_state))]
        for i, poly in enumerate(self.polynomials()):
            n = max(2, math.ceil((poly.hi - poly.lo) / spacing) + 1)
            xi = np.linspace(poly.lo, poly.hi, n)
            # a unit c0 variance: only the points' Jacobian d_state is used
            pts = polynomial_points(poly, 3 + i, 1.0, n, poly.lo, poly.hi, n_state,
                                    self._turn_of(i))  # fmt: skip
            rows.append(np.einsum("ni,nij->nj", poly.normals(xi), pts.d_state))
            ds = np.sqrt(1.0 + poly.slope(xi) ** 2) * ((poly.hi - poly.lo) / (n - 1))
            ds[[0, -1]] *= 0.5  # the trapezoid rule: each point weighs its share of the arc
            lengths.append(ds)
        return np.concatenate(lengths), np.vstack(rows)

    # -- one step -----------------------------------------------------------------------------
    def step(self, odometry: np.ndarray, ranges: np.ndarray) -> SlamStepInfo:
        """Advance by one control period given odometry (3,) and range readings (B,).

        BLAS runs on ``config.blas_threads`` threads meanwhile (see :mod:`polyslam_env.core.blas`).
        """
        with blas_threads(self.config.blas_threads):
            return self._step(odometry, ranges)

    def _step(self, odometry: np.ndarray, ranges: np.ndarray) -> SlamStepInfo:
        start = lap = time.perf_counter()
        cfg = self.config
        self.step_count += 1
        self._predict(odometry)
        self._screen_innovations(np.asarray(ranges, dtype=float))
        pose_cov = self.cov[:3, :3]
        f = ekf.divergence_ratio(pose_cov, cfg.p0, cfg.k_divergence, self._kp0_norm)
        rho = ekf.thresholds(f, cfg.rho_min, cfg.rho_max)
        sigma = ekf.thresholds(f, cfg.sigma_min, cfg.sigma_max)
        if self.profile is not None:
            lap = self._lap("predict", lap)

        points = store_beams(
            self.mean[:3], pose_cov, ranges, self.beam_angles, cfg.range_sigma, self.step_count
        )
        assoc = self.book.associate(
            points,
            self.table.packed(),
            self.c0s,
            rho,
            sigma,
            cfg.squared_error,
            candidates=self._association_candidates(points, sigma),
            rows=self.table.arrays(),
            extends=self._continues_past_end if cfg.stretch_ends else None,
        )
        if self.profile is not None:
            lap = self._lap("association", lap)

        self._extend_extents(points, assoc)
        refit = sum(self._refit(r.landmark_id, r.points, rho) for r in assoc.refits)
        created = merged = 0
        for request in assoc.new_landmarks:
            new_id = self._create(request.points, rho)
            if new_id is not None:
                created += 1
                merged += self._merge_into_map(new_id)
        linked = self._link_changed()
        if self.profile is not None:
            lap = self._lap("map", lap)

        good = sorted(
            (b, self.table.index_of(lid))
            for b, lid in assoc.good_ids.items()
            if lid in self.table and self._update_beams[b] and self._long_enough(lid)
        )
        used = self._update(good, np.asarray(ranges, dtype=float))
        self.divergence_f = f
        self.diverging = self._is_diverging()
        if self.profile is not None:
            self._lap("update", lap)
        return SlamStepInfo(
            step=self.step_count,
            time_s=time.perf_counter() - start,
            n_landmarks=self.n_landmarks,
            beams_used=used,
            created=created,
            refit=refit,
            merged=merged,
            rho=rho,
            sigma=sigma,
            divergence_f=f,
            diverging=self.diverging,
            linked=linked,
        )

    def _association_candidates(self, points: Sequence[StoredPoint], sigma: float) -> np.ndarray:
        """Landmarks whose box lies within σ_k (in metres) of this step's points' box: the
        only ones a point can be good or bad for (see MapBook.associate); with
        ``stretch_ends``, within GAP_SPLIT when that is wider (a point may continue one)."""
        if not points:
            return np.zeros(0, dtype=int)
        xs, ys = zip(*(p.xy.tolist() for p in points), strict=True)
        box = np.array([min(xs), max(xs), min(ys), max(ys)])
        reach = math.sqrt(sigma) if self.config.squared_error else sigma  # ε² ≤ σ_k there
        if self.config.stretch_ends:
            reach = max(reach, GAP_SPLIT)
        reach = reach * (1.0 + 1e-9) + 1e-12  # ≥ the threshold despite rounding
        return boxes_near(self._boxes(), box, reach)

    def _boxes(self) -> np.ndarray:
        """Bounding boxes (n, 4) of the landmarks at the current c0s, cached by the table until
        the map or the state changes (the association and an update without map change share
        them)."""
        return self.table.boxes(self.c0s, self._state_version)

    def _predict(self, odometry: np.ndarray) -> None:
        """EKF prediction into the working arrays (the mean is small: a fresh copy)."""
        self.mean = self.mean.copy()
        ekf.predict_inplace(self.mean, self.cov, odometry, self.config.odom_cov, self._first_xy)
        self._first_xy = (float(self.mean[0]), float(self.mean[1]))

    def _lap(self, stage: str, since: float) -> float:
        """Record the time since ``since`` under ``stage`` (profiling on); returns now."""
        now = time.perf_counter()
        assert self.profile is not None
        self.profile.setdefault(stage, []).append(now - since)
        return now

    def _extend_extents(self, points: Sequence[StoredPoint], assoc: AssociationResult) -> None:
        """Stretch a landmark's extent over the points just beyond its end that its curve,
        continued there, explains (:meth:`_continued_xi`).

        A good point (ε ≤ ρ_k of an end point) belongs to the same wall (paper §3.1, case 1);
        the extent grows to it only when the extrapolated curve itself explains it, otherwise
        the extrapolation would be trusted where it bends away from a curved wall. An
        ``extended`` point (ε > ρ_k, up to GAP_SPLIT past the end: the association's
        ``extends`` test) stretches the extent the same way; its beam, which meets the curve
        at the very end of the new extent, is not used in this step's update.

        With ``stretch_ends``, a good point past the extent that the curve does not explain
        does not update c0 either. The paper takes its beam to have no admissible intersection
        there, but a beam that comes in obliquely past the end can cross the curve inside
        the extent and stop short of it: on a shelf's side face, a few centimetres from the
        corner of the face the landmark is. Its innovation is then the distance between the
        two faces along the beam (13 cm in the warehouse episode where this was found), and
        with a few centimetres of pose uncertainty the χ² gate let it through: one beam moved
        the pose by 4 cm and 0.24°.
        """
        table = self.table
        for point in points:
            idx = assoc.good.get(point.beam, assoc.extended.get(point.beam))
            if idx is None or self._within_extent(point, idx):
                continue
            xi = self._continued_xi(point, idx)
            if xi is not None:
                table.extend_to_hit(idx, xi)
            elif self.config.stretch_ends:
                assoc.good_ids.pop(point.beam, None)  # its hit is not on the landmark

    def _within_extent(self, point: StoredPoint, idx: int) -> bool:
        """Whether ``point``'s ξ lies on landmark ``idx``'s extent."""
        table = self.table
        xi = point.xy[0] if table.variate[idx] == 1 else point.xy[1]
        return bool(table.lo[idx] <= xi <= table.hi[idx])

    def _continued_xi(self, point: StoredPoint, idx: int) -> float | None:
        """ξ of ``point``, which lies past landmark ``idx``'s extent (the caller's test), when
        the curve continued there explains it (|η − p(ξ)| ≤ 2σ of the range noise); None
        otherwise."""
        table = self.table
        v1 = table.variate[idx] == 1
        xi, eta = (point.xy[0], point.xy[1]) if v1 else (point.xy[1], point.xy[0])
        curve = float(table.polys[idx].with_c0(0.0).value(xi)) + self.mean[3 + idx]
        return float(xi) if abs(eta - curve) <= 2.0 * self.config.range_sigma else None

    def _continues_past_end(self, point: StoredPoint, idx: int) -> bool:
        """The association's ``extends`` test (``stretch_ends``): ``point`` lies at most
        GAP_SPLIT past landmark ``idx``'s end, on its continued curve, where that curve is
        known to within the range noise relative to the robot: lever² · var(turn) ≤ σ²,
        the lever being the distance from the shape's pivot and the turn its rotation
        relative to the robot's heading (:meth:`_relative_turn_var`). A shape fitted on a
        short stretch is not stretched far on its frozen slope; a cluster, a join or a refit
        brings its next piece instead."""
        if self._within_extent(point, idx):
            return False
        xi = self._continued_xi(point, idx)
        if xi is None:
            return False
        table = self.table
        if min(abs(xi - table.lo[idx]), abs(xi - table.hi[idx])) > GAP_SPLIT:
            return False
        lever = xi - float(table.pivot[idx])
        return lever * lever * self._relative_turn_var(idx) <= self._range_var

    def _relative_turn_var(self, idx: int) -> float:
        """Variance of landmark ``idx``'s shape rotation relative to the robot's heading:
        var(α − θ) from the state with rotation states; otherwise the kernels' frozen-shape
        model (the fit's slope error and the heading's random walk since the fit)."""
        if self.config.rotation_states:
            a = self._turn_index(idx)
            cov = self.cov
            return float(cov[a, a] + cov[2, 2] - 2.0 * cov[a, 2])
        poly = self.table.polys[idx]
        return self._rotation_fit_var(poly) + float(self._turn_var()[idx])

    def _screen_innovations(self, ranges: np.ndarray) -> None:
        """Hook of :meth:`_is_diverging`, run right after the prediction: the NIS of every beam
        against the map as it stood before this step's changes (created or refit landmarks
        would explain the very beams they were made of), at the predicted pose. A beam without
        return whose predicted hit lies within range counts with the range r_max: a lower
        bound of its true range, so its NIS is a lower bound too.

        Only the beams the update uses (``update_spacing_deg``) are screened: the alarm's
        count is binomial for independent beams, and beams closer together share more of
        their landmark's error (with all seventeen default beams, 3 of 100 healthy episodes
        raised the flag)."""
        if self.n_landmarks == 0:
            return
        outlier = self._outlier
        screened = np.ascontiguousarray(ranges[self._update_beams])
        args = (self.mean, self.cov, self._screen_angles, screened, outlier)
        k = kernels.screen_scan(*args, *self._map_args())
        self._screen.extend(outlier[:k].tolist())

    def _is_diverging(self) -> bool:
        """The paper's test (P beyond K·P0) or the innovation screen: at least
        ``_screen_alarm`` of the last :data:`SCREEN_WINDOW` screened beams are outliers
        (:meth:`_screen_innovations`, thresholds in the note on :data:`SCREEN_WINDOW`).

        A lost filter (kidnapped, wheels slipping) predicts most beams wrong at once, while a
        healthy one meets an outlier now and then; counting outliers rather than summing NIS
        keeps one gross outlier from raising the alarm alone.
        """
        cfg = self.config
        pose_cov = self.cov[:3, :3]
        # λ_max(P − K P0) ≤ ‖P‖_F − λ_min(K P0): far below K P0, skip the eigenvalues
        small = float((pose_cov * pose_cov).sum()) < (0.5 * self._kp0_min) ** 2
        if not small and ekf.is_diverging(pose_cov, cfg.p0, cfg.k_divergence):
            return True
        return sum(self._screen) >= self._screen_alarm

    # -- public landmark insertion (map exchange) -----------------------------------------------
    def insert_landmark(
        self, fit: Fit, merge: bool = True, turn: tuple[np.ndarray, float] | None = None
    ) -> int:
        """Add a landmark from an external fit (e.g. a received polynomial refitted in this
        robot's frame); ``fit.Gx``/``fit.Gy``/``fit.V`` must describe its c0's dependence on
        this robot's state and on the inputs' noise. With rotation states, ``turn`` =
        (∂α/∂pose (3,), variance of the rest) says what turns its shape when that is not the
        current heading (a received wall: the frame transform's turn); the shape's own fit
        variance is added to it. Runs the merge check unless ``merge`` is False. Returns the
        id of the landmark that holds it afterwards (after a merge, the merged landmark's
        id)."""
        lid = self._augment(fit, turn=turn)
        self._received.add(lid)
        if merge and self._merge_into_map(lid):
            return self.table.ids[-1]
        return lid

    def remove_landmark(self, landmark_id: int) -> None:
        """Drop a landmark from the map and its c0 from the state (a marginalisation: the
        rest of the covariance is unchanged), e.g. a received landmark superseded by a newer
        version from the same sender."""
        self._remove(landmark_id)

    def changed_since(self, step: int) -> list[int]:
        """Ids of the landmarks created, refit or merged after ``step`` (exchange payloads)."""
        table = self.table
        return [lid for lid, at in zip(table.ids, table.changed_at, strict=True) if at > step]

    # -- landmark generation (paper eq. 4–5) ------------------------------------------------------
    def _augment(
        self,
        fit: Fit,
        side: int = 0,
        evidence: tuple[float, float] | None = None,
        rotation: Sequence[tuple[int, float]] = (),
        turn: tuple[np.ndarray, float] | None = None,
        points: PointSet | None = None,
        turn_gradient: tuple[np.ndarray, float] | None = None,
    ) -> int:
        """Append a fitted landmark to the state; returns its new id. ``side``: the face its
        beams saw (+1 from +η, −1 from −η, 0 unknown; see :mod:`~polyslam_env.slam.merging`);
        ``evidence``: the ξ-interval of its supporting hits (default: the fit's extent, i.e.
        its points' — a received landmark keeps the sender's evidence so); the extent is cut
        to it ± ``landmarks.EXTENT_MARGIN``. With rotation states the shape's turn α goes in
        too (:meth:`_add_rotation`), a weighted mean of the turns of the landmarks in
        ``rotation`` ((index, weight) pairs) and of the current heading (or of ``turn``, see
        :meth:`insert_landmark`).

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
        pivot = None
        if points is not None and self.config.rotation_states:
            pivot = centroid_xi(points, fit.poly.variate)
        n = len(self.table)
        self.mean, self.cov = ekf.augment(self.mean, self.cov, fit.c0, fit.Gx, fit.Gy, fit.V)
        evidence = (fit.poly.lo, fit.poly.hi) if evidence is None else evidence
        poly = clip_to_evidence(fit.poly, evidence)
        if self.config.rotation_states:
            self._add_rotation(n, poly, rotation, turn, turn_gradient)
        landmark_id = self.table.append(
            poly,
            pivot=0.5 * (poly.lo + poly.hi) if pivot is None else pivot,
            xi_var=float(self.cov[0, 0] if poly.variate == 1 else self.cov[1, 1]),
            model_var=max(fit.rms**2 - self.config.range_sigma**2, 0.0),
            fit_half=max(0.5 * (poly.hi - poly.lo), 0.05),
            step=self.step_count,
            side=side,
            evidence=evidence,
        )
        self._wall_of[landmark_id] = landmark_id
        self._direction_of[landmark_id] = landmark_id
        return landmark_id

    def _add_rotation(
        self,
        n: int,
        poly: Polynomial,
        rotation: Sequence[tuple[int, float]],
        turn: tuple[np.ndarray, float] | None = None,
        gradient: tuple[np.ndarray, float] | None = None,
    ) -> None:
        """The new landmark's shape turn α into the state, after its c0 was appended at index
        3 + 2n and before its table row is: [pose, c0_1 … c0_n, α_1 … α_n, c0_new] becomes
        [pose, c0_1 … c0_new, α_1 … α_new].

        α is the angle by which the true wall is turned from the stored shape about its
        centroid. A shape fitted now, to points placed with the current pose estimate, is
        turned by the current heading error plus its slope's fit error: its row is a copy of
        the heading's, with the fit's variance (:meth:`_rotation_fit_var`) added (a clone, as
        in Roumeliotis & Burdick's stochastic cloning). A shape fitted over older landmarks'
        points (a refit, or a merge with ``merge_turn="weights"``) takes their turns with the
        weights in ``rotation``, and the rest, 1 − Σ w, from the current heading with that share
        of the fit variance. A merge with ``merge_turn="fit"`` (the default) passes ``gradient``
        instead, (∂α/∂X, variance) of the merged fit's own direction
        (:func:`~polyslam_env.slam.fitting.turn_gradient`): the pieces' offsets fix a long
        wall's direction far better than their own short turns. α is
        then *considered*, not estimated (no gain: the stored shape stays the estimate), and
        its correlations carry how a wall made long ago ties the current heading to the
        heading of its time.
        """
        size = self.mean.size  # 3 + 2n + 1: the new c0 is last
        gx = np.zeros(size)
        if gradient is not None:  # a merge's turn from its fit (config.merge_turn "fit")
            gx[: size - 1], var = gradient
        else:
            rest = 1.0
            for row, weight in rotation:
                gx[3 + n + row] += weight
                rest -= weight
            var = self._rotation_fit_var(poly)
            if turn is None:
                gx[2] += rest
            else:  # e.g. a received wall: the frame transform's turn
                gx[:3] += rest * np.asarray(turn[0], dtype=float)
                var += turn[1]
            var *= rest * rest
        mean, cov = ekf.augment(self.mean, self.cov, 0.0, gx, np.ones(1), np.array([[var]]))
        order = np.r_[0 : 3 + n, size - 1, 3 + n : size - 1, size]
        self.mean, self.cov = mean[order], cov[np.ix_(order, order)]

    def _rotation_fit_var(self, poly: Polynomial) -> float:
        """Variance of a fitted shape's turn from its slope's fit error: the slope's
        σ²·M⁻¹[1, 1]/h² (N = ε_Z + 1 equally spaced points over the half-extent h, order ≥ 1:
        the kernels' frozen-shape model) over (1 + b'²)², the slope-to-angle factor at the
        centroid."""
        order = max(len(np.trim_zeros(np.asarray(poly.coeffs[1:], dtype=float), "b")), 1)
        inverse = _fit_inverse_table(self._n_fit, self.config.order)[order]
        half = max(0.5 * (poly.hi - poly.lo), 0.05)
        slope = float(poly.slope(0.5 * (poly.lo + poly.hi)))
        return float(self._range_var * inverse[1, 1] / (half * half) / (1.0 + slope * slope) ** 2)

    def _remove(self, landmark_id: int) -> None:
        idx = self.table.index_of(landmark_id)
        drop = [3 + idx]
        if self.config.rotation_states:
            drop.append(self._turn_index(idx))
        self.mean, self.cov = ekf.remove(self.mean, self.cov, drop)
        self.table.remove(idx)
        self._wall_of.pop(landmark_id, None)
        self._direction_of.pop(landmark_id, None)
        self._received.discard(landmark_id)

    def _replace(
        self,
        old_ids: Sequence[int],
        fit: Fit,
        side: int = 0,
        evidence: tuple[float, float] | None = None,
        rotation: Sequence[tuple[int, float]] = (),
        points: PointSet | None = None,
        turn_gradient: tuple[np.ndarray, float] | None = None,
    ) -> int:
        """Add the fit (its G_x may touch the old c0s; ``points``: what it was fitted on) and
        then drop the old landmarks."""
        new_id = self._augment(
            fit, side, evidence, rotation, points=points, turn_gradient=turn_gradient
        )
        for lid in old_ids:
            self._join_walls(new_id, lid)
            if lid in self._received:
                self._received.add(new_id)
            self._remove(lid)
        return new_id

    def _refit(self, landmark_id: int, bad: Sequence, rho: float) -> int:
        """Refit a landmark on Q_bad ∪ R; returns 1 if it was replaced."""
        if landmark_id not in self.table:
            return 0
        state_index = self.table.state_index(landmark_id)
        poly = self.table.polys[state_index - 3].with_c0(self.mean[state_index])
        pts = qbad_refit_points(
            bad,
            poly,
            state_index,
            self.c0_variance(landmark_id),
            self.config.eps_m,
            self.mean[:3],
            self.mean.size,
            self._turn_of(state_index - 3),
        )
        fit = self._fit(pts)
        if fit is None or fit.rms > self._max_fit_rms(rho):
            return 0  # the bad points do not make one wall with p*: keep p* as it is
        side = self._side_in(int(self.table.side[state_index - 3]), poly, fit.poly)
        xy = np.array([p.xy for p in bad], dtype=float)  # (k, 2) the bad hits
        xi_bad = xy[:, 0] if fit.poly.variate == 1 else xy[:, 1]
        evidence = hull(
            evidence_on(self._evidence(state_index - 3), poly, fit.poly),
            (float(xi_bad.min()), float(xi_bad.max())),
        )
        rotation = [(state_index - 3, _length_weight(poly.hi - poly.lo, float(np.ptp(xi_bad))))]
        new_id = self._replace([landmark_id], fit, side, evidence, rotation, pts)
        self._merge_into_map(new_id)
        return 1

    def _create(self, cluster: Sequence, rho: float) -> int | None:
        """A new landmark from a full cluster; unused points go back to a cluster."""
        result = fit_cluster(
            cluster,
            self.mean[:3],
            self.mean.size,
            max_rms=self._max_fit_rms(rho),
            order=self.config.order,
            shape_fixed=True,
            auto_order=self.config.auto_order,
            min_noise_var=self.config.range_sigma**2,
        )
        self.book.restore_cluster(result.leftover)
        if result.fit is None:
            return None
        return self._augment(result.fit, _observed_side(result.used, result.fit.poly.variate))

    def _max_fit_rms(self, rho: float) -> float:
        """Largest RMS residual a new or refit polynomial may have: min(ρ_k, 2.5 σ_range).

        The paper accepts a fit within ρ_k (8 cm at first), four times the 2 cm range noise:
        a cubic across a straight wall and the start of a bulge passes that, and the robot
        then localises against a wall that is not there. A right shape leaves residuals at
        the noise level; 2.5σ leaves room for the drift between the points' steps.
        """
        return min(rho, 2.5 * self.config.range_sigma)

    def _merge_into_map(self, landmark_id: int) -> int:
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
        for _ in range(len(self.table)):
            merged_id = self._merge_once(landmark_id)
            if merged_id is None:
                break
            landmark_id = merged_id
            merges += 1
        return merges

    def _merge_once(self, landmark_id: int) -> int | None:
        """One merge of ``landmark_id`` with its best partner whose merged fit passes; the
        merged id, or None. Partners are tried in :func:`choose_merge`'s order (smallest γ
        first): a join to the next piece of a wall that one polynomial cannot follow must not
        hide an overlap with a landmark of the same stretch (a received wall was left beside
        the robot's own one, 2.4 cm apart over 6 m, when only the best was tried)."""
        if landmark_id not in self.table:
            return None
        idx = self.table.index_of(landmark_id)
        c0s = self.c0s
        cfg = self.config
        reach = cfg.gamma_max * (1.0 + 1e-9) + 1e-12  # ≥ γ_M despite rounding
        near = self.table.near(self._box(idx), c0s, reach)
        near = near[near != idx]
        poly = self._polynomial(idx)
        partners = [self._polynomial(int(j)) for j in near]
        sides = self.table.side
        while len(near):
            choice = choose_merge(
                poly,
                float(c0s[idx]),
                partners,
                c0s[near],
                cfg.gamma_max,
                cfg.merge_min_overlap,
                new_side=int(sides[idx]),
                sides=sides[near].tolist(),
                join_gap=JOIN_GAP if cfg.join_pieces else None,
            )
            if choice is None:
                return None
            j = int(near[choice.partner])
            merged = self._merge_pair(
                landmark_id, idx, poly, j, partners[choice.partner], choice.joined
            )
            if merged is not None:
                return merged
            near = np.delete(near, choice.partner)
            del partners[choice.partner]
        return None

    def _merge_pair(
        self, landmark_id: int, idx: int, poly: Polynomial, j: int, other: Polynomial, joined: bool
    ) -> int | None:
        """Merge landmark ``landmark_id`` (index ``idx``, shape ``poly``) with the one at index
        ``j`` (shape ``other``) when one polynomial explains both; the merged id, or None (the
        state unchanged)."""
        cfg = self.config
        sides = self.table.side
        other_id = self.table.ids[j]
        pts = merge_points(
            poly,
            3 + idx,
            float(self.cov[3 + idx, 3 + idx]),
            other,
            3 + j,
            float(self.cov[3 + j, 3 + j]),
            cfg.eps_m,
            self.mean.size,
            self._turn_of(idx),
            self._turn_of(j),
        )
        fit = self._fit(pts)
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
            limit = self._max_fit_rms(cfg.rho_max)
        else:
            limit = np.inf
        if fit.rms > limit:
            return None
        side = _combine_sides(
            self._side_in(int(sides[idx]), poly, fit.poly),
            self._side_in(int(sides[j]), other, fit.poly),
        )
        evidence = hull(
            evidence_on(self._evidence(idx), poly, fit.poly),
            evidence_on(self._evidence(j), other, fit.poly),
        )
        w = _length_weight(poly.hi - poly.lo, other.hi - other.lo)
        rotation = [(idx, w), (j, 1 - w)]
        gradient = None
        if cfg.rotation_states and cfg.merge_turn == "fit":
            gradient = turn_gradient(pts, fit, centroid_xi(pts, fit.poly.variate))
        return self._replace([landmark_id, other_id], fit, side, evidence, rotation, pts, gradient)

    # -- links between pieces of one wall (links.py) ---------------------------------------------
    def _link_changed(self) -> int:
        """Link the landmarks created, refit or merged ``config.link_age`` steps ago to the
        straight pieces of their walls across gaps (:meth:`_link_walls`); a linked landmark is
        then checked for merges again (pieces a few cm apart that no join fit could explain
        may now be one polynomial). Returns the number of links."""
        if self.config.link_gap <= 0.0 and not self.config.square_walls:
            return 0
        table = self.table
        made_at = self.step_count - self.config.link_age
        fresh = [lid for lid, at in zip(table.ids, table.changed_at, strict=True)
                 if at == made_at]  # fmt: skip
        links = 0
        for landmark_id in fresh:
            made = self._link_walls(landmark_id) + self._square_wall(landmark_id)
            if made:
                links += made
                self._merge_into_map(landmark_id)
        return links

    def _link_walls(self, landmark_id: int) -> int:
        """Link a straight landmark to every straight piece of another wall group, made at
        least ``config.link_age`` steps ago, whose evidence lies at most ``config.link_gap``
        from its own along their common axis, nearest first, when the collinearity
        pseudo-measurement passes its χ²(2) gate (:mod:`~polyslam_env.slam.links`); returns
        the number of links made."""
        cfg, table = self.config, self.table
        if cfg.link_gap <= 0.0 or landmark_id not in table or landmark_id in self._received:
            return 0
        idx = table.index_of(landmark_id)
        if table.order[idx] != 1:
            return 0
        evidence = self._evidence(idx)
        reach = cfg.link_gap * (1.0 + 1e-9) + EXTENT_MARGIN
        candidates = []
        matured = self.step_count - cfg.link_age  # partners at least as old (_link_changed)
        for j in table.near(self._box(idx), self.c0s, reach).tolist():
            if j == idx or table.variate[j] != table.variate[idx] or table.order[j] != 1:
                continue
            if table.changed_at[j] > matured or table.ids[j] in self._received:
                continue
            gap = evidence_gap(evidence, self._evidence(j))
            if -2.0 * EXTENT_MARGIN <= gap <= cfg.link_gap:
                candidates.append((gap, table.ids[j]))
        links = 0
        for _, other_id in sorted(candidates):
            if self._wall_of[other_id] != self._wall_of[landmark_id]:
                links += self._link_pair(landmark_id, other_id)
        return links

    def _link_pair(self, first: int, second: int) -> bool:
        """The collinearity update of two straight landmarks (rows at the middle of each one's
        evidence, noise each fit's variance beyond the range noise plus
        ``config.wall_straightness``²), estimating their two turns (:meth:`_apply_turn`);
        whether it passed the gate and was applied."""
        table = self.table
        i, j = table.index_of(first), table.index_of(second)
        xis = np.array([0.5 * sum(self._evidence(i)), 0.5 * sum(self._evidence(j))])
        if self._direction_of[first] == self._direction_of[second]:
            xis = xis.mean(keepdims=True)  # parallel already: only the offset is new
        residual, H = link_rows(
            self._polynomial(i), 3 + i, self._turn_of(i),
            self._polynomial(j), 3 + j, self._turn_of(j),
            xis, self.mean.size,
        )  # fmt: skip
        r = float(table.model_var[i] + table.model_var[j]) + self.config.wall_straightness**2
        if not self._update_pair(i, j, -residual, H, r * np.eye(xis.size)):
            return False
        self._join_walls(first, second)
        return True

    def _square_wall(self, landmark_id: int) -> int:
        """Tie straight landmark ``landmark_id`` in direction to the straight landmark of
        another direction group, made at least ``config.link_age`` steps ago, whose angle to
        it the state knows best, by the pseudo-measurement that their angle is a multiple of
        90° (:func:`~polyslam_env.slam.links.off_square`), noise ``config.wall_squareness_deg``²
        plus each fit's direction variance beyond the range noise, gated by χ²(1); estimates
        the two lines' turns as a link does. Needs ``config.square_walls`` and rotation
        states; received landmarks take no part. Returns 1 if tied, else 0."""
        cfg, table = self.config, self.table
        if (
            not cfg.square_walls
            or not cfg.rotation_states
            or landmark_id not in table
            or landmark_id in self._received
        ):
            return 0
        i = table.index_of(landmark_id)
        if table.order[i] != 1 or not self._long_enough(landmark_id):
            return 0
        group = self._direction_of[landmark_id]
        matured = self.step_count - cfg.link_age
        others = np.array(
            [
                j
                for j, (lid, at) in enumerate(zip(table.ids, table.changed_at, strict=True))
                if table.order[j] == 1
                and at <= matured
                and lid not in self._received
                and self._direction_of[lid] != group
                and self._long_enough(lid)
            ],
            dtype=np.int64,
        )
        if others.size == 0:
            return 0
        t_i, t_others = self._turn_index(i), self._turn_index(0) + others
        cov = self.cov
        relative = cov[t_i, t_i] + cov[t_others, t_others] - 2.0 * cov[t_i, t_others]
        j = int(others[int(np.argmin(relative))])
        t_j = self._turn_index(j)
        angle = line_angle(table.polys[i]) + self.mean[t_i]
        angle -= line_angle(table.polys[j]) + self.mean[t_j]
        H = np.zeros((1, self.mean.size))
        H[0, t_i], H[0, t_j] = 1.0, -1.0
        r = math.radians(cfg.wall_squareness_deg) ** 2 + sum(
            float(table.model_var[k]) / float(table.fit_half[k]) ** 2 for k in (i, j)
        )
        if not self._update_pair(i, j, np.array([-off_square(angle)]), H, np.array([[r]])):
            return 0
        self._join_groups(self._direction_of, landmark_id, table.ids[j])
        return 1

    def _update_pair(
        self, i: int, j: int, innovation: np.ndarray, H: np.ndarray, R: np.ndarray
    ) -> bool:
        """A pseudo-measurement tying straight landmarks ``i`` and ``j`` (indices):
        :func:`~polyslam_env.slam.ekf.update_rows` with every turn but the two lines' own
        considered, then both stored lines turned by their estimates (:meth:`_apply_turn`);
        whether it passed its gate and was applied."""
        considered = None
        if self.config.rotation_states:  # every turn but the two lines' own
            turns = self._turn_index(0) + np.arange(len(self.table))
            considered = np.delete(turns, [i, j])
        result = ekf.update_rows(
            self.mean, self.cov, innovation, H, R, self.config.gate_prob, considered
        )
        if result is None:
            return False
        before = self.mean[:3].copy()
        self.mean, self.cov, _ = result
        if self.config.rotation_states:
            for k in (i, j):
                self._apply_turn(k)
        self._state_version += 1
        self._carry_stored_points(before, self.mean[:3])
        return True

    def _apply_turn(self, index: int) -> None:
        """Turn straight landmark ``index``'s stored line by its estimated turn α̂ about its
        pivot and reset α̂ to 0: an error-state reset. Turns about one point add, and the
        offset at the pivot stays (:func:`~polyslam_env.slam.links.turned_line`), so the
        errors keep their meaning and the covariance stays."""
        t = self._turn_index(index)
        line = turned_line(self._polynomial(index), float(self.table.pivot[index]), self.mean[t])
        self.mean[3 + index], self.mean[t] = line.c0, 0.0
        self.table.set_shape(index, line)

    def _join_walls(self, keep: int, other: int) -> None:
        """Put landmark ``other``'s wall group into landmark ``keep``'s (a link or a merge:
        what they share is in the state now, and must not be used again), and so their
        direction groups (one wall is parallel to itself)."""
        self._join_groups(self._wall_of, keep, other)
        self._join_groups(self._direction_of, keep, other)

    @staticmethod
    def _join_groups(group_of: dict[int, int], keep: int, other: int) -> None:
        """Put landmark ``other``'s group of ``group_of`` into landmark ``keep``'s."""
        target, source = group_of[keep], group_of[other]
        if target == source:
            return
        for lid, group in group_of.items():
            if group == source:
                group_of[lid] = target

    def _long_enough(self, landmark_id: int) -> bool:
        """Whether the landmark is long enough to update the pose (``min_update_extent``)."""
        floor = self.config.min_update_extent
        if floor <= 0.0:
            return True
        i = self.table.index_of(landmark_id)
        return bool(self.table.hi[i] - self.table.lo[i] >= floor)

    def _turn_of(self, index: int) -> tuple[int, float] | None:
        """(state index of landmark ``index``'s turn α, its pivot ξ), None without rotation
        states: points sampled on its shape move with α (``fitting.polynomial_points``), so
        a fit over them (a refit's R, a merge) has its c0's dependence on α in G_x."""
        if not self.config.rotation_states:
            return None
        return self._turn_index(index), float(self.table.pivot[index])

    def _turn_index(self, index: int) -> int:
        """State index of landmark ``index``'s turn α (rotation states follow the n c0s)."""
        return 3 + len(self.table) + index

    def _evidence(self, index: int) -> tuple[float, float]:
        """ξ-interval (on its own axis) of the hits supporting landmark ``index``."""
        lo, hi = self.table.evidence[index].tolist()
        return lo, hi

    @staticmethod
    def _side_in(side: int, old: Polynomial, new: Polynomial) -> int:
        """The face ``side`` of ``old`` expressed on ``new`` (their variates may differ)."""
        if side == 0:
            return 0
        normal = face_normal(old, 0.5 * (old.lo + old.hi), side)
        return 1 if float(normal @ face_normal(new, 0.5 * (new.lo + new.hi), 1)) >= 0 else -1

    def _polynomial(self, index: int) -> Polynomial:
        """Landmark ``index`` (state 3 + index) with its current c0."""
        return self.table.polys[index].with_c0(float(self.mean[3 + index]))

    def _box(self, index: int) -> np.ndarray:
        """(4,) bounding box (x_min, x_max, y_min, y_max) of landmark ``index``."""
        return self.table.boxes(self.c0s)[index]

    def _fit(self, points: PointSet) -> Fit | None:
        fit = fit_polynomial(
            points,
            self.config.order,
            None,
            shape_fixed=True,
            auto_order=self.config.auto_order,
            min_noise_var=self.config.range_sigma**2,
        )
        if not (
            np.isfinite(fit.c0) and np.all(np.isfinite(fit.Gx)) and np.all(np.isfinite(fit.Gy))
        ):
            return None
        if fit.poly.max_slope() > MAX_SLOPE:  # curves away between its points: not one wall
            return None
        return fit

    # -- EKF update -------------------------------------------------------------------------------
    def _update(self, beams: list[tuple[int, int]], ranges: np.ndarray) -> int:
        """Batched, gated update with the associated beams ((beam, landmark index) pairs;
        their rows as in :meth:`_map_args`, each on the landmark it is cast onto, which must
        be its own with ``end_sigma`` > 0); returns how many were used."""
        if not beams or self.n_landmarks == 0:
            return 0
        mean = self.mean
        before = mean[:3].copy()
        chosen, assigned = np.array(beams, dtype=np.int64).T.copy()
        args = (mean, self.cov, self.beam_angles, ranges, chosen, assigned)
        used = kernels.update_scan(*args, *self._map_args())
        if used < 0:  # no usable row: nothing ran
            return 0
        self._state_version += 1
        if used:  # else the pose did not move
            self._carry_stored_points(before, mean[:3])
        return used

    def _map_args(self) -> tuple[Any, ...]:  # the kernels type their arguments
        """The map and model arguments of the scan kernels (``kernels.screen_scan``,
        ``kernels.update_scan``): the landmarks within range at the current mean, the table's
        arrays, the model constants and the χ² gate.

        Each beam's hit (:func:`~polyslam_env.slam.kernels.beam_rows`, a whole scan per call,
        on the landmarks within range) gives one row of H: the pose part and 1/D on the c0
        hit (SPEC §3, :mod:`~polyslam_env.slam.measurement`). Near-tangent hits are skipped.
        R adds to the range noise the landmark's fit variance beyond the noise, and with
        ``shape_follows_pose`` the frozen shape's own errors:

        A shape was fitted to points placed with the pose estimate of its time, so that
        pose's error moves the whole shape rigidly. ``c0``'s Jacobian G_x carries the part of
        that motion a constant offset can: the shift of the curve at its centroid ξ_c. What
        it cannot carry (the shape is outside the state, as in the paper) is

        * the rotation by δα about the centroid (ξ_c, η_c), which changes η at ξ* by
          ±[(ξ* − ξ_c) + B'(ξ*)(η* − η_c)]·δα (+ for x¹-variate, − for x²-variate), and
        * the translation along ξ by δξ, which changes η at ξ* by −(B'(ξ*) − B'(ξ_c))·δξ.

        The heading error changes little after a landmark is made (odometry turns it by
        little and a wall hardly corrects absolute heading), so the shape's rotation is taken
        equal to the robot's current heading error: ±lever/D is added to ∂h/∂θ
        (∂h/∂η = ∂h/∂c0 = 1/D). Without it a frozen slope makes the absolute heading look
        observable: P_θθ shrinks while the error stays. The position error, in contrast, is
        corrected by the update, so the translation term is treated as noise: its variance
        ((B'(ξ*) − B'(ξ_c))/D)²·σ²_ξ, with σ²_ξ the pose variance along ξ when the landmark was
        made, goes into R together with the shape's own fit error: the shape was fitted to
        noisy points, so its estimation error is a bias every later beam on it shares. For N
        points equally spaced over the fitted extent, the fit's η at t = (ξ* − ξ_c)/half-extent
        has variance σ² a(t)ᵀM⁻¹a(t) (a = [1, t, …, t^m]); the constant part σ²/N is c0's and
        already in the state, the rest goes into R. It is small inside the fitted extent
        (~σ²·m/N) and grows fast where the curve is extrapolated. N = ε_Z + 1, the size of the
        cluster a landmark is born from. And the rotation the shape is taken to share is the
        heading error *when it was fitted*, which the current one has drifted from since: that
        drift's variance (:meth:`_turn_var`) times (lever/D)² goes into R as well.

        With rotation states (``shape_rotation="considered"``) the rotation is instead the
        landmark's own α: ±lever/D goes to ∂h/∂α, and neither the heading drift nor the
        slope's part of the fit variance (σ²·t²·M⁻¹[1, 1], which α's variance holds) enters R.
        The last four arguments are the landmark count, α_1's state index (−1: none),
        the first considered state index (the α block, or the state size: none) and
        ``end_sigma``: the update leaves out beams whose hit may lie past their landmark's
        end (``kernels.ends_in_doubt``).
        """
        table, n_fit = self.table, self._n_fit
        return (
            self.max_range + REACH_MARGIN,
            table.variate,
            table.order,
            table.shape,
            table.lo,
            table.hi,
            self._boxes(),
            self.max_range,
            self._min_sine,
            self._range_var,
            table.model_var,
            self.config.shape_follows_pose,
            table.pivot,
            table.xi_var,
            self._turn_var(),
            table.fit_half,
            _fit_inverse_table(n_fit, table.shape.shape[1] - 1),
            n_fit,
            self._gate,
            len(table),
            3 + len(table) if self.config.rotation_states else -1,  # α_1's state index
            # the considered entries (Schmidt): the rotations, or none
            3 + len(table) if self.config.rotation_states else self.mean.size,
            self.config.end_sigma,
        )

    def _turn_var(self) -> np.ndarray:  # (n,)
        """Per landmark, the variance of the robot's heading change since its shape was last
        fitted: the odometry's heading variance per step times the steps since then.

        ``shape_follows_pose`` takes a frozen shape's rotation to equal the current heading
        error; it equals the heading error *when the shape was fitted*, and the two drift apart
        by the heading noise the odometry adds in between (a random walk). Its effect on a
        beam, ±lever·δ/D, is an error of that beam's range; its variance goes into R
        (``kernels.beam_rows``). Without it the filter trusts walls made long ago, when it comes
        back to them around a loop, as if its heading had not moved since.
        """
        age = self.step_count - np.asarray(self.table.changed_at, dtype=float)
        return age * self._turn_var_per_step

    def _carry_stored_points(self, before: np.ndarray, after: np.ndarray) -> None:
        """Move cluster and Q_bad points rigidly with a pose correction.

        Stored points were placed from the pose estimates of their steps, which odometry ties
        rigidly to the current pose; the fits model them so (∂π/∂X through the current pose).
        When the update corrects the current pose, the recent trajectory moves with it, and so
        must the points: else a new landmark mixes stale coordinates with the corrected pose.
        """
        book, table = self.book, self.table
        groups = [*book.clusters, *table.qbad.values()]
        flat = [p for group in groups for p in group]
        if not flat:
            return
        moved = _carry(flat, before, after)
        start = 0
        clusters = []
        for group in book.clusters:
            clusters.append(moved[start : start + len(group)])
            start += len(group)
        book.clusters = clusters
        qbad = {}
        for lid, pts in table.qbad.items():  # most landmarks have none
            qbad[lid] = moved[start : start + len(pts)] if pts else []
            start += len(pts)
        table.qbad = qbad


def update_beam_mask(angles: np.ndarray, spacing_deg: float) -> np.ndarray:
    """Which beams (B,) bool enter the EKF update: in order of angle, each beam at least
    ``spacing_deg`` from the last one kept, starting from the first (all when 0)."""
    keep = np.zeros(len(angles), dtype=bool)
    last = -np.inf
    tol = 1e-9
    for i in np.argsort(angles, kind="stable"):
        if np.rad2deg(angles[i] - last) >= spacing_deg - tol:
            keep[i] = True
            last = angles[i]
    return keep


@functools.lru_cache(maxsize=16)
def _fit_inverse_table(n_points: int, max_order: int) -> np.ndarray:
    """(M+1, M+1, M+1): [m, :m+1, :m+1] is (AᵀA)⁻¹ for monomials of t up to order m at
    ``n_points`` points equally spaced over [−1, 1] (m = 1 … M; the rest zero)."""
    table = np.zeros((max_order + 1,) * 3)
    for order in range(1, max_order + 1):
        if n_points > order:  # else no fit of that order exists
            a = np.linspace(-1.0, 1.0, n_points)[:, None] ** np.arange(order + 1)
            table[order, : order + 1, : order + 1] = np.linalg.inv(a.T @ a)
    return table


def _length_weight(first: float, second: float) -> float:
    """Weight of the first of two fitted pieces in the turn of one shape fitted over both: a
    slope's precision grows as N·L² for N points over a length L, and N with L: as L³."""
    a, b = max(first, 1e-6) ** 3, max(second, 1e-6) ** 3
    return a / (a + b)


def _carry(points: list[StoredPoint], before: np.ndarray, after: np.ndarray) -> list[StoredPoint]:
    """The points moved by the rigid motion taking pose ``before`` (3,) to ``after`` (3,).

    All points go through one (N, 7) array [xy, direction, pose] and one 7×7 matmul; each
    new point's arrays are row views of the result.
    """
    bx, by, dtheta = float(before[0]), float(before[1]), float(after[2] - before[2])
    ax, ay = float(after[0]), float(after[1])
    c, s = math.cos(dtheta), math.sin(dtheta)
    rows = np.concatenate([a for p in points for a in (p.xy, p.direction, p.pose)])
    rows = rows.reshape(len(points), 7) - np.array([bx, by, 0.0, 0.0, bx, by, 0.0])
    motion = np.zeros((7, 7))  # Rᵀ on xy, direction and pose xy (row vectors times Rᵀ)
    motion[0, :2] = motion[2, 2:4] = motion[4, 4:6] = c, s
    motion[1, :2] = motion[3, 2:4] = motion[5, 4:6] = -s, c
    motion[6, 6] = 1.0
    rows = rows @ motion
    rows += np.array([ax, ay, 0.0, 0.0, ax, ay, dtheta])
    new = tuple.__new__
    return [
        new(StoredPoint, (moved, turned, p.sigma, p.weight, pose, p.beam, p.step))
        for moved, turned, pose, p in zip(
            rows[:, :2], rows[:, 2:4], rows[:, 4:], points, strict=True
        )
    ]


def _observed_side(points: Sequence[StoredPoint], variate: int) -> int:
    """The face the beams of ``points`` saw on a curve of ``variate``: beams travelling
    towards +η came from the −η side (−1), and vice versa; 0 if they cancel."""
    axis = 1 if variate == 1 else 0
    total = sum(float(p.direction[axis]) for p in points)
    return -1 if total > 0 else (1 if total < 0 else 0)


def _combine_sides(a: int, b: int) -> int:
    """Face of a merge: the common one, the known one, or 0 (both faces: a thin wall)."""
    if a == b or b == 0:
        return a
    return b if a == 0 else 0

"""One robot's polynomial EKF SLAM: :class:`PolySlam`, the stateful shell that strings its
parts together.

Each step follows SPEC §3's order: predict from odometry → extraction and data association
(creating and refitting landmarks) → merge check → batched, gated EKF update with the beams
associated to a landmark → end points follow from the updated c0s. The ordinary step is two
compiled calls (:mod:`~polyslam_env.slam.step_kernels`); the map's rare changes run between
them (:mod:`~polyslam_env.slam.maintenance`, :mod:`~polyslam_env.slam.walls`).

The robot works in its own start frame R_{j,0} and never sees ground truth.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from polyslam_env.core.blas import blas_threads
from polyslam_env.slam import ekf, kernels, step_kernels
from polyslam_env.slam.columns import (
    G_REQUEST,
    G_ROW,
    N_NEW,
    N_PER_BEAM,
    N_REFIT,
    N_VALUES,
    NEW,
    REFIT,
    S_SCREEN_ALARM,
    ST_EXTENTS,
    ST_FRESH,
    ST_OUTLIERS,
    ST_PAPER_TEST,
    ST_SCREEN,
    ST_USED,
    V_BEFORE,
    V_F,
    V_FIRST_X,
    V_FIRST_Y,
    V_RHO,
    V_SIGMA,
)
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.divergence import (
    SCREEN_CONTAMINATION,
    SCREEN_FALSE_ALARM,
    SCREEN_WINDOW,
    beyond_k_p0,
)
from polyslam_env.slam.fitting import Fit, polynomial_points
from polyslam_env.slam.landmarks import LandmarkTable, ShapesView
from polyslam_env.slam.layout import StateLayout
from polyslam_env.slam.lineage import Lineage
from polyslam_env.slam.links import frozen_slope_var
from polyslam_env.slam.maintenance import MapMaintenance, fit_inverse_table
from polyslam_env.slam.model import REACH_MARGIN, step_model, update_beam_mask
from polyslam_env.slam.polynomial import Polynomial, polyval
from polyslam_env.slam.stored import PointArrays, StoredPoints
from polyslam_env.slam.walls import WallGraph

__all__ = [
    "REACH_MARGIN",
    "SCREEN_CONTAMINATION",
    "SCREEN_FALSE_ALARM",
    "SCREEN_WINDOW",
    "PolySlam",
    "SlamStepInfo",
    "update_beam_mask",
]


class SlamStepInfo(NamedTuple):
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
    default; :attr:`c0s` is the c0 block; :mod:`~polyslam_env.slam.layout`); everything else
    about landmark ``i`` (stable id ``landmark_ids[i]``: shape, extent, …) is row i of
    :attr:`table`, the map's one record, and the beam points kept for later are
    :attr:`points`. ``mean`` and ``cov`` are working arrays (the prediction and the update
    write into them): copy to keep them.

    The class strings its parts together: the compiled step (:mod:`~polyslam_env.slam.
    step_kernels`: prediction, association, update), the map maintenance (:attr:`maintenance`:
    landmarks created, refit, merged, inserted, removed), the wall graph (:attr:`walls`:
    links and square ties) and the divergence monitor (:mod:`~polyslam_env.slam.divergence`).
    Every change of the map's landmarks is a lineage event (:attr:`lineage`).

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
    shape is fitted (:mod:`~polyslam_env.slam.layout`), never estimated by the beams
    (Schmidt–Kalman: zero gain, so the stored shape stays the estimate), its correlations
    updated by every beam on it (``kernels.update_sparse``).

    **Pieces of one wall linked.** A straight landmark made, refit or merged ``link_age``
    steps ago is linked to the straight pieces of its wall across gaps up to ``link_gap``
    (doorways) by a collinearity pseudo-measurement (:mod:`~polyslam_env.slam.walls`); that
    update does estimate the two lines' turns, and turns the stored lines by them. With
    ``square_walls`` a straight landmark is also tied square to the straight wall of another
    direction group whose angle to it is best known.

    Set :attr:`profile` to a dict to collect per-stage wall times (s) of every step under
    the keys ``predict``, ``association``, ``map`` (refits, new landmarks, merges, links) and
    ``update``; None (the default) skips the timing.
    """

    def __init__(
        self,
        config: SlamConfig,
        beam_angles: Sequence[float] | np.ndarray,
        max_range: float,
    ) -> None:
        self.config = config
        self.beam_angles = np.asarray(beam_angles, dtype=float)  # (B,)
        self._model = step_model(config, self.beam_angles, max_range)  # the compiled step's
        self.max_range = float(max_range)
        self.mean = np.zeros(3)  # (3+n,) relative to the true start (see class docstring)
        self._cov = np.zeros((3, 3))  # (3+n, 3+n) ditto: the true start is known exactly
        # P's lower triangle waits for its copy from the upper one, before this column (cov)
        self._mirror_from: int | None = None
        self.table = LandmarkTable()  # the map: ids, shapes, extents, … in state order
        self.points = StoredPoints()  # the clusters' and Q_bad sets' beam points
        self.layout = StateLayout(config.rotation_states)
        self.lineage = Lineage()  # every change of the map's landmarks, in order
        self.maintenance = MapMaintenance(self)
        self.walls = WallGraph(self)  # follows the lineage
        self.step_count = 0
        self.diverging = False
        self.divergence_f = 0.0
        self.profile: dict[str, list[float]] | None = None
        self._state_version = 0  # bumped by every update (map changes bump the table's version)
        # the compiled step's outcome (columns: G_*, ST_*, V_*), kept between steps: the
        # screen's window and the first-estimates position live there
        status = np.zeros(ST_SCREEN + SCREEN_WINDOW, dtype=np.int64)
        values = np.zeros(N_VALUES)
        values[V_FIRST_X] = values[V_FIRST_Y] = math.nan  # no prediction yet: the standard F
        per_beam = np.full((N_PER_BEAM, self.beam_angles.size), -1, dtype=np.int64)
        self._outcome = (per_beam, status, values)
        self._fit_width = 0
        self._inverse = np.zeros((1, 1, 1))

    @property
    def cov(self) -> np.ndarray:  # (3+n, 3+n)
        """The state's covariance, symmetric. The compiled update writes P's upper triangle
        and its pose block only (``kernels.joseph_blocks``); the lower triangle is mirrored
        here, on the first read after an update, not on every step."""
        if self._mirror_from is not None:
            kernels.mirror_lower(self._cov, self._mirror_from)
            self._mirror_from = None
        return self._cov

    @cov.setter
    def cov(self, value: np.ndarray) -> None:
        self._cov = value
        self._mirror_from = None

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
        return self._cov[:3, :3] + ekf.start_error_cov(self.mean, self.config.p0)

    @property
    def pose_cov_relative(self) -> np.ndarray:  # (3, 3)
        """The filter's P_S: the pose's covariance relative to the robot's true start, the
        frame its map lives in (what a map exchange must use)."""
        return self._cov[:3, :3].copy()

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
        share one (:mod:`~polyslam_env.slam.walls`); a copy."""
        return dict(self.walls.wall_of)

    @property
    def direction_groups(self) -> dict[int, int]:
        """Landmark id → its direction group: straight walls tied square (or parallel, as
        pieces of one wall are) to each other, directly or through others (:mod:`~polyslam_env.
        slam.walls`); a copy."""
        return dict(self.walls.direction_of)

    @property
    def last_update_beams(self) -> np.ndarray:
        """The beams (ascending indices) the last step handed to its update: each good for a
        landmark still in the map, one of the update's beams, on a long enough landmark (the
        update's own tests may still leave some out)."""
        return np.flatnonzero(self._outcome[0][G_ROW] >= 0)

    def c0_variance(self, landmark_id: int) -> float:
        k = self.table.state_index(landmark_id)
        return float(self._cov[k, k])

    def turn_variance(self, landmark_id: int) -> float:
        """Variance (rad²) of the landmark's turn α (needs rotation states)."""
        if not self.config.rotation_states:
            raise ValueError("turn_variance: this filter has no turn states (shape_rotation)")
        k = self.layout.turn_index(self.table.index_of(landmark_id), len(self.table))
        return float(self._cov[k, k])

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
                                    self.maintenance.turn_of(i))  # fmt: skip
            rows.append(np.einsum("ni,nij->nj", poly.normals(xi), pts.d_state))
            ds = np.sqrt(1.0 + poly.slope(xi) ** 2) * ((poly.hi - poly.lo) / (n - 1))
            ds[[0, -1]] *= 0.5  # the trapezoid rule: each point weighs its share of the arc
            lengths.append(ds)
        return np.concatenate(lengths), np.vstack(rows)

    def map_frozen_variance(self, spacing: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
        """What :meth:`map_error_jacobian` leaves out: at the same points, the variance (M,)
        of each point's offset along the curve's normal from its landmark's frozen errors (no
        state holds them; :meth:`frozen_variance`), and the landmark row of each point (M,)
        int: one landmark's frozen error is one curve, shared by its points."""
        variances, rows = [np.zeros(0)], [np.zeros(0, dtype=np.int64)]
        for i, poly in enumerate(self.polynomials()):
            n = max(2, math.ceil((poly.hi - poly.lo) / spacing) + 1)
            xi = np.linspace(poly.lo, poly.hi, n)
            eta_var = self.frozen_variance(i, xi)
            variances.append(eta_var / (1.0 + poly.slope(xi) ** 2))  # η error → normal offset
            rows.append(np.full(n, i, dtype=np.int64))
        return np.concatenate(variances), np.concatenate(rows)

    def frozen_variance(self, row: int, xi: np.ndarray) -> np.ndarray:
        """The variance (k,) of landmark ``row``'s frozen error along η at each ``xi`` (k,):
        :func:`~polyslam_env.slam.kernels.frozen_offset_var`, the terms the update adds to a
        beam's R there."""
        cfg, table = self.config, self.table
        eta_var = np.empty(xi.size)
        kernels.frozen_offset_var(
            table.shape_buffer[row], int(table.order[row]), xi, float(table.pivot[row]),
            float(table.fit_half[row]), float(table.model_var[row]), float(table.xi_var[row]),
            float(table.shift_slope[row]),
            (self.step_count - int(table.changed_at[row])) * float(cfg.odom_cov[2, 2]),
            self._fit_inverse(), cfg.eps_z + 1, cfg.range_sigma**2, cfg.shape_follows_pose,
            cfg.shape_shift == "pose", cfg.rotation_states, eta_var,
        )  # fmt: skip
        return eta_var

    def frozen_slope_variance(self, row: int, xi: float) -> float:
        """The variance of landmark ``row``'s frozen error in its slope B' at ``xi``, the
        slope's counterpart of :meth:`frozen_variance`: the misfit beyond the range noise as
        a direction (model_var/h², as a square tie takes it), the shape's fit
        (:func:`~polyslam_env.slam.links.frozen_slope_var`) and, with shapes that follow
        the pose, the fit-time shift along ξ on the curvature (B''² · xi_var)."""
        cfg, table = self.config, self.table
        half = float(table.fit_half[row])
        var = float(table.model_var[row]) / half**2 + frozen_slope_var(
            table.shape_buffer[row], int(table.order[row]), (xi - float(table.pivot[row])) / half,
            half, self._fit_inverse(), cfg.range_sigma**2, cfg.rotation_states,
        )  # fmt: skip
        if cfg.shape_follows_pose:
            bend = float(polyval(xi, table.polys[row].coeffs, derivative=2))
            var += bend * bend * float(table.xi_var[row])
        return var

    def step(self, odometry: np.ndarray, ranges: np.ndarray) -> SlamStepInfo:
        """Advance by one control period given odometry (3,) and range readings (B,).

        Two compiled calls (:mod:`~polyslam_env.slam.step_kernels`) with the rare map changes
        between them; those run with BLAS on ``config.blas_threads`` threads (see
        :mod:`polyslam_env.core.blas`): their products are the step's only BLAS calls.
        """
        start = lap = time.perf_counter()
        self.step_count += 1
        self.mean = self.mean.copy()  # a fresh working mean (callers may hold the last one)
        odometry = np.asarray(odometry, dtype=float)
        ranges = np.asarray(ranges, dtype=float)
        self.points.reserve(ranges.size)
        table, points, model = self.table, self.points, self._model
        real, index, shape = table.buffers
        preal, pindex, counters = points.buffers
        per_beam, status, values = self._outcome
        fit_inverse, n = self._fit_inverse(), len(table)
        if self.profile is None:
            step_kernels.begin_step(
                self.mean, self._cov, odometry, ranges, model.beams, real, index, shape, n, preal,
                pindex, counters, model.params, model.switches, fit_inverse, self.step_count,
                per_beam, status, values,
            )  # fmt: skip
        else:
            step_kernels.predict_step(
                self.mean, self._cov, odometry, ranges, model.beams, real, index, shape, n,
                model.params, model.switches, fit_inverse, self.step_count, status, values,
            )  # fmt: skip
            lap = self._lap("predict", lap)
            step_kernels.associate_step(
                self.mean, self._cov, ranges, model.beams, real, index, shape, n, preal, pindex,
                counters, model.params, model.switches, fit_inverse, self.step_count, per_beam,
                status, values,
            )  # fmt: skip
            lap = self._lap("association", lap)
        if status[ST_EXTENTS]:
            table.extents_changed()
        rho, sigma = float(values[V_RHO]), float(values[V_SIGMA])
        counts = (0, 0, 0, 0)
        if points.counters[N_REFIT] or points.counters[N_NEW] or status[ST_FRESH]:
            with blas_threads(self.config.blas_threads):
                counts = self._change_map(rho, int(status[ST_FRESH]))
            real, index, shape = table.buffers  # (the map changes may have grown them)
            fit_inverse, n = self._fit_inverse(), len(table)
        refit, created, merged, linked = counts
        if self.profile is not None:
            lap = self._lap("map", lap)

        step_kernels.finish_step(
            self.mean, self._cov, ranges, model.beams, real, index, shape, n, model.params,
            model.switches, fit_inverse, self.step_count, per_beam, status, values,
        )  # fmt: skip
        used = int(status[ST_USED])
        if used > 0:  # kernels.update_scan's consider_from
            considered = self.config.rotation_states
            self._mirror_from = 3 + n if considered else self._cov.shape[0]
        if used >= 0:  # the update ran
            self.state_moved(values[V_BEFORE : V_BEFORE + 3] if used else None)
        self.divergence_f = float(values[V_F])
        self.diverging = bool(
            (status[ST_PAPER_TEST] and beyond_k_p0(self._cov, self.config))
            or status[ST_OUTLIERS] >= model.switches[S_SCREEN_ALARM]
        )
        if self.profile is not None:
            self._lap("update", lap)
        return SlamStepInfo(
            self.step_count, time.perf_counter() - start, n, max(used, 0), created,
            refit, merged, rho, sigma, self.divergence_f, self.diverging, linked,
        )  # fmt: skip

    def _change_map(self, rho: float, fresh: int) -> tuple[int, int, int, int]:
        """This step's requests (refits, new landmarks with their merges) and links: (refit,
        created, merged, linked) counts."""
        points, maintenance = self.points, self.maintenance
        per_beam = self._outcome[0]
        refit = 0
        for request in range(int(points.counters[N_REFIT])):
            landmark_id = int(per_beam[G_REQUEST, request])
            refit += maintenance.refit(landmark_id, self._take(REFIT, request), rho)
        created = merged = 0
        for request in range(int(points.counters[N_NEW])):
            new_id = maintenance.create(self._take(NEW, request), rho)
            if new_id is not None:
                created += 1
                merged += maintenance.merge_into_map(new_id)
        points.counters[N_REFIT] = points.counters[N_NEW] = 0
        # links are sought for landmarks changed link_age steps ago: those the kernel counted,
        # or (link_age 0) those changed now
        changed_now = self.config.link_age == 0 and (refit or created)
        linked = self.walls.link_changed() if fresh or changed_now else 0
        return refit, created, merged, linked

    def _fit_inverse(self) -> np.ndarray:
        """The frozen shapes' fit model (``fit_inverse_table``) up to the table's widest order."""
        width = self.table.shape_buffer.shape[1]
        if width != self._fit_width:
            self._fit_width = width
            self._inverse = fit_inverse_table(
                self.config.eps_z + 1, max(self.config.order, width - 1)
            )
        return self._inverse

    def state_moved(self, before: np.ndarray | None) -> None:
        """An update changed the state (the boxes' cache key moves); when the pose moved from
        ``before`` (3,), the stored points move with it (:meth:`StoredPoints.carry`)."""
        self._state_version += 1
        if before is not None:
            self.points.carry(before, self.mean[:3])

    def _lap(self, stage: str, since: float) -> float:
        """Record the time since ``since`` under ``stage`` (profiling on); returns now."""
        now = time.perf_counter()
        assert self.profile is not None
        self.profile.setdefault(stage, []).append(now - since)
        return now

    def _take(self, kind: int, owner: int) -> PointArrays:
        """The points of one of this step's requests (copies), which leave the stored points."""
        rows = self.points.rows_of(kind, owner)
        taken = self.points.take(rows)
        self.points.drop(rows)
        return taken

    # -- the map exchange's landmarks --------------------------------------------------------
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
        id); :attr:`lineage` records what happened."""
        with blas_threads(self.config.blas_threads):
            return self.maintenance.insert(fit, merge, turn)

    def remove_landmark(self, landmark_id: int) -> None:
        """Drop a landmark from the map and its c0 from the state (a marginalisation: the
        rest of the covariance is unchanged), e.g. a received landmark superseded by a newer
        version from the same sender."""
        self.maintenance.remove(landmark_id)

    def changed_since(self, step: int) -> list[int]:
        """Ids of the landmarks created, refit or merged after ``step`` (exchange payloads)."""
        table = self.table
        return [table.ids[j] for j in np.flatnonzero(table.changed_at > step).tolist()]

    def landmark_boxes(self) -> np.ndarray:
        """Bounding boxes (n, 4) = (x_min, x_max, y_min, y_max) of the landmarks at the current
        c0s, in table order, cached until the map or the state changes (read-only: the map's
        merge check and the exchange share them)."""
        return self.table.boxes(self.c0s, self._state_version)

"""SLAM parameters. The defaults are the paper's §4 values except where marked; the preset
``paper`` holds exactly the paper's algorithm and values."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from polyslam_env.core.config import (
    Config,
    check_choice,
    check_non_negative,
    check_positive,
    check_range,
)
from polyslam_env.core.errors import ConfigError

#: The SLAM back-ends the env runs (``slam.backend``): the polynomial EKF of the core paper,
#: or a point-landmark filter over the pillars (``polyslam_env.slam.backends``).
BACKENDS: tuple[str, ...] = (
    "polynomial",
    "fastslam2",
    "em_fastslam",
    "mblcc",
    "multirobot_known_start",
    "seif",
)
#: What turns a landmark's frozen shape (``SlamConfig.shape_rotation``).
SHAPE_ROTATIONS: tuple[str, ...] = ("heading", "considered")
#: How a merged landmark's turn is made (``SlamConfig.merge_turn``).
MERGE_TURNS: tuple[str, ...] = ("fit", "weights")
#: Whose own error is bounded over the updates it enters (``SlamConfig.reuse_bound``).
REUSE_BOUNDS: tuple[str, ...] = ("none", "curved", "all")
#: What a frozen curved shape's shift along its axis is taken to be (``SlamConfig.shape_shift``).
SHAPE_SHIFTS: tuple[str, ...] = ("noise", "pose")


@dataclass(frozen=True)
class PointBackendConfig(Config):
    """The settings of the point-landmark back-ends in the env (seed 003's values). Their
    motion noise is ``slam.odom_sigma_*`` and their measurement noise the pillar sensor's
    (``world.pillar_sensor``), the same sources the polynomial EKF uses for its own."""

    particles: int = 10  # N (fastslam2, em_fastslam, mblcc)
    resample_fraction: float = 0.75  # resample when N_eff < fraction · N
    em_mobility: tuple[float, float, float] = (0.008, 0.005, 0.001)  # R: m, m, rad
    consensus_step: float = 0.1  # ε of MBLCC's eq. 12
    max_active: int = 20  # SEIF: landmarks linked to the pose at most
    # Anonymous readings (world.pillar_sensor.identities: false): a reading joins the nearest
    # landmark whose χ²(2) distance is within this quantile, starts a new landmark when every
    # landmark is beyond ``new_landmark_prob``'s, and is dropped in between.
    gate_prob: float = 0.99
    new_landmark_prob: float = 0.9999  # χ²(2) quantile beyond which a reading starts a landmark

    def validate(self) -> None:
        if isinstance(self.particles, bool) or self.particles < 1:
            raise ConfigError(f"slam.points.particles: must be >= 1, got {self.particles!r}")
        check_range("slam.points.resample_fraction", self.resample_fraction, 0.0, 1.0)
        for i, r in enumerate(self.em_mobility):
            check_non_negative(f"slam.points.em_mobility[{i}]", r)
        check_range("slam.points.consensus_step", self.consensus_step, 0.0, 1.0)
        if isinstance(self.max_active, bool) or self.max_active < 1:
            raise ConfigError(f"slam.points.max_active: must be >= 1, got {self.max_active!r}")
        for name in ("gate_prob", "new_landmark_prob"):
            p = getattr(self, name)
            if not (math.isfinite(p) and 0.5 <= p < 1.0):
                raise ConfigError(f"slam.points.{name}: must be in [0.5, 1), got {p!r}")
        if self.new_landmark_prob < self.gate_prob:
            raise ConfigError(
                f"slam.points.new_landmark_prob: must be >= gate_prob ({self.gate_prob}),"
                f" got {self.new_landmark_prob}"
            )

    @property
    def gates(self) -> tuple[float, float]:
        """The χ²(2) thresholds on d² of (gate_prob, new_landmark_prob): −2 ln(1 − p)."""
        return -2.0 * math.log1p(-self.gate_prob), -2.0 * math.log1p(-self.new_landmark_prob)


@dataclass(frozen=True)
class SlamConfig(Config):
    """Parameters of the per-robot polynomial EKF SLAM (SPEC §3, "Paper parameters")."""

    order: int = 3  # m, the largest polynomial order
    auto_order: bool = True  # pick each fit's order ≤ m by BIC (False: always m, as printed)
    # with auto_order, a fit of beam hits keeps the next order when its one more coefficient
    # is significant at 1 % (fitting.next_term_limits): a short piece of a curved wall whose
    # sagitta the all-dof χ² test lets pass as a line becomes a curve (docs/notes/floors.md,
    # Round 6); off: the χ² test alone
    curvature_test: bool = False
    rho_min: float = 0.08  # m, good-approximation threshold ρ at zero uncertainty
    rho_max: float = 0.24  # m, ... at K·P0
    sigma_min: float = 0.1  # m, "unmapped" threshold σ at zero uncertainty
    sigma_max: float = 0.3  # m, ... at K·P0
    eps_m: int = 5  # ε_M: Q_bad size that triggers a refit; points per polynomial in merges
    eps_z: int = 15  # ε_Z: cluster size that triggers a new polynomial (paper: 10, see PRESETS)
    k_divergence: float = 150.0  # K: P_{k|k-1} beyond K·P0 means divergence
    cluster_radius: float = 0.35  # m, R: neighbourhood radius for clustering
    gamma_max: float = 0.35  # m, γ_M: merge threshold on the RMS error
    merge_min_overlap: float = 0.1  # m, overlap length that counts as "overlapping"
    range_sigma: float = 0.02  # m, range noise the filter assumes
    odom_sigma_xy: float = 0.001  # m, process noise the filter assumes (per step)
    odom_sigma_theta_deg: float = 0.01  # degrees, ditto
    p0_sigma: tuple[float, float, float] = (0.05, 0.05, 0.0175)  # initial pose std (m, m, rad)
    gate_prob: float = 0.99  # χ² gate probability for each beam's innovation
    tangent_min_deg: float = 10.0  # beams hitting closer to tangent than this are skipped
    squared_error: bool = False  # the paper's squared end-point distance in association
    shape_follows_pose: bool = True  # shapes move with the pose error in ∂h/∂pose (robot.py)
    # What turns a landmark's frozen shape (with shape_follows_pose; robot.py):
    # "heading": the robot's current heading error (no state of its own);
    # "considered": its own state, the heading error it was fitted with plus the fit's own
    #   slope error, carried with its correlations but never estimated (Schmidt–Kalman).
    shape_rotation: str = "considered"
    # A merged landmark's turn α (with rotation states): "fit", the merged fit's direction as
    # a function of both pieces' c0s and turns plus the fit's residual scatter
    # (fitting.turn_gradient; docs/design/slam.md "Shapes, turns and walls"); "weights", a
    # length-weighted mean of the pieces' turns (their offsets' share left out: α comes out
    # underconfident, and the maps' own expected precision several times too pessimistic)
    merge_turn: str = "fit"
    # A landmark's own error beyond c0 and α (its fit's misfit and frozen shape) is one error
    # for every beam on it in every update until it is refitted, not new noise each step: the
    # u-th update its beams enter weighs that part u(u+1) times (Σ 1/(u(u+1)) = 1, so by
    # Cauchy–Schwarz the weights bound the error's share over all its updates;
    # kernels.reuse_factors). "curved": landmarks of order ≥ 2 (a line's shape is its c0 and
    # α, both states); "all": lines too (their misfit on jagged walls); "none": fresh each step
    reuse_bound: str = "curved"
    # A curved shape is frozen shifted along its axis ξ by the pose's error along ξ when it was
    # fitted (c0 carries the shift only where the shape turns about, its pivot). "pose": that
    # shift is predicted from the *current* pose's error along ξ (kernels.shift_prediction:
    # the errors nested, all of it right after the fit, little of it on a return to a shape
    # fitted when the pose was better known) and only what the prediction leaves goes into R;
    # "noise" (the paper preset): the shift is noise in R, independent of the pose, so the
    # curve's change of slope between its pivot and each hit told the filter where the robot
    # is along ξ, information a shape placed by that same pose does not hold
    # (docs/notes/floors.md, Round 4)
    shape_shift: str = "noise"
    # a beam is used only on a landmark face it can hit: the association leaves out the
    # landmarks whose seen face (SIDE) the beam would meet from behind, and the update leaves
    # out a beam its cast meets from behind (kernels.on_seen_face): the object's other face,
    # which the map does not hold, stands in between (a table's far edge, a thick wall's far
    # face), and read as the mapped face it turns the object's thickness into a pose error.
    # Off by default: the generators' walls have no thickness, and there a wall's far side
    # does hold its near side's line (docs/notes/floors.md, Round 10); on in
    # configs/real_building.yaml
    seen_faces: bool = False
    join_pieces: bool = True  # join end-to-end pieces of one wall (merging.py; paper: False)
    stretch_ends: bool = True  # a hit just past an end stretches it (association; paper: False)
    # beams whose hit lies within this many σ (of its place along the curve) of a landmark's
    # end are not used in the update: they may pass the end (kernels.ends_in_doubt); nor are
    # beams that, cast from the sigma points at this many σ of the pose and the landmark's c0,
    # miss it (kernels.steady_beams: short curved landmarks, round pillars); paper: 0
    end_sigma: float = 2.0
    # landmarks whose extent (along ξ, m) is shorter than this do not update the pose: a shape
    # fitted over a short stretch (a round pillar's arc as a line or a cubic) errs there more
    # than its fit model says (docs/design/consistency.md; the round columns'
    # arcs are at most 0.24–0.4 m long); 0: every landmark (paper)
    min_update_extent: float = 0.3
    # beams in the update are at least this far apart in angle (degrees; 0: every beam; the
    # others feed only the map: robot.update_beam_mask; paper: 0)
    update_spacing_deg: float = 22.5
    link_clusters: bool = True  # clusters joined by a point near both (association; paper: False)
    # straight pieces of one wall whose supporting hits are at most this far apart along it
    # (m: a doorway, 0.6–1.0 m in the generators and in most buildings, and the end margins)
    # are linked by a collinearity pseudo-measurement when its χ² gate passes (links.py);
    # 0: never (paper)
    link_gap: float = 1.2
    # with link_gap, pieces of one curved wall are linked too (a curve to a curve or a line,
    # same variate, evidence that meets: walls.CURVE_LINK_GAP): they meet at the junction
    # with one tangent (links.junction_rows), the curves' turns considered, the lines'
    # estimated; needs rotation states; False: straight pieces only (docs/notes/curved.md)
    curve_links: bool = False
    # steps after a landmark is made (refit, merged) that its links are sought: by then the
    # beams have updated its c0, while a fresh fit hangs the hits of several steps on one pose
    # and states its offset relative to that pose too precisely (linked at once, the lone
    # office robot's final NEES was 4.9 over 20 runs, above the band; docs/design/slam.md)
    link_age: int = 10
    # m, how far a real wall may run from the straight line through its linked pieces (the
    # links' noise beyond the fits'): the generators' and YAML maps' walls are exactly straight,
    # so this is a floor that keeps the link's innovation covariance well conditioned; raise
    # it for walls that are not (links.py)
    wall_straightness: float = 0.001
    # straight walls meet at right angles (most floor plans; the generators' walls are all
    # parallel to the axes): a straight landmark ``link_age`` steps old is tied in direction to
    # the best-known straight landmark of another direction group when the χ²(1) gate on
    # their angle's distance from the nearest multiple of 90° passes (links.py); False: never
    # (paper; set it for walls at other angles)
    square_walls: bool = True
    # tie walls square only while the robot's own confident straight walls say its floor is
    # rectilinear (links.rectilinear: square to one of them in all but a tenth of their
    # length); False: whenever the χ² gate passes (as before). Off by default: on the traced
    # Willow office it turned the ties off and its maps fell from 0.84–0.89 to 0.46–0.67
    # map_precision (docs/results/floors.md); on for angled, curved and cave floors
    square_evidence: bool = False
    # tie walls i and j square only when a third confident straight wall, no piece of
    # either, is square to both (links.pair_supported): the evidence per pair of directions,
    # not per floor (docs/notes/floors.md, Round 6); False: as square_evidence says
    square_pair_evidence: bool = False
    # degrees, how far a real wall may be from square to the others (the square link's noise
    # beyond the fits'): 1 mm per metre, as wall_straightness
    wall_squareness_deg: float = 0.057
    blas_threads: int = 1  # BLAS threads during a step (polyslam_env/core/blas.py); 0: leave as is
    backend: str = "polynomial"  # one of BACKENDS; the point ones map the pillars
    points: PointBackendConfig = field(default_factory=PointBackendConfig)

    def validate(self) -> None:
        if not 1 <= self.order <= 5:
            raise ConfigError(f"slam.order: must be in 1..5, got {self.order!r}")
        for name in (
            "rho_min",
            "rho_max",
            "sigma_min",
            "sigma_max",
            "k_divergence",
            "cluster_radius",
            "gamma_max",
            "range_sigma",
        ):
            check_positive(f"slam.{name}", getattr(self, name))
        if self.rho_max < self.rho_min:
            raise ConfigError(
                f"slam.rho_max: must be >= rho_min ({self.rho_min}), got {self.rho_max}"
            )
        if self.sigma_max < self.sigma_min:
            raise ConfigError(
                f"slam.sigma_max: must be >= sigma_min ({self.sigma_min}), got {self.sigma_max}"
            )
        for name in ("eps_m", "eps_z"):
            if getattr(self, name) < self.order + 1:
                raise ConfigError(
                    f"slam.{name}: must be >= order + 1 = {self.order + 1} to fit a"
                    f" polynomial, got {getattr(self, name)}"
                )
        check_non_negative("slam.merge_min_overlap", self.merge_min_overlap)
        check_non_negative("slam.end_sigma", self.end_sigma)
        check_non_negative("slam.min_update_extent", self.min_update_extent)
        check_non_negative("slam.link_gap", self.link_gap)
        if (
            isinstance(self.link_age, bool)
            or not isinstance(self.link_age, int)
            or self.link_age < 0
        ):
            raise ConfigError(f"slam.link_age: must be an integer >= 0, got {self.link_age!r}")
        check_positive("slam.wall_straightness", self.wall_straightness)
        check_positive("slam.wall_squareness_deg", self.wall_squareness_deg)
        for name in (
            "square_walls",
            "square_evidence",
            "square_pair_evidence",
            "curvature_test",
            "curve_links",
            "seen_faces",
        ):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(
                    f"slam.{name}: must be true or false, got {getattr(self, name)!r}"
                )
        check_range("slam.update_spacing_deg", self.update_spacing_deg, 0.0, 360.0)
        check_non_negative("slam.odom_sigma_xy", self.odom_sigma_xy)
        check_non_negative("slam.odom_sigma_theta_deg", self.odom_sigma_theta_deg)
        for i, s in enumerate(self.p0_sigma):
            check_positive(f"slam.p0_sigma[{i}]", s)
        check_range("slam.gate_prob", self.gate_prob, 0.5, 1.0)
        check_range("slam.tangent_min_deg", self.tangent_min_deg, 0.0, 89.0)
        check_non_negative("slam.blas_threads", self.blas_threads)
        check_choice("slam.backend", self.backend, BACKENDS)
        check_choice("slam.shape_rotation", self.shape_rotation, SHAPE_ROTATIONS)
        check_choice("slam.merge_turn", self.merge_turn, MERGE_TURNS)
        check_choice("slam.reuse_bound", self.reuse_bound, REUSE_BOUNDS)
        check_choice("slam.shape_shift", self.shape_shift, SHAPE_SHIFTS)

    @property
    def rotation_states(self) -> bool:
        """Whether each landmark's shape rotation is a state (``shape_rotation``)."""
        return self.shape_follows_pose and self.shape_rotation != "heading"

    @cached_property
    def p0(self) -> np.ndarray:  # (3, 3)
        """The start-error covariance diag(p0_sigma²), built once (read every step by every
        robot) and read-only, so no caller can change it for the others."""
        p0 = np.diag(np.square(self.p0_sigma))
        p0.flags.writeable = False
        return p0

    @property
    def odom_cov(self) -> np.ndarray:  # (3, 3)
        s_th = math.radians(self.odom_sigma_theta_deg)
        return np.diag([self.odom_sigma_xy**2, self.odom_sigma_xy**2, s_th**2])


#: ``paper``: the paper's algorithm and §4 values. Our defaults differ in these places:
#: end-to-end pieces of one wall are joined (``join_pieces``); a hit just past a wall's end on
#: its continued curve stretches it (``stretch_ends``); a beam whose hit may lie past a wall's
#: end is left out of the update (``end_sigma``), and so is a landmark shorter than 0.3 m
#: (``min_update_extent``); only beams 22.5° apart enter the update
#: (``update_spacing_deg``; the paper's five are 45° apart); a point near two clusters joins
#: them (``link_clusters``), so the sparse hits of beams sweeping a wall come together; and
#: ε_Z is 15, not 10, because linked clusters grow fast and a shape fitted to more points
#: carries a smaller frozen error (docs/results/fidelity.md has the measurements).
PRESETS: dict[str, SlamConfig] = {
    "paper": SlamConfig(
        eps_z=10,
        join_pieces=False,
        stretch_ends=False,
        end_sigma=0.0,
        min_update_extent=0.0,
        update_spacing_deg=0.0,
        link_clusters=False,
        link_gap=0.0,
        square_walls=False,
        shape_rotation="heading",
        reuse_bound="none",
        shape_shift="noise",
    )
}


def slam_preset(name: str) -> SlamConfig:
    """A named SLAM preset; an unknown name is an error listing the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(f"slam preset: unknown {name!r} (known: {', '.join(PRESETS)})") from None

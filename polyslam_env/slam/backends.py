"""The SLAM back-ends the env runs, selected by ``slam.backend`` (:data:`BACKENDS`).

``polynomial`` is the core paper's polynomial-landmark EKF (:class:`~polyslam_env.slam.robot.
PolySlam`), which maps walls from the range beams. The others map the pillars, from the pillar
sensor's range–bearing readings with known identities, with the filters of
:mod:`polyslam_env.slam.points`:

* ``fastslam2``, ``em_fastslam``, ``mblcc``: seed 003's particle filters (MBLCC adds the
  Kalman-consensus correction from the other robots' landmark estimates, which travel over the
  channel: :mod:`polyslam_env.comms.consensus`);
* ``multirobot_known_start``: seed 003's comparison, one particle filter over the whole
  team's poses with one shared map (:mod:`polyslam_env.slam.points.shared_map`); centralised
  (every robot's data reach it at once, no message is modelled), a privileged baseline that
  needs known starts;
* ``seif``: seed 001's sparse extended information filter.

In the env they use the odometry motion model (:func:`~polyslam_env.slam.points.models.
move_odometry`) with the noise the polynomial EKF assumes (``slam.odom_sigma_*``) and the
pillar sensor's noise. Like the polynomial EKF they are **anchored at the true start**: the
filter starts exactly at its frame origin and estimates relative to where the robot really
started, and the unobservable start error e₀ ~ N(0, P0) is added to the reported covariance as
J P0 Jᵀ (:func:`~polyslam_env.slam.ekf.start_error_cov`). Sampling P0 into the particles
instead would not survive: resampling keeps the descendants of a few initial particles, so the
spread of a direction nothing observes collapses and the filter turns overconfident.

:class:`PointSlamRobot` gives them the members the env reads of a
:class:`~polyslam_env.slam.robot.PolySlam` (``pose``, ``pose_cov``, ``pose_cov_relative``,
``diverging``, ``polynomials()``, ``step``), so the stages, observations, rewards and metrics
treat every back-end alike; a point back-end has no polynomial map (``polynomials()`` is
empty, so the wall-map metrics report ``has_map`` 0 and the map reward terms stay 0) and
reports its landmarks (:meth:`PointSlamRobot.landmarks`) for the landmark metrics instead.
fastslam2, em_fastslam and seif exchange nothing in the env (the channel stays unused).

With 10 particles the FastSLAM filters are overconfident (NEES far above 3 over an episode):
the particle spread after each sweep reflects one sweep's proposal, not the error the poses
share with the landmarks, the known inconsistency of FastSLAM with few particles (Bailey,
Nieto & Nebot 2006). SEIF is consistent (tests/environment/test_backends.py).
"""

from __future__ import annotations

import time

import numpy as np

from polyslam_env.core.blas import blas_threads
from polyslam_env.core.geometry import (
    compose,
    inverse,
    rotation,
    transform_covariance,
    transform_points,
)
from polyslam_env.slam.config import BACKENDS, SlamConfig
from polyslam_env.slam.ekf import start_error_cov
from polyslam_env.slam.points import models
from polyslam_env.slam.points.association import associate
from polyslam_env.slam.points.config import PointSlamConfig, algorithm_config
from polyslam_env.slam.points.fastslam import PointFastSlam
from polyslam_env.slam.points.interface import (
    LandmarkMap,
    LandmarkMessage,
    PointMeasurements,
    PointSlamBackend,
)
from polyslam_env.slam.points.seif import PointSeif
from polyslam_env.slam.points.seif_fusion import InformationMap, fuse_with_transform
from polyslam_env.slam.points.shared_map import SharedMapFastSlam
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam, SlamStepInfo

__all__ = [
    "BACKENDS",
    "POINT_BACKENDS",
    "PointSlamRobot",
    "SlamRobot",
    "make_point_slam",
    "make_point_slams",
    "point_slam_config",
]

#: The back-ends that map pillars (they need ``world.pillar_sensor.enabled``).
POINT_BACKENDS: tuple[str, ...] = tuple(b for b in BACKENDS if b != "polynomial")


def point_slam_config(
    slam: SlamConfig, sigma_range: float, sigma_bearing_deg: float
) -> PointSlamConfig:
    """The full filter settings of ``slam.backend`` (a point back-end) in the env: its
    algorithm switches, ``slam.points``, odometry motion with ``slam.odom_sigma_*`` and the
    pillar sensor's measurement noise (``sigma_range`` m, ``sigma_bearing_deg``)."""
    pts = slam.points
    base = PointSlamConfig(
        particles=pts.particles,
        resample_fraction=pts.resample_fraction,
        em_mobility=pts.em_mobility,
        consensus_step=pts.consensus_step if slam.backend == "mblcc" else 0.0,
        sigma_r=sigma_range,
        sigma_b_deg=sigma_bearing_deg,
        motion="odometry",
        odom_sigma_xy=slam.odom_sigma_xy,
        odom_sigma_theta_deg=slam.odom_sigma_theta_deg,
    )
    if slam.backend in ("seif", "multirobot_known_start"):
        return base
    # algorithm_config's mblcc would lift ε = 0 to the seed's 0.1; here ε is what was set
    return algorithm_config(slam.backend, base).replace(consensus_step=base.consensus_step)


class PointSlamRobot:
    """One robot's point-landmark back-end with the members the env reads of a
    :class:`~polyslam_env.slam.robot.PolySlam`.

    ``pose_cov_relative`` is the back-end's own covariance (relative to the true start),
    ``pose_cov`` that plus J P0 Jᵀ for the start error ``p0`` (3, 3). These filters have no
    divergence test: ``diverging`` stays False.
    """

    def __init__(
        self,
        backend: PointSlamBackend,
        config: PointSlamConfig,
        p0: np.ndarray,
        blas: int = 1,
        gates: tuple[float, float] | None = None,
        frame: np.ndarray | None = None,
    ) -> None:
        self.backend = backend
        #: this robot's frame in the back-end's (None: the same); a shared filter works in one
        #: frame for the team and the robot reports in its own
        self._to_own = None if frame is None else inverse(np.asarray(frame, dtype=float))
        self.config = config  # the back-end's settings
        self.p0 = np.asarray(p0, dtype=float)
        self.blas = blas  # BLAS threads during a step, as ``slam.blas_threads``
        #: χ²(2) thresholds (join, new) for anonymous readings; None: readings carry ids
        self.gates = gates
        self._next_id = 0  # the next own landmark id (anonymous readings)
        self.diverging = False
        self.steps = 0
        self._seen: set[int] = set()  # landmark ids the back-end holds
        #: SEIF map fusion (comms/seif_exchange.py): per sender, its own map as received
        #: (its frame), the accepted transform of that frame into this robot's and the
        #: transform's covariance
        self.fusion_sources: dict[int, tuple[InformationMap, np.ndarray, np.ndarray]] = {}
        self._sources_version = 0  # bumped by every change of the sources
        self._fused: tuple[tuple[int, int], LandmarkMap] | None = None  # (step, version), map
        self._read_pose()

    @property
    def pose_cov(self) -> np.ndarray:  # (3, 3)
        """The pose's covariance in the robot's frame: the back-end's own plus J P0 Jᵀ."""
        return self.pose_cov_relative + start_error_cov(self.pose, self.p0)

    def _read_pose(self) -> None:
        pose, cov = self.backend.pose()
        if self._to_own is not None:
            # before its first step the robot is at its frame origin, exactly (the transform
            # from the shared frame would leave rounding there)
            pose = compose(self._to_own, pose) if self.steps else np.zeros(3)
            cov = transform_covariance(cov, self._to_own)
        self.pose, self.pose_cov_relative = pose, cov

    @property
    def anonymous(self) -> bool:
        """Whether the readings' ids are ignored and the robot associates them itself."""
        return self.gates is not None

    def step(self, odometry: np.ndarray, ids: np.ndarray, z: np.ndarray) -> SlamStepInfo:
        """One control period: the odometry increment (3,) and the sweep's pillar readings,
        ids (m,) (ignored when :attr:`anonymous`) and (range, bearing) z (m, 2)."""
        start = time.perf_counter()
        u = np.asarray(odometry, dtype=float)
        with blas_threads(self.blas):
            if self.gates is not None:
                ids, z = self._associate(u, z, *self.gates)
            self.backend.step(u[None], PointMeasurements(ids, z))
            self.steps += 1
            self._read_pose()
        before = len(self._seen)
        self._seen.update(int(i) for i in ids)  # known association: a new id is a new landmark
        return SlamStepInfo(
            step=self.steps,
            time_s=time.perf_counter() - start,
            n_landmarks=len(self._seen),
            beams_used=len(ids),
            created=len(self._seen) - before,
            refit=0,
            merged=0,
            rho=0.0,
            sigma=0.0,
            divergence_f=0.0,
            diverging=False,
        )

    def _associate(
        self, odometry: np.ndarray, z: np.ndarray, gate: float, new: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Own ids for anonymous readings z (m, 2) (:func:`~polyslam_env.slam.points.
        association.associate` with the χ² thresholds ``gate`` and ``new``, from the pose
        predicted by ``odometry``): the readings kept, in their order, with the id of their
        landmark or a new one."""
        config = self.config
        pose, jac_pose, jac_u, q = models.motion(self.pose, odometry, config)
        pose_cov = jac_pose @ self.pose_cov_relative @ jac_pose.T + jac_u @ q @ jac_u.T
        lm = self.backend.landmarks()
        noise = np.diag(np.square(config.measurement_sigmas))
        found = associate(pose, pose_cov, lm.means, lm.covs, z, noise, gate, new)
        ids = np.full(len(z), -1, dtype=np.int64)
        known = found.slots >= 0
        ids[known] = lm.ids[found.slots[known]]
        for j in np.flatnonzero(found.new):
            ids[j] = self._next_id
            self._next_id += 1
        keep = ids >= 0
        return ids[keep], z[keep]

    def polynomials(self) -> list[Polynomial]:
        """No polynomial map: the wall-map metrics see an empty map."""
        return []

    def add_fusion_source(
        self, sender: int, theirs: InformationMap, transform: np.ndarray, cov: np.ndarray
    ) -> None:
        """Keep ``sender``'s own map (its frame) with the accepted ``transform`` of that frame
        into this robot's and the transform's covariance, replacing any older one."""
        self.fusion_sources[sender] = (theirs, transform, cov)
        self._sources_version += 1

    def information_map(self) -> InformationMap:
        """A SEIF robot's own map in information form, the pose eliminated (seed 001's unit
        of fusion): means (n, 2), information (2n, 2n), pillar ids (evaluation only)."""
        if not isinstance(self.backend, PointSeif):
            raise TypeError("only a SEIF robot has a map in information form")
        info, _ = self.backend.landmark_information()
        means = self.backend.mu[3:].reshape(-1, 2).copy()
        return InformationMap(means, info, np.array(self.backend.ids, dtype=np.int64))

    def landmarks(self) -> LandmarkMap:
        """The back-end's landmark map, in this robot's frame; with SEIF fusion sources, its
        own map with every source fused in (senders in order)."""
        if self.fusion_sources:
            key = (self.steps, self._sources_version)
            if self._fused is None or self._fused[0] != key:
                fused = self.information_map()
                for _, (theirs, transform, cov) in sorted(self.fusion_sources.items()):
                    fused = fuse_with_transform(fused, theirs, transform, cov)
                self._fused = (key, LandmarkMap(fused.ids, fused.means, fused.covariances()))
            return self._fused[1]
        lm = self.backend.landmarks()
        if self._to_own is None:
            return lm
        rot = rotation(float(self._to_own[2]))
        return LandmarkMap(lm.ids, transform_points(lm.means, self._to_own), rot @ lm.covs @ rot.T)

    def export_message(self) -> LandmarkMessage:
        return self.backend.export_message()

    def import_messages(self, messages: list[LandmarkMessage]) -> None:
        self.backend.import_messages(messages)


#: A robot's SLAM in the env, whichever the back-end.
SlamRobot = PolySlam | PointSlamRobot


def make_point_slam(
    slam: SlamConfig,
    sensor_sigmas: tuple[float, float],
    rng: np.random.Generator,
    robot_id: int,
    identities: bool = True,
) -> PointSlamRobot:
    """Robot ``robot_id``'s point back-end (``slam.backend``), anchored at its frame origin
    with start error P0, for a pillar sensor of noise ``sensor_sigmas`` (m, degrees) whose
    readings carry the pillars' ``identities`` (else the robot associates them); the particle
    filters draw from ``rng``."""
    config = point_slam_config(slam, *sensor_sigmas)
    origin = np.zeros(3)
    backend: PointSlamBackend
    if slam.backend == "seif":
        backend = PointSeif(config, origin, slam.points.max_active, robot_id=robot_id)
    else:
        backend = PointFastSlam(config, origin, rng, robot_id=robot_id)
    gates = None if identities else slam.points.gates
    return PointSlamRobot(backend, config, slam.p0, slam.blas_threads, gates)


def make_point_slams(
    slam: SlamConfig,
    sensor_sigmas: tuple[float, float],
    rng: np.random.Generator,
    starts: np.ndarray,
    identities: bool = True,
) -> list[PointSlamRobot]:
    """The team's point back-ends (:func:`make_point_slam` each), or for
    ``multirobot_known_start`` one shared filter in the world frame started at the robots'
    known ``starts`` (N, 3), each robot reporting in its own frame."""
    if slam.backend != "multirobot_known_start":
        return [
            make_point_slam(slam, sensor_sigmas, rng, i, identities) for i in range(len(starts))
        ]
    if not identities:
        raise ValueError("multirobot_known_start pairs the robots' readings by pillar identity")
    config = point_slam_config(slam, *sensor_sigmas)
    team = SharedMapFastSlam(config, np.asarray(starts, dtype=float), rng)
    return [
        PointSlamRobot(team.robot(i), config, slam.p0, slam.blas_threads, frame=start)
        for i, start in enumerate(np.asarray(starts, dtype=float))
    ]

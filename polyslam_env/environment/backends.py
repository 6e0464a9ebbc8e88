"""The team's SLAM as the env's stages call it: one object per ``slam.backend``.

:func:`make_team_slam` builds, at every reset, the object of the configured back-end; the
stages then call the same methods whatever it is (no test of a back-end's type anywhere in
the env):

* :class:`NoSlam` (``slam_enabled=False``): every robot knows its true pose in its frame and
  has no map;
* :class:`PolynomialTeam` (``polynomial``): each robot's :class:`~polyslam_env.slam.robot.
  PolySlam` on its range beams, the rendezvous map exchange
  (:class:`~polyslam_env.comms.exchange.RendezvousExchange`) when a channel is configured,
  and in the exchange's alignment mode on pillars each robot's
  :class:`~polyslam_env.slam.features.FeatureBook`;
* :class:`PointTeam` (the point back-ends of :mod:`polyslam_env.slam.backends`): each robot's
  pillar filter, with MBLCC's landmark consensus or the SEIF map fusion when configured.

A team object owns the per-robot filters (``robots``, robot i's at i) and whatever exchange
belongs to them. It steps them (:meth:`TeamSlam.step`), reports the pose estimates of the
whole team (:meth:`TeamSlam.estimates`), runs its exchange after the SLAM step
(:meth:`TeamSlam.exchange`), gives each robot's map as points for the observations and as
arrays for the map rewards (:meth:`TeamSlam.map_points`, :meth:`TeamSlam.map_shapes`), and
what the end-of-episode metrics need (:meth:`TeamSlam.polynomials`,
:meth:`TeamSlam.landmarks`, :meth:`TeamSlam.counters`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from polyslam_env.comms.channel import ChannelConfig, in_radio_range
from polyslam_env.comms.consensus import ConsensusExchange
from polyslam_env.comms.exchange import AlignmentAttempt, ExchangeStep, RendezvousExchange
from polyslam_env.comms.seif_exchange import SeifMapExchange
from polyslam_env.core.geometry import between, transform_points, wrap_remainder
from polyslam_env.metrics.mapping import MapShapes, map_points
from polyslam_env.slam.backends import PointSlamRobot, make_point_slams
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import start_error_covs
from polyslam_env.slam.features import FeatureBook
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam, SlamStepInfo
from polyslam_env.world.config import WorldConfig

if TYPE_CHECKING:
    from polyslam_env.environment.config import EnvConfig
    from polyslam_env.environment.observations import MapSampler
    from polyslam_env.environment.sensing import Sensing
    from polyslam_env.world.physics import World

__all__ = [
    "NoSlam",
    "PointTeam",
    "PolynomialTeam",
    "TeamSlam",
    "exchange_maps",
    "make_exchange",
    "make_team_slam",
    "run_slam",
]

_NO_MAP = MapShapes(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
_NO_POINTS = np.zeros((0, 2))  # (0, 2): the map of a robot without one
#: A (3,) true transform between two robots' frames, for a wrong-alignment count.
TrueTransform = Callable[[AlignmentAttempt], np.ndarray]


class TeamSlam:
    """What the env's stages ask of the team's SLAM (module docstring); this base class is
    the team without SLAM's answers where a back-end has nothing to say."""

    #: The per-robot filters (robot i's at i); empty without SLAM.
    robots: Sequence[Any] = ()
    #: The polynomial map exchange (None: none; only :class:`PolynomialTeam` has one).
    map_exchange: RendezvousExchange | None = None
    #: Per robot, its pillar feature book (the map exchange's alignment mode on pillars).
    features: Sequence[FeatureBook] = ()
    #: MBLCC's landmark consensus (:class:`PointTeam` with ``slam.backend: mblcc``).
    consensus: ConsensusExchange | None = None
    #: The SEIF map fusion (:class:`PointTeam` with ``slam.backend: seif``, alignment mode).
    fusion: SeifMapExchange | None = None

    def step(
        self, active: np.ndarray, odometry: np.ndarray, sensing: Sensing
    ) -> list[SlamStepInfo | None]:  # (N,)
        """One SLAM step of every active robot (changes the filters) on its odometry (N, 3)
        and this step's readings; None for robots without SLAM or failed."""
        return [None] * len(active)

    def estimates(self, world: World, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's pose estimate (N, 3) and its covariance (N, 3, 3), each in its own
        frame (``starts`` (N, 3): the frames in the world)."""
        raise NotImplementedError

    def exchange(self, step: int, world: World, sensing: Sensing) -> ExchangeStep | None:
        """The exchange after SLAM step ``step`` (changes the exchange and the filters); the
        polynomial map exchange's step, None for the others."""
        return None

    def map_points(self, i: int) -> np.ndarray:  # (M, 2)
        """Robot i's map as points in its frame (the observations' occupied cells)."""
        return _NO_POINTS

    def team_map_points(self, robots: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`map_points` of ``robots`` (K) in one array (M, 2), robot ``robots[k]``'s rows
        ``starts[k]:starts[k + 1]`` (``starts`` (K + 1,) int64)."""
        maps = [self.map_points(i) for i in robots]
        starts = np.zeros(len(maps) + 1, dtype=np.int64)
        starts[1:] = np.array([len(m) for m in maps], dtype=np.int64).cumsum()
        return (np.concatenate(maps) if maps else _NO_POINTS), starts

    def map_shapes(self, i: int) -> MapShapes:
        """Robot i's wall map as arrays (the map rewards' input; empty without one)."""
        return _NO_MAP

    def polynomials(self, i: int) -> list[Polynomial] | None:
        """Robot i's wall map (None without SLAM: the metrics report ``slam`` 0)."""
        return None

    def landmarks(self, i: int) -> tuple[np.ndarray | None, np.ndarray] | None:
        """Robot i's pillar map (ids, None when anonymous; means (M, 2)), None if it has none."""
        return None

    def diverging(self, i: int) -> bool:
        """Whether robot i's filter flags divergence now."""
        return False

    def bytes_sent(self) -> np.ndarray:  # (N,) int64
        """Bytes each robot sent so far over the map exchange (the ``bytes`` reward term)."""
        return np.zeros(0, dtype=np.int64)

    def counters(self, i: int, true_transform: TrueTransform) -> dict[str, float]:
        """Robot i's traffic for the end-of-episode metrics, with ``alignments_wrong``
        counted against ``true_transform`` of each of its accepted alignments."""
        return {}

    def pose_cov_relative(self, i: int) -> np.ndarray | None:
        """The filter's own covariance (3, 3) of robot i's pose relative to its true start
        (what the renderer draws); None without SLAM."""
        return None

    def render_map(self, i: int, start: np.ndarray) -> list[np.ndarray]:
        """Robot i's map as polylines placed by ``start`` (3,) (the renderer's)."""
        return []


class NoSlam(TeamSlam):
    """``slam_enabled=False``: the robots know their true poses (zero covariance), no map."""

    def __init__(self, num_robots: int) -> None:
        self.robots: list[Any] = []
        self._covs = np.zeros((num_robots, 3, 3))

    def estimates(self, world: World, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return between(starts, world.poses, wrap_remainder), self._covs.copy()


class _Filters(TeamSlam):
    """A team of per-robot filters that each report ``pose``, ``pose_cov``,
    ``pose_cov_relative``, ``diverging`` and ``polynomials()``, all with the start-error
    covariance ``p0`` (3, 3)."""

    def __init__(self, robots: Sequence[PolySlam | PointSlamRobot], p0: np.ndarray) -> None:
        self.robots = list(robots)
        self.p0 = p0

    def estimates(self, world: World, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's ``pose`` and ``pose_cov`` (P_S + J P0 Jᵀ), the start errors' share of
        the team in one call (:func:`~polyslam_env.slam.ekf.start_error_covs`)."""
        poses, relative = self._relative()
        return poses, relative + start_error_covs(poses, self.p0)

    def _relative(self) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's pose (N, 3) and its filter's own covariance P_S (N, 3, 3)."""
        robots = self.robots
        return np.array([r.pose for r in robots]), np.array([r.pose_cov_relative for r in robots])

    def polynomials(self, i: int) -> list[Polynomial] | None:
        return self.robots[i].polynomials()

    def diverging(self, i: int) -> bool:
        return bool(self.robots[i].diverging)

    def pose_cov_relative(self, i: int) -> np.ndarray | None:
        return self.robots[i].pose_cov_relative


class PolynomialTeam(_Filters):
    """Each robot's polynomial EKF, the rendezvous map exchange (``exchange`` None: off) and,
    for the exchange's alignment mode on pillars, each robot's pillar feature book."""

    def __init__(
        self,
        robots: Sequence[PolySlam],
        p0: np.ndarray,
        exchange: RendezvousExchange | None,
        samplers: Sequence[MapSampler],
        angles: np.ndarray,
        features: Sequence[FeatureBook] = (),
    ) -> None:
        super().__init__(robots, p0)
        self.slams = list(robots)
        self.map_exchange = exchange
        self.samplers = list(samplers)
        self.features = list(features)
        self.angles = angles  # (B,) beam angles, for the exchange's scan logs

    def step(
        self, active: np.ndarray, odometry: np.ndarray, sensing: Sensing
    ) -> list[SlamStepInfo | None]:
        robots = range(len(self.slams))
        return run_slam(self.slams, robots, active, odometry, sensing.ranges)

    def _relative(self) -> tuple[np.ndarray, np.ndarray]:
        """The filters' pose (N, 3) and P_S (N, 3, 3) read from their states (no copy of the
        pose each). P_S through ``pose_cov_relative``, not ``cov``: reading ``cov`` mirrors
        P's lower triangle after every update (O(n²), the SLAM leaves it for the first read
        that needs it), which this read every step made every step (579 mirrors in 200 steps
        of the office-floor team, 19 without)."""
        slams = self.slams
        return np.array([s.mean[:3] for s in slams]), np.array([s.pose_cov_relative for s in slams])

    def exchange(self, step: int, world: World, sensing: Sensing) -> ExchangeStep | None:
        """Place the pillars each active robot sees in its feature book (alignment mode on
        pillars), then the map exchange's step (:func:`exchange_maps`)."""
        active = world.active
        for i, book in enumerate(self.features):
            if active[i]:
                reading = sensing.pillars[i]
                book.add(self.slams[i].pose, reading.ids, reading.z, reading.descriptors)
        exchange = self.map_exchange
        if exchange is None:
            return None
        poses = world.poses if exchange.config.mode == "alignment" else None  # the radio's
        return exchange_maps(
            exchange, step, self.slams, active, sensing, self.angles, poses, self.features
        )

    def map_points(self, i: int) -> np.ndarray:
        return self.samplers[i].points(self.slams[i])

    def team_map_points(self, robots: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """Each sampler writes its points straight into the team's array (no copy each)."""
        pairs = [(self.samplers[i], self.slams[i]) for i in robots]
        starts = np.zeros(len(pairs) + 1, dtype=np.int64)
        for k, (sampler, slam) in enumerate(pairs):
            starts[k + 1] = starts[k] + sampler.count(slam)
        out = np.empty((int(starts[-1]), 2))
        for k, (sampler, slam) in enumerate(pairs):
            sampler.write(slam, out[starts[k] : starts[k + 1]])
        return out, starts

    def map_shapes(self, i: int) -> MapShapes:
        slam = self.slams[i]
        table = slam.table
        coeffs = table.shape.copy()  # (n, M+1) [0, b_1, …]: c0 from the state
        coeffs[:, 0] = slam.c0s
        return MapShapes(table.variate, coeffs, table.lo, table.hi)

    def bytes_sent(self) -> np.ndarray:
        exchange = self.map_exchange
        if exchange is None:
            return np.zeros(len(self.slams), dtype=np.int64)
        return np.array([exchange.bytes_sent(i) for i in range(len(self.slams))], dtype=np.int64)

    def counters(self, i: int, true_transform: TrueTransform) -> dict[str, float]:
        if self.map_exchange is None:
            return {}
        out: dict[str, float] = dict(self.map_exchange.counters(i))
        out["alignments_wrong"] = _wrong(self.map_exchange.alignments, i, true_transform)
        return out

    def render_map(self, i: int, start: np.ndarray) -> list[np.ndarray]:
        return map_points(self.slams[i].polynomials(), start, 0.02)


class PointTeam(_Filters):
    """Each robot's point-landmark filter over the pillars, with MBLCC's landmark consensus
    (``consensus``) or the SEIF map fusion between robots (``fusion``) when configured."""

    def __init__(
        self,
        robots: Sequence[PointSlamRobot],
        p0: np.ndarray,
        consensus: ConsensusExchange | None = None,
        fusion: SeifMapExchange | None = None,
    ) -> None:
        super().__init__(robots, p0)
        self.points = list(robots)
        self.consensus = consensus
        self.fusion = fusion

    def step(
        self, active: np.ndarray, odometry: np.ndarray, sensing: Sensing
    ) -> list[SlamStepInfo | None]:
        pillars = sensing.pillars
        return [
            robot.step(odometry[i], pillars[i].ids, pillars[i].z) if active[i] else None
            for i, robot in enumerate(self.points)
        ]

    def exchange(self, step: int, world: World, sensing: Sensing) -> ExchangeStep | None:
        """MBLCC's consensus messages or the SEIF map fusion, if on (no polynomial exchange:
        returns None)."""
        if self.consensus is not None:
            self.consensus.step(step, self.points, world.active, world.poses)
        if self.fusion is not None:
            self.fusion.step(step, self.points, world.active, world.poses)
        return None

    def map_points(self, i: int) -> np.ndarray:
        return self.points[i].landmarks().means

    def landmarks(self, i: int) -> tuple[np.ndarray | None, np.ndarray] | None:
        robot = self.points[i]
        lm = robot.landmarks()
        return (None if robot.anonymous else lm.ids, lm.means)

    def counters(self, i: int, true_transform: TrueTransform) -> dict[str, float]:
        out: dict[str, float] = {}
        if self.consensus is not None:
            out.update(self.consensus.counters(i))
        if self.fusion is not None:
            out.update(self.fusion.counters(i))
            out["alignments_wrong"] = _wrong(self.fusion.alignments, i, true_transform)
        return out

    def render_map(self, i: int, start: np.ndarray) -> list[np.ndarray]:
        """A square of 0.6 m around each landmark estimate, wide enough to show around the
        pillar it marks."""
        square = 0.3 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]])  # (5, 2)
        centres = transform_points(self.map_points(i), start)  # (M, 2)
        return [c + square for c in centres]


#: An accepted alignment more than this far from the true transform between the two robots'
#: frames is wrong (issue 18's definition): 0.2 m in position or 3° in heading.
WRONG_ALIGNMENT_M = 0.2
WRONG_ALIGNMENT_DEG = 3.0


def is_wrong_alignment(transform: np.ndarray | None, truth: np.ndarray) -> bool:
    """Whether an accepted ``transform`` (3,) is more than 0.2 m or 3° off ``truth`` (3,);
    False for a declined one (None)."""
    if transform is None:
        return False
    err = between(truth, transform, wrap_remainder)
    return bool(
        np.hypot(err[0], err[1]) > WRONG_ALIGNMENT_M
        or abs(err[2]) > np.radians(WRONG_ALIGNMENT_DEG)
    )


def _wrong(attempts: Sequence[AlignmentAttempt], i: int, truth: TrueTransform) -> int:
    """How many of robot i's accepted alignments are wrong."""
    return sum(
        a.receiver == i and is_wrong_alignment(a.result.transform, truth(a)) for a in attempts
    )


# -- construction -------------------------------------------------------------------------------
def make_team_slam(
    config: EnvConfig,
    rngs: dict[str, np.random.Generator],
    start_poses: np.ndarray,
    samplers: Callable[[], list[MapSampler]],
) -> TeamSlam:
    """The team's SLAM of ``config`` (``slam_enabled``, ``slam.backend``, ``channel``) with
    the episode's named streams ``rngs`` and the robots' frames ``start_poses`` (N, 3);
    ``samplers()`` makes the robots' map samplers (polynomial maps only)."""
    n = config.num_robots
    if not config.slam_enabled:
        return NoSlam(n)
    wc, channel = config.world, config.channel
    angles = np.asarray(wc.range_sensor.angles)  # (B,)
    sensor = wc.pillar_sensor
    if config.slam.backend == "polynomial":
        slams = [PolySlam(config.slam, angles, wc.range_sensor.max_range) for _ in range(n)]
        pillars = channel is not None and channel.mode == "alignment"
        pillars = pillars and channel is not None and channel.features == "pillars"
        features = [FeatureBook(sensor.descriptor_dim) for _ in range(n)] if pillars else []
        exchange = None
        if channel is not None:
            exchange = make_exchange(
                channel, n, rngs["channel"], wc, config.slam, rngs["alignment"]
            )
        return PolynomialTeam(slams, config.slam.p0, exchange, samplers(), angles, features)
    sigmas = (sensor.sigma_range, sensor.sigma_bearing_deg)
    ids = sensor.identities
    points = make_point_slams(config.slam, sigmas, rngs["particles"], start_poses, ids)
    consensus = fusion = None
    if channel is not None and config.slam.backend == "mblcc":
        consensus = ConsensusExchange(channel, start_poses, rngs["channel"])
    if channel is not None and channel.mode == "alignment" and config.slam.backend == "seif":
        fusion = SeifMapExchange(channel, n, rngs["channel"], rngs["alignment"])
    return PointTeam(points, config.slam.p0, consensus, fusion)


def make_exchange(
    channel: ChannelConfig,
    num_robots: int,
    rng: np.random.Generator,
    world: WorldConfig,
    slam: SlamConfig,
    align_rng: np.random.Generator | None = None,
) -> RendezvousExchange:
    """The rendezvous exchange of a team (env and ``simulate``): ``rng`` is the channel's
    stream, ``align_rng`` the aligners' (alignment mode); the camera's noise and the SLAM's
    order settings come from the configs."""
    return RendezvousExchange(
        channel,
        num_robots,
        rng,
        world.camera.sigma_d,
        world.camera.sigma_bearing,
        slam.order,
        slam.auto_order,
        max_range=world.range_sensor.max_range,
        align_rng=align_rng,
    )


# -- the polynomial team's cores, shared with simulate -------------------------------------------
def run_slam(
    slams: Sequence[PolySlam],
    robots: Sequence[int],
    active: np.ndarray,
    odometry: np.ndarray,
    ranges: np.ndarray,
) -> list[SlamStepInfo | None]:
    """One step (changes the SLAMs) of every polynomial SLAM whose robot is active:
    ``slams[j]`` runs on world robot ``robots[j]``'s odometry (N, 3) and ranges (N, B); None
    for failed robots."""
    live = active.tolist()
    return [
        slam.step(odometry[i], ranges[i]) if live[i] else None
        for slam, i in zip(slams, robots, strict=True)
    ]


def exchange_maps(
    exchange: RendezvousExchange,
    step: int,
    slams: Sequence[PolySlam],
    active: np.ndarray,
    sensing: Sensing,
    angles: np.ndarray,
    poses: np.ndarray | None = None,
    features: Sequence[FeatureBook] = (),
) -> ExchangeStep:
    """One exchange step (changes the exchange and the receivers' SLAMs) after the SLAM step
    ``step``: log the active robots' scans, then detect, send, deliver and apply. Alignment
    mode needs the true ``poses`` (N, 3) (the radio's range is physics) and the robots'
    ``features``."""
    for i, s in enumerate(slams):
        if active[i]:
            exchange.record_scan(i, s.pose, sensing.ranges[i], angles)
    in_range: list[tuple[int, int]] = []
    if exchange.config.mode == "alignment":
        if poses is None:
            raise ValueError("alignment mode needs the robots' true poses for the radio range")
        near = in_radio_range(poses, exchange.config.range)  # (N, N)
        i_idx, j_idx = np.nonzero(np.triu(near, k=1))
        in_range = list(zip(i_idx.tolist(), j_idx.tolist(), strict=True))
    return exchange.step(
        step, slams, sensing.detections, active, in_range=in_range, features=features
    )

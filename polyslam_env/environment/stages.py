"""The stages of an episode: ``reset`` makes the state, ``step`` runs the stages in order.

Each stage is a function of what it reads (the :class:`EpisodeState` and the outputs of earlier
stages) that returns what it produces; a stage that changes the state says so in its first
line. In the order ``PolySlamParallelEnv.step`` runs them:

    simulate → sense → slam → map_features → exchange → record → observe → sweep_coverage
    → map_bookkeeping → (reward terms, combine: :mod:`~polyslam_env.environment.rewards`)
    → fail_robots → done → infos

:func:`~polyslam_env.apps.simulate.simulate` runs the team without the RL env through the same
cores — :func:`simulate`, :func:`sense`, :func:`run_slam`, :func:`exchange_maps` and
:func:`record` — so the two cannot drift. Step numbers are 1-based everywhere: step ``k`` is
the ``k``-th control period, after which the histories hold ``k + 1`` poses; the exchange is
told that number (only differences of step numbers change what it does). One difference is
left on purpose: the env's reset takes a camera frame for the first observations and
``simulate`` does not, so with the exchange on their ``camera`` streams are one frame apart.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from polyslam_env import metrics
from polyslam_env.comms.channel import ChannelConfig, in_radio_range
from polyslam_env.comms.consensus import ConsensusExchange
from polyslam_env.comms.exchange import AlignmentAttempt, ExchangeStep, RendezvousExchange
from polyslam_env.comms.seif_exchange import SeifMapExchange
from polyslam_env.core.geometry import beam_endpoints, between, wrap_remainder
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.faults import FaultEvent, FaultPlan, kidnap, perturb_starts
from polyslam_env.environment.observations import (
    MapSampler,
    ObservationEncoder,
    RobotView,
    belief_grids,
    sweep_beliefs,
)
from polyslam_env.environment.rewards import MAPPING_STEP, MAPPING_TOL, MapChanges
from polyslam_env.environment.state import EpisodeState, Sensing, estimate
from polyslam_env.metrics.episode import RobotHistory, final_robot_metrics, team_metrics
from polyslam_env.slam.backends import PointSlamRobot, SlamRobot, make_point_slams
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.features import FeatureBook
from polyslam_env.slam.robot import PolySlam, SlamStepInfo
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.grid import FreeGrid
from polyslam_env.world.layout import Layout
from polyslam_env.world.physics import StepResult, World
from polyslam_env.world.point_sensor import PillarReading
from polyslam_env.world.sensors import Detection

__all__ = [
    "done",
    "exchange",
    "exchange_maps",
    "fail_robots",
    "infos",
    "inject_faults",
    "make_exchange",
    "map_bookkeeping",
    "new_episode",
    "observe",
    "record",
    "record_histories",
    "run_slam",
    "sense",
    "simulate",
    "slam",
    "sweep_coverage",
]

Obs = np.ndarray | dict[str, np.ndarray]
_NO_POINTS = np.zeros((0, 2))  # (0, 2): the map of a robot without SLAM


# -- reset ----------------------------------------------------------------------------------------
def new_episode(
    config: EnvConfig, rngs: dict[str, np.random.Generator], layout: Layout, free: FreeGrid
) -> EpisodeState:
    """A fresh episode on ``layout`` (its free-space grid ``free``) with the named streams
    ``rngs``: a new pymunk world, fresh SLAMs, grids and histories, the first sensor readings
    and the first coverage sweep.

    Each robot's frame is its nominal start pose (the layout's); with ``initial_error`` (and
    SLAM on) its true start is drawn around it from N(0, P0) (:func:`perturb_starts`, stream
    ``start_error``), while its SLAM starts at x̂ = 0 with covariance P0. Without SLAM the robot
    knows its true pose, so ``initial_error`` has no effect there.
    """
    n = config.num_robots
    wc, oc = config.world, config.observation
    world = World(layout, wc, n, rngs)
    coverage = metrics.CoverageGrid(free.mask, free.origin, free.resolution)
    start_poses = world.poses  # (N, 3), each robot's frame in the absolute frame
    if config.initial_error and config.slam_enabled:
        perturb_starts(world, config.slam.p0, rngs["start_error"])
    angles = np.asarray(wc.range_sensor.angles)  # (B,)
    max_range = wc.range_sensor.max_range
    pillar_sensor = wc.pillar_sensor
    slams: list[SlamRobot] = []
    if config.slam_enabled and config.slam.backend == "polynomial":
        slams = [PolySlam(config.slam, angles, max_range) for _ in range(n)]
    elif config.slam_enabled:
        rng = rngs["particles"]
        sigmas = (pillar_sensor.sigma_range, pillar_sensor.sigma_bearing_deg)
        ids = pillar_sensor.identities
        slams = list(make_point_slams(config.slam, sigmas, rng, start_poses, ids))
    polynomial = config.slam_enabled and config.slam.backend == "polynomial"
    channel = config.channel
    on_pillars = (
        channel is not None and channel.mode == "alignment" and channel.features == "pillars"
    )
    pillar_books = polynomial and on_pillars
    features = [FeatureBook(pillar_sensor.descriptor_dim) for _ in range(n)] if pillar_books else []
    state = EpisodeState(
        rngs=rngs,
        world=world,
        coverage=coverage,
        start_poses=start_poses,
        angles=angles,
        slams=slams,
        exchange=None
        if config.channel is None or not polynomial
        else make_exchange(config.channel, n, rngs["channel"], wc, config.slam, rngs["alignment"]),
        consensus=ConsensusExchange(config.channel, start_poses, rngs["channel"])
        if config.channel is not None and config.slam_enabled and config.slam.backend == "mblcc"
        else None,
        seif_exchange=SeifMapExchange(channel, n, rngs["channel"], rngs["alignment"])
        if channel is not None
        and channel.mode == "alignment"
        and config.slam_enabled
        and config.slam.backend == "seif"
        else None,
        features=features,
        beliefs=belief_grids(oc, layout.bounds, max_range, n),
        samplers=[MapSampler(0.5 * oc.grid_resolution) for _ in range(n)],
        histories=[],  # filled below: a history starts from the robot's estimate
        sensing=sense(world),
        last_rendezvous=[None] * n,
        completeness=[0.0] * n,
        map_error=[0.0] * n,
        bytes_sent=[0] * n,
        links=[],
        coverage_series=[],
    )
    state.histories = [
        RobotHistory(
            start_poses[i],
            *estimate(state, i),
            true_pose=world.poses[i],
            p0=config.slam.p0 if config.slam_enabled else None,
        )
        for i in range(n)
    ]
    sweep_coverage(state)
    return state


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


# -- shared with simulate -------------------------------------------------------------------------
def simulate(world: World, commands: np.ndarray, slip: np.ndarray | None = None) -> StepResult:
    """Drive the world (changes it) with (v, ω) commands (N, 2) for one control period;
    ``slip`` (N,) the wheel-slip factors of the step (None: no slip, see ``World.step``)."""
    return world.step(commands, slip)


def sense(world: World, camera: bool = True) -> Sensing:
    """Every robot's ranges, noisy and noiseless from one ray cast (stream ``sensor``), its
    camera detections (stream ``camera``; failed robots see none) and, with the pillar sensor
    on, its pillar readings (stream ``pillar_sensor``). ``camera=False`` or a camera switched
    off in the world's config skips the camera (and its draws) and reports no detections."""
    true_ranges, ranges = world.scan_with_truth()
    on = camera and world.config.camera.enabled
    detections = world.camera() if on else [[] for _ in range(world.num_robots)]
    pillars = tuple(world.sense_pillars()) if world.config.pillar_sensor.enabled else ()
    return Sensing(ranges, true_ranges, detections, pillars)


def run_slam(
    slams: Sequence[SlamRobot],
    robots: Sequence[int],
    active: np.ndarray,
    odometry: np.ndarray,
    ranges: np.ndarray,
    pillars: Sequence[PillarReading] = (),
) -> list[SlamStepInfo | None]:
    """One step (changes the SLAMs) of every SLAM whose robot is active: ``slams[j]`` runs on
    world robot ``robots[j]``'s odometry (N, 3) and its ranges (N, B) (polynomial EKF) or its
    pillar readings ``pillars`` (point back-ends); None for failed robots."""
    out: list[SlamStepInfo | None] = []
    for slam, i in zip(slams, robots, strict=True):
        if not active[i]:
            out.append(None)
        elif isinstance(slam, PointSlamRobot):
            out.append(slam.step(odometry[i], pillars[i].ids, pillars[i].z))
        else:
            out.append(slam.step(odometry[i], ranges[i]))
    return out


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


def record(
    histories: Sequence[RobotHistory],
    robots: Sequence[int],
    world: World,
    sensing: Sensing,
    estimates: Sequence[tuple[np.ndarray, np.ndarray]],
    slam_infos: Sequence[SlamStepInfo | None],
    collided: np.ndarray,
) -> None:
    """Append the step to the histories (changes them) of active robots: ``histories[j]``
    follows world robot ``robots[j]`` with estimate ``estimates[j]`` (pose (3,), cov (3, 3)).

    Hit points are the true points the beams hit: the noiseless ranges of the step's ray cast
    placed with the true poses (beams without return give none).
    """
    poses = world.poses  # (N, 3)
    ok = np.isfinite(sensing.true_ranges)  # (N, B)
    phi = poses[:, 2:3] + world.range_sensor.angles  # (N, B)
    ranges = np.where(ok, sensing.true_ranges, 0.0)  # no inf · cos: no NaN, no warning
    ends = beam_endpoints(poses[:, None, :2], phi, ranges)  # (N, B, 2)
    for history, i, (est, cov), info in zip(histories, robots, estimates, slam_infos, strict=True):
        if not world.active[i]:
            continue
        history.record(
            poses[i],
            est,
            cov,
            ends[i][ok[i]],
            None if info is None else info.time_s,
            bool(collided[i]),
            bool(info is not None and info.diverging),
        )


# -- the env's stages -----------------------------------------------------------------------------
def slam(state: EpisodeState, odometry: np.ndarray) -> list[SlamStepInfo | None]:  # (N,)
    """The SLAM stage (changes the SLAMs): :func:`run_slam` for robot i's own SLAM; None for
    every robot without SLAM."""
    world = state.world
    if not state.slams:
        return [None] * world.num_robots
    robots = range(len(state.slams))
    sensing = state.sensing
    return run_slam(state.slams, robots, world.active, odometry, sensing.ranges, sensing.pillars)


def map_features(state: EpisodeState) -> None:
    """The feature stage (changes the feature books): every active robot places the pillars
    it sees with its SLAM's pose estimate (:class:`~polyslam_env.slam.features.FeatureBook`);
    nothing outside the exchange's alignment mode, the books' only reader."""
    for i, book in enumerate(state.features):
        if state.world.active[i]:
            reading = state.sensing.pillars[i]
            book.add(state.slams[i].pose, reading.ids, reading.z, reading.descriptors)


def exchange(state: EpisodeState) -> ExchangeStep | None:
    """The exchange stage (changes links, last rendezvous, exchange, SLAMs): the mutual
    sightings for rendering, then :func:`exchange_maps` if the exchange is on."""
    state.links = _mutual_pairs(state.sensing.detections)
    if state.consensus is not None:
        points = [s for s in state.slams if isinstance(s, PointSlamRobot)]
        state.consensus.step(state.step_count, points, state.world.active, state.world.poses)
    if state.seif_exchange is not None:
        points = [s for s in state.slams if isinstance(s, PointSlamRobot)]
        state.seif_exchange.step(state.step_count, points, state.world.active, state.world.poses)
    if state.exchange is None:
        return None
    out = exchange_maps(
        state.exchange,
        state.step_count,
        [s for s in state.slams if isinstance(s, PolySlam)],  # all of them: see new_episode
        state.world.active,
        state.sensing,
        state.angles,
        state.world.poses,
        state.features,
    )
    for i, j in out.new_rendezvous:
        state.last_rendezvous[i] = state.last_rendezvous[j] = state.step_count
    return out


def record_histories(
    state: EpisodeState,
    result: StepResult,
    slam_infos: Sequence[SlamStepInfo | None],
    estimates: Sequence[tuple[np.ndarray, np.ndarray]],
) -> None:
    """The record stage (changes the histories): :func:`record` of every robot."""
    robots = range(state.world.num_robots)
    record(
        state.histories, robots, state.world, state.sensing, estimates, slam_infos, result.collided
    )


def observe(
    state: EpisodeState,
    encoder: ObservationEncoder,
    acting: Mapping[str, int],
    estimates: Sequence[tuple[np.ndarray, np.ndarray]],
) -> dict[str, Obs]:
    """Observations of the ``acting`` agents (name → robot); first sweeps each active robot's
    beams into its own belief grid, placed with its estimated pose (changes the grids)."""
    sweeping = [i for i in acting.values() if state.world.active[i]]
    if sweeping:
        poses = np.array([estimates[i][0] for i in sweeping])  # (K, 3)
        grids = [state.beliefs[i] for i in sweeping]
        sweep_beliefs(grids, poses, state.angles, state.sensing.ranges[sweeping])
    robots = list(acting.values())
    if not robots:
        return {}
    covs = np.array([estimates[i][1] for i in robots])  # (K, 3, 3)
    stds = np.sqrt(np.maximum(np.diagonal(covs, axis1=1, axis2=2), 0.0))  # (K, 3)
    views = [_view(state, i, estimates[i][0], std) for i, std in zip(robots, stds, strict=True)]
    return dict(zip(acting, encoder.encode_team(views), strict=True))


def _view(state: EpisodeState, i: int, pose: np.ndarray, pose_std: np.ndarray) -> RobotView:
    """What robot i knows, with its estimated pose (3,) and the standard deviations (3,) of
    its pose estimate."""
    last = state.last_rendezvous[i]
    count = state.exchange.rendezvous(i) if state.exchange is not None else 0
    return RobotView(
        ranges=state.sensing.ranges[i],
        pose=pose,
        pose_std=pose_std,
        map_points=_map_points(state, i),
        belief=state.beliefs[i],
        detections=state.sensing.detections[i],
        steps_since_rendezvous=None if last is None else state.step_count - last,
        rendezvous=count,
        step=state.step_count,
    )


def _map_points(state: EpisodeState, i: int) -> np.ndarray:  # (M, 2)
    """Robot i's map as points in its frame: its polynomials sampled, or its landmarks."""
    if not state.slams:
        return _NO_POINTS
    slam = state.slams[i]
    if isinstance(slam, PointSlamRobot):
        return slam.landmarks().means
    return state.samplers[i].points(slam)


def sweep_coverage(state: EpisodeState) -> np.ndarray:  # (N,) m²
    """Sweep every active robot's beams (true poses) into the team coverage grid and append
    the team coverage to the series (changes both); return the area of free cells first swept
    by the team now, per robot."""
    grid = state.coverage
    world = state.world
    max_range = world.config.range_sensor.max_range
    # Gains against the grid as it was before this step (counted before anything is marked),
    # so a cell first swept by two robots at once counts for both.
    new_cells = grid.sweep_team(
        world.poses, state.angles, state.sensing.ranges, max_range, world.active
    )
    gains = new_cells * grid.resolution**2
    state.coverage_series.append(grid.coverage)
    return gains


def map_bookkeeping(
    state: EpisodeState,
    acting: Mapping[str, int],
    slam_infos: Sequence[SlamStepInfo | None],
    exchanged: ExchangeStep | None,
) -> MapChanges:
    """Update each acting robot's map completeness, map error and bytes-sent count (changes
    them) and return the changes. Completeness and map error (ground truth, the map placed by
    the robot's true start pose) are re-evaluated only when the robot's map changed
    structurally (a landmark created, refit, merged, linked or received), else their changes
    are 0."""
    received = {d.receiver for d in exchanged.delivered} if exchanged is not None else set()
    completeness: dict[int, float] = {}
    map_error: dict[int, float] = {}
    bytes_sent: dict[int, int] = {}
    for i in acting.values():
        completeness[i], map_error[i] = _map_change(state, i, slam_infos[i], i in received)
        bytes_sent[i] = _bytes_change(state, i)
    return MapChanges(completeness, bytes_sent, map_error)


def _map_change(
    state: EpisodeState, i: int, info: SlamStepInfo | None, received: bool
) -> tuple[float, float]:
    """Changes of robot i's completeness and map error ∫δ ds (m²) this step (0, 0 if its map
    did not change); both sampled every ``MAPPING_STEP``, the map placed by the true start."""
    if info is None or not (info.created or info.refit or info.merged or info.linked or received):
        return 0.0, 0.0
    polys = state.slams[i].polynomials()
    place = state.histories[i].true[0]  # the true start (see metrics.mapping)
    layout = state.world.layout
    comp, error = metrics.completeness_and_error(
        polys, place, layout, tol=MAPPING_TOL, step=MAPPING_STEP
    )
    d_comp, state.completeness[i] = comp - state.completeness[i], comp
    d_error, state.map_error[i] = error - state.map_error[i], error
    return d_comp, d_error


def _bytes_change(state: EpisodeState, i: int) -> int:
    if state.exchange is None:
        return 0
    total = state.exchange.bytes_sent(i)
    delta, state.bytes_sent[i] = total - state.bytes_sent[i], total
    return delta


def inject_faults(state: EpisodeState, plan: FaultPlan) -> list[FaultEvent]:
    """The fault stage, after the motion of the step (changes the world): kidnap the active
    robots whose kidnap is due (stream ``faults``); returns the kidnaps and the slips that
    start this step (the slip itself acts in :func:`simulate`)."""
    k = state.step_count
    kidnaps = [f for f in plan.due(k, "kidnap") if state.world.active[f.robot]]
    events = []
    if kidnaps:
        cov = state.coverage  # its free cells: the same free space as the env's FreeGrid
        free = FreeGrid(np.asarray(cov.free), cov.origin, cov.resolution)
        events = [kidnap(state.world, f, state.rngs["faults"], free) for f in kidnaps]
    events += [
        FaultEvent("slip", f.robot, k, last_step=f.last_step, scale=f.scale)
        for f in plan.due(k, "slip")
    ]
    return events


# -- episode end ----------------------------------------------------------------------------------
def fail_robots(
    state: EpisodeState, acting: Mapping[str, int], fault_at: Mapping[int, int]
) -> set[int]:
    """Disable (changes the world) the acting robots whose fault is due at this step; returns
    them."""
    failed = [i for i in acting.values() if fault_at.get(i) == state.step_count]
    for i in failed:
        state.world.disable(i)
    return set(failed)


def done(
    state: EpisodeState, config: EnvConfig, acting: Mapping[str, int], failed: set[int]
) -> tuple[dict[str, bool], dict[str, bool]]:
    """Coverage target (unless None) → all terminated; failed robots → terminated;
    max_steps → all truncated."""
    target = config.coverage_target
    reached = target is not None and state.coverage.coverage >= target
    truncated = state.step_count >= config.max_steps
    terminations = {agent: bool(reached or i in failed) for agent, i in acting.items()}
    truncations = dict.fromkeys(acting, bool(truncated))
    return terminations, truncations


def infos(
    state: EpisodeState,
    acting: Mapping[str, int],
    terms: Mapping[str, dict[str, float]],
    terminations: Mapping[str, bool],
    truncations: Mapping[str, bool],
    events: Sequence[FaultEvent] = (),
) -> dict[str, dict[str, Any]]:
    """Per agent: its reward terms, the step, whether its SLAM flags divergence now
    (``diverging``) and the first step it did (``diverged_at``, None if never), and the
    faults that hit it this step (``faults``, only when some did); at its last step also its
    final metrics and the team's."""
    out: dict[str, dict[str, Any]] = {}
    team: dict[str, Any] | None = None
    for agent, i in acting.items():
        history = state.histories[i]
        info: dict[str, Any] = {
            "reward_terms": terms[agent],
            "step": state.step_count,
            "diverging": bool(state.slams and state.slams[i].diverging),
            "diverged_at": history.diverged_at,
        }
        hits = [e.to_info() for e in events if e.robot == i]
        if hits:
            info["faults"] = hits
        if terminations[agent] or truncations[agent]:
            if team is None:
                team = team_metrics(state.coverage_series, state.coverage)
            info["metrics"] = _final_metrics(state, i)
            info["team"] = dict(team)
        out[agent] = info
    return out


def _final_metrics(state: EpisodeState, i: int) -> dict[str, float]:
    counters: dict[str, float] = {}
    if state.exchange is not None:
        counters.update(state.exchange.counters(i))
        counters["alignments_wrong"] = sum(
            a.receiver == i and is_wrong_alignment(a.result.transform, _true_transform(state, a))
            for a in state.exchange.alignments
        )
    if state.consensus is not None:
        counters.update(state.consensus.counters(i))
    if state.seif_exchange is not None:
        counters.update(state.seif_exchange.counters(i))
        counters["alignments_wrong"] = sum(
            a.receiver == i and is_wrong_alignment(a.result.transform, _true_transform(state, a))
            for a in state.seif_exchange.alignments
        )
    slam = state.slams[i] if state.slams else None
    landmarks = None
    if isinstance(slam, PointSlamRobot):
        lm = slam.landmarks()
        landmarks = (None if slam.anonymous else lm.ids, lm.means)
    return final_robot_metrics(
        state.histories[i],
        slam.polynomials() if slam is not None else None,
        state.world.layout,
        state.coverage.robot_coverage(i),
        counters,
        landmarks,
    )


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


def _true_transform(state: EpisodeState, attempt: AlignmentAttempt) -> np.ndarray:
    """The true transform (3,) of the sender's map frame into the receiver's: each SLAM's
    frame is its robot's true start (``RobotHistory.true[0]``)."""
    receiver = state.histories[attempt.receiver].true[0]
    sender = state.histories[attempt.sender].true[0]
    return between(receiver, sender, wrap_remainder)


def _mutual_pairs(detections: list[list[Detection]]) -> list[tuple[int, int]]:
    """Pairs (i < j) that see each other."""
    seen = {(i, d.target) for i, dets in enumerate(detections) for d in dets}
    return sorted((i, j) for i, j in seen if i < j and (j, i) in seen)

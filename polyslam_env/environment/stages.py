"""The stages of an episode: ``reset`` makes the state, ``step`` runs the stages in order.

Each stage is a function of what it reads (the :class:`EpisodeState` and the outputs of earlier
stages) that returns what it produces; a stage that changes the state says so in its first
line. In the order ``PolySlamParallelEnv.step`` runs them:

    simulate → sense → slam → exchange → record → observe → sweep_coverage → map_bookkeeping
    → (reward terms, combine: :mod:`~polyslam_env.environment.rewards`) → fail_robots → done
    → infos

Every stage works on the whole team at once: the SLAM stage and the exchange call the team's
SLAM object (:mod:`~polyslam_env.environment.backends`, one per ``slam.backend``), the sensing,
the belief and coverage sweeps and the observations are compiled calls over (N, …) arrays.

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
from polyslam_env.comms.exchange import AlignmentAttempt, ExchangeStep
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment import kernels
from polyslam_env.environment.backends import (
    WRONG_ALIGNMENT_DEG,
    WRONG_ALIGNMENT_M,
    exchange_maps,
    is_wrong_alignment,
    make_exchange,
    make_team_slam,
    run_slam,
)
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.faults import FaultEvent, FaultPlan, kidnap, perturb_starts
from polyslam_env.environment.observations import (
    MapSampler,
    ObservationEncoder,
    TeamView,
    belief_grids,
    sweep_beliefs,
)
from polyslam_env.environment.rewards import MAPPING_STEP, MAPPING_TOL, MapChanges
from polyslam_env.environment.sensing import Sensing
from polyslam_env.environment.state import NEVER, EpisodeState
from polyslam_env.metrics.episode import TeamHistory, final_robot_metrics, team_metrics
from polyslam_env.slam.robot import SlamStepInfo
from polyslam_env.world.grid import FreeGrid
from polyslam_env.world.layout import Layout
from polyslam_env.world.physics import StepResult, World
from polyslam_env.world.sensors import CameraFrame

__all__ = [
    "WRONG_ALIGNMENT_DEG",
    "WRONG_ALIGNMENT_M",
    "done",
    "exchange",
    "exchange_maps",
    "fail_robots",
    "infos",
    "inject_faults",
    "is_wrong_alignment",
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


# -- reset ----------------------------------------------------------------------------------------
def new_episode(
    config: EnvConfig,
    rngs: dict[str, np.random.Generator],
    layout: Layout,
    free: FreeGrid,
    recycle: World | None = None,
) -> EpisodeState:
    """A fresh episode on ``layout`` (its free-space grid ``free``) with the named streams
    ``rngs``: a new pymunk world, the team's fresh SLAM, grids and histories, the first sensor
    readings and the first coverage sweep.

    Each robot's frame is its nominal start pose (the layout's); with ``initial_error`` (and
    SLAM on) its true start is drawn around it from N(0, P0) (:func:`perturb_starts`, stream
    ``start_error``), while its SLAM starts at x̂ = 0 with covariance P0. Without SLAM the robot
    knows its true pose, so ``initial_error`` has no effect there. ``recycle``: the previous
    episode's world, whose walls the new one reuses when the layout is the same (``World``).
    """
    n = config.num_robots
    wc, oc = config.world, config.observation
    world = World(layout, wc, n, rngs, recycle=recycle)
    coverage = metrics.CoverageGrid(free.mask, free.origin, free.resolution)
    start_poses = world.poses  # (N, 3), each robot's frame in the absolute frame
    if config.initial_error and config.slam_enabled:
        perturb_starts(world, config.slam.p0, rngs["start_error"])

    def samplers() -> list[MapSampler]:
        return [MapSampler(0.5 * oc.grid_resolution) for _ in range(n)]

    state = EpisodeState(
        rngs=rngs,
        world=world,
        coverage=coverage,
        start_poses=start_poses,
        angles=np.asarray(wc.range_sensor.angles),  # (B,)
        slam=make_team_slam(config, rngs, start_poses, samplers),
        beliefs=belief_grids(oc, layout.bounds, wc.range_sensor.max_range, n),
        history=TeamHistory(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3))),  # below
        histories=[],  # ditto
        sensing=sense(world),
        last_rendezvous=np.full(n, NEVER, dtype=np.int64),
        rendezvous=np.zeros(n, dtype=np.int64),
        completeness=np.zeros(n),
        map_error=np.zeros(n),
        bytes_sent=np.zeros(n, dtype=np.int64),
        links=[],
        coverage_series=[],
    )
    poses, covs = state.slam.estimates(world, start_poses)  # a history starts from them
    p0 = config.slam.p0 if config.slam_enabled else None
    state.history = TeamHistory(start_poses, poses, covs, world.poses, p0, state.angles)
    state.histories = [state.history.robot(i) for i in range(n)]
    sweep_coverage(state)
    return state


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
    frame = world.camera_frame() if on else CameraFrame.empty(world.num_robots)
    pillars = tuple(world.sense_pillars()) if world.config.pillar_sensor.enabled else ()
    return Sensing(ranges, true_ranges, frame, pillars)


def record(
    history: TeamHistory,
    robots: Sequence[int],
    world: World,
    sensing: Sensing,
    estimates: tuple[np.ndarray, np.ndarray],
    slam_infos: Sequence[SlamStepInfo | None],
    collided: np.ndarray,
) -> None:
    """Append the step to the team's history (changes it), for the slots whose robot is
    active: slot j follows world robot ``robots[j]`` with estimate ``estimates`` = (poses
    (J, 3), covariances (J, 3, 3)) row j and the SLAM step ``slam_infos[j]``.

    The history keeps the noiseless ranges of the step's ray cast: its hit points are the true
    points the beams hit, placed with the true poses when read (beams without return give
    none; :meth:`~polyslam_env.metrics.episode.TeamHistory.hits`).
    """
    poses, active, ranges = world.poses, world.active, sensing.true_ranges  # (N, …)
    times = np.array([np.nan if i is None else i.time_s for i in slam_infos])  # (J,)
    diverging = np.array([i is not None and i.diverging for i in slam_infos], dtype=bool)
    est, cov = estimates
    n = len(active)
    # every robot, in order, all active (count_nonzero: a C call): the arrays as they are
    if robots == range(n) and np.count_nonzero(active) == n:
        slots = np.arange(n)
        history.record(slots, poses, est, cov, ranges, times, collided, diverging)
        return
    of = np.asarray(robots, dtype=np.int64)  # (J,) slot → world robot
    slots = active[of].nonzero()[0]  # (K,)
    if not len(slots):
        return
    live = of[slots]  # (K,) their robots' rows of the world's arrays
    history.record(
        slots, poses[live], est[slots], cov[slots], ranges[live], times[slots], collided[live],
        diverging[slots],
    )  # fmt: skip


# -- the env's stages -----------------------------------------------------------------------------
def slam(state: EpisodeState, odometry: np.ndarray) -> list[SlamStepInfo | None]:  # (N,)
    """The SLAM stage (changes the SLAMs): one step of the team's SLAM on the odometry
    (N, 3) and this step's readings; None for every robot without SLAM or failed."""
    return state.slam.step(state.world.active, odometry, state.sensing)


def exchange(state: EpisodeState) -> ExchangeStep | None:
    """The exchange stage (changes links, rendezvous counts, bytes sent, the exchange and
    SLAMs): the mutual sightings for rendering, then the team SLAM's exchange; the robots of
    each new rendezvous count it and remember its step."""
    seen = state.sensing.camera.seen  # (N, N)
    state.links = []
    if any(state.sensing.detections):  # (most steps nobody sees anyone)
        i_idx, j_idx = (seen & seen.T).nonzero()  # row by row, as np.triu(…, k=1) then nonzero
        upper = i_idx < j_idx
        state.links = list(zip(i_idx[upper].tolist(), j_idx[upper].tolist(), strict=True))
    out = state.slam.exchange(state.step_count, state.world, state.sensing)
    if out is None:
        return None
    for pair in out.new_rendezvous:
        state.last_rendezvous[list(pair)] = state.step_count
        state.rendezvous[list(pair)] += 1
    return out


def record_histories(
    state: EpisodeState,
    result: StepResult,
    slam_infos: Sequence[SlamStepInfo | None],
    estimates: tuple[np.ndarray, np.ndarray],
) -> None:
    """The record stage (changes the histories): :func:`record` of every robot."""
    robots = range(state.world.num_robots)
    record(
        state.history, robots, state.world, state.sensing, estimates, slam_infos, result.collided
    )


def observe(
    state: EpisodeState,
    encoder: ObservationEncoder,
    acting: Mapping[str, int],
    estimates: tuple[np.ndarray, np.ndarray],
) -> dict[str, Obs]:
    """Observations of the ``acting`` agents (name → robot); first sweeps each active robot's
    beams into its own belief grid, placed with its estimated pose (changes the grids).
    Everything a robot knows is gathered for the team into one :class:`TeamView`."""
    poses, covs = estimates
    active = state.world.active
    robots = list(acting.values())
    # every robot acting (the usual case): views of the team's arrays, not copies
    every = robots == list(range(len(active)))
    if every and np.count_nonzero(active) == len(active):  # all active
        sweep_beliefs(state.beliefs, poses, state.angles, state.sensing.ranges)
    else:
        sweeping = [i for i in robots if active[i]]
        if sweeping:
            grids = [state.beliefs[i] for i in sweeping]
            sweep_beliefs(grids, poses[sweeping], state.angles, state.sensing.ranges[sweeping])
    if not robots:
        return {}
    pick: slice | list[int] = slice(None) if every else robots
    k = len(robots)
    stds, since, step = np.empty((k, 3)), np.empty(k, dtype=np.int64), np.empty(k, np.int64)
    kernels.team_status(
        covs[pick], state.last_rendezvous[pick], state.step_count, NEVER, stds, since, step
    )
    map_points, starts = state.slam.team_map_points(robots)
    camera = state.sensing.camera
    team = TeamView(
        ranges=state.sensing.ranges[pick],
        poses=poses[pick],
        pose_stds=stds,
        map_points=map_points,
        map_starts=starts,
        belief=state.beliefs[0],  # a team's grids are rows of one stack (belief_grids)
        belief_rows=np.array(robots, dtype=np.int64),
        seen=camera.seen[pick],
        distance=camera.distance[pick],
        bearing=camera.bearing[pick],
        since=since,
        rendezvous=state.rendezvous[pick],
        step=step,
    )
    return dict(zip(acting, encoder.encode_team(team), strict=True))


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
    for i in acting.values():
        completeness[i], map_error[i] = _map_change(state, i, slam_infos[i], i in received)
    total = state.slam.bytes_sent()  # (N,), or (0,) without a map exchange
    if len(total):
        sent = (total - state.bytes_sent).tolist()
        state.bytes_sent[:] = total
    else:
        sent = [0] * len(state.bytes_sent)
    return MapChanges(completeness, {i: sent[i] for i in acting.values()}, map_error)


def _map_change(
    state: EpisodeState, i: int, info: SlamStepInfo | None, received: bool
) -> tuple[float, float]:
    """Changes of robot i's completeness and map error ∫δ ds (m²) this step (0, 0 if its map
    did not change); both sampled every ``MAPPING_STEP``, the map placed by the true start."""
    if info is None or not (info.created or info.refit or info.merged or info.linked or received):
        return 0.0, 0.0
    place = state.histories[i].true[0]  # the true start (see metrics.mapping)
    comp, error = metrics.completeness_and_error(
        state.slam.map_shapes(i), place, state.world.layout, tol=MAPPING_TOL, step=MAPPING_STEP
    )
    d_comp = comp - float(state.completeness[i])
    d_error = error - float(state.map_error[i])
    state.completeness[i], state.map_error[i] = comp, error
    return d_comp, d_error


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
        info: dict[str, Any] = {
            "reward_terms": terms[agent],
            "step": state.step_count,
            "diverging": state.slam.diverging(i),
            "diverged_at": state.histories[i].diverged_at,
        }
        if events:
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
    team = state.slam
    return final_robot_metrics(
        state.histories[i],
        team.polynomials(i),
        state.world.layout,
        state.coverage.robot_coverage(i),
        team.counters(i, lambda attempt: _true_transform(state, attempt)),
        team.landmarks(i),
    )


def _true_transform(state: EpisodeState, attempt: AlignmentAttempt) -> np.ndarray:
    """The true transform (3,) of the sender's map frame into the receiver's: each SLAM's
    frame is its robot's true start (``RobotHistory.true[0]``)."""
    receiver = state.histories[attempt.receiver].true[0]
    sender = state.histories[attempt.sender].true[0]
    return between(receiver, sender, wrap_remainder)

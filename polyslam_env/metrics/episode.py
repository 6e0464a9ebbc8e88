"""What a robot did during an episode, and the metrics reported at its end.

This module owns the per-robot record of an episode and the numbers computed from it, for both
the env and :func:`polyslam_env.apps.simulate.simulate` (which run the same record stage,
:func:`polyslam_env.environment.stages.record`):

* :class:`TeamHistory` grows by one row per step for the whole team (true and estimated
  poses, covariances, beam hit points, SLAM wall times, collisions, path length), and each of
  its slots, a :class:`RobotHistory`, becomes a :class:`RobotRun`;
* :func:`robot_metrics` turns a :class:`RobotRun` into the paper's numbers (SPEC §5);
* :func:`final_robot_metrics` and :func:`team_metrics` are the env's end-of-episode
  ``infos[agent]["metrics"]`` and ``infos[agent]["team"]``.

Hit points are the true points the beams hit: the noiseless ranges of the step's ray cast
placed with the true pose (see :class:`~polyslam_env.environment.state.Sensing`). A failed
robot's history stops at its failure.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from polyslam_env import metrics
from polyslam_env.core.geometry import beam_endpoints, between
from polyslam_env.metrics import kernels
from polyslam_env.metrics.mapping import QUALITY_KEYS, MapShapes, map_quality
from polyslam_env.slam.ekf import start_error_covs
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.layout import Layout

__all__ = [
    "COMMS_METRICS",
    "FLAG_KEYS",
    "MAP_METRIC_KEYS",
    "METRIC_UNITS",
    "ROBOT_METRIC_KEYS",
    "RobotHistory",
    "RobotRun",
    "TeamHistory",
    "final_robot_metrics",
    "map_metrics",
    "meaningful",
    "robot_metrics",
    "start_nees",
    "team_metrics",
]

#: The exchange's counters among the end-of-episode metrics (0 without an exchange).
COUNTER_KEYS: tuple[str, ...] = (
    "bytes_sent",
    "bytes_received",
    "rendezvous",
    "alignments_attempted",
    "alignments_accepted",
    "alignments_wrong",
)
#: Keys of ``infos[agent]["metrics"]`` (all finite floats, never NaN; see
#: :func:`final_robot_metrics` for the values without a map or without SLAM).
ROBOT_METRIC_KEYS: tuple[str, ...] = (
    "nees",
    "nees_rel",
    "start_nees",
    "nees_paper",
    *QUALITY_KEYS,
    "pose_error",
    "landmark_error",
    "has_landmarks",
    "slam",
    "coverage",
    *COUNTER_KEYS,
    "slam_time_ms",
    "collisions",
    "path_length",
)
#: The unit of each end-of-episode metric ("" for a pure number: a NEES, a fraction or a count).
METRIC_UNITS: dict[str, str] = {
    "nees": "",
    "nees_rel": "",
    "start_nees": "",
    "nees_paper": "m², rad²",
    "nu": "m",
    "nu_mean": "m",
    "nu_mean_abs": "m",
    "completeness": "",
    "completeness_seen": "",
    "map_precision": "",
    "duplicates": "",
    "pose_error": "m",
    "landmark_error": "m",
    "landmarks": "",
    "coverage": "",
    "bytes_sent": "B",
    "bytes_received": "B",
    "rendezvous": "",
    "alignments_attempted": "",
    "alignments_accepted": "",
    "alignments_wrong": "",
    "slam_time_ms": "ms",
    "collisions": "",
    "path_length": "m",
}
#: Metrics that are 0/1 flags saying which other metrics mean something (``has_map``,
#: ``has_landmarks``, ``slam``): tables show the metrics, not the flags.
FLAG_KEYS: tuple[str, ...] = ("has_map", "has_landmarks", "slam")
#: The map-quality metrics (:func:`map_metrics`), in order.
MAP_METRIC_KEYS: tuple[str, ...] = (
    "nu",
    "nu_mean",
    "nu_mean_abs",
    "completeness",
    "completeness_seen",
    "map_precision",
    "duplicates",
    "has_map",
)
_SLAM_KEYS = (
    "nees",
    "nees_rel",
    "start_nees",
    "nees_paper",
    *MAP_METRIC_KEYS,
    "pose_error",
    "landmark_error",
    "has_landmarks",
    "slam_time_ms",
)


@dataclass
class RobotRun:
    """Everything one robot did in a simulation (estimates in its own start frame)."""

    start_pose: np.ndarray  # (3,) robot's frame R_{j,0} in the absolute frame (metrics only)
    true_poses: np.ndarray  # (K+1, 3) absolute
    est_poses: np.ndarray  # (K+1, 3) in the robot's start frame
    est_covs: np.ndarray  # (K+1, 3, 3)
    polynomials: list[Polynomial]  # final map, robot frame
    hit_points: np.ndarray  # (H, 2) true points its beams hit (absolute), for hit_fraction
    slam_times: np.ndarray  # (K,) seconds per SLAM step
    diverged: bool  # flagged at any step
    collisions: int
    comms: dict[str, int] = field(default_factory=dict)  # exchange counters (empty: no exchange)
    p0: np.ndarray | None = None  # (3, 3) the start-error covariance est_covs include, if any


#: Exchange counters that :func:`robot_metrics` reports (zeros when there was no exchange).
COMMS_METRICS = ("bytes_sent", "bytes_received", "rendezvous", "messages_lost")


def map_metrics(
    polys: list[Polynomial],
    true_start: np.ndarray,
    frame: np.ndarray,
    hit_points: np.ndarray,
    layout: Layout,
) -> dict[str, float]:
    """The map-quality metrics (:data:`MAP_METRIC_KEYS`) of one robot's map ``polys`` (own
    frame): placed by its true start pose ``true_start`` (3,), except ``nu_mean_abs``, placed by
    its nominal ``frame`` (3,), which includes the unobservable initial offset (see
    :mod:`polyslam_env.metrics.mapping`). ``hit_points`` (H, 2) are its true beam hits. An empty
    map gives the stated values with ``has_map`` 0.0."""
    shapes = MapShapes.of(polys)  # packed once for all the metrics (the same numbers)
    return map_quality(shapes, true_start, frame, hit_points, layout)


def nees_relative(run: RobotRun) -> float:
    """Mean NEES of the filter itself: the estimate against the true pose seen from the
    robot's **true** start, with the covariance minus the start error's share J P0 Jᵀ
    (:func:`~polyslam_env.slam.ekf.start_error_covs`), i.e. the filter's own P_S. Unlike
    ``nees``, it does not carry the robot's unobservable start offset e₀ᵀP0⁻¹e₀ ~ χ²(3) for the
    whole episode. Step 0 is left out (P_S = 0 there: the start is known exactly in that
    frame). Without ``p0`` (no start-error model) it equals ``nees``."""
    if run.p0 is None or len(run.est_poses) < 2:
        return metrics.nees(run.true_poses, run.est_poses, run.est_covs, run.start_pose)
    covs = run.est_covs[1:] - start_error_covs(run.est_poses[1:], run.p0)
    return metrics.nees(run.true_poses[1:], run.est_poses[1:], covs, run.true_poses[0])


def start_nees(run: RobotRun) -> float:
    """e₀ᵀP0⁻¹e₀: the robot's true start e₀ in its frame (the nominal start) against the
    start-error covariance P0 it was drawn from, ~ χ²(3). The filter can never observe e₀
    (nothing it senses is referenced to the frame), so this part of ``nees`` stays for the
    whole episode: P(χ²(3) > 6) = 11 % of robots have a mean ``nees`` above 6 from it alone.
    0.0 without a start-error model (``p0`` None: the robot starts at its frame's origin)."""
    if run.p0 is None:
        return 0.0
    e0 = between(run.start_pose, run.true_poses[0])
    return float(e0 @ np.linalg.solve(run.p0, e0))


def robot_metrics(run: RobotRun, layout: Layout) -> dict[str, float]:
    """The paper's metrics (SPEC §5) for one robot, plus the map-quality metrics
    (:func:`map_metrics`, the map placed by the robot's true start ``true_poses[0]``) and
    timing. NEES compares the estimate mapped through the nominal frame ``start_pose``."""
    polys = run.polynomials
    hit = metrics.hit_fraction(run.hit_points, layout) if len(run.hit_points) else 0.0
    times = run.slam_times
    return {
        **_estimation_metrics(run, layout),
        "hit_fraction": hit,
        "landmarks": float(len(polys)),
        "slam_time_ms": _slam_time_ms(times),
        "slam_time_ms_median": 1e3 * float(np.median(times)) if len(times) else 0.0,
        "diverged": float(run.diverged),
        "collisions": float(run.collisions),
        **{key: float(run.comms.get(key, 0)) for key in COMMS_METRICS},
    }


def _estimation_metrics(run: RobotRun, layout: Layout) -> dict[str, float]:
    """The NEES forms and the map-quality metrics of :func:`robot_metrics`, in its order
    (with :func:`_slam_time_ms`, what the env's end-of-episode metrics keep of it)."""
    sp = run.start_pose
    nees, paper = metrics.nees_and_paper(run.true_poses, run.est_poses, run.est_covs, sp)
    return {
        "nees": nees,
        "nees_rel": nees_relative(run),
        "start_nees": start_nees(run),
        "nees_paper": paper,
        **map_metrics(run.polynomials, run.true_poses[0], sp, run.hit_points, layout),
    }


def _slam_time_ms(times: np.ndarray) -> float:
    """The mean SLAM step time (ms) of the seconds ``times`` (K,); 0.0 for none."""
    return 1e3 * float(np.mean(times)) if len(times) else 0.0


class TeamHistory:
    """What a team did during an episode, one slot per history (a robot's SLAM; ``simulate``
    gives a robot a second, lone SLAM in a slot of its own), in growable arrays: one
    :meth:`record` per step writes every slot's row at once.

    Slot ``j``'s rows ``0 … len(j) − 1`` are its steps (row 0: the start); a slot whose robot
    failed stops growing. :meth:`robot` is slot j as a :class:`RobotHistory`.

    The beams' hit points are kept as each step's true ranges and placed by the recorded true
    pose when :meth:`hits` reads them (the same operations on the same numbers as placing them
    every step, done once per episode instead of every step).
    """

    def __init__(
        self,
        start_poses: np.ndarray,
        est_poses: np.ndarray,
        est_covs: np.ndarray,
        true_poses: np.ndarray | None = None,
        p0: np.ndarray | None = None,
        angles: np.ndarray | None = None,
    ) -> None:
        """Slot j starts from its frame ``start_poses[j]`` (J, 3) (absolute), estimate
        ``est_poses[j]`` (J, 3) and covariance ``est_covs[j]`` (J, 3, 3) (own frame), and its
        robot's true pose ``true_poses[j]`` (J, 3) (default: the frame's origin); ``p0`` (3, 3)
        is the start-error covariance the estimates include, if any; ``angles`` (B,) the beams'
        angles in the robot's frame, whose true ranges :meth:`record` takes (None: no beams)."""
        self.start_poses = np.array(start_poses, dtype=float).reshape(-1, 3)  # (J, 3) absolute
        j = len(self.start_poses)
        self.p0 = None if p0 is None else np.asarray(p0, dtype=float)
        self.angles = np.zeros(0) if angles is None else np.asarray(angles, dtype=float)  # (B,)
        first = self.start_poses if true_poses is None else np.asarray(true_poses, dtype=float)
        self._true = np.empty((64, j, 3))  # (capacity, J, 3) absolute
        self._est = np.empty((64, j, 3))  # own frames
        self._cov = np.empty((64, j, 3, 3))
        self._times = np.full((64, j), np.nan)  # s per SLAM step, NaN: none (row 0: none)
        self._beams = np.full((64, j, len(self.angles)), np.inf)  # true ranges (row 0: none)
        self._true[0], self._est[0], self._cov[0] = first, est_poses, est_covs
        self.lengths = np.ones(j, dtype=np.int64)  # (J,) rows of each slot
        self._records = 0  # record calls so far: no slot has more than 1 + this many rows
        self._hits = np.empty((256, 2))  # (capacity, 2) hit points given as points, absolute
        self._hit_owner = np.empty(256, dtype=np.int64)  # its slot
        self._n_hits = 0
        self.collisions = np.zeros(j, dtype=np.int64)  # (J,)
        self.path_length = np.zeros(j)  # (J,) m, true distance travelled
        self.diverged = np.zeros(j, dtype=bool)  # (J,) flagged at any step
        self.diverged_at = np.full(j, -1, dtype=np.int64)  # (J,) first step flagged, −1: never

    def __len__(self) -> int:
        return len(self.start_poses)

    def robot(self, j: int) -> RobotHistory:
        """Slot ``j`` as a :class:`RobotHistory`."""
        return RobotHistory.of(self, j)

    def record(
        self,
        slots: np.ndarray,
        true_poses: np.ndarray,
        est_poses: np.ndarray,
        est_covs: np.ndarray,
        ranges: np.ndarray,
        slam_times: np.ndarray,
        collided: np.ndarray,
        diverging: np.ndarray,
    ) -> None:
        """Append one step to the slots ``slots`` (K,) (ascending; the others are not
        recorded): true poses (K, 3), estimates (K, 3), covariances (K, 3, 3), the true ranges
        (K, B) of the beams at :attr:`angles` (``inf`` or NaN: no return), SLAM seconds (K,)
        (NaN: none), collided and diverging flags (K,)."""
        self._records += 1
        self._grow(self._records + 1)
        kernels.record_rows(
            slots, true_poses, est_poses, est_covs, slam_times, ranges, collided, diverging,
            self.lengths, self._true, self._est, self._cov, self._times, self._beams,
            self.path_length, self.collisions, self.diverged, self.diverged_at,
        )  # fmt: skip

    def _grow(self, rows: int) -> None:
        """Room for ``rows`` rows per slot (the capacity doubles)."""
        have = len(self._true)
        if rows <= have:
            return
        size = max(rows, 2 * have)
        fill = {"_times": np.nan, "_beams": np.inf}
        for name in ("_true", "_est", "_cov", "_times", "_beams"):
            old = getattr(self, name)
            new = (
                np.full((size, *old.shape[1:]), fill[name])
                if name in fill
                else np.empty((size, *old.shape[1:]))
            )
            new[:have] = old
            setattr(self, name, new)

    def add_hits(self, hits: np.ndarray, owners: np.ndarray) -> None:
        """Hit points (H, 2) (absolute) given as points, with the slot of each ``owners`` (H,)."""
        n, m = self._n_hits, len(hits)
        if n + m > len(self._hits):
            size = max(n + m, 2 * len(self._hits))
            grown, owner = np.empty((size, 2)), np.empty(size, dtype=np.int64)
            grown[:n], owner[:n] = self._hits[:n], self._hit_owner[:n]
            self._hits, self._hit_owner = grown, owner
        self._hits[n : n + m] = hits
        self._hit_owner[n : n + m] = owners
        self._n_hits = n + m

    # -- one slot's record ----------------------------------------------------------------
    def true(self, j: int) -> np.ndarray:  # (k+1, 3)
        return self._true[: self.lengths[j], j]

    def est(self, j: int) -> np.ndarray:  # (k+1, 3)
        return self._est[: self.lengths[j], j]

    def cov(self, j: int) -> np.ndarray:  # (k+1, 3, 3)
        return self._cov[: self.lengths[j], j]

    def slam_times(self, j: int) -> np.ndarray:  # (k',) seconds of the steps that had one
        times = self._times[1 : self.lengths[j], j]
        return times[~np.isnan(times)]

    def hits(self, j: int) -> np.ndarray:  # (H_j, 2)
        """Slot j's hit points (absolute): those given as points, then its recorded beams'
        (step by step, beam by beam) ``true + r·(cos φ, sin φ)`` with φ the true heading plus
        the beam's angle, the operations :func:`~polyslam_env.core.geometry.beam_endpoints`
        did for each step."""
        n = self._n_hits
        given = self._hits[:n][self._hit_owner[:n] == j]
        rows = slice(1, int(self.lengths[j]))
        ranges = self._beams[rows, j]  # (k, B)
        if ranges.size == 0:
            return given
        poses = self._true[rows, j]  # (k, 3)
        ok = np.isfinite(ranges)
        phi = poses[:, 2:3] + self.angles  # (k, B)
        ends = beam_endpoints(poses[:, None, :2], phi, np.where(ok, ranges, 0.0))  # (k, B, 2)
        placed = ends[ok]
        return np.concatenate([given, placed]) if len(given) else placed


class RobotHistory:
    """What one robot did during an episode (estimates in its own start frame): one slot of a
    :class:`TeamHistory` (its own one-slot team when made alone).

    ``start_pose`` is the robot's frame in the absolute frame; ``true_pose`` its true pose at
    the start, which is the frame's origin unless the start is drawn with an initial error.
    ``true``, ``est`` and ``cov`` are the rows so far (read-only views: (k+1, 3), (k+1, 3),
    (k+1, 3, 3)).
    """

    def __init__(
        self,
        start_pose: np.ndarray,
        est_pose: np.ndarray,
        est_cov: np.ndarray,
        true_pose: np.ndarray | None = None,
        p0: np.ndarray | None = None,
    ) -> None:
        first = None if true_pose is None else np.asarray(true_pose, dtype=float)[None]
        team = TeamHistory(
            np.asarray(start_pose, dtype=float)[None],
            np.asarray(est_pose, dtype=float)[None],
            np.asarray(est_cov, dtype=float)[None],
            first,
            p0,
        )
        self._bind(team, 0)

    @classmethod
    def of(cls, team: TeamHistory, slot: int) -> RobotHistory:
        """Slot ``slot`` of ``team``."""
        history = cls.__new__(cls)
        history._bind(team, slot)
        return history

    def _bind(self, team: TeamHistory, slot: int) -> None:
        self.team, self.slot = team, slot
        self.start_pose = team.start_poses[slot]  # (3,) absolute
        self.p0 = team.p0

    @property
    def true(self) -> np.ndarray:  # (k+1, 3) absolute
        return self.team.true(self.slot)

    @property
    def est(self) -> np.ndarray:  # (k+1, 3) own frame
        return self.team.est(self.slot)

    @property
    def cov(self) -> np.ndarray:  # (k+1, 3, 3)
        return self.team.cov(self.slot)

    @property
    def collisions(self) -> int:
        return int(self.team.collisions[self.slot])

    @property
    def path_length(self) -> float:  # m, true distance travelled
        return float(self.team.path_length[self.slot])

    @property
    def diverged(self) -> bool:
        return bool(self.team.diverged[self.slot])

    @property
    def diverged_at(self) -> int | None:
        """The first step (1-based) flagged diverging, None if never."""
        at = int(self.team.diverged_at[self.slot])
        return None if at < 0 else at

    def record(
        self,
        true_pose: np.ndarray,
        est_pose: np.ndarray,
        est_cov: np.ndarray,
        hits: np.ndarray,
        slam_time: float | None,
        collided: bool,
        diverging: bool,
    ) -> None:
        """Append one step: poses (3,), covariance (3, 3), beam hit points (h, 2) (absolute;
        a team's history records its beams' ranges instead)."""
        hits = np.asarray(hits, dtype=float).reshape(-1, 2)
        team = self.team
        team.record(
            np.array([self.slot]),
            np.asarray(true_pose, dtype=float)[None],
            np.asarray(est_pose, dtype=float)[None],
            np.asarray(est_cov, dtype=float)[None],
            np.full((1, len(team.angles)), np.inf),  # no beams of its own
            np.array([np.nan if slam_time is None else slam_time]),
            np.array([bool(collided)]),
            np.array([bool(diverging)]),
        )
        team.add_hits(hits, np.full(len(hits), self.slot))

    def true_path(self) -> np.ndarray:  # (k, 2)
        return self.true[:, :2].copy()

    def est_path_abs(self) -> np.ndarray:  # (k, 2)
        """Estimated positions in the absolute frame, placed by the true start (as the map
        metrics place the map; the frame's offset from the true start is unobservable)."""
        return metrics.pose_to_absolute(self.est.copy(), self.true[0])[:, :2]

    def run(self, polys: list[Polynomial]) -> RobotRun:
        return RobotRun(
            start_pose=self.start_pose.copy(),
            true_poses=self.true.copy(),
            est_poses=self.est.copy(),
            est_covs=self.cov.copy(),
            polynomials=polys,
            hit_points=self.team.hits(self.slot),
            slam_times=self.team.slam_times(self.slot),
            diverged=self.diverged,
            collisions=self.collisions,
            p0=self.p0,
        )


def final_robot_metrics(
    history: RobotHistory,
    polys: list[Polynomial] | None,
    layout: Layout,
    coverage: float,
    counters: Mapping[str, float],
    landmarks: tuple[np.ndarray | None, np.ndarray] | None = None,
) -> dict[str, float]:
    """``infos[agent]["metrics"]``: every key of :data:`ROBOT_METRIC_KEYS`, a finite float.

    ``slam`` is 1.0 with SLAM. ``polys`` None (no SLAM: the robot knows its true pose and
    builds no map) gives ``slam`` 0.0 and, for the SLAM metrics, the values of a robot with an
    empty map and no estimation error: nees, nees_rel, start_nees, nees_paper, ν, nu_mean,
    nu_mean_abs, duplicates, completeness, completeness_seen, pose_error and slam_time_ms 0.0,
    map_precision 1.0,
    has_map 0.0. A point back-end has no polynomials (``polys`` empty: has_map 0.0) and gives
    its pillar map ``landmarks`` = (ids (M,), means (M, 2) in its frame): ``landmark_error`` is
    the mean distance (m) of the estimates, placed by the true start, to the true centres of
    the pillars they name (ids None, anonymous readings: to the nearest true centre), with
    ``has_landmarks`` 1.0 and ``landmarks`` their number (0.0 and landmark_error 0.0 without
    landmarks).
    ``pose_error`` is the mean position error (m) over the episode, placed by the true start.
    """
    out = dict.fromkeys(ROBOT_METRIC_KEYS, 0.0)
    out["map_precision"] = 1.0
    if polys is not None:
        run = history.run(polys)
        paper = _estimation_metrics(run, layout)
        out.update({k: float(paper[k]) for k in _SLAM_KEYS if k in paper})
        out["slam_time_ms"] = _slam_time_ms(run.slam_times)
        out["slam"] = 1.0
        out["pose_error"] = metrics.position_error(run.true_poses, run.est_poses, run.true_poses[0])
    if landmarks is not None and len(landmarks[1]):
        ids, means = landmarks
        centres = layout.pillars[:, :2]
        if ids is None:
            truth = centres[metrics.nearest_points(means, history.true[0], centres)]
        else:
            truth = centres[np.asarray(ids, dtype=int)]
        out["landmark_error"] = float(
            np.mean(metrics.landmark_distances(means, history.true[0], truth))
        )
        out["has_landmarks"] = 1.0
        out["landmarks"] = float(len(means))
    out["coverage"] = float(coverage)
    out["collisions"] = float(history.collisions)
    out["path_length"] = history.path_length
    for key in COUNTER_KEYS:
        out[key] = float(counters.get(key, 0.0))
    return out


#: Metrics whose value only means something for a robot with a map (else the stated empty-map
#: value, which must not enter an average of map errors).
NEEDS_MAP = frozenset({"nu", "nu_mean", "nu_mean_abs", "map_precision", "duplicates"})
#: Metrics that only mean something for a robot with a pillar map (``has_landmarks`` 1).
NEEDS_LANDMARKS = frozenset({"landmark_error"})


def meaningful(robots: Iterable[Mapping[str, float]], key: str) -> list[float]:
    """``key``'s values over the robots (``infos[agent]["metrics"]`` dicts) for which it is
    meaningful: :data:`NEEDS_MAP` keys from robots with ``has_map`` 1, :data:`NEEDS_LANDMARKS`
    keys from robots with ``has_landmarks`` 1, the other SLAM metrics
    from robots with ``slam`` 1, any other key from every robot (absent or None skipped)."""
    out = []
    for m in robots:
        if key in NEEDS_MAP and m.get("has_map", 1.0) != 1.0:
            continue
        if key in NEEDS_LANDMARKS and m.get("has_landmarks", 0.0) != 1.0:
            continue
        if key in _SLAM_KEYS and m.get("slam", 1.0) != 1.0:
            continue
        value = m.get(key)
        if value is not None:
            out.append(float(value))
    return out


def team_metrics(
    coverage_series: Sequence[float], grid: metrics.CoverageGrid
) -> dict[str, float | int | None]:
    """``infos[agent]["team"]``: coverage, steps to 50 % / 90 % (None if not reached), overlap.

    ``coverage_series[k]`` is the team coverage after env step k (k = 0: after reset).
    """
    series = np.asarray(coverage_series, dtype=float)
    return {
        "coverage": float(grid.coverage),
        "steps_to_50": metrics.time_to_fraction(series, 0.5),
        "steps_to_90": metrics.time_to_fraction(series, 0.9),
        "overlap": float(grid.overlap()),
    }

"""What a robot did during an episode, and the metrics reported at its end.

This module owns the per-robot record of an episode and the numbers computed from it, for both
the env and :func:`polyslam_env.apps.simulate.simulate` (which run the same record stage,
:func:`polyslam_env.environment.stages.record`):

* :class:`RobotHistory` grows by one entry per step (true and estimated poses, covariances,
  beam hit points, SLAM wall times, collisions, path length) and becomes a :class:`RobotRun`;
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
from polyslam_env.core.geometry import between
from polyslam_env.slam.ekf import start_error_cov
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
    "nu",
    "nu_mean",
    "nu_mean_abs",
    "completeness",
    "completeness_seen",
    "map_precision",
    "duplicates",
    "has_map",
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
    return {
        "nu": metrics.nu(polys, true_start, layout),
        "nu_mean": metrics.nu_mean(polys, true_start, layout),
        "nu_mean_abs": metrics.nu_mean(polys, frame, layout),
        "completeness": metrics.completeness(polys, true_start, layout),
        "completeness_seen": metrics.completeness_seen(polys, true_start, layout, hit_points),
        "map_precision": metrics.map_precision(polys, true_start, layout),
        "duplicates": metrics.duplicates(polys),
        "has_map": metrics.has_map(polys),
    }


def nees_relative(run: RobotRun) -> float:
    """Mean NEES of the filter itself: the estimate against the true pose seen from the
    robot's **true** start, with the covariance minus the start error's share J P0 Jᵀ
    (:func:`~polyslam_env.slam.ekf.start_error_cov`), i.e. the filter's own P_S. Unlike
    ``nees``, it does not carry the robot's unobservable start offset e₀ᵀP0⁻¹e₀ ~ χ²(3) for the
    whole episode. Step 0 is left out (P_S = 0 there: the start is known exactly in that
    frame). Without ``p0`` (no start-error model) it equals ``nees``."""
    if run.p0 is None or len(run.est_poses) < 2:
        return metrics.nees(run.true_poses, run.est_poses, run.est_covs, run.start_pose)
    covs = run.est_covs[1:] - np.array([start_error_cov(e, run.p0) for e in run.est_poses[1:]])
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
    sp = run.start_pose
    polys = run.polynomials
    hit = metrics.hit_fraction(run.hit_points, layout) if len(run.hit_points) else 0.0
    return {
        "nees": metrics.nees(run.true_poses, run.est_poses, run.est_covs, sp),
        "nees_rel": nees_relative(run),
        "start_nees": start_nees(run),
        "nees_paper": metrics.nees_paper(run.true_poses, run.est_poses, run.est_covs, sp),
        **map_metrics(polys, run.true_poses[0], sp, run.hit_points, layout),
        "hit_fraction": hit,
        "landmarks": float(len(polys)),
        "slam_time_ms": 1e3 * float(np.mean(run.slam_times)) if len(run.slam_times) else 0.0,
        "slam_time_ms_median": 1e3 * float(np.median(run.slam_times))
        if len(run.slam_times)
        else 0.0,
        "diverged": float(run.diverged),
        "collisions": float(run.collisions),
        **{key: float(run.comms.get(key, 0)) for key in COMMS_METRICS},
    }


class RobotHistory:
    """What one robot did during an episode (estimates in its own start frame).

    ``start_pose`` is the robot's frame in the absolute frame; ``true_pose`` its true pose at
    the start, which is the frame's origin unless the start is drawn with an initial error.
    """

    def __init__(
        self,
        start_pose: np.ndarray,
        est_pose: np.ndarray,
        est_cov: np.ndarray,
        true_pose: np.ndarray | None = None,
        p0: np.ndarray | None = None,
    ) -> None:
        self.start_pose = np.asarray(start_pose, dtype=float).copy()  # (3,) absolute
        self.p0 = None if p0 is None else np.asarray(p0, dtype=float)  # start-error cov in cov
        first = self.start_pose if true_pose is None else np.asarray(true_pose, dtype=float)
        self.true: list[np.ndarray] = [first.copy()]  # (3,) each, absolute
        self.est: list[np.ndarray] = [np.asarray(est_pose, dtype=float).copy()]  # (3,) own frame
        self.cov: list[np.ndarray] = [np.asarray(est_cov, dtype=float).copy()]  # (3, 3) each
        self.hits: list[np.ndarray] = []  # (h, 2) each, absolute
        self.slam_times: list[float] = []  # s
        self.collisions = 0
        self.path_length = 0.0  # m, true distance travelled
        self.diverged = False
        self.diverged_at: int | None = None  # first step (1-based) flagged diverging

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
        """Append one step: poses (3,), covariance (3, 3), beam hit points (h, 2)."""
        (x, y), (x0, y0) = true_pose[:2].tolist(), self.true[-1][:2].tolist()
        self.path_length += float(np.hypot(x - x0, y - y0))
        self.true.append(np.array(true_pose, dtype=float))  # np.array copies
        self.est.append(np.array(est_pose, dtype=float))
        self.cov.append(np.array(est_cov, dtype=float))
        self.hits.append(hits)
        if slam_time is not None:
            self.slam_times.append(slam_time)
        self.collisions += int(collided)
        if diverging and not self.diverged:
            self.diverged_at = len(self.true) - 1
        self.diverged |= diverging

    def true_path(self) -> np.ndarray:  # (k, 2)
        return np.array([p[:2] for p in self.true])

    def est_path_abs(self) -> np.ndarray:  # (k, 2)
        """Estimated positions in the absolute frame, placed by the true start (as the map
        metrics place the map; the frame's offset from the true start is unobservable)."""
        return metrics.pose_to_absolute(np.array(self.est), self.true[0])[:, :2]

    def run(self, polys: list[Polynomial]) -> RobotRun:
        return RobotRun(
            start_pose=self.start_pose,
            true_poses=np.array(self.true),
            est_poses=np.array(self.est),
            est_covs=np.array(self.cov),
            polynomials=polys,
            hit_points=np.vstack(self.hits) if self.hits else np.zeros((0, 2)),
            slam_times=np.array(self.slam_times),
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
        paper = robot_metrics(run, layout)
        out.update({k: float(paper[k]) for k in _SLAM_KEYS if k in paper})
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

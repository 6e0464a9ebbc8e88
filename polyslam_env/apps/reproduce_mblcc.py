"""Reproduce seed 003's experiment (Chen et al., §4): Table 1 and Fig 5.

Each run draws one kinematic episode (``world.kinematic``: three cars on preset paths in a
random landmark field) and runs the four algorithms on the very same data: ``fastslam2``,
``em_fastslam`` and ``mblcc`` (one filter per robot; MBLCC robots exchange their best
particle's landmark estimates after every sweep) and ``multirobot_known_start`` (one joint
filter, one shared map, FastSLAM 2.0's proposal), plus a second reading of the seed's
ref. [10], ``shared_map_motion_proposal`` (the same joint filter drawing from the motion
model, as the seed does not say which proposal [10] used). Every per-robot filter of robot r
draws from the stream ``filter/r<r>`` of the run's seed (common random numbers: the
algorithms differ by their steps, not by luck), the joint filters from ``filter/team``.

Per robot and run: ``pose_error`` = mean over sweeps of the position error ‖p̂ − p‖ of the
weighted particle mean; ``landmark_error`` = at the end, mean ‖m̂ − m‖ over the landmarks that
robot observed (for the shared map too, so the columns compare like with like); and
``landmark_rmse`` (the same as a root mean square), whose mean over robots and runs is the
ARMSE of Fig 5. The table reports mean and standard deviation over runs; ``paired`` the
per-run differences between algorithms (mean ± standard error), which resolve orderings the
table's overlapping spreads cannot.

The particles' diversity, per robot (``diversity``): the effective sample size N_eff / N the
resampling decisions saw at the robot's sweeps, the resamplings of its particles per own
sweep (in a joint filter every robot's sweep may resample them), the particle spread
√tr P_xy, and ``lineages_<L>``: how many distinct particles of L own sweeps ago the current
set descends from (:func:`~polyslam_env.slam.points.particles.surviving_ancestors`).

``em_sweep``: EM-FastSLAM with R scaled by each of ``em_scales`` and ``em_passes`` moves per
sweep, each paired with FastSLAM 2.0 on the same seeds (same episode, same filter stream).

What 50 runs give (seeds 0–49, default config): MBLCC and the shared-map filter halve
FastSLAM 2.0's errors for r1 and r2 (paired differences ≈ −0.45 to −0.55 m, 4–5 standard
errors) and lower them less for r3; EM-FastSLAM equals FastSLAM 2.0 within noise (±0.1 m):
with the seed's R the move is ≤ 8 mm / 0.001 rad per sweep, measured ≈ 2 mm against a
particle spread of ≈ 5 cm, too small to matter. MBLCC ties the shared map for r1 and r2 and
trails it for r3, which shares a landmark with a robot in the previous sweep in ≈ 30 % of its
observations (r2: 50 %), while the shared map keeps every robot's information for good.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env import metrics
from polyslam_env.apps.jobs import Runner, run_jobs, succeeded
from polyslam_env.core.blas import blas_threads
from polyslam_env.core.config import Config
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.seeding import make_rngs
from polyslam_env.slam.points import (
    LandmarkMessage,
    PointFastSlam,
    PointMeasurements,
    PointSlamConfig,
    SharedMapFastSlam,
    SharedMapRobot,
    algorithm_config,
)
from polyslam_env.slam.points.particles import surviving_ancestors
from polyslam_env.world.kinematic import KinematicConfig, KinematicEpisode, simulate_episode

#: The seed's Table 1 columns, in its order (``multirobot_known_start``: our first reading of
#: its ref. [10], with FastSLAM 2.0's proposal).
ALGORITHMS = ("fastslam2", "em_fastslam", "multirobot_known_start", "mblcc")
#: Baselines beside the seed's columns: the shared-map filter with the motion-model proposal.
BASELINES = ("shared_map_motion_proposal",)
COLUMNS = (*ALGORITHMS, *BASELINES)
SHARED_MAP = {"multirobot_known_start": "fastslam2", "shared_map_motion_proposal": "motion"}
METRICS = ("pose_error", "landmark_error")
#: Lags (own sweeps; 0.2 s each in the seed's world) at which surviving ancestors are counted:
#: one sweep, 5 s and 20 s back.
LAGS = (1, 25, 100)
DIVERSITY = ("effective_size", "resample_rate", "spread", *(f"lineages_{lag}" for lag in LAGS))
#: Seed's Table 1: (mean of pose, variance of pose, mean of landmark, variance of landmark)
#: per robot and algorithm, in metres as printed.
PAPER_TABLE: dict[str, tuple[tuple[float, float, float, float], ...]] = {
    "fastslam2": (
        (0.7029, 0.4280, 0.7003, 0.4305),
        (1.2852, 0.5213, 1.4001, 0.6827),
        (0.7690, 0.5263, 0.6539, 0.5502),
    ),
    "em_fastslam": (
        (0.4101, 0.2206, 0.4701, 0.2159),
        (0.7469, 0.3352, 0.5861, 0.2925),
        (0.6889, 0.4470, 0.5960, 0.5019),
    ),
    "multirobot_known_start": (
        (0.3872, 0.3010, 0.2808, 0.2039),
        (0.4561, 0.2014, 0.5031, 0.2022),
        (0.4501, 0.2803, 0.4391, 0.3618),
    ),
    "mblcc": (
        (0.2501, 0.1850, 0.2048, 0.1206),
        (0.2873, 0.1769, 0.3551, 0.1527),
        (0.3541, 0.2061, 0.3789, 0.3284),
    ),
}


@dataclass(frozen=True)
class MblccReproduceConfig(Config):
    """The seed's §4: world, filter settings, runs and the particle counts of Fig 5."""

    runs: int = 50
    world: KinematicConfig = field(default_factory=KinematicConfig)
    slam: PointSlamConfig = field(default_factory=PointSlamConfig)
    fig5_particles: tuple[int, ...] = (5, 10, 20, 50, 100, 200)
    fig5_runs: int = 10  # runs per particle count (the first seeds)
    # EM sweep: R (slam.em_mobility) times each scale, with each number of moves per sweep,
    # over all ``runs`` seeds; () skips it.
    em_scales: tuple[float, ...] = (1.0, 10.0, 100.0)
    em_passes: tuple[int, ...] = (1, 5)

    def validate(self) -> None:
        if self.runs < 1 or self.fig5_runs < 0:
            raise ConfigError("runs must be >= 1 and fig5_runs >= 0")
        if any(n < 1 for n in self.fig5_particles):
            raise ConfigError(f"fig5_particles: must all be >= 1, got {self.fig5_particles}")
        if any(not x > 0 for x in self.em_scales):
            raise ConfigError(f"em_scales: must all be > 0, got {self.em_scales}")
        if any(n < 1 for n in self.em_passes):
            raise ConfigError(f"em_passes: must all be >= 1, got {self.em_passes}")

    def em_settings(self) -> list[tuple[float, int]]:
        """The EM sweep's (R scale, moves per sweep) pairs, scale-major."""
        return [(x, n) for x in self.em_scales for n in self.em_passes]

    def filter_config(self) -> PointSlamConfig:
        """The filters' settings with the world's true noise, period and wheelbase."""
        return matched_filter_config(self.slam, self.world)


def matched_filter_config(slam: PointSlamConfig, world: KinematicConfig) -> PointSlamConfig:
    """``slam`` with the kinematic world's true noise, control period and wheelbase (every
    point-landmark study runs its filters on the models that made the data)."""
    return slam.replace(
        sigma_v=world.sigma_v,
        sigma_g_deg=world.sigma_g_deg,
        sigma_r=world.sigma_r,
        sigma_b_deg=world.sigma_b_deg,
        dt=world.dt,
        wheelbase=world.wheelbase,
    )


RunMetrics = dict[str, list[dict[str, float]]]  # algorithm → per robot → metric → value
ParticleBackend = PointFastSlam | SharedMapRobot
Job = tuple[MblccReproduceConfig, int, int | None, tuple[float, int] | None]


def make_backends(
    algorithm: str, config: PointSlamConfig, episode: KinematicEpisode, seed: int
) -> list[ParticleBackend]:
    """The team's back-ends for one algorithm (a :data:`COLUMNS` name), seeded from the run's
    seed."""
    starts = np.array([r.initial_pose for r in episode.robots])
    if algorithm in SHARED_MAP:
        rng = make_rngs(seed, ["filter/team"])["filter/team"]
        team = SharedMapFastSlam(config.replace(proposal=SHARED_MAP[algorithm]), starts, rng)
        return [team.robot(i) for i in range(len(starts))]
    rngs = make_rngs(seed, [f"filter/r{i}" for i in range(len(starts))])
    cfg = algorithm_config(algorithm, config)
    return [PointFastSlam(cfg, p, rngs[f"filter/r{i}"], robot_id=i) for i, p in enumerate(starts)]


def run_algorithm(
    backends: Sequence[ParticleBackend], episode: KinematicEpisode
) -> list[dict[str, float]]:
    """Drive the back-ends sweep by sweep (messages of sweep k−1 before sweep k); metrics."""
    errors: list[list[float]] = [[] for _ in backends]
    spreads: list[list[float]] = [[] for _ in backends]
    sizes: list[list[float]] = [[] for _ in backends]
    # Each filter's steps' parents; robots of one joint filter share its list.
    parents: dict[int, list[np.ndarray]] = {}
    steps: list[list[int]] = [[] for _ in backends]  # each robot's sweeps' steps in its filter
    history = [parents.setdefault(id(_filter_of(b)), []) for b in backends]
    messages: list[LandmarkMessage] = []
    for k in range(episode.sweeps):
        active = [i for i, r in enumerate(episode.robots) if k < len(r.sweeps)]
        for i in active:
            robot, backend = episode.robots[i], backends[i]
            backend.import_messages(messages)
            ids, z = robot.sweeps[k]
            backend.step(robot.controls[k], PointMeasurements(ids, z))
            mean, cov = backend.pose()
            errors[i].append(float(np.hypot(*(mean[:2] - robot.true_poses[k, :2]))))
            spreads[i].append(float(np.sqrt(max(np.trace(cov[:2, :2]), 0.0))))
            done = backend.last_sweep
            assert done is not None
            sizes[i].append(done.effective_size / len(done.parents))
            history[i].append(done.parents)
            steps[i].append(len(history[i]) - 1)
        messages = [backends[i].export_message() for i in active]
    out = []
    for i, backend in enumerate(backends):
        seen = np.unique(np.concatenate([ids for ids, _ in episode.robots[i].sweeps]))
        lm = backend.landmarks()
        where = {int(j): s for s, j in enumerate(lm.ids)}
        est = lm.means[[where[int(j)] for j in seen]]
        d = metrics.landmark_distances(est, np.zeros(3), episode.landmarks[seen])  # one frame
        out.append(
            {
                "pose_error": float(np.mean(errors[i])),
                "landmark_error": float(d.mean()),
                "landmark_rmse": float(np.sqrt(np.mean(d * d))),
                "effective_size": float(np.mean(sizes[i])),
                "spread": float(np.mean(spreads[i])),
                **lineage_metrics(history[i], steps[i]),
            }
        )
    return out


def _filter_of(backend: ParticleBackend) -> object:
    """The filter whose particles a back-end's robot holds (the team's, for a joint filter)."""
    return backend.team if isinstance(backend, SharedMapRobot) else backend


def lineage_metrics(parents: Sequence[np.ndarray], steps: Sequence[int]) -> dict[str, float]:
    """One robot's ``resample_rate`` (resamplings of its filter per own sweep, counted from its
    first sweep to its last) and ``lineages_<L>`` (mean over its sweeps k ≥ L of the particles
    at its sweep k − L with descendants at sweep k; left out if it has no more than L
    sweeps)."""
    first, last = steps[0], steps[-1]
    resampled = sum(
        not np.array_equal(parents[s], np.arange(len(parents[s])))
        for s in range(first + 1, last + 1)
    )
    out = {"resample_rate": resampled / max(len(steps) - 1, 1)}
    for lag in LAGS:
        counts = [
            surviving_ancestors(parents, steps[k - lag], steps[k]) for k in range(lag, len(steps))
        ]
        if counts:
            out[f"lineages_{lag}"] = float(np.mean(counts))
    return out


def run_one(
    config: MblccReproduceConfig,
    seed: int,
    particles: int | None = None,
    em: tuple[float, int] | None = None,
) -> RunMetrics:
    """One seeded episode through every column (``particles`` overrides N), or with ``em`` =
    (R scale, moves per sweep) through EM-FastSLAM at that setting alone."""
    episode = simulate_episode(config.world, seed)
    slam = config.filter_config()
    if particles is not None:
        slam = slam.replace(particles=particles)
    if em is not None:
        scale, passes = em
        mobility = tuple(scale * r for r in slam.em_mobility)
        slam = slam.replace(em_mobility=mobility, em_passes=passes)
    columns = ("em_fastslam",) if em is not None else COLUMNS
    with blas_threads(1):
        return {
            alg: run_algorithm(make_backends(alg, slam, episode, seed), episode) for alg in columns
        }


def _job(job: Job) -> RunMetrics:
    return run_one(*job)


def _reuses_table(config: MblccReproduceConfig, setting: tuple[float, int]) -> bool:
    """Whether an EM setting is the table's own EM-FastSLAM (its runs are reused)."""
    return setting == (1.0, config.slam.em_passes)


def reproduce(
    config: MblccReproduceConfig,
    workers: int | Runner = 2,
    progress: Callable[[int], None] | None = None,
) -> tuple[
    list[RunMetrics], dict[int, list[RunMetrics]], dict[tuple[float, int], list[RunMetrics]]
]:
    """The table's runs (seeds 0..runs−1), Fig 5's runs per particle count and the EM sweep's
    runs per (R scale, moves per sweep), all in one pool of ``workers`` processes."""
    n = config.slam.particles
    jobs: list[Job] = [(config, s, None, None) for s in range(config.runs)]
    sweep = [p for p in config.fig5_particles if p != n]
    jobs += [(config, s, p, None) for p in sweep for s in range(config.fig5_runs)]
    em = [e for e in config.em_settings() if not _reuses_table(config, e)]
    jobs += [(config, s, None, e) for e in em for s in range(config.runs)]
    results = run_jobs(_job, jobs, workers, progress, seed_of=lambda job: job[1])
    table = results[: config.runs]
    table_runs = succeeded(table)
    by_n = {n: succeeded(table[: config.fig5_runs])} if n in config.fig5_particles else {}
    for k, p in enumerate(sweep):
        start = config.runs + k * config.fig5_runs
        by_n[p] = succeeded(results[start : start + config.fig5_runs])
    by_em: dict[tuple[float, int], list[RunMetrics]] = {}
    start = config.runs + len(sweep) * config.fig5_runs
    for e in config.em_settings():
        if _reuses_table(config, e):
            em_runs = table
        else:
            em_runs = results[start : start + config.runs]
            start += config.runs
        by_em[e] = [
            {"em_fastslam": run["em_fastslam"], "fastslam2": fs2["fastslam2"]}
            for run, fs2 in zip(em_runs, table, strict=True)
            if run is not None and fs2 is not None
        ]
    return table_runs, dict(sorted(by_n.items())), by_em


def total_jobs(config: MblccReproduceConfig) -> int:
    """The number of runs :func:`reproduce` makes."""
    fig5 = sum(p != config.slam.particles for p in config.fig5_particles) * config.fig5_runs
    em = sum(not _reuses_table(config, e) for e in config.em_settings()) * config.runs
    return config.runs + fig5 + em


def summarise(
    runs: Sequence[RunMetrics],
    by_n: dict[int, list[RunMetrics]] | None = None,
    by_em: dict[tuple[float, int], list[RunMetrics]] | None = None,
) -> dict[str, Any]:
    """``table[metric][column]`` = per robot {mean, std} over runs, ``diversity`` likewise for
    the particle-diversity measures; the seed's ordering claims as named ``checks``; paired
    differences; Fig 5's ARMSE per column and particle count; the EM sweep."""
    table = _per_robot_table(runs, (*METRICS, "landmark_rmse"))
    checks: dict[str, bool] = {}
    for metric in METRICS:
        means = {a: np.array([s["mean"] for s in table[metric][a]]) for a in COLUMNS}
        others = [a for a in ALGORITHMS if a != "mblcc"]
        checks[f"mblcc_lowest_{metric}_every_robot"] = bool(
            all(np.all(means["mblcc"] < means[a]) for a in others)
        )
        others = [a for a in ALGORITHMS if a != "fastslam2"]
        checks[f"fastslam2_highest_{metric}_every_robot"] = bool(
            all(np.all(means["fastslam2"] > means[a]) for a in others)
        )
        checks[f"em_fastslam_below_fastslam2_{metric}_every_robot"] = bool(
            np.all(means["em_fastslam"] < means["fastslam2"])
        )
        checks[f"mblcc_below_shared_map_motion_proposal_{metric}_every_robot"] = bool(
            np.all(means["mblcc"] < means["shared_map_motion_proposal"])
        )
    em_sweep = em_sweep_summary(by_em or {})
    for metric in METRICS:
        checks[f"em_fastslam_below_fastslam2_{metric}_every_robot_at_some_em_setting"] = any(
            all(c["mean"] < 0 for c in cell["paired"][metric]["robots"]) for cell in em_sweep
        )
    armse = {
        alg: {
            str(n): float(np.mean([[rb["landmark_rmse"] for rb in run[alg]] for run in rs]))
            for n, rs in (by_n or {}).items()
            if rs
        }
        for alg in COLUMNS
    }
    return {
        "runs": len(runs),
        "table": table,
        "diversity": _per_robot_table(runs, DIVERSITY),
        "checks": checks,
        "paired": paired_differences(runs),
        "em_sweep": em_sweep,
        "per_run": list(runs),
        "armse_by_particles": armse,
        "paper": {a: [list(row) for row in rows] for a, rows in PAPER_TABLE.items()},
    }


def _per_robot_table(
    runs: Sequence[RunMetrics], metrics: Sequence[str], columns: Sequence[str] = COLUMNS
) -> dict[str, dict[str, list[dict[str, float]]]]:
    """``[metric][column]`` = per robot {mean, std} over runs."""
    out: dict[str, dict[str, list[dict[str, float]]]] = {}
    for metric in metrics:
        out[metric] = {}
        for alg in columns:
            robots = len(runs[0][alg])
            cells = []
            for r in range(robots):
                # a run shorter than a lineage lag has no count at that lag
                v = np.array([run[alg][r][metric] for run in runs if metric in run[alg][r]])
                mean, std = (float(v.mean()), float(v.std())) if len(v) else (np.nan, np.nan)
                cells.append({"mean": mean, "std": std})
            out[metric][alg] = cells
    return out


#: Column pairs whose per-run differences say whether an ordering is resolved by the runs.
PAIRS = (
    ("em_fastslam", "fastslam2"),
    ("mblcc", "fastslam2"),
    ("mblcc", "em_fastslam"),
    ("mblcc", "multirobot_known_start"),
    ("mblcc", "shared_map_motion_proposal"),
    ("shared_map_motion_proposal", "multirobot_known_start"),
)

Robots = list[dict[str, float]]  # one run of one column: per robot → metric → value


def mean_and_se(d: np.ndarray) -> dict[str, float]:
    """Mean of d and its standard error (nan for fewer than two values)."""
    se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
    return {"mean": float(d.mean()), "se": se}


def paired(a: Sequence[Robots], b: Sequence[Robots], metric: str) -> dict[str, Any]:
    """Paired differences a − b over runs (a[k] and b[k] from the same seed): ``robots`` per
    robot, ``team`` of the robots' mean; each {mean, se}."""
    d = np.array(
        [[x[r][metric] - y[r][metric] for r in range(len(x))] for x, y in zip(a, b, strict=True)]
    )
    return {
        "robots": [mean_and_se(d[:, r]) for r in range(d.shape[1])],
        "team": mean_and_se(d.mean(axis=1)),
    }


def paired_differences(runs: Sequence[RunMetrics]) -> dict[str, dict[str, list[dict[str, float]]]]:
    """Per metric, pair "a-b" and robot: mean of the per-run difference a − b and its
    standard error. The algorithms run on the same episodes with common random numbers, so
    the paired difference is far less noisy than the difference of the table's means."""
    return {
        metric: {
            f"{a}-{b}": paired([r[a] for r in runs], [r[b] for r in runs], metric)["robots"]
            for a, b in PAIRS
        }
        for metric in METRICS
    }


def em_sweep_summary(by_em: dict[tuple[float, int], list[RunMetrics]]) -> list[dict[str, Any]]:
    """Per EM setting (R = ``scale`` × ``slam.em_mobility``, ``passes`` moves per sweep): the
    mean and std per robot over runs of the errors (``table``) and of the particle diversity
    (``diversity``), and the paired differences EM − FastSLAM 2.0, each of
    ``by_em``'s runs holding both on one seed (the seeds where both succeeded)."""
    out = []
    for (scale, passes), em_runs in by_em.items():
        em = [run["em_fastslam"] for run in em_runs]
        fs2 = [run["fastslam2"] for run in em_runs]
        table = _per_robot_table(em_runs, (*METRICS, *DIVERSITY), ("em_fastslam",))
        out.append(
            {
                "scale": float(scale),
                "passes": int(passes),
                "runs": len(em),
                "table": {m: table[m]["em_fastslam"] for m in METRICS},
                "diversity": {m: table[m]["em_fastslam"] for m in DIVERSITY},
                "paired": {m: paired(em, fs2, m) for m in METRICS},
            }
        )
    return out


def table_text(summary: dict[str, Any]) -> str:
    """Our table next to the seed's Table 1 (its "mean" columns)."""
    head = f"{'robot':<6}{'algorithm':<28}{'pose error / m':>18}{'seed':>8}"
    head += f"{'landmark error / m':>24}{'seed':>8}"
    lines = [head, "-" * len(head)]
    robots = len(summary["table"]["pose_error"]["fastslam2"])
    for r in range(robots):
        for alg in COLUMNS:
            p = summary["table"]["pose_error"][alg][r]
            m = summary["table"]["landmark_error"][alg][r]
            rows = PAPER_TABLE.get(alg, ())
            pose_ref, lm_ref = (
                (f"{rows[r][0]:.4f}", f"{rows[r][2]:.4f}") if r < len(rows) else ("—", "—")
            )
            lines.append(
                f"{(f'r{r + 1}' if alg == ALGORITHMS[0] else ''):<6}{alg:<28}"
                f"{p['mean']:>8.4f} ± {p['std']:<7.4f}{pose_ref:>8}"
                f"{m['mean']:>14.4f} ± {m['std']:<7.4f}{lm_ref:>8}"
            )
    return "\n".join(lines)


def em_sweep_text(summary: dict[str, Any]) -> str:
    """The EM sweep: per setting, EM − FastSLAM 2.0 (paired, mean ± standard error) per robot
    and for the team's mean, pose and landmark error."""
    head = f"{'R ×':>6}{'moves':>7}  {'metric':<16}{'r1':>18}{'r2':>18}{'r3':>18}{'team':>18}"
    lines = [head, "-" * len(head)]
    for cell in summary["em_sweep"]:
        for metric in METRICS:
            d = cell["paired"][metric]
            text = "".join(f"{c['mean']:>+10.3f} ± {c['se']:<5.3f}" for c in d["robots"])
            team = d["team"]
            lines.append(
                f"{cell['scale']:>6g}{cell['passes']:>7}  {metric:<16}{text}"
                f"{team['mean']:>+10.3f} ± {team['se']:<5.3f}"
            )
    return "\n".join(lines)


def diversity_text(summary: dict[str, Any]) -> str:
    """Per column, the robots' mean of each diversity measure (mean over runs)."""
    names = {"effective_size": "N_eff/N", "resample_rate": "resample/sweep", "spread": "spread/m"}
    head = f"{'column':<28}" + "".join(f"{names.get(m, m):>16}" for m in DIVERSITY)
    lines = [head, "-" * len(head)]
    for alg in COLUMNS:
        row = [np.mean([c["mean"] for c in summary["diversity"][m][alg]]) for m in DIVERSITY]
        lines.append(f"{alg:<28}" + "".join(f"{v:>16.3f}" for v in row))
    return "\n".join(lines)


def _write_figure(fig: Any, path: Path) -> Path:
    import io

    import matplotlib.pyplot as plt

    from polyslam_env.core.io import write_atomic

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return write_atomic(path, buf.getvalue())


def plot_armse(summary: dict[str, Any], path: Path) -> Path:
    """Fig 5: landmark ARMSE against the number of particles, one curve per algorithm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for alg in COLUMNS:
        curve = summary["armse_by_particles"][alg]
        ns = sorted(int(n) for n in curve)
        ax.plot(ns, [curve[str(n)] for n in ns], marker="o", label=alg)
    ax.set_xscale("log")
    ax.set_xlabel("particles N")
    ax.set_ylabel("landmark ARMSE / m")
    ax.set_title("Fig 5: ARMSE against the number of particles")
    ax.grid(True, alpha=0.3)
    ax.legend()
    return _write_figure(fig, path)


def plot_diversity(summary: dict[str, Any], path: Path) -> Path:
    """Surviving ancestors against the lag, and N_eff / N, per column (robots' mean)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    div = summary["diversity"]
    for alg in COLUMNS:
        ys = [np.mean([c["mean"] for c in div[f"lineages_{lag}"][alg]]) for lag in LAGS]
        left.plot(LAGS, ys, marker="o", label=alg)
    left.set_xscale("log")
    left.set_xlabel("lag L (own sweeps of 0.2 s)")
    left.set_ylabel("particles of L sweeps ago with descendants")
    left.grid(True, alpha=0.3)
    left.legend(fontsize=8)
    x = np.arange(3)
    for k, alg in enumerate(COLUMNS):
        ys = [c["mean"] for c in div["effective_size"][alg]]
        right.bar(x + 0.16 * (k - 2), ys, width=0.16, label=alg)
    right.set_xticks(x, ["r1", "r2", "r3"])
    right.set_ylabel("mean N_eff / N before resampling")
    right.grid(True, alpha=0.3, axis="y")
    fig.suptitle(f"Particle diversity over {summary['runs']} runs")
    return _write_figure(fig, path)

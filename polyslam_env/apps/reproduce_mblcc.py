"""Reproduce seed 003's experiment (Chen et al., §4): Table 1 and Fig 5.

Each run draws one kinematic episode (``world.kinematic``: three cars on preset paths in a
random landmark field) and runs the four algorithms on the very same data: ``fastslam2``,
``em_fastslam`` and ``mblcc`` (one filter per robot; MBLCC robots exchange their best
particle's landmark estimates after every sweep) and ``multirobot_known_start`` (one joint
filter, one shared map). Every per-robot filter of robot r draws from the stream
``filter/r<r>`` of the run's seed (common random numbers: the algorithms differ by their
steps, not by luck), the joint filter from ``filter/team``.

Per robot and run: ``pose_error`` = mean over sweeps of the position error ‖p̂ − p‖ of the
weighted particle mean; ``landmark_error`` = at the end, mean ‖m̂ − m‖ over the landmarks that
robot observed (for the shared map too, so the columns compare like with like); and
``landmark_rmse`` (the same as a root mean square), whose mean over robots and runs is the
ARMSE of Fig 5. The table reports mean and standard deviation over runs; ``paired`` the
per-run differences between algorithms (mean ± standard error), which resolve orderings the
table's overlapping spreads cannot.

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
    PointSlamBackend,
    PointSlamConfig,
    SharedMapFastSlam,
    algorithm_config,
)
from polyslam_env.world.kinematic import KinematicConfig, KinematicEpisode, simulate_episode

#: Table columns, in the seed's order.
ALGORITHMS = ("fastslam2", "em_fastslam", "multirobot_known_start", "mblcc")
METRICS = ("pose_error", "landmark_error")
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

    def validate(self) -> None:
        if self.runs < 1 or self.fig5_runs < 0:
            raise ConfigError("runs must be >= 1 and fig5_runs >= 0")
        if any(n < 1 for n in self.fig5_particles):
            raise ConfigError(f"fig5_particles: must all be >= 1, got {self.fig5_particles}")

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


def make_backends(
    algorithm: str, config: PointSlamConfig, episode: KinematicEpisode, seed: int
) -> list[PointSlamBackend]:
    """The team's back-ends for one algorithm, seeded from the run's seed."""
    starts = np.array([r.initial_pose for r in episode.robots])
    if algorithm == "multirobot_known_start":
        team = SharedMapFastSlam(config, starts, make_rngs(seed, ["filter/team"])["filter/team"])
        return [team.robot(i) for i in range(len(starts))]
    rngs = make_rngs(seed, [f"filter/r{i}" for i in range(len(starts))])
    cfg = algorithm_config(algorithm, config)
    return [PointFastSlam(cfg, p, rngs[f"filter/r{i}"], robot_id=i) for i, p in enumerate(starts)]


def run_algorithm(
    backends: Sequence[PointSlamBackend], episode: KinematicEpisode
) -> list[dict[str, float]]:
    """Drive the back-ends sweep by sweep (messages of sweep k−1 before sweep k); metrics."""
    errors: list[list[float]] = [[] for _ in backends]
    messages: list[LandmarkMessage] = []
    for k in range(episode.sweeps):
        active = [i for i, r in enumerate(episode.robots) if k < len(r.sweeps)]
        for i in active:
            robot, backend = episode.robots[i], backends[i]
            backend.import_messages(messages)
            ids, z = robot.sweeps[k]
            backend.step(robot.controls[k], PointMeasurements(ids, z))
            errors[i].append(float(np.hypot(*(backend.pose()[0][:2] - robot.true_poses[k, :2]))))
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
            }
        )
    return out


def run_one(config: MblccReproduceConfig, seed: int, particles: int | None = None) -> RunMetrics:
    """One seeded episode through all four algorithms (``particles`` overrides N)."""
    episode = simulate_episode(config.world, seed)
    slam = config.filter_config()
    if particles is not None:
        slam = slam.replace(particles=particles)
    with blas_threads(1):
        return {
            alg: run_algorithm(make_backends(alg, slam, episode, seed), episode)
            for alg in ALGORITHMS
        }


def _job(job: tuple[MblccReproduceConfig, int, int | None]) -> RunMetrics:
    return run_one(*job)


def reproduce(
    config: MblccReproduceConfig,
    workers: int | Runner = 2,
    progress: Callable[[int], None] | None = None,
) -> tuple[list[RunMetrics], dict[int, list[RunMetrics]]]:
    """The table's runs (seeds 0..runs−1) and Fig 5's runs per particle count, in parallel."""
    n = config.slam.particles
    jobs: list[tuple[MblccReproduceConfig, int, int | None]] = [
        (config, s, None) for s in range(config.runs)
    ]
    sweep = [p for p in config.fig5_particles if p != n]
    jobs += [(config, s, p) for p in sweep for s in range(config.fig5_runs)]
    results = run_jobs(_job, jobs, workers, progress, seed_of=lambda job: job[1])
    table_runs = succeeded(results[: config.runs])
    by_n = {n: succeeded(results[: config.fig5_runs])} if n in config.fig5_particles else {}
    for k, p in enumerate(sweep):
        start = config.runs + k * config.fig5_runs
        by_n[p] = succeeded(results[start : start + config.fig5_runs])
    return table_runs, dict(sorted(by_n.items()))


def summarise(
    runs: Sequence[RunMetrics], by_n: dict[int, list[RunMetrics]] | None = None
) -> dict[str, Any]:
    """``table[metric][algorithm]`` = per robot {mean, std} over runs; the seed's ordering
    claims as named ``checks``; Fig 5's ARMSE per algorithm and particle count."""
    robots = len(runs[0][ALGORITHMS[0]])
    table: dict[str, dict[str, list[dict[str, float]]]] = {}
    for metric in (*METRICS, "landmark_rmse"):
        table[metric] = {}
        for alg in ALGORITHMS:
            table[metric][alg] = []
            for r in range(robots):
                v = np.array([run[alg][r][metric] for run in runs])
                table[metric][alg].append({"mean": float(v.mean()), "std": float(v.std())})
    checks: dict[str, bool] = {}
    for metric in METRICS:
        means = {a: np.array([s["mean"] for s in table[metric][a]]) for a in ALGORITHMS}
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
    armse = {
        alg: {
            str(n): float(np.mean([[rb["landmark_rmse"] for rb in run[alg]] for run in rs]))
            for n, rs in (by_n or {}).items()
            if rs
        }
        for alg in ALGORITHMS
    }
    return {
        "runs": len(runs),
        "table": table,
        "checks": checks,
        "paired": paired_differences(runs),
        "per_run": list(runs),
        "armse_by_particles": armse,
        "paper": {a: [list(row) for row in rows] for a, rows in PAPER_TABLE.items()},
    }


#: Algorithm pairs whose per-run differences say whether an ordering is resolved by the runs.
PAIRS = (
    ("em_fastslam", "fastslam2"),
    ("mblcc", "fastslam2"),
    ("mblcc", "em_fastslam"),
    ("mblcc", "multirobot_known_start"),
)


def paired_differences(runs: Sequence[RunMetrics]) -> dict[str, dict[str, list[dict[str, float]]]]:
    """Per metric, pair "a-b" and robot: mean of the per-run difference a − b and its
    standard error. The algorithms run on the same episodes with common random numbers, so
    the paired difference is far less noisy than the difference of the table's means."""
    robots = len(runs[0][ALGORITHMS[0]])
    out: dict[str, dict[str, list[dict[str, float]]]] = {}
    for metric in METRICS:
        out[metric] = {}
        for a, b in PAIRS:
            cells = []
            for r in range(robots):
                d = np.array([run[a][r][metric] - run[b][r][metric] for run in runs])
                se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
                cells.append({"mean": float(d.mean()), "se": se})
            out[metric][f"{a}-{b}"] = cells
    return out


def table_text(summary: dict[str, Any]) -> str:
    """Our table next to the seed's Table 1 (its "mean" columns)."""
    head = f"{'robot':<6}{'algorithm':<24}{'pose error / m':>22}{'seed':>8}"
    head += f"{'landmark error / m':>24}{'seed':>8}"
    lines = [head, "-" * len(head)]
    robots = len(summary["table"]["pose_error"]["fastslam2"])
    for r in range(robots):
        for alg in ALGORITHMS:
            p = summary["table"]["pose_error"][alg][r]
            m = summary["table"]["landmark_error"][alg][r]
            ref = PAPER_TABLE[alg][r] if r < len(PAPER_TABLE[alg]) else (np.nan,) * 4
            lines.append(
                f"{(f'r{r + 1}' if alg == ALGORITHMS[0] else ''):<6}{alg:<24}"
                f"{p['mean']:>12.4f} ± {p['std']:<7.4f}{ref[0]:>8.4f}"
                f"{m['mean']:>14.4f} ± {m['std']:<7.4f}{ref[2]:>8.4f}"
            )
    return "\n".join(lines)


def plot_armse(summary: dict[str, Any], path: Path) -> Path:
    """Fig 5: landmark ARMSE against the number of particles, one curve per algorithm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from polyslam_env.core.io import write_atomic

    fig, ax = plt.subplots(figsize=(6, 4))
    for alg in ALGORITHMS:
        curve = summary["armse_by_particles"][alg]
        ns = sorted(int(n) for n in curve)
        ax.plot(ns, [curve[str(n)] for n in ns], marker="o", label=alg)
    ax.set_xscale("log")
    ax.set_xlabel("particles N")
    ax.set_ylabel("landmark ARMSE / m")
    ax.set_title("Fig 5: ARMSE against the number of particles")
    ax.grid(True, alpha=0.3)
    ax.legend()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return write_atomic(path, buf.getvalue())

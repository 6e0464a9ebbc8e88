"""Reproduce the core paper's §4: Table 1 and Figures 5–8.

Each run simulates the three robots along the paper's paths with map exchange, plus a
"shadow" SLAM for r3 fed the very same odometry and ranges but never exchanging: r3's
single-robot result on the identical episode (the paper's Fig 8). :func:`reproduce` runs the
seeds in parallel processes and :func:`summarise` turns them into the table.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.jobs import Runner, run_jobs, succeeded
from polyslam_env.apps.simulate import SimulationResult, simulate
from polyslam_env.comms.channel import ChannelConfig
from polyslam_env.core.config import Config
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.resources import configs_dir
from polyslam_env.metrics.episode import robot_metrics
from polyslam_env.metrics.mapping import QUALITY_KEYS
from polyslam_env.slam.config import SlamConfig
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map

#: Table 1 of the paper (μ is eᵀPe as printed; ν its summed form; τ seconds per step, Matlab).
PAPER_TABLE: dict[str, tuple[float, float, float]] = {
    "nees_paper": (1.66e-6, 4.66e-7, 1.02e-6),
    "nu": (0.17, 0.19, 0.34),
    "tau_s": (0.61, 0.66, 0.62),
}
#: Per-robot metrics in the table, in order (the map metrics place each map by the robot's
#: true start, ``nu_mean_abs`` by its frame; the paper's setting has no initial error, so the
#: two coincide; ``has_map`` is the fraction of runs in which the robot had a map).
TABLE_KEYS = (
    "nees_paper",
    "nees",
    *QUALITY_KEYS,
    "slam_time_ms",
    "bytes_sent",
    "bytes_received",
    "rendezvous",
)
#: The metrics of r3's lone shadow SLAM (single- vs multi-robot), in order.
SINGLE_KEYS = (
    "nees_paper",
    "nees",
    "nu",
    "nu_mean",
    "completeness",
    "completeness_seen",
    "map_precision",
    "duplicates",
    "slam_time_ms",
)
SINGLE_ROBOT = 2  # r3: the robot of the paper's Fig 8


@dataclass(frozen=True)
class ReproduceConfig(Config):
    """Every parameter of the paper's §4 (``configs/paper.yaml``)."""

    map: str = "paper"
    num_robots: int = 3
    steps: int = 200  # k_f
    runs: int = 100
    initial_error: bool = False  # the paper's setting: each robot starts at its frame origin
    world: WorldConfig = field(default_factory=WorldConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    channel: ChannelConfig = field(default_factory=ChannelConfig)

    def validate(self) -> None:
        for name in ("num_robots", "steps", "runs"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}: must be >= 1, got {getattr(self, name)}")
        if self.num_robots <= SINGLE_ROBOT:
            raise ConfigError(f"num_robots: the paper's comparison needs r3, got {self.num_robots}")


def default_config() -> ReproduceConfig:
    """The shipped ``configs/paper.yaml``."""
    return ReproduceConfig.from_yaml(configs_dir() / "paper.yaml")


@dataclass
class RunResult:
    """What one seed contributes: metrics per robot, r3 without exchange, bytes per meeting."""

    seed: int
    metrics: list[dict[str, float]]
    single: dict[str, float]  # r3's shadow SLAM: same episode, no exchange
    messages: list[dict[str, Any]]  # delivered messages (sender, receiver, bytes, ...)
    result: SimulationResult | None = None  # kept only when asked (figures)


@functools.cache
def _study_map(name: str) -> Layout:
    """The study's map, read once per process: parsing its YAML took ~10 % of a run (the
    layout is read-only, so every run of the process shares it)."""
    return load_map(name)


def run_one(config: ReproduceConfig, seed: int, keep: bool = False) -> RunResult:
    """One seeded run with exchange and the r3 shadow."""
    result = simulate(
        _study_map(config.map),
        num_robots=config.num_robots,
        steps=config.steps,
        seed=seed,
        world_config=config.world,
        slam_config=config.slam,
        initial_error=config.initial_error,
        exchange=config.channel,
        shadow=(SINGLE_ROBOT,),
    )
    shadow = result.shadow_runs[SINGLE_ROBOT]
    return RunResult(
        seed=seed,
        metrics=result.metrics(),
        single=robot_metrics(shadow, result.layout),
        messages=list(result.meta.get("exchange", [])),
        result=result if keep else None,
    )


def _run_job(job: tuple[ReproduceConfig, int, bool]) -> RunResult:
    return run_one(*job)


def reproduce(
    config: ReproduceConfig,
    workers: int | Runner = 2,
    seeds: Sequence[int] | None = None,
    progress: Callable[[int], None] | None = None,
    keep: Sequence[int] = (),
) -> list[RunResult]:
    """All runs (seeds 0..runs−1 unless given), in ``workers`` processes (or as its
    :class:`Runner` says), in seed order, a run that failed left out; the runs of the seeds
    in ``keep`` also keep their simulation (for the figures, so that the figure run is not
    simulated a second time; not with a results log, which holds plain data only)."""
    seeds = list(range(config.runs)) if seeds is None else list(seeds)
    jobs = [(config, s, s in keep) for s in seeds]
    # One run per round trip: a run takes ~0.1–1 s, a round trip ~1 ms, while a chunk of
    # several runs left at the end keeps one worker busy alone (100 runs in chunks of 6 on 2
    # workers: up to 6 runs' time with the other core idle).
    return succeeded(run_jobs(_run_job, jobs, workers, progress, seed_of=lambda job: job[1]))


def summarise(runs: Sequence[RunResult]) -> dict[str, Any]:
    """Mean ± std per robot and metric, r3 single vs multi, exchange checks, bytes."""
    n_robots = len(runs[0].metrics)
    table: dict[str, list[dict[str, float]]] = {}
    for key in TABLE_KEYS:
        table[key] = []
        for robot in range(n_robots):
            v = np.array([r.metrics[robot][key] for r in runs], dtype=float)
            table[key].append(_stats(v))
    single = {key: _stats(np.array([r.single[key] for r in runs])) for key in SINGLE_KEYS}
    rendezvous = np.array([[r.metrics[i]["rendezvous"] for i in range(n_robots)] for r in runs])
    per_meeting = [m["bytes"] for r in runs for m in r.messages]
    multi_c = np.array([r.metrics[SINGLE_ROBOT]["completeness"] for r in runs])
    single_c = np.array([r.single["completeness"] for r in runs])
    return {
        "runs": len(runs),
        "table": table,
        "r3_single": single,
        "checks": {
            "r1_never_exchanges": bool(np.all(rendezvous[:, 0] == 0)),
            "r2_r3_meet_once": bool(np.all(rendezvous[:, 1:3] == 1)),
            "r3_multi_beats_single_completeness": bool(multi_c.mean() > single_c.mean()),
            "r3_multi_beats_single_fraction_of_runs": float(np.mean(multi_c > single_c)),
        },
        "bytes_per_message": _stats(np.array(per_meeting, dtype=float)) if per_meeting else None,
        "paper": {k: list(v) for k, v in PAPER_TABLE.items()},
    }


def _stats(v: np.ndarray) -> dict[str, float]:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": float("nan"), "std": float("nan"), "min": float("nan"), "max": float("nan")}
    return {
        "mean": float(v.mean()),
        "std": float(v.std()),
        "min": float(v.min()),
        "max": float(v.max()),
    }


def table_rows(summary: dict[str, Any]) -> list[list[str]]:
    """The printed table: metric, r1, r2, r3 (mean ± std), paper r1 / r2 / r3."""
    rows = []
    paper = {"nees_paper": "nees_paper", "nu": "nu", "slam_time_ms": "tau_s"}
    for key in TABLE_KEYS:
        cells = [f"{s['mean']:.3g} ± {s['std']:.2g}" for s in summary["table"][key]]
        ref = summary["paper"].get(paper.get(key, ""), None)
        ref_text = " / ".join(f"{v:.3g}" for v in ref) if ref else ""
        if key == "slam_time_ms" and ref:
            ref_text += " s (Matlab)"
        rows.append([key, *cells, ref_text])
    return rows


def write_csv(path: Path, summary: dict[str, Any]) -> None:
    """One line per (metric, robot): mean, std, min, max, paper value."""
    from polyslam_env.core.io import write_atomic

    lines = ["metric,robot,mean,std,min,max,paper"]
    paper = {"nees_paper": "nees_paper", "nu": "nu", "slam_time_ms": "tau_s"}
    for key in TABLE_KEYS:
        for robot, s in enumerate(summary["table"][key]):
            ref = summary["paper"].get(paper.get(key, ""))
            ref_v = "" if ref is None else f"{ref[robot]:.6g}"
            lines.append(
                f"{key},r{robot + 1},{s['mean']:.6g},{s['std']:.6g},{s['min']:.6g},"
                f"{s['max']:.6g},{ref_v}"
            )
    for key, s in summary["r3_single"].items():
        lines.append(
            f"{key},r3_single,{s['mean']:.6g},{s['std']:.6g},{s['min']:.6g},{s['max']:.6g},"
        )
    write_atomic(path, "\n".join(lines) + "\n")


def plot_figures(run: RunResult, out: Path) -> list[Path]:
    """Figs 5–7 (one panel per robot, with exchange) and Fig 8 (r3 single vs multi)."""
    from polyslam_env.render.plots import plot_runs

    assert run.result is not None, "run_one(..., keep=True) keeps the simulation for figures"
    result = run.result
    paths = [
        plot_runs(
            result.layout,
            result.runs,
            out / "figs5-7_multi_robot.png",
            titles=[f"Fig {5 + i}: r{i + 1}, multi-robot" for i in range(len(result.runs))],
        ),
        plot_runs(
            result.layout,
            [result.shadow_runs[SINGLE_ROBOT], result.runs[SINGLE_ROBOT]],
            out / "fig8_r3_single_vs_multi.png",
            titles=["Fig 8: r3 single-robot (no exchange)", "r3 multi-robot (with exchange)"],
        ),
    ]
    return paths

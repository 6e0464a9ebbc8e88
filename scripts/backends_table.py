"""Every ``slam.backend`` on the same seeds: a frontier team of 3 on ``generator:pillar_hall``.

Runs ``configs/pillar_backends.yaml`` once per back-end (only ``slam.backend`` changes; for the
polynomial EKF the channel's 25 m is its camera rendezvous range cap, the camera's 1.5 m
range decides) with ``polyslam evaluate``'s episode runner, in 2 processes, and prints one
markdown row per back-end: mean over robots and episodes (± std over episodes of the robots'
mean) of the pose error, the landmark error (point back-ends) or ``nu_mean`` (polynomial
walls), NEES (with the start error, ``nees``; the filter's own, ``nees_rel``), bytes sent per
robot, SLAM time per robot-step, and the team coverage.

Usage: ``python scripts/backends_table.py [--episodes 10] [--seed 0] [--json PATH]``
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from polyslam_env.apps.rollout import EpisodeResult, evaluate_episode
from polyslam_env.core.io import write_json
from polyslam_env.metrics.episode import meaningful
from polyslam_env.slam.config import BACKENDS

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "pillar_backends.yaml"
COLUMNS = (
    "pose_error",
    "landmark_error",
    "nu_mean",
    "nees",
    "nees_rel",
    "bytes_sent",
    "slam_time_ms",
)


def episode_means(result: EpisodeResult) -> dict[str, float]:
    """The robots' mean of each column (over the robots it is meaningful for) and the team
    coverage, for one episode."""
    out = {}
    for key in COLUMNS:
        values = meaningful(result.robots.values(), key)
        out[key] = float(np.mean(values)) if values else float("nan")
    out["coverage"] = float(result.team["coverage"])
    return out


def run(episodes: int, seed: int) -> dict[str, list[dict[str, float]]]:
    base: dict[str, Any] = yaml.safe_load(CONFIG.read_text())
    seeds = [seed + k for k in range(episodes)]
    out: dict[str, list[dict[str, float]]] = {}
    with ProcessPoolExecutor(max_workers=2) as pool:
        for backend in BACKENDS:
            config = {**base, "slam": {**base["slam"], "backend": backend}}
            jobs = [pool.submit(evaluate_episode, config, "frontier", {}, s) for s in seeds]
            out[backend] = [episode_means(job.result()) for job in jobs]
            print(f"{backend}: {episodes} episodes done", flush=True)
    return out


def cell(values: list[float], digits: int) -> str:
    a = np.array([v for v in values if np.isfinite(v)])
    if len(a) == 0:
        return "—"
    return f"{a.mean():.{digits}f} ± {a.std():.{digits}f}"


def table(rows: dict[str, list[dict[str, float]]]) -> str:
    head = (
        "| slam.backend | pose error (m) | landmark error (m) | nu_mean (m) | nees | nees_rel"
        " | bytes sent | SLAM ms/step | team coverage |"
    )
    lines = [head, "|" + "---|" * 9]
    for backend, episodes in rows.items():
        col = {k: [e[k] for e in episodes] for k in (*COLUMNS, "coverage")}
        cells = [
            cell(col["pose_error"], 3),
            cell(col["landmark_error"], 3),
            cell(col["nu_mean"], 3),
            cell(col["nees"], 1),
            cell(col["nees_rel"], 1),
            cell(col["bytes_sent"], 0),
            cell(col["slam_time_ms"], 2),
            cell(col["coverage"], 3),
        ]
        lines.append(f"| {backend} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="also write the per-episode values here")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes: must be >= 1, got {args.episodes}")
    rows = run(args.episodes, args.seed)
    print(table(rows))
    if args.json:
        print(f"wrote {write_json(args.json, rows)}")


if __name__ == "__main__":
    main()

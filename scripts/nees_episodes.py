"""NEES over whole episodes: seeded frontier runs, pose NEES at every step.

For each seed, one env episode with a frontier team; at every step and for every robot the
standard pose NEES is computed twice: in the robot's frame (covariance ``pose_cov``; the error
includes the unobservable start offset when ``--initial-error`` is on) and relative to the
robot's true start (``pose_cov_relative``: the filter's own consistency). Prints the mean NEES
at the final step and over the episode next to the two-sided 95 % band of the mean of
runs × robots χ²(3) variables (exact for independent runs: one robot, no exchange).

Usage::

    python scripts/nees_episodes.py --map generator:office_floor --runs 20 --steps 400 \\
        --robots 1 --initial-error

``--set slam.update_spacing_deg=0 ...`` overrides env config fields (as ``paired_slam.py``'s
``--a``).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import numpy as np
import scipy.stats
from paired_slam import setting  # scripts/ is on the path when a script runs

from policies.base import make_team
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env


def _nees(err: np.ndarray, cov: np.ndarray) -> float:
    err = err.copy()
    err[2] = wrap_remainder(float(err[2]))
    return float(err @ np.linalg.solve(cov, err))


def env_config(
    map_name: str,
    steps: int,
    robots: int,
    initial_error: bool,
    exchange: bool,
    shape_rotation: str = "considered",
    overrides: tuple[str, ...] = (),
) -> dict[str, Any]:
    """The env config of the runs; ``overrides``: ``KEY=VALUE`` fields
    (``paired_slam.setting``: a ``ConfigError`` names a bad one)."""
    kw: dict[str, Any] = {} if exchange else {"channel": None}
    base = EnvConfig.from_dict(
        {
            "map": map_name,
            "num_robots": robots,
            "max_steps": steps,
            "coverage_target": None,
            "initial_error": initial_error,
            "slam": {"shape_rotation": shape_rotation},
            **kw,
        }
    ).to_dict()
    return setting(base, list(overrides))


def episode(seed: int, config: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Per-step NEES (steps, robots) in the frame and relative to the true start."""
    env = parallel_env(EnvConfig.from_dict(config))
    team = make_team("frontier", env)
    obs, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = np.random.default_rng([seed, 1])
    state = env.unwrapped.episode
    frame, rel = [], []
    while env.agents:
        obs, *_ = env.step(team.act(obs, rng))
        row_f, row_r = [], []
        for i, slam in enumerate(state.slams):
            truth = state.world.poses[i]
            in_frame = between(state.start_poses[i], truth, wrap_remainder)
            from_start = between(state.histories[i].true[0], truth, wrap_remainder)
            row_f.append(_nees(in_frame - slam.pose, slam.pose_cov))
            row_r.append(_nees(from_start - slam.pose, slam.pose_cov_relative))
        frame.append(row_f)
        rel.append(row_r)
    env.close()
    return np.array(frame), np.array(rel)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--map", default="generator:office_floor")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--robots", type=int, default=1)
    ap.add_argument("--initial-error", action="store_true")
    ap.add_argument("--exchange", action="store_true", help="map exchange on (runs correlate)")
    ap.add_argument(
        "--shape-rotation",
        choices=("considered", "heading"),
        default="considered",
        help="slam.shape_rotation (heading: the rotation is the current heading error)",
    )
    ap.add_argument(
        "--set", nargs="*", default=[], help="KEY=VALUE env config overrides (slam.eps_z=10)"
    )
    args = ap.parse_args()
    start = time.perf_counter()
    finals_f, finals_r, means_f, means_r = [], [], [], []
    try:
        config = env_config(
            args.map,
            args.steps,
            args.robots,
            args.initial_error,
            args.exchange,
            args.shape_rotation,
            tuple(args.set),
        )
    except ConfigError as exc:  # a bad override: say which, in one line
        sys.exit(f"nees_episodes: --set: {exc}")
    for seed in range(args.runs):
        f, r = episode(seed, config)
        finals_f += f[-1].tolist()
        finals_r += r[-1].tolist()
        means_f += f.mean(axis=0).tolist()
        means_r += r.mean(axis=0).tolist()
        print(f"seed {seed}: final NEES frame {np.round(f[-1], 2)} relative {np.round(r[-1], 2)}")
    n = len(finals_f)
    lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 3 * n) / n
    print(
        f"{args.runs} runs × {args.robots} robots, {args.steps} steps on {args.map},"
        f" initial_error={args.initial_error}, {time.perf_counter() - start:.0f} s"
    )
    print(
        f"final-step mean NEES: frame {np.mean(finals_f):.2f}, relative {np.mean(finals_r):.2f}"
        f"  (95 % band of the mean of {n}: {lo:.2f}–{hi:.2f})"
    )
    print(f"episode-mean NEES:    frame {np.mean(means_f):.2f}, relative {np.mean(means_r):.2f}")


if __name__ == "__main__":
    main()

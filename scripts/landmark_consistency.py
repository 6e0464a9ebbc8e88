"""Are the landmarks' own uncertainties honest? Per-landmark NEES at the end of whole episodes.

For each seed, one fidelity episode (``polyslam fidelity``'s setting: a frontier team of
``--robots`` on a generated map, ``--steps`` steps, initial error on; the exchange off unless
``--exchange``). At the end, every landmark of every robot's map is compared with the true wall
it lies on, in the robot's **true-start** frame (where its filter lives, ``PolySlam``'s
docstring), at points every ``1/SAMPLES`` of its extent:

* offset: the mean of (true η − mapped η) at the same ξ, the error of its c0 (a rigid shift
  along η), against c0's variance in the filter: c0 NEES, χ²(1) for a consistent filter;
* turn: the slope of that difference along ξ (as an angle), the error of its shape rotation α,
  against α's variance (landmarks of at least ``--min-length`` m): α NEES, χ²(1) likewise.

A robot's landmarks share its pose error, so the mean over one map is not a mean of
independent values; its variance is still at most Var χ²(1) = 2. Over R robots of independent
runs the mean of the per-robot means then lies within 1 ± 1.96·√(2/R) (a normal band,
conservative for that reason) when the filter is consistent. Also printed: the RMS turn error
and RMS α standard deviation (degrees) of the long landmarks, and the heading's standard
deviation relative to the true start at the end, which together say how well walls can hold
the heading.

Usage::

    python scripts/landmark_consistency.py --map warehouse --seeds 10
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from policies.base import make_team
from polyslam_env.apps.fidelity import FidelityConfig, episode_config
from polyslam_env.apps.rollout import run_episode
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import inverse, transform_points
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.metrics.boundary import boundary_samples
from polyslam_env.slam.config import MERGE_TURNS, SlamConfig
from polyslam_env.slam.links import line_angle, off_square
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.generators import GENERATORS

SAMPLES = 60  # points per landmark
XI_TOL = 0.005  # m: a true boundary point at the same ξ
ETA_REACH = 0.4  # m: ... and at most this far from the mapped η (else: another wall)


def wall_errors(poly: Polynomial, boundary: np.ndarray) -> tuple[float, float, int] | None:
    """(offset m, turn rad, points matched) of ``poly`` against the true ``boundary`` points
    (M, 2) in the same frame; None with fewer than half its sample points matched."""
    xi = np.linspace(poly.lo, poly.hi, SAMPLES)
    eta = poly.value(xi)
    bxi, beta = poly.from_xy(boundary)
    where, diffs = [], []
    for x, e in zip(xi, eta, strict=True):
        near = (np.abs(bxi - x) < XI_TOL) & (np.abs(beta - e) < ETA_REACH)
        if near.any():
            d = beta[near] - e
            diffs.append(float(d[np.argmin(np.abs(d))]))
            where.append(float(x))
    if len(diffs) < SAMPLES // 2:
        return None
    slope = float(np.polyfit(where, diffs, 1)[0])
    mean_slope = float(np.mean(poly.slope(np.asarray(where))))
    return float(np.mean(diffs)), slope / (1.0 + mean_slope**2), len(diffs)


def square_turn_error(poly: Polynomial, frame_heading: float) -> float:
    """Turn error (rad) of straight ``poly`` in a frame whose heading in the world is
    ``frame_heading``, where every true wall runs along an axis (the generators' maps): its
    direction's distance from the nearest multiple of 90°."""
    return off_square(line_angle(poly) + frame_heading)


def robot_report(
    env: object, i: int, min_length: float, square_truth: bool = False
) -> dict[str, float]:
    state = env.episode  # type: ignore[attr-defined]
    slam = state.slams[i]
    true_start = state.histories[i].true[0]
    boundary = transform_points(
        boundary_samples(state.world.layout, XI_TOL)[0], inverse(true_start)
    )
    polys = slam.polynomials()
    n = len(polys)
    rotations = slam.config.rotation_states
    c0_nees, a_nees, a_err, a_sd = [], [], [], []
    for j, poly in enumerate(polys):
        found = wall_errors(poly, boundary)
        if found is None:
            continue
        offset, turn, _ = found
        if square_truth and slam.table.order[j] == 1:
            turn = square_turn_error(poly, float(true_start[2]))
        c0_nees.append(offset * offset / slam.cov[3 + j, 3 + j])
        if rotations and poly.length() >= min_length:
            var = slam.cov[3 + n + j, 3 + n + j]
            a_nees.append(turn * turn / var)
            a_err.append(turn)
            a_sd.append(np.sqrt(var))
    return {
        "c0_nees": float(np.mean(c0_nees)) if c0_nees else np.nan,
        "alpha_nees": float(np.mean(a_nees)) if a_nees else np.nan,
        "alpha_err_deg": float(np.degrees(np.sqrt(np.mean(np.square(a_err))))) if a_err else np.nan,
        "alpha_sd_deg": float(np.degrees(np.sqrt(np.mean(np.square(a_sd))))) if a_sd else np.nan,
        "heading_sd_deg": float(np.degrees(np.sqrt(slam.pose_cov_relative[2, 2]))),
        "landmarks": float(len(c0_nees)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", default="warehouse", help="a layout generator (warehouse)")
    parser.add_argument("--seeds", type=int, default=10, help="episodes, seeds 0.. (10)")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--exchange", action="store_true", help="the map exchange on")
    parser.add_argument("--min-length", type=float, default=1.0, help="m, for the turn (1.0)")
    parser.add_argument(
        "--merge-turn",
        choices=MERGE_TURNS,
        default=SlamConfig().merge_turn,
        help="slam.merge_turn: how a merged landmark's turn is made (default: the config's)",
    )
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="env config fields on every episode, as polyslam fidelity --set"
        " (slam.square_walls=false)",
    )
    parser.add_argument(
        "--square-truth",
        action="store_true",
        help="a straight landmark's turn error is its direction's distance from the nearest"
        " multiple of 90° in the true frame (exact on the generators' maps, whose walls all"
        " run along the axes); the default fit to nearby boundary points takes a shelf"
        " corner's perpendicular face for the wall at a short landmark's end",
    )
    args = parser.parse_args(argv)
    if args.map not in GENERATORS:
        print(f"--map: {args.map!r} is not a layout generator; valid: {', '.join(GENERATORS)}")
        return 2
    if args.seeds < 1:
        print(f"--seeds: must be >= 1, got {args.seeds}")
        return 2
    try:
        config = FidelityConfig(
            maps=(args.map,),
            robots=args.robots,
            steps=args.steps,
            env_set=(f"slam.merge_turn={args.merge_turn}", *args.set),
        )
        env = parallel_env(EnvConfig.from_dict(episode_config(config, args.map, args.exchange)))
    except ConfigError as err:
        print(err)
        return 2
    began = time.perf_counter()
    rows = []
    for seed in range(args.seeds):
        run_episode(env, make_team("frontier", env), seed)
        for i in range(args.robots):
            rows.append(robot_report(env, i, args.min_length, args.square_truth))
        print(f"seed {seed} done ({time.perf_counter() - began:.0f} s)", file=sys.stderr)
    keys = list(rows[0])
    table = {k: np.array([r[k] for r in rows]) for k in keys}
    count = len(rows)
    half = 1.96 * np.sqrt(2.0 / count)
    print(
        f"{args.map}, {args.seeds} seeds × {args.robots} robots, {args.steps} steps, exchange"
        f" {'on' if args.exchange else 'off'}; per robot, then mean over the {count} robots:"
    )
    for k in keys:
        v = table[k][np.isfinite(table[k])]
        print(f"  {k:15s} mean {v.mean():7.3f}  min {v.min():7.3f}  max {v.max():7.3f}")
    print(
        f"a consistent filter: c0_nees and alpha_nees means within 1 ± {half:.2f}"
        f" ({1 - half:.2f}–{1 + half:.2f}) in 95 % of such runs"
    )
    print(f"{time.perf_counter() - began:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

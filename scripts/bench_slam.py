"""Benchmark one PolySlam.step against the number of landmarks in the map.

For each map size n (10, 30, 100, 300) a PolySlam gets n landmarks through the public
``insert_landmark``: three walls around the robot (y = ±0.5 m, x = 1 m, so all five beams
hit mapped walls and association + update run every step) and n − 3 short, slightly curved
cubic segments scattered 3–12 m away (out of range, but association and ray casting still
consider every landmark). The robot then shuttles back and forth along x with noisy
odometry and ranges cast on the true walls; after a warm-up, every step is timed.

Times are µs, median and IQR over the timed steps, next to references measured in the same
run (a 3×3 ``np.linalg.solve`` and a (3+n)² matrix-vector product) and the ratio to the
solve, so figures from a loaded machine compare. A second, separate pass turns on
PolySlam's profiling hook (when the implementation has one) for the per-stage breakdown.

    python scripts/bench_slam.py [--quick] [--json PATH] [--sizes 10 30 100 300]
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import compose
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.measurement import ray_intersections
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam

BEAM_ANGLES = np.radians([90.0, 45.0, 0.0, -45.0, -90.0])  # (5,) the default sensor
MAX_RANGE = 2.0
RANGE_SIGMA = 0.02
ODOM_SIGMA = 0.001
SHUTTLE = 20  # steps forward, then as many back
STEP_DX = 0.01  # m per step


# -- the map ----------------------------------------------------------------------------------
def _local_cubic(xi_c: float, eta_c: float, slope: float, k2: float, k3: float) -> np.ndarray:
    """[c0, b1, b2, b3] of η = η_c + s(ξ−ξ_c) + k2(ξ−ξ_c)² + k3(ξ−ξ_c)³ in powers of ξ."""
    shifted = np.polynomial.polynomial.Polynomial([0.0, 1.0]) - xi_c
    p = eta_c + slope * shifted + k2 * shifted**2 + k3 * shifted**3
    coeffs = np.zeros(4)
    coeffs[: len(p.coef)] = p.coef
    return coeffs


def make_walls(n: int, rng: np.random.Generator) -> list[Polynomial]:
    """Three walls around the origin, then n − 3 short cubics 3–12 m away."""
    walls = [
        Polynomial(1, np.array([0.5, 0.0, 0.0, 0.0]), -1.5, 0.9),
        Polynomial(1, np.array([-0.5, 0.0, 0.0, 0.0]), -1.5, 0.9),
        Polynomial(2, np.array([1.0, 0.0, 0.0, 0.0]), -0.45, 0.45),
    ]
    for _ in range(n - 3):
        radius, bearing, heading = (
            rng.uniform(3.0, 12.0),
            rng.uniform(-np.pi, np.pi),
            rng.uniform(0, np.pi),
        )
        centre = radius * np.array([np.cos(bearing), np.sin(bearing)])
        variate = 1 if abs(np.cos(heading)) >= abs(np.sin(heading)) else 2
        xi_c, eta_c = centre if variate == 1 else centre[::-1]
        slope = np.tan(heading) if variate == 1 else 1.0 / np.tan(heading)
        coeffs = _local_cubic(xi_c, eta_c, slope, rng.normal(0, 0.3), rng.normal(0, 0.3))
        half = 0.25 / np.sqrt(1.0 + slope**2)
        walls.append(Polynomial(variate, coeffs, xi_c - half, xi_c + half))
    return walls


def make_slam(walls: list[Polynomial]) -> PolySlam:
    """A PolySlam at the origin whose map holds ``walls`` (inserted without merging)."""
    slam = PolySlam(SlamConfig(), BEAM_ANGLES, MAX_RANGE)
    for wall in walls:
        n_state = slam.mean.size
        gx = np.zeros((1, n_state))
        gx[0, 1 if wall.variate == 1 else 0] = 1.0  # c0 moves with the pose's η
        gx[0, 2] = 0.1  # and a little with its heading
        fit = Fit(
            poly=wall,
            c0=wall.c0,
            Gx=gx,
            Gy=np.ones((1, 1)),
            V=np.array([[RANGE_SIGMA**2]]),
            rms=0.025,
            order=wall.order,
        )
        slam.insert_landmark(fit, merge=False)
    return slam


# -- inputs ---------------------------------------------------------------------------------
def make_inputs(
    walls: list[Polynomial], steps: int, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(odometry (3,), ranges (5,)) per step of the shuttle, ranges cast on the true walls."""
    c0s = np.array([w.c0 for w in walls])
    pose = np.zeros(3)
    out = []
    for k in range(steps):
        direction = 1.0 if (k // SHUTTLE) % 2 == 0 else -1.0
        motion = np.array([direction * STEP_DX, 0.0, 0.0])
        pose = compose(pose, motion)
        odometry = motion + rng.normal(0.0, ODOM_SIGMA, 3) * np.array([1.0, 1.0, 0.01])
        hits = ray_intersections(pose, BEAM_ANGLES, walls, c0s, MAX_RANGE)
        ranges = hits.ranges + rng.normal(0.0, RANGE_SIGMA, BEAM_ANGLES.size)
        out.append((odometry, ranges))
    return out


# -- timing ---------------------------------------------------------------------------------
def _stats(samples: list[float]) -> dict[str, float]:
    """Median and IQR in µs."""
    q25, q50, q75 = np.percentile(np.array(samples) * 1e6, [25, 50, 75])
    return {"median_us": float(q50), "iqr_us": float(q75 - q25)}


def _time_call(fn: Callable[[], Any], repeats: int) -> dict[str, float]:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - start)
    return _stats(samples)


def references(n: int, repeats: int, rng: np.random.Generator) -> dict[str, dict[str, float]]:
    a = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    b = rng.normal(size=3)
    m = rng.normal(size=(3 + n, 3 + n))
    v = rng.normal(size=3 + n)
    return {
        "solve3": _time_call(lambda: np.linalg.solve(a, b), repeats),
        "matvec": _time_call(lambda: m @ v, repeats),
    }


def bench_size(n: int, warmup: int, repeats: int, seed: int) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    walls = make_walls(n, rng)
    inputs = make_inputs(walls, warmup + 2 * repeats, rng)
    slam = make_slam(walls)
    for odometry, ranges in inputs[:warmup]:
        slam.step(odometry, ranges)
    samples, used, created = [], 0, 0
    for odometry, ranges in inputs[warmup : warmup + repeats]:
        start = time.perf_counter()
        info = slam.step(odometry, ranges)
        samples.append(time.perf_counter() - start)
        used += info.beams_used
        created += info.created + info.refit + info.merged
    result: dict[str, Any] = {
        "n": n,
        "landmarks": slam.n_landmarks,
        "step": _stats(samples),
        "beams_used_per_step": used / repeats,
        "map_changes": created,
        "reference": references(n, max(repeats, 200), rng),
        "stages": profile_stages(slam, inputs[warmup + repeats :]),
    }
    result["ratio_to_solve3"] = (
        result["step"]["median_us"] / result["reference"]["solve3"]["median_us"]
    )
    return result


def profile_stages(slam: PolySlam, inputs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Median µs per stage with the profiling hook on ({} if the implementation has none)."""
    if not hasattr(slam, "profile"):
        return {}
    slam.profile = {}
    for odometry, ranges in inputs:
        slam.step(odometry, ranges)
    stages = {name: _stats(times)["median_us"] for name, times in slam.profile.items()}
    slam.profile = None
    return stages


def _print(results: list[dict[str, Any]]) -> None:
    print(
        f"{'n':>5} {'step µs':>9} {'IQR':>7} {'solve3 µs':>9} {'ratio':>7} {'matvec µs':>9}"
        f" {'beams':>6}  stages (median µs)"
    )
    for r in results:
        ref = r["reference"]
        stages = "  ".join(f"{k} {v:.0f}" for k, v in r["stages"].items())
        print(
            f"{r['landmarks']:>5} {r['step']['median_us']:>9.1f} {r['step']['iqr_us']:>7.1f}"
            f" {ref['solve3']['median_us']:>9.2f} {r['ratio_to_solve3']:>7.1f}"
            f" {ref['matvec']['median_us']:>9.2f} {r['beams_used_per_step']:>6.2f}  {stages}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (fewer steps)")
    parser.add_argument("--json", type=Path, help="write the results here")
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 30, 100, 300])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    warmup, repeats = (10, 40) if args.quick else (30, 300)
    results = [bench_size(n, warmup, repeats, args.seed) for n in args.sizes]
    _print(results)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

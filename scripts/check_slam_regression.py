"""Guard for SLAM speed work: the optimised PolySlam must reproduce a saved reference.

``--record`` runs ``simulate("paper", seed=s)`` and ``simulate("cave", num_robots=1, seed=s)``
for seeds 0, 1, 2, captures every robot's SLAM inputs (odometry, ranges per step) and outputs
(est_poses, est_covs, the final polynomials, the final full mean/cov) and saves them.

The default mode checks. It replays the saved inputs through fresh :class:`PolySlam`
instances (so edits elsewhere in the tree, e.g. to the world or simulate, cannot mask or fake
a SLAM change) and, with ``--simulate``, also reruns simulate itself. Every quantity must match
to ``--atol`` (1e-9) absolute; the largest difference per quantity is printed.

    python scripts/check_slam_regression.py --record      # once, before optimising
    python scripts/check_slam_regression.py               # after every change
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.simulate import simulate
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import WorldConfig

REFERENCE = Path("/tmp/slam_regression_reference.pkl")
SEEDS = (0, 1, 2)
RUNS: tuple[tuple[str, dict[str, Any]], ...] = (("paper", {}), ("cave", {"num_robots": 1}))

Record = dict[str, Any]


def _poly_arrays(slam: PolySlam) -> dict[str, np.ndarray]:
    """Final map as arrays: variates (n,), coefficients (n, m+1), extents (n, 2)."""
    polys = slam.polynomials()
    return {
        "variate": np.array([p.variate for p in polys], dtype=int),
        "coeffs": np.array([p.coeffs for p in polys], dtype=float).reshape(len(polys), -1),
        "extent": np.array([[p.lo, p.hi] for p in polys], dtype=float).reshape(len(polys), 2),
        "ids": np.array(slam.landmark_ids, dtype=int),
    }


def _outputs(slam: PolySlam, poses: list[np.ndarray], covs: list[np.ndarray]) -> Record:
    return {
        "est_poses": np.array(poses),
        "est_covs": np.array(covs),
        "mean": slam.mean.copy(),
        "cov": slam.cov.copy(),
        "diverging": slam.diverging,
        **_poly_arrays(slam),
    }


def _run_simulate(map_name: str, seed: int, kwargs: dict[str, Any]) -> list[Record]:
    """simulate() with every PolySlam.step's inputs captured; one record per robot."""
    inputs: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    original = PolySlam.step

    def recording_step(self: PolySlam, odometry: np.ndarray, ranges: np.ndarray) -> Any:
        inputs.setdefault(id(self), []).append(
            (np.array(odometry, dtype=float), np.array(ranges, dtype=float))
        )
        return original(self, odometry, ranges)

    PolySlam.step = recording_step  # type: ignore[method-assign]
    try:
        result = simulate(map_name, seed=seed, **kwargs)
    finally:
        PolySlam.step = original  # type: ignore[method-assign]
    records = []
    for run, odo_ranges in zip(result.runs, inputs.values(), strict=True):
        polys = run.polynomials
        records.append(
            {
                "odometry": np.array([o for o, _ in odo_ranges]),
                "ranges": np.array([r for _, r in odo_ranges]),
                "est_poses": run.est_poses,
                "est_covs": run.est_covs,
                "variate": np.array([p.variate for p in polys], dtype=int),
                "coeffs": np.array([p.coeffs for p in polys]).reshape(len(polys), -1),
                "extent": np.array([[p.lo, p.hi] for p in polys]).reshape(len(polys), 2),
            }
        )
    return records


def _replay(record: Record) -> Record:
    """Feed recorded inputs to a fresh PolySlam with the default configs."""
    wcfg = WorldConfig()
    slam = PolySlam(SlamConfig(), wcfg.range_sensor.angles, wcfg.range_sensor.max_range)
    poses, covs = [slam.pose], [slam.pose_cov]
    for odometry, ranges in zip(record["odometry"], record["ranges"], strict=True):
        slam.step(odometry, ranges)
        poses.append(slam.pose)
        covs.append(slam.pose_cov)
    return _outputs(slam, poses, covs)


def record() -> None:
    cases: dict[str, list[Record]] = {}
    for map_name, kwargs in RUNS:
        for seed in SEEDS:
            sims = _run_simulate(map_name, seed, kwargs)
            for rec in sims:
                rec["replay"] = _replay(rec)
                if not _same_arrays(rec, rec["replay"], ("est_poses", "est_covs")):
                    sys.exit(f"{map_name}/{seed}: replay differs from simulate; cannot record")
            cases[f"{map_name}/seed{seed}"] = sims
    REFERENCE.write_bytes(pickle.dumps(cases))
    print(f"reference of {len(cases)} runs saved to {REFERENCE}")


def _same_arrays(a: Record, b: Record, keys: tuple[str, ...]) -> bool:
    return all(np.array_equal(a[k], b[k]) for k in keys)


def _max_diff(a: Any, b: Any) -> float:
    """Largest absolute difference; inf when shapes (e.g. landmark counts) differ."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return float("inf")
    if a.size == 0:
        return 0.0
    a, b = a.astype(float), b.astype(float)
    same = (a == b) | (np.isnan(a) & np.isnan(b))  # equal infinities and nans count as equal
    with np.errstate(invalid="ignore"):
        diff = np.where(same, 0.0, np.abs(a - b))
    return float(np.max(np.nan_to_num(diff, nan=np.inf)))


def check(atol: float, with_simulate: bool) -> bool:
    cases: dict[str, list[Record]] = pickle.loads(REFERENCE.read_bytes())
    worst: dict[str, float] = {}
    ok = True
    start = time.perf_counter()
    for name, robots in cases.items():
        fresh = None
        if with_simulate:
            map_name, seed = name.split("/seed")
            fresh = _run_simulate(map_name, int(seed), dict(RUNS)[map_name])
        for i, rec in enumerate(robots):
            got = _replay(rec)
            ref = rec["replay"]
            pairs = [(k, ref[k], got[k]) for k in ref]
            if fresh is not None:
                pairs += [(f"sim.{k}", rec[k], fresh[i][k]) for k in rec if k != "replay"]
            for key, want, have in pairs:
                d = _max_diff(want, have)
                worst[key] = max(worst.get(key, 0.0), d)
                if d > atol:
                    ok = False
                    print(f"  MISMATCH {name} robot {i} {key}: max |diff| = {d:.3g}")
    for key, d in worst.items():
        print(f"  {key:16s} max |diff| = {d:.3g}")
    verdict = "OK" if ok else "FAILED"
    print(f"{verdict}: {len(cases)} runs, atol {atol:g}, {time.perf_counter() - start:.1f} s")
    return ok


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help="save the reference")
    parser.add_argument("--simulate", action="store_true", help="also rerun simulate()")
    parser.add_argument("--atol", type=float, default=1e-9)
    args = parser.parse_args()
    if args.record:
        record()
        return
    sys.exit(0 if check(args.atol, args.simulate) else 1)


if __name__ == "__main__":
    main()

"""Guard for env speed work: the optimised env must reproduce a saved reference episode.

``--record`` runs a few seeded episodes of :func:`polyslam_env.parallel_env` (vector and grid
observations, SLAM on and off, continuous random actions from a seeded generator) and saves
every step's observations, rewards, reward terms, terminations, truncations and the final
infos. The default mode reruns them and compares: every number must match to ``--atol``
(1e-9) absolute; the largest difference per quantity is printed.

    python scripts/check_env_regression.py --record      # once, before optimising
    python scripts/check_env_regression.py               # after every change
"""

from __future__ import annotations

import argparse
import pickle
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

import polyslam_env

REFERENCE = Path("/tmp/env_regression_reference.pkl")
STEPS = 150
RUNS: tuple[tuple[str, int, dict[str, Any]], ...] = (
    ("paper-vector", 0, {"map": "paper", "observation__mode": "vector"}),
    ("paper-vector", 1, {"map": "paper", "observation__mode": "vector"}),
    ("paper-grid", 2, {"map": "paper", "observation__mode": "grid"}),
    ("two_rooms-noslam", 3, {"map": "two_rooms", "slam_enabled": False}),
)


def episode(config: dict[str, Any], seed: int, steps: int) -> list[dict[str, Any]]:
    """Per step: what the env returned, as plain numbers and arrays."""
    env = polyslam_env.parallel_env(**config)
    observations, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out: list[dict[str, Any]] = [{"obs": observations}]
    for _ in range(steps):
        if not env.agents:
            break
        actions = {
            a: rng.uniform(env.action_space(a).low, env.action_space(a).high) for a in env.agents
        }
        obs, rewards, terms, truncs, infos = env.step(actions)
        out.append(
            {
                "obs": obs,
                "rewards": rewards,
                "terminations": terms,
                "truncations": truncs,
                "reward_terms": {a: infos[a].get("reward_terms") for a in infos},
            }
        )
    env.close()
    return out


def _leaves(value: Any, path: str = "") -> Iterator[tuple[str, Any]]:
    """(path, leaf) pairs of nested dicts/lists; leaves are numbers, bools, arrays or None."""
    if isinstance(value, dict):
        for key in sorted(value, key=str):
            yield from _leaves(value[key], f"{path}/{key}")
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from _leaves(item, f"{path}[{i}]")
    else:
        yield path, value


def _kind(path: str) -> str:
    """Quantity name of a leaf path for the report (the step index and agent dropped)."""
    parts = [p for p in path.split("/") if p and not p.startswith("robot_")]
    return "/".join(p.split("[")[0] for p in parts[1:3]) or path


def compare(reference: Any, current: Any, atol: float) -> dict[str, float]:
    """Largest absolute difference per quantity (inf where structure or values differ)."""
    worst: dict[str, float] = {}
    ref_leaves, cur_leaves = dict(_leaves(reference)), dict(_leaves(current))
    for path in ref_leaves.keys() | cur_leaves.keys():
        kind = _kind(path)
        if path not in ref_leaves or path not in cur_leaves:
            worst[kind] = float("inf")
            continue
        a, b = ref_leaves[path], cur_leaves[path]
        if a is None or b is None:
            diff = 0.0 if a is None and b is None else float("inf")
        else:
            x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
            if x.shape != y.shape:
                diff = float("inf")
            else:
                same_nan = np.isnan(x) & np.isnan(y)
                both_inf = np.isinf(x) & (x == y)
                d = np.where(same_nan | both_inf, 0.0, np.abs(x - y))
                diff = float(np.max(d, initial=0.0))
                diff = diff if np.isfinite(diff) else float("inf")
        worst[kind] = max(worst.get(kind, 0.0), diff)
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help="save a new reference")
    parser.add_argument("--atol", type=float, default=1e-9)
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument("--reference", type=Path, default=REFERENCE)
    args = parser.parse_args(argv)
    results = {
        f"{name}/seed{seed}": episode(config, seed, args.steps) for name, seed, config in RUNS
    }
    if args.record:
        args.reference.write_bytes(pickle.dumps(results))
        print(f"reference of {len(results)} episodes saved to {args.reference}")
        return 0
    reference = pickle.loads(args.reference.read_bytes())
    ok = True
    for key in reference:
        worst = compare(reference[key], results.get(key), args.atol)
        bad = {k: v for k, v in worst.items() if v > args.atol}
        ok &= not bad
        summary = ", ".join(f"{k} {v:.1e}" for k, v in sorted(worst.items()) if v > 0) or "exact"
        print(f"{'ok ' if not bad else 'BAD'} {key}: {summary}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""The env's reset on a fixed map, with the last world's walls reused and with a fresh space.

A reset on the same map hands the last world's pymunk space (its static walls and pillars) to
the new world (``World._take_space``) instead of building ~190 segments again; the episodes
are the same to the bit (``tests/world/test_physics.py``). This script times ``env.reset()``
both ways in turns, in one process, on the benchmark's paper env (``ENV_CONFIG``) and any
other map given, after an episode of random steps so the space has been used.

    python scripts/bench_reset.py [--map paper --map office ...] [--resets 200] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.benchmark_harness import ENV_CONFIG, Stats, random_stepper
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.world.physics import World

ROUNDS = 10  # turns of (reuse, fresh) blocks


def time_resets(map_name: str, resets: int, seed: int = 0) -> dict[str, Any]:
    """Median ms per reset, walls reused and a fresh space, each over ``ROUNDS`` blocks."""
    take = World._take_space
    reuse = [True]

    def maybe_take(world: World, old: World | None) -> Any:
        return take(world, old) if reuse[0] else None

    World._take_space = maybe_take  # type: ignore[method-assign]
    try:
        env = parallel_env(**{**ENV_CONFIG, "map": map_name})
        step = random_stepper(env, seed)
        for _ in range(100):  # a used space: contacts, arbiters, a grown index
            step()
        per_block = max(1, resets // (2 * ROUNDS))
        samples: dict[str, list[float]] = {"reuse": [], "fresh": []}
        for _ in range(ROUNDS):
            for label in ("reuse", "fresh"):
                reuse[0] = label == "reuse"
                start = time.perf_counter()
                for k in range(per_block):
                    env.reset(seed=seed + k)
                samples[label].append(1e3 * (time.perf_counter() - start) / per_block)
        env.close()
    finally:
        World._take_space = take  # type: ignore[method-assign]
    out: dict[str, Any] = {"map": map_name}
    for label, values in samples.items():
        out[f"{label}_ms"] = Stats.of(values).to_dict()
    out["fresh_over_reuse"] = float(np.median(samples["fresh"]) / np.median(samples["reuse"]))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", action="append", help="maps (default: paper)")
    parser.add_argument("--resets", type=int, default=200, help="resets per side (default 200)")
    parser.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = parser.parse_args(argv)
    if args.resets < 2 * ROUNDS:
        parser.error(f"--resets: at least {2 * ROUNDS}, got {args.resets}")
    rows = [time_resets(name, args.resets) for name in args.map or ["paper"]]
    print(f"{'map':<14}{'reuse ms':>10}{'fresh ms':>10}{'fresh/reuse':>13}")
    for row in rows:
        print(
            f"{row['map']:<14}{row['reuse_ms']['median']:>10.2f}{row['fresh_ms']['median']:>10.2f}"
            f"{row['fresh_over_reuse']:>13.2f}"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

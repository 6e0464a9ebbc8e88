"""Detection rate and delay of the divergence flag on injected faults, and its false alarms.

Runs the seeded trials of ``tests/slam/divergence_trials.py`` (one wall-following robot on a
generated 6 × 4 m rooms map, initial_error on, fault at step 60) and prints one table row per
scenario: how many runs flagged within 20 steps of the fault, the delays, and how many
flagged before the fault (false alarms); then the healthy episodes (no fault, 80 steps) in
which the flag ever fired. Run from the repository root::

    PYTHONPATH=. python scripts/divergence_rates.py --seeds 60 --jobs 1
"""

from __future__ import annotations

import argparse
import statistics
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from tests.slam.divergence_trials import (
    DEADLINE,
    FAULT_STEP,
    KIDNAP_05,
    KIDNAP_10,
    SLIP_05,
    detection_delay,
    first_alarm,
)

SCENARIOS: dict[str, dict[str, Any]] = {
    "kidnap 0.5 m": KIDNAP_05,
    "kidnap 1.0 m": KIDNAP_10,
    f"slip 0.5 x {DEADLINE} steps": SLIP_05,
}


def _trial(job: tuple[str, int]) -> tuple[str, int, int | None]:
    name, seed = job
    if name == "healthy":
        return name, seed, first_alarm(seed, None, FAULT_STEP + DEADLINE)
    return name, seed, detection_delay(seed, SCENARIOS[name])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=60, help="seeds 0 … N−1 per scenario")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    args = parser.parse_args()
    jobs = [(name, s) for name in [*SCENARIOS, "healthy"] for s in range(args.seeds)]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(_trial, jobs))
    print(f"fault at step {FAULT_STEP}, deadline {DEADLINE} steps, {args.seeds} seeds each")
    print(f"{'scenario':<24} {'detected':>9} {'rate':>6} {'median':>7} {'max':>4} {'early':>6}")
    for name in SCENARIOS:
        delays = [d for n, _, d in results if n == name]
        hits = [d for d in delays if d is not None and d >= 0]
        early = sum(d == -1 for d in delays)
        median = f"{statistics.median(hits):.0f}" if hits else "-"
        top = f"{max(hits)}" if hits else "-"
        count, rate = f"{len(hits)}/{len(delays)}", len(hits) / len(delays)
        print(f"{name:<24} {count:>9} {rate:>6.1%} {median:>7} {top:>4} {early:>6}")
    alarms = [(s, a) for n, s, a in results if n == "healthy" and a is not None]
    print(
        f"healthy ({FAULT_STEP + DEADLINE} steps): flag fired in {len(alarms)}/{args.seeds}"
        f" episodes {alarms}"
    )


if __name__ == "__main__":
    main()

"""Issue 42's done-criteria over a ``polyslam fidelity`` study: one markdown row per map.

``polyslam fidelity`` checks its own (older, looser) targets: ``nu_mean`` ≤ 0.05 m, the pose
``nees`` as a mean, 5 mm of exchange slack. The issue on real buildings and non-rectilinear
floors asks, of every robot with the exchange on: ``nu_mean`` ≤ 0.03 m, ``map_precision``
≥ 0.9, ``completeness_seen`` ≥ 0.8, ``duplicates`` ≤ 0.05, ``nees_rel`` ≤ 6 as a Monte Carlo
mean (per robot slot over the seeds; the largest is shown); team coverage ≥ 0.85; and, exchange
on against off (paired by seed and robot, mean ± 95 % t half-width), ``completeness_seen``
higher and ``nu_mean`` no more than 3 mm worse. With ``--against B``, also each map the two
studies share, exchange on, robot by robot paired by seed (this study − B): a variant (a
policy, a ``--set``) against the default. Usage::

    python scripts/floor_targets.py out/fidelity/summary.json [--against out/base/summary.json]
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from polyslam_env.metrics.statistics import paired_interval

NU_MAX, PRECISION_MIN, SEEN_MIN, DUPLICATES_MAX, NEES_REL_MAX, COVERAGE_MIN = (
    0.03, 0.9, 0.8, 0.05, 6.0, 0.85,
)  # fmt: skip
NU_SLACK_MM = 3.0


def map_row(name: str, on: Sequence[Mapping[str, Any]], off: Sequence[Mapping[str, Any]]) -> str:
    """The markdown row of one map: counts of robots meeting each target, the worst Monte
    Carlo mean of ``nees_rel``, teams meeting coverage, the paired exchange effects."""
    robots = [r for ep in on for r in ep["robots"].values()]
    slots = sorted(on[0]["robots"])

    def count(ok: Any) -> str:
        return f"{sum(bool(ok(r)) for r in robots)}/{len(robots)}"

    nees_rel = max(np.mean([ep["robots"][k]["nees_rel"] for ep in on]) for k in slots)
    teams = sum(ep["team"]["coverage"] >= COVERAGE_MIN for ep in on)
    by_seed = {ep["seed"]: ep for ep in off}
    seen, nu = [], []
    for ep in on:
        other = by_seed[ep["seed"]]
        for k in slots:
            a, b = ep["robots"][k], other["robots"][k]
            seen.append(a["completeness_seen"] - b["completeness_seen"])
            nu.append(1000.0 * (a["nu_mean"] - b["nu_mean"]))
    (ds, hs), (dn, hn) = paired_interval(seen), paired_interval(nu)
    return (
        f"| {name} | {on[0]['steps']} | {len(on)} | {count(lambda r: r['nu_mean'] <= NU_MAX)} | "
        f"{count(lambda r: r['map_precision'] >= PRECISION_MIN)} | "
        f"{count(lambda r: r['completeness_seen'] >= SEEN_MIN)} | "
        f"{count(lambda r: r['duplicates'] <= DUPLICATES_MAX)} | {nees_rel:.2f} | "
        f"{teams}/{len(on)} | {ds:+.3f} ± {hs:.3f} | {dn:+.2f} ± {hn:.2f} |"
    )


def table(summary: Mapping[str, Any]) -> str:
    head = (
        "| map | steps | seeds | `nu_mean` ≤ 0.03 | `map_precision` ≥ 0.9 | "
        "`completeness_seen` ≥ 0.8 | `duplicates` ≤ 0.05 | `nees_rel` MC mean, worst robot "
        "(≤ 6) | team coverage ≥ 0.85 | exchange on − off: `completeness_seen` (> 0) | "
        "`nu_mean` mm (≤ 3) |\n|---|---|---|---|---|---|---|---|---|---|---|"
    )
    rows = [
        map_row(name, by["exchange_on"], by["exchange_off"])
        for name, by in summary["episodes"].items()
    ]
    return "\n".join([head, *rows])


PAIRED = ("nu_mean", "map_precision", "completeness_seen", "nees_rel", "pose_error")


def against(summary: Mapping[str, Any], base: Mapping[str, Any]) -> str:
    """Per map both studies ran: each metric's mean in ``base`` and in ``summary``, and their
    difference paired by seed and robot (exchange on; seeds only one study ran are left
    out)."""
    lines = [
        "| map | metric | base | this | this − base (paired, 95 % t) | robots |",
        "|---|---|---|---|---|---|",
    ]
    for name, by in summary["episodes"].items():
        if name not in base["episodes"]:
            continue
        theirs = {ep["seed"]: ep for ep in base["episodes"][name]["exchange_on"]}
        pairs = [
            (ep["robots"][k], theirs[ep["seed"]]["robots"][k])
            for ep in by["exchange_on"]
            if ep["seed"] in theirs
            for k in sorted(ep["robots"])
        ]
        for metric in PAIRED:
            mine = [a[metric] for a, _ in pairs]
            ref = [b[metric] for _, b in pairs]
            d, h = paired_interval([x - y for x, y in zip(mine, ref, strict=True)])
            lines.append(
                f"| {name} | `{metric}` | {np.mean(ref):.4g} | {np.mean(mine):.4g} | "
                f"{d:+.4g} ± {h:.2g} | {len(pairs)} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("summary", help="a polyslam fidelity study's summary.json")
    parser.add_argument("--against", help="another study's summary.json to pair with")
    args = parser.parse_args()
    with open(args.summary) as f:
        summary = json.load(f)
    print(table(summary))
    if args.against:
        with open(args.against) as f:
            print()
            print(against(summary, json.load(f)))


if __name__ == "__main__":
    main()

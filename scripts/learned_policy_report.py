"""A policy against a baseline, paired by seed, from ``polyslam evaluate`` JSON files.

Reads the files that ``polyslam evaluate --policy frontier,random,ppo --json FILE`` wrote (one
per map), and prints, pooled over all their episodes:

* each policy's team coverage, team overlap and ``nu_mean`` (the robots' mean), and the last
  policy's ratio to the first (the baseline) and points above ``random`` (if it ran);
* the paired differences last − first per seed, with a 95 % t interval, of team coverage at
  the end and at step 200, overlap, ``nu_mean``, ``map_precision`` (the robots' mean), bytes
  sent (the team's sum, goal messages included) and steps to 90 % (an episode that never
  reached 90 % counts as its step limit + 1, a censored value: the count of such episodes is
  printed with it);
* when the last policy is ``ppo_goals`` (the goal-choice network): on the same maps and
  seeds, the team coverage when the slot is chosen uniformly at random among the candidates
  (what the network's training adds), and how often the network picks each slot.

    polyslam evaluate --policy frontier,random,ppo --map generator:office_floor --seed 10000 \\
        --episodes 10 --json office.json
    python scripts/learned_policy_report.py office.json warehouse.json
    python scripts/learned_policy_report.py --policies frontier,frontier_team team.json
"""

from __future__ import annotations

import argparse
import collections
import json
from multiprocessing import Pool
from typing import Any

import numpy as np

import polyslam_env
from policies.base import PolicyContext, make_policy
from policies.goals import CANDIDATES, FEATURES, GoalPolicy
from polyslam_env.metrics.statistics import t_half_width

POLICIES = ("frontier", "random", "ppo")
#: The step of the "coverage at step" comparison (issue 44: team coverage at 200 steps).
AT_STEP = 200


class UniformGoals(GoalPolicy):
    """A candidate slot drawn uniformly from the filled ones."""

    def choose(self, features: np.ndarray, rng: np.random.Generator) -> int:
        filled = int(features[: CANDIDATES * len(FEATURES) : len(FEATURES)].sum())
        return int(rng.integers(max(filled, 1)))


def _episode(job: tuple[dict[str, Any], int, str]) -> tuple[float, list[int]]:
    """Team coverage of one episode of ``uniform`` or ``ppo`` goals, and the slots chosen."""
    config, seed, kind = job
    env = polyslam_env.parallel_env(config)
    obs, _ = env.reset(seed=seed)
    chosen: list[int] = []
    team: dict[str, GoalPolicy] = {}
    for a in env.possible_agents:
        if kind == "uniform":
            team[a] = UniformGoals(PolicyContext.from_env(env, a))
        else:
            policy = make_policy("ppo_goals", env, a)
            assert isinstance(policy, GoalPolicy)
            team[a] = policy
        team[a].reset(seed)
    for policy in team.values():
        pick = policy.choose

        def record(f: np.ndarray, rng: np.random.Generator, pick: Any = pick) -> int:
            slot = int(pick(f, rng))
            chosen.append(slot)
            return slot

        policy.choose = record  # type: ignore[method-assign,assignment]
    rng = np.random.default_rng(seed)
    while env.agents:
        obs, *_ = env.step({a: team[a].act(obs[a], rng) for a in env.agents})
    assert env.episode is not None
    return float(env.episode.coverage.coverage), chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", help="polyslam evaluate --json files")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--policies",
        default=",".join(POLICIES),
        help="the policies to report, the baseline first and the compared one last"
        f" (default {','.join(POLICIES)})",
    )
    args = parser.parse_args()
    names = args.policies.split(",")
    base, last = names[0], names[-1]
    cov: dict[str, list[float]] = {p: [] for p in names}
    overlap: dict[str, list[float]] = {p: [] for p in names}
    nu: dict[str, list[float]] = {p: [] for p in names}
    precision: dict[str, list[float]] = {p: [] for p in names}
    sent: dict[str, list[float]] = {p: [] for p in names}
    at200: dict[str, list[float]] = {p: [] for p in names}
    steps90: dict[str, list[float]] = {p: [] for p in names}
    never: dict[str, int] = dict.fromkeys(names, 0)
    jobs = []
    for path in args.files:
        report = json.load(open(path))
        config = report["configs"][last] if "configs" in report else report["config"]
        seeds = {p: sorted(e["seed"] for e in report["episodes"][p]) for p in names}
        if any(seeds[p] != seeds[base] for p in names):
            raise SystemExit(f"{path}: the policies' seeds differ (a failed episode?): {seeds}")
        for p in names:
            for e in sorted(report["episodes"][p], key=lambda e: e["seed"]):
                cov[p].append(float(e["team"]["coverage"]))
                overlap[p].append(float(e["team"]["overlap"]))
                robots_all = list(e["robots"].values())
                robots = [r for r in robots_all if r.get("has_map", 1.0)]
                nu[p].append(float(np.mean([r["nu_mean"] for r in robots])))
                precision[p].append(float(np.mean([r["map_precision"] for r in robots])))
                sent[p].append(  # the exchange's and the goal messages' (as polyslam evaluate)
                    sum(r["bytes_sent"] + r.get("goal_bytes_sent", 0.0) for r in robots_all)
                )
                series = e["coverage"]  # per step; an episode that ended early stays there
                at200[p].append(float(series[min(AT_STEP, len(series)) - 1]))
                reached = e["team"]["steps_to_90"]
                never[p] += reached is None
                steps90[p].append(float(e["steps"] + 1 if reached is None else reached))
        jobs += [(config, int(s), kind) for s in report["seeds"] for kind in ("uniform", "ppo")]
    for p in names:
        print(
            f"{p:9s} team coverage {np.mean(cov[p]):.3f} ± {np.std(cov[p]):.3f}"
            f"  overlap {np.mean(overlap[p]):.3f} ± {np.std(overlap[p]):.3f}"
            f"  nu_mean {np.mean(nu[p]):.4f} m  ({len(cov[p])} episodes)"
        )
    ratio = f"{last} / {base} coverage {np.mean(cov[last]) / np.mean(cov[base]):.3f}"
    if "random" in names:
        ratio += f"; {last} − random {100 * (np.mean(cov[last]) - np.mean(cov['random'])):+.1f}"
        ratio += " points"
    print(ratio)
    for name, values in (
        ("coverage", cov),
        (f"coverage at step {AT_STEP}", at200),
        ("overlap", overlap),
        ("nu_mean", nu),
        ("map_precision", precision),
        ("bytes sent", sent),
        ("steps to 90 %", steps90),
    ):
        diff = np.array(values[last]) - np.array(values[base])
        relative = 100 * diff.mean() / np.mean(values[base])
        half = f"{t_half_width(diff):.4f}" if diff.size > 1 else "n/a (one pair)"
        print(
            f"{last} − {base} {name}, paired by seed: {diff.mean():+.4f} ± {half}"
            f" (95 % t interval; {relative:+.1f} %)"
        )
    print(
        f"never reached 90 % (counted as the step limit + 1): {base} {never[base]},"
        f" {last} {never[last]} of {len(cov[base])}"
    )
    if last != "ppo_goals":
        return
    with Pool(args.workers) as pool:
        results = pool.map(_episode, jobs)
    uniform = [c for (c, _), (_, _, k) in zip(results, jobs, strict=True) if k == "uniform"]
    slots = collections.Counter(
        s
        for (_, chosen), (_, _, k) in zip(results, jobs, strict=True)
        if k == "ppo"
        for s in chosen
    )
    total = sum(slots.values())
    print(f"uniform slot choice: team coverage {np.mean(uniform):.3f} ± {np.std(uniform):.3f}")
    share = ", ".join(f"slot {k}: {v / total:.2f}" for k, v in sorted(slots.items()))
    print(f"ppo_goals' choices over {total} decisions: {share}")


if __name__ == "__main__":
    main()

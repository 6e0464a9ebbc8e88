"""The shipped ``ppo`` policy against its baselines, from ``polyslam evaluate`` JSON files.

Reads the files that ``polyslam evaluate --policy frontier,random,ppo --json FILE`` wrote (one
per map), and prints, pooled over all their episodes:

* each policy's team coverage and ``nu_mean`` (the robots' mean), and ``ppo``'s ratio to
  ``frontier`` and points above ``random``;
* the paired differences ``ppo − frontier`` per seed, with a 95 % t interval;
* on the same maps and seeds, the team coverage when the slot is chosen uniformly at random
  among the candidates (what the network's training adds), and how often the network picks
  each slot.

    polyslam evaluate --policy frontier,random,ppo --map generator:office_floor --seed 10000 \\
        --episodes 10 --json office.json
    python scripts/learned_policy_report.py office.json warehouse.json
"""

from __future__ import annotations

import argparse
import collections
import json
from multiprocessing import Pool
from typing import Any

import numpy as np
from scipy import stats

import polyslam_env
from policies.base import PolicyContext, make_policy
from policies.goals import CANDIDATES, FEATURES, GoalPolicy

POLICIES = ("frontier", "random", "ppo")


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
            policy = make_policy("ppo", env, a)
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


def _interval(diff: np.ndarray) -> float:
    return float(stats.t.ppf(0.975, len(diff) - 1) * diff.std(ddof=1) / np.sqrt(len(diff)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", help="polyslam evaluate --json files")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    cov: dict[str, list[float]] = {p: [] for p in POLICIES}
    nu: dict[str, list[float]] = {p: [] for p in POLICIES}
    jobs = []
    for path in args.files:
        report = json.load(open(path))
        config = report["configs"]["ppo"] if "configs" in report else report["config"]
        for p in POLICIES:
            for e in report["episodes"][p]:
                cov[p].append(float(e["team"]["coverage"]))
                robots = [r for r in e["robots"].values() if r.get("has_map", 1.0)]
                nu[p].append(float(np.mean([r["nu_mean"] for r in robots])))
        jobs += [(config, int(s), kind) for s in report["seeds"] for kind in ("uniform", "ppo")]
    for p in POLICIES:
        print(
            f"{p:9s} team coverage {np.mean(cov[p]):.3f} ± {np.std(cov[p]):.3f}"
            f"  nu_mean {np.mean(nu[p]):.4f} m  ({len(cov[p])} episodes)"
        )
    print(
        f"ppo / frontier coverage {np.mean(cov['ppo']) / np.mean(cov['frontier']):.3f};"
        f" ppo − random {100 * (np.mean(cov['ppo']) - np.mean(cov['random'])):+.1f} points"
    )
    for name, values in (("coverage", cov), ("nu_mean", nu)):
        diff = np.array(values["ppo"]) - np.array(values["frontier"])
        print(
            f"ppo − frontier {name}, paired by seed: {diff.mean():+.4f} ± {_interval(diff):.4f}"
            " (95 % t interval)"
        )
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
    print(f"ppo's choices over {total} decisions: {share}")


if __name__ == "__main__":
    main()

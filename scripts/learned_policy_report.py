"""A policy against a baseline, paired by map and seed, from ``polyslam evaluate`` JSON files.

Reads the files that ``polyslam evaluate --policy frontier,random,ppo --json FILE`` wrote (one
per map, or several: the episodes of a policy are pooled over all files, keyed by map and
seed), and prints, over the episodes every reported policy played:

* each policy's team coverage, team overlap and ``nu_mean`` (the robots' mean), and the last
  policy's ratio to the first (the baseline) and points above ``random`` (if it ran);
* the paired differences last − first per map and seed, with a 95 % t interval, of team
  coverage at the end and at step 200, overlap, ``nu_mean``, ``map_precision`` (the robots'
  mean), bytes sent (the team's sum, goal messages included) and steps to 90 % (an episode
  that never reached 90 % counts as its step limit + 1, a censored value: the count of such
  episodes is printed with it);
* with ``--phases``, where the steps go: the paired difference of the steps to 30, 50, 70, 80,
  85 and 90 % team coverage (censored as above) and of the team coverage at steps 50, 100 …
  400 (an episode that ended early keeps its last coverage);
* when the last policy is ``ppo_goals`` (the goal-choice network): on the same maps and
  seeds, the team coverage when the slot is chosen uniformly at random among the candidates
  (what the network's training adds), and how often the network picks each slot.

``NAME=FILE`` reads a file of one policy under the name NAME: a candidate checkpoint
evaluated as ``--policy ppo --checkpoint RUN.zip`` then pairs with the shipped ``ppo`` of
another file.

    polyslam evaluate --policy frontier,random,ppo --map generator:office_floor --seed 10000 \\
        --episodes 10 --json office.json
    python scripts/learned_policy_report.py office.json warehouse.json
    python scripts/learned_policy_report.py --policies frontier,frontier_team team.json
    python scripts/learned_policy_report.py --phases --policies ppo,tuned \\
        office.json tuned=office_tuned.json
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


#: Team coverages whose steps ``--phases`` pairs, and the steps whose coverage it pairs.
THRESHOLDS = (0.3, 0.5, 0.7, 0.8, 0.85, 0.9)
PHASE_STEPS = (50, 100, 150, 200, 250, 300, 350, 400)


def _read(args: list[str]) -> tuple[dict[str, dict[tuple[str, int], Any]], list[Any]]:
    """Per policy, its episodes by (map, seed) from the files ``args`` (``FILE`` or
    ``NAME=FILE``), and per file (config of each policy, map, seeds) for ``ppo_goals``' jobs."""
    episodes: dict[str, dict[tuple[str, int], Any]] = collections.defaultdict(dict)
    files = []
    for arg in args:
        name, _, path = arg.rpartition("=") if "=" in arg else ("", "", arg)
        try:
            report = json.load(open(path))
            by_policy = report["episodes"]
            if "policy" in report:  # one policy's file
                by_policy = {report["policy"]: by_policy}
            configs = report.get("configs") or dict.fromkeys(by_policy, report.get("config"))
            where = report["map"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise SystemExit(f"{path}: not a polyslam evaluate --json file ({e})") from None
        if name:
            if len(by_policy) != 1:
                raise SystemExit(
                    f"{arg}: NAME=FILE needs a file of one policy, got {list(by_policy)}"
                )
            by_policy = {name: next(iter(by_policy.values()))}
            configs = {name: next(iter(configs.values()))}
        for policy, eps in by_policy.items():
            for episode in eps:
                key = (where, int(episode["seed"]))
                if key in episodes[policy]:
                    raise SystemExit(
                        f"{path}: {policy} seed {key[1]} on {where} also in another file"
                    )
                episodes[policy][key] = episode
        files.append((configs, where, report.get("seeds", [])))
    return episodes, files


def _coverage(e: dict[str, Any], step: int) -> float:
    """Team coverage after ``step`` steps (the series starts at the reset; an episode that ended
    early keeps its last value)."""
    series = e["coverage"]
    return float(series[min(step, len(series) - 1)])


def _steps_to(e: dict[str, Any], level: float) -> float:
    """Steps to team coverage ``level``; the step limit + 1 when never reached."""
    series = np.asarray(e["coverage"])
    reached = np.nonzero(series >= level)[0]
    return float(reached[0] if len(reached) else e["steps"] + 1)


def _paired(label: str, last: str, base: str, b: np.ndarray, a: np.ndarray) -> None:
    """Print ``a − b`` paired, with its 95 % t interval and relative to ``b``'s mean."""
    diff = a - b
    relative = 100 * diff.mean() / np.mean(b)
    half = f"{t_half_width(diff):.4f}" if diff.size > 1 else "n/a (one pair)"
    print(
        f"{last} − {base} {label}, paired by seed: {diff.mean():+.4f} ± {half}"
        f" (95 % t interval; {relative:+.1f} %)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "files", nargs="+", help="polyslam evaluate --json files (NAME=FILE renames its policy)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--policies",
        default=",".join(POLICIES),
        help="the policies to report, the baseline first and the compared one last"
        f" (default {','.join(POLICIES)})",
    )
    parser.add_argument(
        "--phases", action="store_true", help="also pair the steps to each coverage level"
    )
    args = parser.parse_args()
    names = args.policies.split(",")
    base, last = names[0], names[-1]
    episodes, files = _read(args.files)
    missing = [p for p in names if p not in episodes]
    if missing:
        raise SystemExit(
            f"no episodes of {', '.join(missing)} in the files (have {sorted(episodes)})"
        )
    keys = sorted(set.intersection(*(set(episodes[p]) for p in names)))
    dropped = {p: len(episodes[p]) - len(keys) for p in names if len(episodes[p]) > len(keys)}
    if not keys:
        raise SystemExit(f"the policies {names} share no (map, seed)")
    if dropped:
        print(f"left out, not played by every policy: {dropped} episodes")
    table = {p: [episodes[p][k] for k in keys] for p in names}

    def column(p: str, value: Any) -> np.ndarray:
        return np.array([value(e) for e in table[p]], dtype=float)

    def robots(e: dict[str, Any]) -> list[dict[str, float]]:  # those with a map
        return [r for r in e["robots"].values() if r.get("has_map", 1.0)]

    measures = {
        "coverage": lambda e: e["team"]["coverage"],
        f"coverage at step {AT_STEP}": lambda e: _coverage(e, AT_STEP),
        "overlap": lambda e: e["team"]["overlap"],
        "nu_mean": lambda e: np.mean([r["nu_mean"] for r in robots(e)]),
        "map_precision": lambda e: np.mean([r["map_precision"] for r in robots(e)]),
        # the exchange's and the goal messages' (as polyslam evaluate)
        "bytes sent": lambda e: sum(
            r["bytes_sent"] + r.get("goal_bytes_sent", 0.0) for r in e["robots"].values()
        ),
        "steps to 90 %": lambda e: _steps_to(e, 0.9),
    }
    values = {m: {p: column(p, f) for p in names} for m, f in measures.items()}
    for p in names:
        cov, overlap, nu = values["coverage"][p], values["overlap"][p], values["nu_mean"][p]
        print(
            f"{p:9s} team coverage {cov.mean():.3f} ± {cov.std():.3f}"
            f"  overlap {overlap.mean():.3f} ± {overlap.std():.3f}"
            f"  nu_mean {nu.mean():.4f} m  ({len(cov)} episodes)"
        )
    end = values["coverage"]
    ratio = f"{last} / {base} coverage {end[last].mean() / end[base].mean():.3f}"
    if "random" in names:
        ratio += f"; {last} − random {100 * (end[last].mean() - end['random'].mean()):+.1f}"
        ratio += " points"
    print(ratio)
    for m in measures:
        _paired(m, last, base, values[m][base], values[m][last])
    never = {p: int(sum(e["team"]["steps_to_90"] is None for e in table[p])) for p in (base, last)}
    print(
        f"never reached 90 % (counted as the step limit + 1): {base} {never[base]},"
        f" {last} {never[last]} of {len(keys)}"
    )
    if args.phases:
        for level in THRESHOLDS:
            b, a = (column(p, lambda e, v=level: _steps_to(e, v)) for p in (base, last))
            _paired(f"steps to {100 * level:.0f} %", last, base, b, a)
        for step in PHASE_STEPS:
            b, a = (column(p, lambda e, s=step: _coverage(e, s)) for p in (base, last))
            _paired(f"coverage at step {step}", last, base, b, a)
    if last != "ppo_goals":
        return
    jobs = [
        (configs[last], int(s), kind)
        for configs, _, seeds in files
        if last in configs
        for s in seeds
        for kind in ("uniform", "ppo")
    ]
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

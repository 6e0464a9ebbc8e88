"""Two SLAM settings on the very same episodes: a paired comparison of map metrics.

Closed-loop comparisons of SLAM variants are noisy: the frontier policy acts on the map, so a
variant changes the robots' paths, and a handful of seeds then differ mostly by where the
robots went. Here setting A drives each seeded episode of ``polyslam fidelity`` (frontier
team, ``initial_error`` on, the map exchange on or off) and its team actions are recorded;
setting B replays those actions. True motion depends only on the actions and the seed (noise
enters odometry and sensors only, SLAM never touches the world), so both settings see the
same trajectories and the same measurements, which the script checks. What differs is the
SLAM alone, robot by robot.

Settings are ``--a`` / ``--b`` overrides of the env config (``slam.stretch_ends=false``,
``slam.eps_z=10``, ``channel.align_maps=false``; values are YAML); either defaults to the
fidelity config. Printed per metric: the means under A and B, the paired difference B − A
with its 95 % t interval over robots × seeds, and how many robots miss the issue-14 target
under each.

Usage::

    python scripts/paired_slam.py --map office_floor --seeds 12 --a slam.stretch_ends=false
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import numpy as np

from policies.base import make_team
from polyslam_env.apps.fidelity import FidelityConfig, episode_config
from polyslam_env.apps.jobs import run_jobs
from polyslam_env.apps.rollout import run_episode
from polyslam_env.cli.common import progress_bar
from polyslam_env.core.config import parse_overrides
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.metrics.statistics import t_half_width

#: metric → (target, True when a value must be at least the target)
METRICS = {
    "completeness_seen": (0.8, True),
    "map_precision": (0.9, True),
    "nu_mean": (0.05, False),
    "nees_rel": (6.0, False),
    "duplicates": (0.05, False),
}


class _Recorder:
    """A team whose actions are kept, step by step."""

    def __init__(self, team: Any) -> None:
        self.team, self.actions = team, []  # type: ignore[var-annotated]
        self.policies = team.policies  # their metrics go into the episode's results

    def reset(self, seed: int | None = None) -> None:
        self.team.reset(seed)

    def act(self, observations: Any, rng: np.random.Generator) -> Any:
        action = self.team.act(observations, rng)
        self.actions.append(action)
        return action


class _Replay:
    """Recorded team actions, played back in order."""

    def __init__(self, actions: list[Any]) -> None:
        self.actions, self.k = actions, 0
        self.policies: dict[str, Any] = {}  # no policy runs: no policy metrics

    def reset(self, seed: int | None = None) -> None:
        self.k = 0

    def act(self, observations: Any, rng: np.random.Generator) -> Any:
        action = self.actions[self.k]
        self.k += 1
        return action


def setting(base: dict[str, Any], pairs: list[str]) -> dict[str, Any]:
    """The env config ``base`` with ``["slam.eps_z=10", ...]`` applied (dotted keys reach
    nested fields through ``Config.replace``, values are YAML), validated; a one-line error
    on a malformed pair, a ``ConfigError`` on an unknown field or a bad value."""
    try:
        overrides = parse_overrides(pairs)
    except ConfigError as err:  # a malformed pair: the script's one-line exit
        sys.exit(f"paired_slam: {err}")
    return EnvConfig.from_dict(base).replace(**overrides).to_dict()


def _final_true_poses(env: Any) -> np.ndarray:  # (N, 3)
    return np.array([h.true[-1] for h in env.episode.histories])


def pair(job: tuple[dict[str, Any], dict[str, Any], int]) -> dict[str, Any]:
    """Setting A under the frontier policy, then B replaying A's actions; per-robot metrics."""
    config_a, config_b, seed = job
    env = parallel_env(EnvConfig.from_dict(config_a))
    recorder = _Recorder(make_team("frontier", env))
    result_a = run_episode(env, recorder, seed)  # type: ignore[arg-type]
    true_a = _final_true_poses(env)
    env.close()
    env = parallel_env(EnvConfig.from_dict(config_b))
    result_b = run_episode(env, _Replay(recorder.actions), seed)  # type: ignore[arg-type]
    if not np.array_equal(true_a, _final_true_poses(env)):
        raise RuntimeError(f"seed {seed}: the replay drove the robots elsewhere")
    env.close()
    agents = sorted(result_a.robots)
    return {
        "seed": seed,
        "a": [{m: result_a.robots[r][m] for m in METRICS} for r in agents],
        "b": [{m: result_b.robots[r][m] for m in METRICS} for r in agents],
    }


def report(results: list[dict[str, Any]]) -> str:
    lines = ["| metric | A | B | B − A (95 % t) | robots missing the target A / B |"]
    lines.append("|---|---|---|---|---|")
    for metric, (target, at_least) in METRICS.items():
        a = np.array([r[metric] for res in results for r in res["a"]])
        b = np.array([r[metric] for res in results for r in res["b"]])
        d = b - a
        half = t_half_width(d)
        miss_a = int(np.sum(a < target if at_least else a > target))
        miss_b = int(np.sum(b < target if at_least else b > target))
        lines.append(
            f"| {metric} | {a.mean():.4f} | {b.mean():.4f} | {d.mean():+.4f} ± {half:.4f} "
            f"| {miss_a} / {miss_b} of {len(d)} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", default="office_floor", help="layout generator")
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--exchange", choices=("on", "off"), default="on")
    parser.add_argument("--a", nargs="*", default=[], help="setting A: KEY=VALUE overrides")
    parser.add_argument("--b", nargs="*", default=[], help="setting B: KEY=VALUE overrides")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", default=None, help="write the per-robot results here")
    args = parser.parse_args()
    if args.seeds < 2:
        sys.exit(f"paired_slam: --seeds must be >= 2, got {args.seeds}")
    base = episode_config(FidelityConfig(), args.map, args.exchange == "on")
    configs = []
    for name, pairs in (("a", args.a), ("b", args.b)):
        try:
            configs.append(setting(base, pairs))
        except ConfigError as exc:  # a bad override: say which, in one line
            sys.exit(f"paired_slam: --{name}: {exc}")
    seeds = range(args.seed, args.seed + args.seeds)
    jobs = [(configs[0], configs[1], seed) for seed in seeds]
    start = time.perf_counter()
    with progress_bar(len(jobs), "paired episodes", "seed") as bar:
        results = run_jobs(pair, jobs, args.workers, lambda k: bar.update(1))
    print(
        f"{args.map}, exchange {args.exchange}, seeds {args.seed}–{args.seed + args.seeds - 1};"
        f" A: {' '.join(args.a) or 'fidelity config'}; B: {' '.join(args.b) or 'fidelity config'}"
        f" (A's policy runs, B replays its actions); {time.perf_counter() - start:.0f} s"
    )
    print(report(results))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f)


if __name__ == "__main__":
    main()

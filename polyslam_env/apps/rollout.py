"""Running episodes with a team policy, for ``polyslam run`` and ``polyslam evaluate``.

The runner (not the policy) may read the env: it records the team coverage after every step
for the coverage-over-time plots and collects ``infos[agent]["metrics"]`` and ``["team"]``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from policies.base import TeamPolicy, make_team
from polyslam_env.core.jit import compile_seconds
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import PolySlamParallelEnv, parallel_env
from polyslam_env.metrics.episode import meaningful

__all__ = [
    "COMPARED",
    "EpisodeResult",
    "EvaluateJob",
    "compare",
    "episode_row",
    "evaluate_episode",
    "evaluate_job",
    "run_episode",
    "summarise",
    "warm_up",
]


@dataclass
class EpisodeResult:
    """What one episode produced (plain data, picklable, JSON-ready via :meth:`to_dict`)."""

    seed: int
    steps: int
    robots: dict[str, dict[str, float]]  # agent → infos[agent]["metrics"]
    team: dict[str, Any]  # infos[...]["team"] at the episode end
    coverage: list[float] = field(default_factory=list)  # team coverage after reset, each step

    def to_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "steps": self.steps,
            "robots": self.robots,
            "team": self.team,
            "coverage": self.coverage,
        }


def policy_rng(seed: int) -> np.random.Generator:
    """The policies' random stream of episode ``seed``, separate from the env's."""
    return np.random.default_rng([seed, 1])


def run_episode(
    env: PolySlamParallelEnv,
    team: TeamPolicy,
    seed: int,
    on_step: Callable[[PolySlamParallelEnv], None] | None = None,
) -> EpisodeResult:
    """One seeded episode; the policies' rng is ``default_rng(seed)``, separate from the env's.

    ``on_step(env)`` is called after reset and after every step (rendering, progress).
    """
    observations, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = policy_rng(seed)
    state = env.episode
    assert state is not None  # made by reset
    coverage = [float(state.coverage.coverage)]
    robots: dict[str, dict[str, float]] = {}
    team_info: dict[str, Any] = {}
    if on_step is not None:
        on_step(env)
    while env.agents:
        observations, _, _, _, infos = env.step(team.act(observations, rng))
        coverage.append(float(state.coverage.coverage))
        for agent, info in infos.items():
            if "metrics" in info:
                robots[agent] = dict(info["metrics"])
                team_info = dict(info["team"])
        if on_step is not None:
            on_step(env)
    for agent, policy in team.policies.items():
        if agent in robots:
            robots[agent].update(policy.metrics())  # what only the policy knows
    ordered = {a: robots[a] for a in env.possible_agents if a in robots}
    return EpisodeResult(seed, state.step_count, ordered, team_info, coverage)


def warm_up(
    env: PolySlamParallelEnv,
    team: TeamPolicy,
    seed: int,
    steps: int,
    on_step: Callable[[], None] | None = None,
) -> float:
    """Play the first ``steps`` steps of the seeded episode (fewer if it ends sooner), untimed,
    so that the compiled kernels they use are compiled or loaded from numba's disk cache
    before a timed run of the same episode; returns the seconds that took
    (:func:`~polyslam_env.core.jit.compile_seconds`). The env and the team are reset again by
    :func:`run_episode`, so the timed episode is the same, bit for bit."""
    before = compile_seconds()
    observations, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = policy_rng(seed)
    for _ in range(steps):
        if not env.agents:
            break
        observations, *_ = env.step(team.act(observations, rng))
        if on_step is not None:
            on_step()
    return compile_seconds() - before


def evaluate_episode(
    config: Mapping[str, Any],
    policy: str,
    policy_kwargs: Mapping[str, Any],
    seed: int,
    after: Callable[[PolySlamParallelEnv, EpisodeResult], None] | None = None,
) -> EpisodeResult:
    """Build the env and team in this process and run one episode (a worker's job);
    ``after(env, result)`` runs at the end, before the env is closed (it may add to
    ``result``: what only the episode's final state holds)."""
    env = parallel_env(EnvConfig.from_dict(dict(config)))
    try:
        result = run_episode(env, make_team(policy, env, **policy_kwargs), seed)
        if after is not None:
            after(env, result)
        return result
    finally:
        env.close()


#: An evaluation job: the env config (a dict), the policy's name and keyword arguments, seed.
EvaluateJob = tuple[Mapping[str, Any], str, Mapping[str, Any], int]


def evaluate_job(job: EvaluateJob) -> EpisodeResult:
    """:func:`evaluate_episode` of one job (what :func:`~polyslam_env.apps.jobs.run_jobs`
    runs, in a worker or as a Ray task)."""
    return evaluate_episode(*job)


def _spread(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    a = a[np.isfinite(a)]
    if len(a) == 0:
        return dict.fromkeys(("mean", "std", "min", "max"), float("nan"))
    return {
        "mean": float(a.mean()),
        "std": float(a.std()),
        "min": float(a.min()),
        "max": float(a.max()),
    }


def summarise(results: list[EpisodeResult]) -> dict[str, Any]:
    """Mean, std, min and max over episodes: per robot and metric, and per team metric.

    ``steps_to_*`` are None in an episode that never reached that coverage; such episodes are
    left out of the statistics and ``reached`` counts the others.
    """
    agents = sorted({a for r in results for a in r.robots}, key=lambda a: (len(a), a))
    robots = {}
    for agent in agents:
        keys = sorted({k for r in results if agent in r.robots for k in r.robots[agent]})
        robots[agent] = {
            k: _spread([r.robots[agent][k] for r in results if agent in r.robots]) for k in keys
        }
    team: dict[str, dict[str, float]] = {}
    for key in sorted({k for r in results for k in r.team}):
        values = [r.team[key] for r in results if r.team.get(key) is not None]
        team[key] = _spread([float(v) for v in values])
        if key.startswith("steps_to_"):
            team[key]["reached"] = float(len(values))
    team["steps"] = _spread([float(r.steps) for r in results])
    return {"episodes": len(results), "robots": robots, "team": team}


#: The columns of a comparison of policies (``polyslam evaluate --policy a,b``): one value per
#: episode each (see :func:`episode_row`).
COMPARED = ("coverage", "steps_to_90", "nu_mean", "completeness", "bytes_sent")


def episode_row(result: EpisodeResult) -> dict[str, float | None]:
    """One episode's values of :data:`COMPARED`: the team coverage and ``steps_to_90`` (None
    if never reached), the robots' mean ``nu_mean`` (over robots with a map) and
    ``completeness`` (over robots with SLAM), NaN when there are none (e.g. without SLAM),
    and the bytes all robots sent (the env's exchange and, for policies that send messages of
    their own, e.g. ``frontier_team``'s goals, their ``goal_bytes_sent``)."""

    def robots(key: str) -> list[float]:
        return [v for v in meaningful(result.robots.values(), key) if np.isfinite(v)]

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else float("nan")

    steps_to_90 = result.team.get("steps_to_90")
    return {
        "coverage": float(result.team.get("coverage", float("nan"))),
        "steps_to_90": None if steps_to_90 is None else float(steps_to_90),
        "nu_mean": mean(robots("nu_mean")),
        "completeness": mean(robots("completeness")),
        "bytes_sent": float(sum(robots("bytes_sent")) + sum(robots("goal_bytes_sent"))),
    }


def compare(by_policy: Mapping[str, list[EpisodeResult]]) -> dict[str, dict[str, dict[str, float]]]:
    """Per policy and :data:`COMPARED` column: mean, std, min and max over its episodes
    (``steps_to_90`` over the episodes that reached it: ``reached`` of ``episodes``)."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for policy, results in by_policy.items():
        rows = [episode_row(r) for r in results]
        stats = {}
        for key in COMPARED:
            values = [float(v) for row in rows if (v := row[key]) is not None]
            stats[key] = _spread(values)
            if key == "steps_to_90":
                stats[key]["reached"] = float(len(values))
                stats[key]["episodes"] = float(len(rows))
        out[policy] = stats
    return out

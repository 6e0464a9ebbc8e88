"""The benchmark's ``floor`` section: the office-floor frontier episode of issue 41.

What ``polyslam fidelity``, ``evaluate`` and goal-choice training run: a generated office floor
(``generator:office_floor``, layout seed 9), 3 robots driven by the frontier team, initial
error on, the rendezvous exchange on, the episode's config built exactly as ``fidelity`` builds
it (:func:`~polyslam_env.apps.fidelity.episode_config`). The episode runs from its reset like
:func:`~polyslam_env.apps.rollout.run_episode`; steps ``first + 1 … last`` (101 … 400) are
measured, the first ones only warm up (kernels loaded from numba's cache, maps growing).

Two passes over the same seeded episode:

* timed: wall time of each env step (``env.step``) and of each team act (``team.act``), their
  mean and median in ms and the means in MPE ``simple_spread`` steps (the MPE rate measured in
  the same run by the ``reference`` section);
* profiled: cProfile's count of Python calls per env step and per team act, a figure that does
  not depend on the machine or its load. The env step's calls are split into the team SLAM's
  step (:meth:`~polyslam_env.environment.backends.TeamSlam.step`), its exchange
  (:meth:`~polyslam_env.environment.backends.TeamSlam.exchange`) and the rest of the step
  (physics, sensing, observations, rewards' bookkeeping, infos), each counted by its own
  profiler (the switches between them are not counted).
"""

from __future__ import annotations

import cProfile
import pstats
import time
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["FLOOR_MAP", "FLOOR_ROBOTS", "FLOOR_SEED", "bench_floor", "floor_config", "mpe_calls"]

FLOOR_MAP, FLOOR_SEED, FLOOR_ROBOTS = "office_floor", 9, 3


def floor_config(last: int) -> dict[str, Any]:
    """The episode's EnvConfig (as a dict), ``last`` steps long: ``fidelity``'s exchange-on
    episode of the office floor with 3 robots."""
    from polyslam_env.apps.fidelity import FidelityConfig, episode_config

    config = FidelityConfig(maps=(FLOOR_MAP,), robots=FLOOR_ROBOTS, steps=last)
    return episode_config(config, FLOOR_MAP, exchange=True)


def _episode(last: int, seed: int) -> tuple[Any, Any, Any, np.random.Generator]:
    """The env after its seeded reset, the frontier team, its first observations and the
    team's random stream (as :func:`~polyslam_env.apps.rollout.run_episode` seeds them)."""
    from policies.base import make_team
    from polyslam_env.environment.config import EnvConfig
    from polyslam_env.environment.parallel import parallel_env

    env = parallel_env(EnvConfig.from_dict(floor_config(last)))
    team = make_team("frontier", env)
    observations, _ = env.reset(seed=seed)
    team.reset(seed)
    return env, team, observations, np.random.default_rng([seed, 1])


def _timed(first: int, last: int, seed: int) -> tuple[list[float], list[float], float]:
    """Seconds of each measured env step and team act, and the team coverage at the end."""
    env, team, observations, rng = _episode(last, seed)
    env_s, act_s = [], []
    for k in range(1, last + 1):
        start = time.perf_counter()
        actions = team.act(observations, rng)
        middle = time.perf_counter()
        observations, *_ = env.step(actions)
        end = time.perf_counter()
        if k > first:
            act_s.append(middle - start)
            env_s.append(end - middle)
    coverage = float(env.episode.coverage.coverage)
    env.close()
    return env_s, act_s, coverage


def _switched(method: Callable[..., Any], inner: cProfile.Profile, outer: cProfile.Profile) -> Any:
    """``method`` profiled by ``inner`` instead of ``outer`` (which is on around it)."""

    def switched(*args: Any) -> Any:
        outer.disable()
        inner.enable()
        try:
            return method(*args)
        finally:
            inner.disable()
            outer.enable()

    return switched


def _calls(profiler: cProfile.Profile) -> int:
    """The calls a profiler saw, without the switches of :func:`_switched` (this module's
    own functions and the profilers' enable/disable)."""
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    return int(
        sum(
            row[1]
            for (path, _, name), row in stats.items()
            if path != __file__ and "_lsprof.Profiler" not in name
        )
    )


def _profiled(first: int, last: int, seed: int) -> dict[str, float]:
    """Python calls per measured env step (total, team SLAM step, exchange, the rest) and per
    team act."""
    env, team, observations, rng = _episode(last, seed)
    rest, slam, exchange, act = (cProfile.Profile() for _ in range(4))
    for k in range(1, last + 1):
        if k == first + 1:  # the episode's team SLAM object exists from the reset on
            backend = env.episode.slam
            setattr(backend, "step", _switched(backend.step, slam, rest))  # noqa: B010
            setattr(backend, "exchange", _switched(backend.exchange, exchange, rest))  # noqa: B010
        on = k > first
        if on:
            act.enable()
        actions = team.act(observations, rng)
        if on:
            act.disable()
            rest.enable()
        observations, *_ = env.step(actions)
        if on:
            rest.disable()
    env.close()
    n = last - first
    parts = {"slam": _calls(slam) / n, "exchange": _calls(exchange) / n, "rest": _calls(rest) / n}
    return {"env": sum(parts.values()), **parts, "act": _calls(act) / n}


def mpe_calls(steps: int = 200, seed: int = 0) -> float | None:
    """Python calls per step of MPE ``simple_spread`` (3 agents; None without ``mpe2``)."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return None
    env = simple_spread_v3.parallel_env(N=3)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    profiler = cProfile.Profile()
    for k in range(20 + steps):
        if not env.agents:
            env.reset()
        actions = {a: int(rng.integers(env.action_space(a).n)) for a in env.agents}
        if k >= 20:
            profiler.enable()
        env.step(actions)
        if k >= 20:
            profiler.disable()
    env.close()
    return _calls(profiler) / steps


def bench_floor(
    steps: tuple[int, int], mpe_steps_per_s: float | None, seed: int = FLOOR_SEED
) -> dict[str, Any]:
    """The floor section's row: steps ``steps[0] + 1 … steps[1]`` of the episode (module
    docstring), timed and profiled; ms figures also in MPE steps when ``mpe_steps_per_s`` (the
    same run's MPE rate) is given."""
    first, last = steps
    if not 0 <= first < last:
        raise ValueError(f"floor steps: expected 0 <= first < last, got {steps}")
    env_s, act_s, coverage = _timed(first, last, seed)
    calls = _profiled(first, last, seed)
    mpe_ms = None if not mpe_steps_per_s else 1e3 / mpe_steps_per_s

    def figure(seconds: list[float]) -> dict[str, Any]:
        mean = 1e3 * float(np.mean(seconds))
        return {
            "mean_ms": mean,
            "median_ms": 1e3 * float(np.median(seconds)),
            "mpe_steps": None if mpe_ms is None else mean / mpe_ms,
        }

    return {
        "map": "generator:" + FLOOR_MAP,
        "seed": seed,
        "robots": FLOOR_ROBOTS,
        "steps": [first + 1, last],
        "env_step": figure(env_s),
        "team_act": figure(act_s),
        "env_calls": calls["env"],
        "env_calls_slam": calls["slam"],
        "env_calls_exchange": calls["exchange"],
        "env_calls_rest": calls["rest"],
        "act_calls": calls["act"],
        "mpe_calls": mpe_calls(),
        "coverage": coverage,
    }

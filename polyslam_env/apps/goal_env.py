"""The goal-choice env that ``polyslam train`` uses with ``control: goals``.

A PettingZoo parallel env over ``polyslam_v0`` in which each robot's action is a candidate slot
of its :class:`~policies.goals.GoalPolicy` (``Discrete(CANDIDATES)``) and its observation is
that policy's feature vector. One step of this env is one decision: ``decide_every`` steps of
the underlying env, during which each robot's planner drives to the chosen goal (replanning on
its own when the goal is reached or blocked). The reward of a step is the sum of the env's
rewards over those steps, and its infos are the last env step's (so the end-of-episode metrics
reach the training logs).

The same :class:`GoalPolicy` code runs here and behind ``polyslam run --policy ppo``, in the
same order (observe → features → commit → drive), so a network trained here sees at run time
exactly what it saw in training.

With several maps (``configs`` of one env each), every episode picks one with the env's own
generator. Episode seeds are drawn from ``[0, seed_limit)``, so evaluation seeds from
``seed_limit`` on (``training.EVAL_SEED``) are layouts never trained on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from policies.base import PolicyContext
from policies.goals import CANDIDATES, GoalPolicy, feature_size
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import PolySlamParallelEnv, parallel_env

__all__ = ["GoalChoiceEnv"]


class GoalChoiceEnv(ParallelEnv[str, np.ndarray, np.int64]):
    """Decisions among frontier candidates as a parallel env (module doc)."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "polyslam_goals_v0",
        "render_modes": [],
        "is_parallelizable": True,
    }

    def __init__(
        self, configs: Sequence[EnvConfig], decide_every: int = 8, seed_limit: int = 10_000
    ) -> None:
        if not configs:
            raise ConfigError("goal training: no env config")
        robots = {c.num_robots for c in configs}
        if len(robots) != 1:
            raise ConfigError(f"goal training: every map needs the same num_robots, got {robots}")
        for c in configs:
            if c.faults:
                raise ConfigError("goal training: env.faults must be empty (robots never leave)")
        self.envs: list[PolySlamParallelEnv] = [parallel_env(c) for c in configs]
        self.possible_agents = list(self.envs[0].possible_agents)
        self.agents: list[str] = []
        self.decide_every, self.seed_limit = int(decide_every), int(seed_limit)
        self.teams = [
            {
                a: GoalPolicy(PolicyContext.from_env(env, a), decide_every=self.decide_every)
                for a in self.possible_agents
            }
            for env in self.envs
        ]
        self._obs_space = spaces.Box(-1.0, 3.0, (feature_size(),), dtype=np.float32)
        self._act_space: spaces.Discrete = spaces.Discrete(CANDIDATES)
        self._rng = np.random.default_rng()
        self._current = 0
        self.episode_seed: int | None = None  # the underlying env's seed this episode
        self.render_mode = None

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._act_space

    @property
    def env(self) -> PolySlamParallelEnv:
        """The env of the current episode."""
        return self.envs[self._current]

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self._current = int(self._rng.integers(len(self.envs)))
        self.episode_seed = episode_seed = int(self._rng.integers(self.seed_limit))
        obs, infos = self.env.reset(seed=episode_seed, options=options)
        team = self.teams[self._current]
        features = {}
        for a in self.possible_agents:
            team[a].reset(episode_seed)
            team[a].observe(obs[a])  # the first step is always a decision
            features[a] = team[a].features()
        self.agents = self.possible_agents[:]
        return features, {a: infos.get(a, {}) for a in self.agents}

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        env, team = self.env, self.teams[self._current]
        for a in self.agents:
            team[a].commit(int(actions[a]))
        total = dict.fromkeys(self.agents, 0.0)
        while True:
            obs, rew, term, trunc, infos = env.step({a: team[a].drive() for a in env.agents})
            for a, r in rew.items():
                total[a] += float(r)
            if not env.agents:
                break
            due = [team[a].observe(obs[a]) for a in env.agents]
            if all(due):
                break
        features = {
            a: team[a].features() if env.agents else np.zeros(feature_size(), np.float32)
            for a in self.agents
        }
        terminated = {a: bool(term.get(a, False)) for a in self.agents}
        truncated = {a: bool(trunc.get(a, False)) for a in self.agents}
        infos = {a: infos.get(a, {}) for a in self.agents}
        if not env.agents:
            self.agents = []
        return features, total, terminated, truncated, infos

    def close(self) -> None:
        for env in self.envs:
            env.close()

    @property
    def unwrapped(self) -> Any:
        return self

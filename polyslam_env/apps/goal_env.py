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

from policies.base import PolicyContext
from policies.goals import CANDIDATES, GoalPolicy, feature_size
from polyslam_env.apps.draw_env import MapDrawEnv, Step
from polyslam_env.environment.config import EnvConfig

__all__ = ["GoalChoiceEnv"]


class GoalChoiceEnv(MapDrawEnv):
    """Decisions among frontier candidates as a parallel env (module doc)."""

    metadata: ClassVar[dict[str, Any]] = {**MapDrawEnv.metadata, "name": "polyslam_goals_v0"}

    def __init__(
        self, configs: Sequence[EnvConfig], decide_every: int = 8, seed_limit: int = 10_000
    ) -> None:
        obs_space = spaces.Box(-1.0, 3.0, (feature_size(),), dtype=np.float32)
        act_space: spaces.Discrete = spaces.Discrete(CANDIDATES)
        super().__init__(configs, obs_space, act_space, seed_limit, what="goal training")
        self.decide_every = int(decide_every)
        self.teams = [
            {
                a: GoalPolicy(PolicyContext.from_env(env, a), decide_every=self.decide_every)
                for a in self.possible_agents
            }
            for env in self.envs
        ]

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        obs, infos = self.draw(seed, options)
        team = self.teams[self._current]
        features = {}
        for a in self.possible_agents:
            team[a].reset(self.episode_seed)
            team[a].observe(obs[a])  # the first step is always a decision
            features[a] = team[a].features()
        return features, infos

    def step(self, actions: Mapping[str, Any]) -> Step:
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
        return self.finish(lambda a: team[a].features(), total, term, trunc, infos)

"""The base of ``polyslam train``'s wrapper envs: one of several maps per episode, layout seeds
kept below the evaluation seeds.

:class:`MapDrawEnv` is a PettingZoo parallel env over one ``polyslam_v0`` env per map config
(all with the same ``num_robots`` and no faults, so robots never leave mid-episode). Every
reset picks a map and an episode seed in ``[0, seed_limit)`` with its own generator, so
evaluation seeds from ``seed_limit`` on (``training.EVAL_SEED``) are layouts never trained
on. Subclasses set the spaces and translate actions and observations
(:mod:`~polyslam_env.apps.goal_env`, :mod:`~polyslam_env.apps.drive_env`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import PolySlamParallelEnv, parallel_env
from polyslam_env.environment.vector import Step

__all__ = ["MapDrawEnv", "Step"]


class MapDrawEnv(ParallelEnv[str, np.ndarray, Any]):
    """One of ``configs``' envs per episode (module doc); ``what`` names the training kind
    in error messages."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        configs: Sequence[EnvConfig],
        obs_space: spaces.Space[Any],
        act_space: spaces.Space[Any],
        seed_limit: int = 10_000,
        what: str = "training",
    ) -> None:
        if not configs:
            raise ConfigError(f"{what}: no env config")
        robots = {c.num_robots for c in configs}
        if len(robots) != 1:
            raise ConfigError(f"{what}: every map needs the same num_robots, got {robots}")
        for c in configs:
            if c.faults:
                raise ConfigError(f"{what}: env.faults must be empty (robots never leave)")
        self.envs: list[PolySlamParallelEnv] = [parallel_env(c) for c in configs]
        self.possible_agents = list(self.envs[0].possible_agents)
        self.agents: list[str] = []
        self.seed_limit = int(seed_limit)
        self._obs_space, self._act_space = obs_space, act_space
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

    def draw(
        self, seed: int | None, options: dict[str, Any] | None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        """Pick this episode's map and layout seed and reset its env: its observations and
        infos (every agent present)."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self._current = int(self._rng.integers(len(self.envs)))
        self.episode_seed = int(self._rng.integers(self.seed_limit))
        obs, infos = self.env.reset(seed=self.episode_seed, options=options)
        self.agents = self.possible_agents[:]
        return obs, {a: infos.get(a, {}) for a in self.agents}

    def finish(
        self,
        features: Callable[[str], np.ndarray],
        rewards: dict[str, float],
        term: dict[str, Any],
        trunc: dict[str, Any],
        infos: dict[str, Any],
    ) -> Step:
        """A step's return for every agent of this step, from the last env step's flags and
        infos: ``features(agent)`` while the episode goes on, zeros once it is over (then no
        agent is left)."""
        over = not self.env.agents
        assert self._obs_space.shape is not None  # a Box
        zeros = np.zeros(self._obs_space.shape, np.float32)
        out = {a: zeros if over else features(a) for a in self.agents}
        terminated = {a: bool(term.get(a, False)) for a in self.agents}
        truncated = {a: bool(trunc.get(a, False)) for a in self.agents}
        infos = {a: infos.get(a, {}) for a in self.agents}
        if over:
            self.agents = []
        return out, rewards, terminated, truncated, infos

    def close(self) -> None:
        for env in self.envs:
            env.close()

    @property
    def unwrapped(self) -> Any:
        return self

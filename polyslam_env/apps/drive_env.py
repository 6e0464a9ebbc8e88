"""The driving env that ``polyslam train`` uses with ``control: drive``.

A PettingZoo parallel env over ``polyslam_v0`` (one of several maps per episode,
:class:`~polyslam_env.apps.draw_env.MapDrawEnv`) in which each robot's observation is its
:class:`~policies.drive.DriveGuide`'s features (beams, two points of the path its own map plans
to a frontier, whether it has one, whether it stalled, its previous action) and its action is
(v, ω) on the unit box ``[−1, 1]²``, mapped to the robot's limits. One step of this env is
``repeat`` steps of the underlying env with the action held (action repeat); the guide folds
every one of them into its map.

The reward of a step is the env's reward summed over those steps plus the named shaping term
``progress`` × the metres gained along the path the guide had planned before each step
(:meth:`~policies.drive.DriveGuide.progress`): the network is paid for following its own
planner's path as well as for the area it sweeps. ``progress = 0`` trains on the env's reward
alone. With ``team`` the guides are :class:`~policies.drive.TeamDriveGuide`'s, sharing a
radio per team (``frontier_team``'s goal messages and discount). Infos are the last env
step's (so the end-of-episode metrics reach the training logs).

The same :class:`DriveGuide` code runs here and behind ``polyslam run --policy ppo_drive``
(:class:`~policies.drive.DrivePolicy`), in the same order (observe → features → act), so the
network sees at run time what it saw in training.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from policies.base import PolicyContext
from policies.drive import DriveGuide, TeamDriveGuide, feature_size
from policies.radio import team_radio
from polyslam_env.apps.draw_env import MapDrawEnv, Step
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig

__all__ = ["DriveEnv"]


class DriveEnv(MapDrawEnv):
    """(v, ω) from the network, features from the own map's planner (module doc)."""

    metadata: ClassVar[dict[str, Any]] = {**MapDrawEnv.metadata, "name": "polyslam_drive_v0"}

    def __init__(
        self,
        configs: Sequence[EnvConfig],
        repeat: int = 1,
        progress: float = 1.0,
        seed_limit: int = 10_000,
        team: bool = False,
    ) -> None:
        if repeat < 1:
            raise ConfigError(f"drive training: repeat must be >= 1, got {repeat!r}")
        for c in configs:
            if c.action.mode != "continuous":
                raise ConfigError("drive training: env.action.mode must be 'continuous'")
        act_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        super().__init__(configs, act_space, act_space, seed_limit, what="drive training")
        self.repeat, self.progress = int(repeat), float(progress)
        self.team = bool(team)
        self.guides = [self._guides(env) for env in self.envs]
        sizes = {
            feature_size(len(g.context.beam_angles)) for team in self.guides for g in team.values()
        }
        if len(sizes) != 1:
            raise ConfigError(
                f"drive training: every map needs the same beams, got {sizes} features"
            )
        self._obs_space = spaces.Box(-1.0, 1.0, (sizes.pop(),), dtype=np.float32)

    def _guides(self, env: Any) -> dict[str, DriveGuide]:
        """The guide of every robot of ``env`` (``team``: sharing one radio)."""
        contexts = [PolicyContext.from_env(env, a) for a in self.possible_agents]
        if not self.team:
            return {c.agent: DriveGuide(c) for c in contexts}
        radio = team_radio(contexts, env.unwrapped.radio_links)
        return {c.agent: TeamDriveGuide(c, radio=radio) for c in contexts}

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        obs, infos = self.draw(seed, options)
        guides = self.guides[self._current]
        features = {}
        for a in self.possible_agents:
            guides[a].reset(self.episode_seed)
            guides[a].observe(obs[a])
            features[a] = guides[a].features()
        return features, infos

    def step(self, actions: Mapping[str, Any]) -> Step:
        env, guides = self.env, self.guides[self._current]
        physical = {}
        for a in self.agents:
            physical[a] = guides[a].acted(np.asarray(actions[a], dtype=float))
        total = dict.fromkeys(self.agents, 0.0)
        for _ in range(self.repeat):
            obs, rew, term, trunc, infos = env.step({a: physical[a] for a in env.agents})
            for a, r in rew.items():
                total[a] += float(r)
            if not env.agents:
                break
            for a in env.agents:
                guides[a].observe(obs[a])
                total[a] += self.progress * guides[a].progress()
        return self.finish(lambda a: guides[a].features(), total, term, trunc, infos)

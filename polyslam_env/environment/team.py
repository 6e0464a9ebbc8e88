"""Gymnasium side of the env: the whole team as one agent, and the registered ids.

``register_envs()`` registers ``polyslam/Team-v0`` with an entry-point string, so it costs
nothing but a dict entry; the package calls it on import. The PettingZoo env is imported only
when a :class:`TeamEnv` is built.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import gymnasium
import numpy as np
from gymnasium import spaces

from polyslam_env.core.errors import ConfigError

if TYPE_CHECKING:
    from polyslam_env.environment.config import EnvConfig
    from polyslam_env.environment.parallel import PolySlamParallelEnv

__all__ = ["TEAM_ENV_ID", "TeamEnv", "register_envs"]

#: The Gymnasium id of the centralised (whole team = one agent) env.
TEAM_ENV_ID = "polyslam/Team-v0"


def register_envs() -> None:
    """Register the Gymnasium ids (idempotent; no heavy imports)."""
    if TEAM_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=TEAM_ENV_ID, entry_point="polyslam_env.environment.team:TeamEnv")


class TeamEnv(gymnasium.Env[np.ndarray, np.ndarray]):
    """The robots of ``polyslam_v0`` driven together by one centralised agent.

    ## Description
    Wraps :func:`polyslam_env.parallel_env`; robot ``i`` is ``robot_i``. Needs vector
    observations and continuous actions.

    ## Action Space
    ``Box((2N,), float32)``: robot ``i``'s ``(v, ω)`` at ``[2i, 2i+2)``, same limits as the
    PettingZoo action space (out-of-range values are clipped by the env). Actions of robots
    that failed are ignored.

    ## Observation Space
    ``Box((N·D,), float32)``: the robots' vector observations concatenated in robot order.
    A robot that failed while the others go on gets zeros, from the step in which it failed.

    ## Rewards
    ``team_reward="sum"`` (default): the sum of the robots' rewards this step; ``"mean"``:
    their mean (over the robots that acted). The per-robot infos, reward terms included, are
    in ``info["robots"]``.

    ## Episode End
    When the PettingZoo episode ends (no live robot left): ``terminated`` if every robot that
    acted in the last step was terminated (coverage target reached, or the last robot
    failed), else ``truncated`` (``max_steps``). ``info["team"]`` then holds the team metrics.

    ## Arguments
    ``TeamEnv(config=None, render_mode=None, team_reward="sum", **overrides)``, ``config`` and
    ``overrides`` as for ``parallel_env``. ``render`` passes through.

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | str | Path | None = None,
        render_mode: str | None = None,
        team_reward: Literal["sum", "mean"] = "sum",
        **overrides: Any,
    ) -> None:
        from polyslam_env.environment.parallel import (
            parallel_env,
        )  # lazy: pymunk, PettingZoo, scipy

        if team_reward not in ("sum", "mean"):
            raise ConfigError(f"team_reward: must be 'sum' or 'mean', got {team_reward!r}")
        self.par_env: PolySlamParallelEnv = parallel_env(config, render_mode, **overrides)
        cfg = self.par_env.config
        if cfg.observation.mode != "vector":
            raise ConfigError(
                f"observation.mode: TeamEnv needs 'vector', got {cfg.observation.mode!r}"
            )
        if cfg.action.mode != "continuous":
            raise ConfigError(f"action.mode: TeamEnv needs 'continuous', got {cfg.action.mode!r}")
        self.render_mode = render_mode
        self.team_reward = team_reward
        self.robots = list(self.par_env.possible_agents)
        obs_box = self.par_env.observation_space(self.robots[0])
        act_box = self.par_env.action_space(self.robots[0])
        assert isinstance(obs_box, spaces.Box) and isinstance(act_box, spaces.Box)
        n = len(self.robots)
        self._obs_dim = int(obs_box.shape[0])
        self.observation_space = spaces.Box(
            np.tile(obs_box.low, n), np.tile(obs_box.high, n), dtype=np.float32
        )
        self.action_space = spaces.Box(
            np.tile(act_box.low, n), np.tile(act_box.high, n), dtype=np.float32
        )

    def _concat(self, obs: Mapping[str, Any], shown: set[str]) -> np.ndarray:  # (N·D,)
        """Robots in ``shown`` with an observation get it; the others zeros."""
        out = np.zeros((len(self.robots), self._obs_dim), dtype=np.float32)  # (N, D)
        for i, robot in enumerate(self.robots):
            if robot in shown and robot in obs:
                out[i] = obs[robot]
        return out.reshape(-1)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        obs, infos = self.par_env.reset(seed=seed, options=options)
        return self._concat(obs, set(obs)), {"robots": infos}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self.par_env.agents:
            raise RuntimeError("step() called after the episode ended; call reset() first")
        a = np.asarray(action, dtype=np.float32).reshape(len(self.robots), 2)  # (N, 2)
        acting = list(self.par_env.agents)
        actions = {robot: a[self.robots.index(robot)] for robot in acting}
        obs, rewards, terms, _, infos = self.par_env.step(actions)
        over = not self.par_env.agents
        shown = set(acting) if over else set(self.par_env.agents)
        values = [rewards[r] for r in acting]
        reward = float(np.sum(values) if self.team_reward == "sum" else np.mean(values))
        terminated = over and all(terms[r] for r in acting)
        truncated = over and not terminated
        info: dict[str, Any] = {"robots": infos}
        if over:
            info["team"] = next(i["team"] for i in infos.values() if "team" in i)
        return self._concat(obs, shown), reward, terminated, truncated, info

    def render(self) -> Any:  # an RGB array or None (gymnasium 1.2 types it as RenderFrame)
        return self.par_env.render()

    def close(self) -> None:
        self.par_env.close()

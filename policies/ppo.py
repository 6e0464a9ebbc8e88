"""``ppo``: a policy trained with Stable-Baselines3 PPO and parameter sharing.

The same network acts for every robot, each on its own observation. Checkpoints are SB3 ``.zip``
files written by ``polyslam train``, of one of three kinds, told apart by their spaces:

* ``control: drive`` (the driving features of :mod:`policies.drive` in, (v, ω) out):
  :class:`policies.drive.TeamDrivePolicy`, the network driving the wheels along the path of a
  ``frontier_team`` guide (the team's robots share a radio: :func:`policies.drive.drive_team`).
  The package ships one (:data:`SHIPPED`, the network of ``ppo_drive``), used when no
  checkpoint is given (docs/results/learning.md: 8–10 % fewer steps to 90 % than both
  frontier policies).
* ``control: goals`` (a ``Discrete`` action): :class:`LearnedGoalPolicy`, the frontier planner
  of :class:`policies.goals.GoalPolicy` with the goal among its candidates picked by the
  network every ``decide_every`` steps. The package ships one (:data:`SHIPPED_GOALS`), the
  policy ``ppo_goals`` (``ppo`` until the driving network replaced it).
* ``control: velocity`` (a ``Box`` over the env's own observation): :class:`PPOPolicy`, the
  network's (v, ω) on the unit box of :class:`polyslam_env.environment.vector.FixedAgents`,
  mapped to the env's physical limits.

torch and SB3 are imported when a checkpoint is loaded, not before.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from policies.base import CheckpointError, Policy, PolicyContext
from policies.drive import SHIPPED_DRIVE, TeamDrivePolicy, drive_team
from policies.drive import feature_size as drive_features
from policies.goals import CANDIDATES, GoalPolicy, feature_size
from policies.loading import load_checkpoint
from policies.radio import Links

__all__ = [
    "SHIPPED",
    "SHIPPED_GOALS",
    "CheckpointError",
    "LearnedGoalPolicy",
    "PPOPolicy",
    "load_checkpoint",
    "make_ppo",
    "make_ppo_goals",
]

#: The learned goal-choice policy shipped with the package (docs/results/learning.md says how
#: it was trained: ``polyslam train --config configs/train_goals.yaml``).
SHIPPED_GOALS = Path(__file__).resolve().parent / "checkpoints" / "ppo_goals.zip"
#: The network behind ``ppo`` when no checkpoint is given: the shipped driving network.
SHIPPED = SHIPPED_DRIVE


def make_ppo(
    context: PolicyContext, checkpoint: str | Path | None = None, deterministic: bool = True
) -> Policy:
    """The ``ppo`` policy of ``checkpoint`` (the shipped one when None), of the kind its
    spaces say (module doc)."""
    checkpoint = _shipped("ppo", SHIPPED) if checkpoint is None else checkpoint
    kind = _kind(context, checkpoint)
    if kind == "goals":
        return LearnedGoalPolicy(context, checkpoint, deterministic)
    if kind == "drive":
        return TeamDrivePolicy(context, checkpoint, deterministic)
    return PPOPolicy(context, checkpoint, deterministic)


def _ppo_team(
    contexts: list[PolicyContext],
    checkpoint: str | Path | None = None,
    deterministic: bool = True,
    links: Links | None = None,
) -> dict[str, Policy]:
    """The ``ppo`` policies of a whole team: a driving network's guides share one radio (with
    the env's ``links``: :func:`policies.radio.team_radio`)."""
    checkpoint = _shipped("ppo", SHIPPED) if checkpoint is None else checkpoint
    if contexts and _kind(contexts[0], checkpoint) == "drive":
        return dict(drive_team(contexts, checkpoint, deterministic, links))
    return {c.agent: make_ppo(c, checkpoint, deterministic) for c in contexts}


def make_ppo_goals(
    context: PolicyContext, checkpoint: str | Path | None = None, deterministic: bool = True
) -> LearnedGoalPolicy:
    """The policy ``ppo_goals``: the goal-choice network of ``checkpoint`` (the shipped
    ``ppo_goals.zip`` when None)."""
    checkpoint = _shipped("ppo_goals", SHIPPED_GOALS) if checkpoint is None else checkpoint
    return LearnedGoalPolicy(context, checkpoint, deterministic)


make_ppo.takes_checkpoint = True  # type: ignore[attr-defined]
make_ppo.team = _ppo_team  # type: ignore[attr-defined]
make_ppo.takes_links = True  # type: ignore[attr-defined]
make_ppo_goals.takes_checkpoint = True  # type: ignore[attr-defined]


def _shipped(name: str, shipped: Path) -> Path:
    """The shipped checkpoint of policy ``name`` (one line if it is missing)."""
    if not shipped.is_file():
        raise CheckpointError(
            f"{name}: no checkpoint given and the shipped one is missing ({shipped});"
            " pass --checkpoint FILE (one written by polyslam train)"
        )
    return shipped


def _kind(context: PolicyContext, checkpoint: str | Path) -> str:
    """What the network of ``checkpoint`` controls: ``goals`` (a ``Discrete`` action),
    ``drive`` (the driving features of :mod:`policies.drive` in, (v, ω) out) or ``velocity``
    (the env's own observation in)."""
    model = load_checkpoint(checkpoint)
    if isinstance(model.action_space, spaces.Discrete):
        return "goals"
    if model.observation_space.shape == (drive_features(len(context.beam_angles)),):
        return "drive"
    return "velocity"


class LearnedGoalPolicy(GoalPolicy):
    """:class:`GoalPolicy` with the network of a ``control: goals`` checkpoint choosing the
    slot (the most likely one by default; a draw with the step's ``rng`` when not
    ``deterministic``). ``frontier`` keyword arguments go to the planner."""

    def __init__(
        self,
        context: PolicyContext,
        checkpoint: str | Path,
        deterministic: bool = True,
        decide_every: int = 8,
        **frontier: Any,
    ) -> None:
        self.model = load_checkpoint(checkpoint)
        self.deterministic = deterministic
        shape, act = self.model.observation_space.shape, self.model.action_space
        if shape != (feature_size(),) or getattr(act, "n", None) != CANDIDATES:
            raise CheckpointError(
                f"checkpoint {str(checkpoint)!r}: not a goal-choice network of this version"
                f" (observations {shape}, actions {act}; expected ({feature_size()},) and"
                f" Discrete({CANDIDATES}))"
            )
        super().__init__(context, decide_every=decide_every, **frontier)

    def choose(self, features: np.ndarray, rng: np.random.Generator) -> int:
        import torch

        policy = self.model.policy
        with torch.no_grad():
            dist = policy.get_distribution(policy.obs_to_tensor(features[None])[0])
            probs = dist.distribution.probs.numpy().reshape(-1).astype(float)  # (K,)
        if self.deterministic:
            return int(np.argmax(probs))
        return int(rng.choice(len(probs), p=probs / probs.sum()))


class PPOPolicy(Policy):
    """Drives one robot with a saved PPO network (deterministic mean action by default).

    Registered as ``ppo``: ``make_policy("ppo", env, agent, checkpoint=path)``. ``act``
    returns the action in the env's action space; ``rng`` is used only when
    ``deterministic`` is False (a draw from the policy's Gaussian).
    """

    takes_checkpoint = True

    def __init__(
        self, context: PolicyContext, checkpoint: str | Path, deterministic: bool = True
    ) -> None:
        super().__init__(context)
        self.deterministic = deterministic
        self.model = load_checkpoint(checkpoint)
        obs_space, act_space = context.observation_space, context.action_space
        self._check_spaces(str(checkpoint), obs_space, act_space)
        assert isinstance(act_space, spaces.Box)
        m_space = self.model.action_space
        self._m_low, self._m_high = m_space.low.astype(float), m_space.high.astype(float)  # (2,)
        self._low, self._high = act_space.low.astype(float), act_space.high.astype(float)  # (2,)

    def _check_spaces(
        self, checkpoint: str, obs_space: spaces.Space[Any], act_space: spaces.Space[Any]
    ) -> None:
        model_obs, model_act = self.model.observation_space, self.model.action_space
        if not isinstance(obs_space, spaces.Box) or obs_space.shape != model_obs.shape:
            raise CheckpointError(
                f"checkpoint {checkpoint!r}: observation space mismatch: the network expects"
                f" shape {model_obs.shape}, the env gives {getattr(obs_space, 'shape', obs_space)}"
                " (same observation settings, num_robots and max_detections as in training?)"
            )
        if not isinstance(act_space, spaces.Box) or act_space.shape != model_act.shape:
            raise CheckpointError(
                f"checkpoint {checkpoint!r}: action space mismatch: the network gives shape"
                f" {model_act.shape}, the env expects {getattr(act_space, 'shape', act_space)}"
                " (continuous actions needed)"
            )

    def act(self, observation: Any, rng: np.random.Generator) -> np.ndarray:  # (2,)
        """The robot's (v, ω) for its observation (D,)."""
        obs = np.asarray(observation, dtype=np.float32)[None]  # (1, D)
        if self.deterministic:
            a, _ = self.model.predict(obs, deterministic=True)
            a = np.asarray(a, dtype=float).reshape(-1)  # (2,)
        else:
            a = self._sample(obs, rng)
        a = np.clip(a, self._m_low, self._m_high)
        frac = (a - self._m_low) / (self._m_high - self._m_low)
        return (self._low + frac * (self._high - self._low)).astype(np.float32)

    def _sample(self, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:  # (2,)
        """A draw from the policy's Gaussian with ``rng`` (not torch's global generator)."""
        import torch

        policy = self.model.policy
        with torch.no_grad():
            dist = policy.get_distribution(policy.obs_to_tensor(obs)[0]).distribution
            mean = dist.mean.numpy().reshape(-1)
            std = dist.stddev.numpy().reshape(-1)
        return np.asarray(mean + std * rng.standard_normal(mean.shape), dtype=float)

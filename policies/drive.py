"""Driving by network: the wheels' (v, ω) from a network, where to go from the robot's own map.

:class:`DriveGuide` is the frontier policy (:mod:`policies.frontier`) without its controller: it
folds every observation into its own map, plans the path to the frontier of best utility and
replans when the frontier policy does (goal reached or no longer a frontier, path blocked,
robot stalled, a robot seen near the goal, every ``replan_every`` steps). It does not drive.
What the network sees each step (:meth:`DriveGuide.features`, layout :data:`FEATURES`), all from
the robot's own observation and own map, in its own frame:

* its 17 beams, range / max range (1: no return);
* the bearing (cos, sin) and distance of two points of its planned path: the one
  ``lookahead`` m ahead (what pure pursuit steers to) and the one ``far`` m ahead (where the
  path turns next);
* whether it has a path (0: no frontier is reachable on its map), whether it stalled
  (moved < 0.1 m in 8 steps), and its previous action.

The network's action is (v, ω) on the unit box, mapped to the robot's limits as
:class:`polyslam_env.environment.vector.FixedAgents` maps it; nothing between the network and
the wheels (no speed cap, no obstacle check). :class:`DrivePolicy` is the policy
``ppo_drive``: a guide and a network of a ``control: drive`` checkpoint
(:mod:`polyslam_env.apps.drive_env` trains one). :meth:`DriveGuide.progress` is the shaping
term of training: metres gained along the path planned before the step.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from policies.base import CheckpointError, PolicyContext, PolicyError
from policies.frontier import FrontierPolicy
from policies.loading import load_checkpoint
from policies.radio import Links, team_radio
from policies.team import TeamFrontierPolicy

__all__ = [
    "FEATURES",
    "SHIPPED_CAREFUL",
    "SHIPPED_DRIVE",
    "DriveGuide",
    "DrivePolicy",
    "TeamDriveGuide",
    "TeamDrivePolicy",
    "feature_size",
    "make_ppo_careful",
    "make_ppo_drive",
]

#: The driving network shipped with the package (docs/results/learning.md says how it was
#: trained: ``polyslam train --config configs/train_drive.yaml``).
SHIPPED_DRIVE = Path(__file__).resolve().parent / "checkpoints" / "ppo_drive.zip"
SHIPPED_CAREFUL = SHIPPED_DRIVE.with_name("ppo_careful.zip")

#: Features after the beams, in order.
FEATURES = (
    "near_cos",  # bearing of the path point `lookahead` m ahead, robot frame
    "near_sin",
    "near_distance",  # its distance / lookahead (clipped at 1)
    "far_cos",  # bearing of the path point `far` m ahead
    "far_sin",
    "far_distance",  # its distance / far (clipped at 1)
    "has_path",  # 1 if a frontier path is planned
    "stalled",  # 1 if the robot moved < 0.1 m over its last 8 steps
    "previous_v",  # the previous action on the unit box
    "previous_omega",
)


def feature_size(beams: int) -> int:
    """Length of the feature vector of a robot with ``beams`` beams."""
    return beams + len(FEATURES)


def remaining(path: np.ndarray, x: float, y: float) -> float:
    """Metres left along ``path`` (P, 2) from (x, y): to its nearest waypoint, then on."""
    d = np.hypot(path[:, 0] - x, path[:, 1] - y)  # (P,)
    i = int(np.argmin(d))
    steps = np.hypot(*np.diff(path[i:], axis=0).T) if i + 1 < len(path) else np.zeros(0)
    return float(d[i] + steps.sum())


class DriveGuide(FrontierPolicy):
    """The frontier policy's own map and planner, without its controller (module doc).

    ``far`` m is the second path point's distance; other keyword arguments are
    :class:`FrontierPolicy`'s. Call :meth:`observe` with each observation, then
    :meth:`features`, then :meth:`acted` with the action taken.
    """

    def __init__(self, context: PolicyContext, far: float = 1.5, **frontier: Any) -> None:
        self.far = float(far)
        super().__init__(context, **frontier)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._pose = np.zeros(3)
        self._ranges = np.full(len(self.context.beam_angles), np.inf)
        self._previous = np.zeros(2)
        self._progress = 0.0
        self._detections = np.zeros((0, 2))

    def observe(self, observation: Any) -> None:
        """Fold ``observation`` into the own map, measure the progress along the old path,
        replan if due."""
        before, path = self._pose, self.path
        pose, ranges, detections = self._sense(observation)
        self._pose, self._ranges, self._detections = pose, ranges, detections
        self._progress = 0.0
        if path is not None and self._step > 1:
            gained = remaining(path, before[0], before[1]) - remaining(path, pose[0], pose[1])
            limit = 1.5 * self.context.v_max * self.context.dt  # a nearest-waypoint jump
            self._progress = min(max(gained, -limit), limit)
        if self._claim(pose, detections) or self._needs_plan(pose):
            self._plan(pose)

    def progress(self) -> float:
        """Metres the last step gained along the path planned before it (negative: lost),
        within ±1.5 · v_max · dt."""
        return self._progress

    def features(self) -> np.ndarray:  # (feature_size(B),) float32
        """What the network sees now (module doc)."""
        ctx, pose = self.context, self._pose
        beams = np.where(np.isfinite(self._ranges), self._ranges / ctx.max_range, 1.0)
        out = np.zeros(feature_size(len(beams)), dtype=np.float32)
        out[: len(beams)] = np.clip(beams, 0.0, 1.0)
        rest = np.zeros(len(FEATURES))
        if self.path is not None:
            for k, reach in enumerate((self.lookahead, self.far)):
                dx, dy = _ahead(self.path, pose, reach) - pose[:2]
                alpha = math.atan2(dy, dx) - pose[2]
                rest[3 * k : 3 * k + 3] = (
                    math.cos(alpha),
                    math.sin(alpha),
                    min(math.hypot(dx, dy) / reach, 1.0),
                )
            rest[6] = 1.0
        rest[7] = float(self._stalled())
        rest[8:10] = self._previous
        out[len(beams) :] = rest
        return out

    def acted(self, unit: np.ndarray) -> np.ndarray:  # (2,) float32
        """Take the action ``unit`` (2,) on the unit box (clipped to it): remember it for the
        next features, and return the physical (v, ω) it drives, ``low + (a + 1)/2 · (high −
        low)`` of the robot's action space (as :class:`~polyslam_env.environment.vector.
        FixedAgents` maps it)."""
        a = np.clip(np.asarray(unit, dtype=float).reshape(2), -1.0, 1.0)
        self._previous = a
        space = self.context.action_space
        assert isinstance(space, spaces.Box)  # DrivePolicy and DriveEnv refuse discrete actions
        low, high = space.low.astype(float), space.high.astype(float)  # (2,)
        return (low + 0.5 * (a + 1.0) * (high - low)).astype(np.float32)

    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        raise NotImplementedError("DriveGuide does not drive; DrivePolicy does")


class TeamDriveGuide(DriveGuide, TeamFrontierPolicy):
    """The guide of ``frontier_team`` (:mod:`policies.team`): a :class:`DriveGuide` whose
    planner also discounts the frontiers near the goals its team-mates announced over a mutual
    sighting, and that announces its own goal while it sees a team-mate. ``radio`` is the
    team's shared :class:`~policies.radio.Radio`; other keywords are
    :class:`~policies.team.TeamFrontierPolicy`'s and :class:`DriveGuide`'s. The features are
    :class:`DriveGuide`'s: only the path they point along changes."""

    def observe(self, observation: Any) -> None:
        """:meth:`DriveGuide.observe` (which hears the team-mates' messages and replans), then
        announce the goal (the frontier team's step, without its controller)."""
        super().observe(observation)
        self._announce(self._pose, self._detections)


def _ahead(path: np.ndarray, pose: np.ndarray, reach: float) -> np.ndarray:  # (2,)
    """The first waypoint of ``path`` (P, 2), from the one nearest ``pose`` on, at least
    ``reach`` m from it (the last when none is)."""
    d = np.hypot(path[:, 0] - pose[0], path[:, 1] - pose[1])  # (P,)
    i = int(np.argmin(d))
    beyond = np.nonzero(d[i:] >= reach)[0]
    return path[i + int(beyond[0])] if len(beyond) else path[-1]


class DrivePolicy(DriveGuide):
    """``ppo_drive``: the guide's features into the network of ``checkpoint``, its (v, ω) to
    the wheels (the mean action by default; a draw with ``rng`` when not ``deterministic``)."""

    takes_checkpoint = True

    def __init__(
        self,
        context: PolicyContext,
        checkpoint: str | Path,
        deterministic: bool = True,
        **guide: Any,
    ) -> None:
        if not isinstance(context.action_space, spaces.Box):
            raise PolicyError("ppo_drive: needs continuous actions (action.mode: continuous)")
        self.model = load_checkpoint(checkpoint)
        self.deterministic = deterministic
        shape = self.model.observation_space.shape
        want = (feature_size(len(context.beam_angles)),)
        if shape != want or getattr(self.model.action_space, "shape", None) != (2,):
            raise CheckpointError(
                f"checkpoint {str(checkpoint)!r}: not a driving network of this version"
                f" (observations {shape}, actions {self.model.action_space}; expected {want}"
                " and a (v, ω) box)"
            )
        super().__init__(context, **guide)

    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        self.observe(observation)
        return self.acted(self.unit_action(self.features(), rng))

    def unit_action(self, features: np.ndarray, rng: np.random.Generator) -> np.ndarray:  # (2,)
        """The network's action on the unit box for ``features``."""
        import torch

        policy = self.model.policy
        with torch.no_grad():
            dist = policy.get_distribution(policy.obs_to_tensor(features[None])[0]).distribution
            mean = dist.mean.numpy().reshape(-1).astype(float)
            if self.deterministic:
                return np.clip(mean, -1.0, 1.0)
            std = dist.stddev.numpy().reshape(-1).astype(float)
        return np.clip(mean + std * rng.standard_normal(2), -1.0, 1.0)


class TeamDrivePolicy(DrivePolicy, TeamDriveGuide):
    """A driving network behind a :class:`TeamDriveGuide` (the policy ``ppo``'s driver; a
    team built with :func:`drive_team` shares one radio)."""


def drive_team(
    contexts: list[PolicyContext],
    checkpoint: str | Path,
    deterministic: bool = True,
    links: Links | None = None,
) -> dict[str, TeamDrivePolicy]:
    """The :class:`TeamDrivePolicy` of every robot of a team, sharing one radio (reaching as
    far as the env's channel with its ``links``: :func:`~policies.radio.team_radio`)."""
    radio = team_radio(contexts, links)
    return {c.agent: TeamDrivePolicy(c, checkpoint, deterministic, radio=radio) for c in contexts}


def make_ppo_drive(
    context: PolicyContext, checkpoint: str | Path | None = None, deterministic: bool = True
) -> DrivePolicy:
    """The policy ``ppo_drive`` of ``checkpoint`` (the shipped one when None)."""
    return DrivePolicy(context, _checkpoint("ppo_drive", SHIPPED_DRIVE, checkpoint), deterministic)


def make_ppo_careful(
    context: PolicyContext, checkpoint: str | Path | None = None, deterministic: bool = True
) -> DrivePolicy:
    """The policy ``ppo_careful`` (``ppo_drive`` fine-tuned with the ``map_error`` term) of
    ``checkpoint`` (the shipped one when None)."""
    return DrivePolicy(
        context, _checkpoint("ppo_careful", SHIPPED_CAREFUL, checkpoint), deterministic
    )


def _checkpoint(name: str, shipped: Path, checkpoint: str | Path | None) -> str | Path:
    """``checkpoint``, or the shipped one of policy ``name`` when None (one line if missing)."""
    if checkpoint is not None:
        return checkpoint
    if not shipped.is_file():
        raise CheckpointError(
            f"{name}: no checkpoint given and the shipped one is missing"
            f" ({shipped}); pass --checkpoint FILE (one written by polyslam train"
            " with control: drive)"
        )
    return shipped


make_ppo_drive.takes_checkpoint = True  # type: ignore[attr-defined]
make_ppo_careful.takes_checkpoint = True  # type: ignore[attr-defined]

"""The reward of ``polyslam_v0``: named terms per robot, combined with weights from config.

The terms are pure functions of what the step's stages produced (coverage gains, map changes,
collisions); they never change the episode state. ``coverage``, ``mapping`` and ``map_error``
are **privileged**: computed from ground truth (the true walls, the true poses), which the
robots never see. The bookkeeping behind them (sweeping the coverage grid, tracking
completeness, map error and bytes sent) is done by the stages
:func:`~polyslam_env.environment.stages.sweep_coverage` and
:func:`~polyslam_env.environment.stages.map_bookkeeping`, which return what changed.
"""

from __future__ import annotations

import operator
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from polyslam_env.environment.config import RewardConfig

__all__ = ["MAPPING_STEP", "MAPPING_TOL", "REWARD_TERMS", "MapChanges", "combine", "reward_terms"]

#: Names of the reward terms, in the order they appear in ``infos[agent]["reward_terms"]``.
REWARD_TERMS: tuple[str, ...] = (
    "coverage",
    "mapping",
    "map_error",
    "bytes",
    "collision",
    "time",
)
#: Sampling step (m) and tolerance (m) of the completeness behind the ``mapping`` term; the
#: map error behind the ``map_error`` term is sampled with the same step.
MAPPING_STEP, MAPPING_TOL = 0.05, 0.05


@dataclass(frozen=True)
class MapChanges:
    """What changed in each acting robot's map bookkeeping during one step (robot → value)."""

    completeness: Mapping[int, float]  # change of map completeness (0 when not re-evaluated)
    bytes_sent: Mapping[int, int]  # bytes sent this step
    map_error: Mapping[int, float]  # change of map error ∫δ ds, m² (0 when not re-evaluated)


def reward_terms(
    acting: Mapping[str, int],
    collided: np.ndarray,
    gains: np.ndarray,
    changes: MapChanges,
) -> dict[str, dict[str, float]]:
    """The unweighted terms of every acting agent (name → robot), from the step's collisions
    (N,), coverage gains (N,) m² and map changes; see the env's class docstring."""
    return {
        agent: {
            "coverage": float(gains[i]),
            "mapping": changes.completeness[i],
            "map_error": -changes.map_error[i],
            "bytes": -changes.bytes_sent[i] / 1000.0,
            "collision": -1.0 if collided[i] else 0.0,
            "time": -1.0,
        }
        for agent, i in acting.items()
    }


#: The weights of :data:`REWARD_TERMS` of a ``RewardConfig``, in that order, in one call.
_weights = operator.attrgetter(*REWARD_TERMS)


def combine(terms: Mapping[str, Mapping[str, float]], weights: RewardConfig) -> dict[str, float]:
    """Σ weight · term per agent; the team mean for everyone in shared mode."""
    w = dict(zip(REWARD_TERMS, _weights(weights), strict=True))  # looked up once per step
    rewards = {
        agent: float(sum([w[name] * value for name, value in t.items()]))
        for agent, t in terms.items()
    }
    if weights.shared and rewards:
        mean = float(np.mean(list(rewards.values())))
        rewards = dict.fromkeys(rewards, mean)
    return rewards

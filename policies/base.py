"""The policy interface, the static facts a policy may know, and the policy registry (SPEC §7).

A :class:`Policy` sees only its agent's observation and a :class:`PolicyContext`: the spaces
and the env's public facts (``env.unwrapped.public_facts()``: beam angles, ranges, speed limits,
dt, observation layout, map and its size), taken once at construction. It never holds the env,
so it cannot read ground truth. Policies import nothing of ``polyslam_env`` but ``core`` and
``scenarios`` (``tests/test_architecture.py`` checks it).

``make_policy(name, env, agent, **kwargs)`` builds one by registry name; :class:`TeamPolicy`
holds one per agent. New policies register a factory ``factory(context, **kwargs) -> Policy``
in :data:`POLICIES`, either the callable itself or a ``"module:attribute"`` string that is
imported only when the policy is made (so torch loads only for learned policies).
"""

from __future__ import annotations

import importlib
import inspect
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from polyslam_env.core.errors import PolyslamError

__all__ = [
    "POLICIES",
    "CheckpointError",
    "Policy",
    "PolicyContext",
    "PolicyError",
    "PolicyFactory",
    "TeamPolicy",
    "make_policy",
    "make_team",
    "policy_factory",
    "policy_names",
]


class PolicyError(PolyslamError, ValueError):
    """A policy cannot be made or cannot run with this env (name, map, action mode...)."""


class CheckpointError(PolicyError):
    """A policy checkpoint is missing, unreadable, or does not fit the env."""


@dataclass(frozen=True, eq=False)
class PolicyContext:
    """What a policy may know besides its observation: static, public facts of the env."""

    agent: str
    index: int  # the agent's number i in robot_i
    num_robots: int
    map: str  # the env config's map value (a name, a path or "generator:<name>")
    map_file: Path | None  # the map file it resolves to (None for generator maps)
    observation_space: spaces.Space[Any]
    action_space: spaces.Space[Any]
    action_mode: str  # "continuous" or "discrete"
    discrete: np.ndarray  # (K, 2) physical (v, ω) of each discrete action
    obs_mode: str  # "vector" or "grid"
    vector_layout: Mapping[str, slice]  # parts of the flat vector (see ObservationEncoder)
    grid_size: int  # G of the local G × G map
    grid_resolution: float  # m per local map cell
    pose_scale: float  # m; the observed position is pose / pose_scale
    pose_std_scale: tuple[float, float, float]  # the observed pose std is std / this, in [0, 1]
    p0_sigma: tuple[float, float, float] | None  # the start prior's std (None: no SLAM)
    map_size: tuple[float, float]  # m, width and height of the map's bounding box
    beam_angles: np.ndarray  # (B,) rad, in the robot frame
    max_range: float  # m
    camera_range: float  # m
    radio_range: float  # m, the channel's range (policies.radio: a longer one links unseen)
    robot_radius: float  # m
    v_max: float  # m/s
    omega_max: float  # rad/s
    allow_reverse: bool
    dt: float  # s, control period
    max_steps: int

    @classmethod
    def from_env(cls, env: Any, agent: str) -> PolicyContext:
        """The context of ``agent`` in a ``polyslam_v0`` env, from its public facts and spaces
        (read once, never kept)."""
        if agent not in env.possible_agents:
            raise PolicyError(
                f"unknown agent {agent!r}; agents are {', '.join(env.possible_agents)}"
            )
        return cls(
            agent=agent,
            index=list(env.possible_agents).index(agent),
            observation_space=env.observation_space(agent),
            action_space=env.action_space(agent),
            **env.unwrapped.public_facts(),
        )

    # -- decoding the observation -----------------------------------------------------------
    def vector(self, observation: Any) -> np.ndarray:  # (D,)
        """The flat vector part of an observation (either mode)."""
        if isinstance(observation, Mapping):
            return np.asarray(observation["vector"], dtype=float)
        return np.asarray(observation, dtype=float)

    def ranges(self, observation: Any) -> np.ndarray:  # (B,) m, inf = no return
        """The beam ranges in metres (no return → inf)."""
        vec = self.vector(observation)
        r = vec[self.vector_layout["ranges"]] * self.max_range
        return np.where(vec[self.vector_layout["no_return"]] > 0.5, np.inf, r)

    def pose(self, observation: Any) -> np.ndarray:  # (3,)
        """The robot's pose estimate (x, y, θ) in its own start frame."""
        x, y, c, s = self.vector(observation)[self.vector_layout["pose"]]
        return np.array([x * self.pose_scale, y * self.pose_scale, math.atan2(s, c)])

    def relative_pose_std(self, observation: Any) -> np.ndarray | None:  # (3,)
        """Standard deviations (m, m, rad) of the pose relative to where the robot really
        started, the filter's own uncertainty P_S: the observed variances less the start
        prior's share, diag(J P0 Jᵀ) = (σx0² + y²σθ0², σy0² + x²σθ0², σθ0²) at the estimated
        (x, y) (P0 diagonal). It grows while the robot maps new ground and shrinks when it sees
        a well-known place again; the share of P0 does not (nothing the robot senses can tell
        where it started). None without SLAM or when an observed deviation is clipped."""
        if self.p0_sigma is None:
            return None
        scaled = self.vector(observation)[self.vector_layout["pose_std"]]
        if np.any(scaled >= 1.0):
            return None
        var = np.square(scaled * np.asarray(self.pose_std_scale))
        x, y, _ = self.pose(observation)
        sx, sy, st = self.p0_sigma
        share = np.array([sx * sx + y * y * st * st, sy * sy + x * x * st * st, st * st])
        return np.sqrt(np.maximum(var - share, 0.0))

    def detections(self, observation: Any) -> np.ndarray:  # (k, 2) distance m, bearing rad
        """The other robots the camera sees, nearest first, as (distance, bearing)."""
        slots = self.vector(observation)[self.vector_layout["detections"]].reshape(-1, 4)
        seen = slots[slots[:, 0] > 0.5]
        return np.column_stack([seen[:, 1] * self.camera_range, np.arctan2(seen[:, 3], seen[:, 2])])

    def local_grid(self, observation: Any) -> np.ndarray:  # (3, G, G) bool: occ, free, unknown
        """The egocentric local map as occupied / free / unknown channels (either mode)."""
        if isinstance(observation, Mapping):
            return np.asarray(observation["grid"]) > 0.5
        g = self.grid_size
        flat = self.vector(observation)[self.vector_layout["local_map"]].reshape(g, g)
        occ, unknown = flat > 0.75, np.abs(flat - 0.5) < 0.25  # values are 0, 0.5 or 1
        return np.stack([occ, ~(occ | unknown), unknown])

    # -- encoding the action ----------------------------------------------------------------
    def action(self, v: float, omega: float) -> Any:
        """(v, ω) in physical units as an action of this env: clipped to the limits
        (continuous, float32) or the nearest discrete action (relative to the limits)."""
        v_lo = -self.v_max if self.allow_reverse else 0.0
        # min(max(x, lo), hi) is numpy's clip of a scalar, signed zeros and nan included
        v = float(min(max(v, v_lo), self.v_max))
        omega = float(min(max(omega, -self.omega_max), self.omega_max))
        if self.action_mode == "discrete":
            scale = np.array([self.v_max, self.omega_max])
            d = np.sum(((self.discrete - (v, omega)) / scale) ** 2, axis=1)  # (K,)
            return np.int64(np.argmin(d))
        return np.array([v, omega], dtype=np.float32)


class Policy(ABC):
    """Maps one agent's observation to an action; state lives between ``reset`` calls."""

    def __init__(self, context: PolicyContext) -> None:
        self.context = context

    def reset(self, seed: int | None = None) -> None:  # noqa: B027 - stateless by default
        """Forget the last episode (called before every episode)."""

    @abstractmethod
    def act(self, observation: Any, rng: np.random.Generator) -> Any:
        """The action for ``observation``; all randomness comes from ``rng``."""

    def metrics(self) -> dict[str, float]:
        """Figures of the episode so far that only the policy knows (e.g. the bytes of the
        messages it sent), added to its robot's results by ``polyslam evaluate``; none here."""
        return {}


PolicyFactory = Callable[..., Policy]
#: Policy name → ``factory(context, **kwargs)`` or a lazy ``"module:attribute"`` string.
POLICIES: dict[str, PolicyFactory | str] = {
    "paper": "policies.scripted:PaperPolicy",
    "frontier": "policies.frontier:FrontierPolicy",
    "frontier_closing": "policies.frontier:frontier_closing",
    "frontier_team": "policies.team:frontier_team",
    "wall_follow": "policies.scripted:WallFollowPolicy",
    "random": "policies.scripted:RandomPolicy",
    "ppo": "policies.ppo:make_ppo",
    "ppo_goals": "policies.ppo:make_ppo_goals",
    "ppo_drive": "policies.drive:make_ppo_drive",
    "ppo_careful": "policies.drive:make_ppo_careful",
}


def policy_names() -> list[str]:
    """The registered policy names, sorted."""
    return sorted(POLICIES)


def policy_factory(name: str) -> PolicyFactory:
    """The factory registered as ``name`` (imported now if lazy); unknown names raise."""
    entry = POLICIES.get(name)
    if entry is None:
        raise PolicyError(f"unknown policy {name!r}; policies are {', '.join(policy_names())}")
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        try:
            factory: PolicyFactory = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as err:
            raise PolicyError(f"policy {name!r} is not available: {err}") from None
        return factory
    return entry


def make_policy(name: str, env: Any, agent: str, **kwargs: Any) -> Policy:
    """The policy ``name`` for ``agent`` of ``env``; ``kwargs`` go to its factory.

    ``checkpoint=None`` is dropped; a checkpoint given to a policy that takes none is an error.
    """
    if kwargs.get("checkpoint", 0) is None:
        kwargs.pop("checkpoint")
    factory = policy_factory(name)
    context = PolicyContext.from_env(env, agent)
    if "checkpoint" in kwargs and not getattr(factory, "takes_checkpoint", False):
        raise PolicyError(f"policy {name!r} takes no checkpoint, got {kwargs['checkpoint']!r}")
    if "checkpoint" not in kwargs and _needs_checkpoint(factory):
        raise CheckpointError(
            f"policy {name!r} needs a checkpoint file (checkpoint=...; polyslam: --checkpoint"
            " FILE, e.g. one written by polyslam train)"
        )
    return factory(context, **kwargs)


def _needs_checkpoint(factory: PolicyFactory) -> bool:
    """Whether ``factory`` has a ``checkpoint`` parameter without a default."""
    try:
        param = inspect.signature(factory).parameters.get("checkpoint")
    except (TypeError, ValueError):  # a callable without a signature: let it decide
        return False
    return param is not None and param.default is inspect.Parameter.empty


class TeamPolicy:
    """One policy per agent: ``{agent: observation}`` → ``{agent: action}``."""

    def __init__(self, policies: Mapping[str, Policy]) -> None:
        self.policies = dict(policies)

    def reset(self, seed: int | None = None) -> None:
        """Reset every member; member i gets ``seed + i`` (None stays None)."""
        for i, policy in enumerate(self.policies.values()):
            policy.reset(None if seed is None else seed + i)

    def act(self, observations: Mapping[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        """Actions of the agents present in ``observations``, in the team's agent order."""
        return {
            agent: policy.act(observations[agent], rng)
            for agent, policy in self.policies.items()
            if agent in observations
        }


def make_team(name: str, env: Any, **kwargs: Any) -> TeamPolicy:
    """The same policy ``name`` for every agent of ``env``. A factory with a ``team``
    attribute makes the whole team at once, ``factory.team(contexts, **kwargs)`` → ``{agent:
    policy}`` (team-mates that share something, e.g. ``frontier_team``'s radio); one whose
    ``takes_links`` is set also gets ``links=env.unwrapped.radio_links``, the medium's
    distance test for that radio (``policies.radio``: the policies never see positions)."""
    factory = policy_factory(name)
    build_team = getattr(factory, "team", None)
    if build_team is None:
        return TeamPolicy({a: make_policy(name, env, a, **kwargs) for a in env.possible_agents})
    checkpoint = kwargs.pop("checkpoint", None)
    if checkpoint is not None:
        if not getattr(factory, "takes_checkpoint", False):
            raise PolicyError(f"policy {name!r} takes no checkpoint, got {checkpoint!r}")
        kwargs["checkpoint"] = checkpoint
    if getattr(factory, "takes_links", False):
        kwargs["links"] = env.unwrapped.radio_links
    contexts = [PolicyContext.from_env(env, a) for a in env.possible_agents]
    return TeamPolicy(build_team(contexts, **kwargs))

"""The PettingZoo parallel environment ``polyslam_v0`` (SPEC §6).

This module owns the env's public face: construction (config, spaces, layout source,
observation encoder, renderer), action validation, and ``reset``/``step``, which make the
:class:`~polyslam_env.environment.state.EpisodeState` and run the stages of
:mod:`polyslam_env.environment.stages` in order: apply actions → simulate → sense → SLAM →
exchange → record → observe → coverage sweep → map bookkeeping → reward terms → combine →
done → infos. Observations come from on-board knowledge only
(:mod:`polyslam_env.environment.observations`); rewards (:mod:`~polyslam_env.environment.rewards`)
may use ground truth; rendering reads a :class:`~polyslam_env.render.state.RenderState` and
never feeds observations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

from polyslam_env import metrics
from polyslam_env.comms.channel import in_radio_range
from polyslam_env.core.errors import ConfigError, MapFileError
from polyslam_env.core.seeding import make_rngs
from polyslam_env.environment import stages
from polyslam_env.environment.config import EnvConfig, resolve_config
from polyslam_env.environment.facts import public_facts, radio_range
from polyslam_env.environment.faults import FaultEvent, FaultPlan
from polyslam_env.environment.observations import ObservationEncoder
from polyslam_env.environment.rewards import REWARD_TERMS, combine, reward_terms
from polyslam_env.environment.state import EpisodeState, estimates
from polyslam_env.render.state import RenderState
from polyslam_env.world.generators import LayoutGenerator, make_generator
from polyslam_env.world.grid import FreeGrid, free_space_grid
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map

if TYPE_CHECKING:
    from polyslam_env.render.renderer import Renderer

__all__ = ["REWARD_TERMS", "PolySlamParallelEnv", "env", "parallel_env"]

Obs = np.ndarray | dict[str, np.ndarray]
Action = Any


class PolySlamParallelEnv(ParallelEnv[str, Obs, Action]):
    """A team of robots explores a 2D world, each running its own polynomial EKF SLAM.

    ## Description
    ``N`` differential-drive robots (pymunk physics) carry range beams and a 360° camera. Every
    robot runs its own polynomial-landmark EKF SLAM (or another ``slam.backend``) in its own
    start frame; when two robots see each other (rendezvous; or, in ``channel.mode``
    ``alignment``, are within radio range) they exchange the polynomials extracted since their
    last meeting over a lossy channel whose bytes are counted. Agents are ``robot_0 … robot_{N−1}``.

    ## Action Space
    ``continuous``: ``Box([v_lo, −ω_max], [v_max, ω_max], float32)`` with ``v_lo = −v_max``
    (or 0 without reverse), units m/s and rad/s. Out-of-range values are **clipped** to the
    limits; NaN/inf or complex values raise ``ValueError`` naming the agent. ``discrete``:
    ``Discrete(K)``, action ``a`` drives ``action.discrete[a] · (v_max, ω_max)``; an index
    outside ``0..K−1`` raises. Actions for agents that already left are ignored; an unknown
    agent name raises ``KeyError``, as does a missing action for a live agent.

    ## Observation Space
    Only on-board knowledge, float32, all values in [−1, 1]. ``vector`` mode, a flat ``Box``:
    ranges/r_max (no return → 1), a no-return flag per beam, the pose estimate
    ``(x/s, y/s, cos θ, sin θ)`` in the robot's start frame (``s``: ``observation.pose_scale``
    or, for ``None``, the larger of 20 m and the map's reach, its diagonal + r_max; clipped),
    pose standard deviations ``(σx/1 m, σy/1 m, σθ/π)`` clipped to 1, the
    egocentric ``G × G`` local map flattened (0 free, 0.5 unknown, 1 occupied; x forward along
    columns, y left along rows, the robot in the centre cell, rotated with the *estimated*
    heading; occupied = the robot's own polynomials, free = cells its own beams swept, placed
    with its estimated poses), camera slots nearest first ``(seen, d/range, cos α, sin α)``,
    channel state ``(steps since last rendezvous / max_steps (1 if never), min(count,
    cap)/cap)`` and ``step / max_steps``. ``grid`` mode: ``Dict(grid=Box(0, 1, (3, G, G)),
    vector=...)`` with channels (occupied, free, unknown) and the same vector minus the map.
    With ``slam_enabled=False`` the "estimate" is the true pose in the start frame with zero
    std, and beam end points mark occupied cells.

    ## Rewards
    Named terms per robot, unweighted in ``infos[agent]["reward_terms"]`` every step:
    ``coverage`` m² of free cells (coverage grid) first swept by the team this step with this
    robot's beams (placed with the true pose; a cell first swept by two robots at once counts
    for both); ``mapping`` the change of the robot's map completeness (share of the true
    boundary within 5 cm of its polynomials, sampled every 5 cm), re-evaluated only in steps
    where its map changed structurally (a landmark created, refit, merged or received), else 0;
    ``map_error`` −(change of the robot's map error ∫δ ds, m²: the distance δ of each map point
    to the nearest true wall integrated over the map's length, sampled every 5 cm, the map
    placed by the robot's true start), re-evaluated on the same steps, else 0 — negative when
    the map gets worse, positive when it improves, and deleting correct map earns nothing;
    ``bytes`` −bytes sent this step / 1000; ``collision`` −1 on a step with a collision;
    ``time`` −1. Reward = Σ weight · term (``reward.*``); with ``reward.shared`` every robot
    gets the mean over the robots that acted this step. ``coverage``, ``mapping`` and
    ``map_error`` are **privileged**: computed from ground truth the robots never observe
    (fine for training signals, not available on a real robot).

    ## Episode End
    Termination for all when the team coverage reaches ``coverage_target`` (``None``: never,
    the episode runs to ``max_steps``, e.g. to replay fixed paths); truncation for all
    at ``max_steps``. A fault ``(robot, step)`` (kind ``fail``) disables the robot at the end of
    env step ``step``: it is terminated and leaves ``agents``, stays as an obstacle, and the
    others go on. Kinds ``kidnap`` and ``slip`` (see ``FaultConfig``) move the true pose unseen
    by odometry, or make the odometry over-report the motion; ``infos[agent]`` holds the
    step's ``faults`` and the divergence flag (``diverging``, ``diverged_at``). At an agent's
    last step ``infos[agent]`` also holds ``"metrics"`` (per robot: nees, nees_rel, start_nees,
    nees_paper, nu, nu_mean, nu_mean_abs, completeness, completeness_seen, map_precision,
    duplicates, has_map, pose_error, landmark_error, has_landmarks, slam, coverage, bytes_sent,
    bytes_received,
    rendezvous, alignments_attempted, alignments_accepted, alignments_wrong, slam_time_ms
    (wall time, not reproducible), collisions, path_length; never NaN: a robot without a map
    has has_map 0 and the values stated in :mod:`polyslam_env.metrics.mapping`, one without a
    pillar map has_landmarks 0, without SLAM slam 0; map metrics place the map by the robot's
    true start, nu_mean_abs by its nominal frame) and ``"team"`` (coverage, steps_to_50,
    steps_to_90, overlap).

    ## SLAM back-ends
    ``slam.backend``: ``polynomial`` (the default, above) or a point-landmark filter over the
    pillars (``fastslam2``, ``em_fastslam``, ``mblcc``, ``multirobot_known_start``,
    ``seif``; needs ``world.pillar_sensor.enabled``): the same stages, observations (its map
    points are its landmark estimates) and rewards (no wall map: ``mapping`` and ``map_error``
    stay 0); see :mod:`polyslam_env.slam.backends`.

    ## Arguments
    ``parallel_env(config=None, render_mode=None, **overrides)``: ``config`` an
    :class:`~polyslam_env.environment.config.EnvConfig`, a dict or a YAML path; overrides use ``__``
    for nested keys (``reward__coverage=2.0``); ``max_cycles`` (PettingZoo's name) is an alias
    of ``max_steps``. ``render_mode`` is ``"human"``, ``"rgb_array"`` or None. ``reset(seed)``
    makes the episode bit-identical for a seed (an integer >= 0; anything else raises
    ``TypeError``/``ValueError`` naming ``seed``); a reset without seed after a seeded one
    continues a seeded sequence of episodes.

    ## Version History
    * v0: initial version. Later in v0, with episodes unchanged bit for bit: the episode's
      internals moved from env attributes (``env.world``, ``env.coverage``, ``env.slams``,
      ``env.step_count``) to one :class:`~polyslam_env.environment.state.EpisodeState`,
      ``env.episode`` (None before the first reset); ``max_cycles`` is accepted as an alias of
      ``max_steps``; ``public_facts()`` gives policies the env's static facts. Issue 14
      (episodes change): ``initial_error`` (default on) draws the true starts from P0; fault
      kinds ``kidnap`` and ``slip``; ``diverging``/``diverged_at``/``faults`` in ``infos``.
      Observations for maps of any size: ``observation.belief_size`` and ``pose_scale``
      default to ``None``, derived from the map's bounding box (a public fact, ``map_size``),
      so every start fits and no position estimate is clipped; on maps whose reach is under
      20 m the observations are as before. Issue 15 (episodes unchanged bit for bit): the
      world's sensing, guard and drive forces, the coverage and belief sweeps and the
      observations run on compiled kernels (numba), the team's observations in one pass.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "polyslam_v0",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | str | Path | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = resolve_config(config, **overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode: must be one of {self.metadata['render_modes']} or None,"
                f" got {render_mode!r}"
            )
        self.render_mode = render_mode
        cfg = self.config
        n = cfg.num_robots
        self.possible_agents = [f"robot_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._layout, self._generator = self._layout_source()
        self._free: FreeGrid | None = None
        if self._layout is not None:
            self._free = free_space_grid(self._layout, cfg.coverage_resolution)
        self._map_size = self._bounding_size()
        self._encoder = ObservationEncoder(cfg, self._map_size)
        self._observation_spaces = {a: self._make_obs_space() for a in self.possible_agents}
        self._action_spaces = {a: self._make_action_space() for a in self.possible_agents}
        self._discrete = np.array(cfg.action.discrete) * (
            cfg.world.robot.v_max,
            cfg.world.robot.omega_max,
        )  # (K, 2) physical (v, ω)
        self._is_discrete = cfg.action.mode == "discrete"
        self._faults = FaultPlan(cfg)
        self._seeder: np.random.Generator | None = None
        # The current episode, made by reset(). Not named ``state``: that is PettingZoo's
        # global-state method ``ParallelEnv.state()``, which this env leaves unimplemented.
        self.episode: EpisodeState | None = None
        self._renderer: Renderer | None = None
        self._renderer_layout: Layout | None = None

    # -- construction helpers ---------------------------------------------------------------
    def _layout_source(self) -> tuple[Layout | None, LayoutGenerator | None]:
        """A fixed layout (checked now, so a bad map fails at construction) or a generator."""
        cfg = self.config
        radius = cfg.world.robot.radius
        gen = cfg.generator_name
        if gen is not None:
            params = {"num_start_poses": cfg.num_robots, "robot_radius": radius}
            params.update(dict(cfg.map_params or {}))
            return None, make_generator(gen, **params)
        layout = load_map(cfg.map, robot_radius=radius)
        if layout.num_start_poses < cfg.num_robots:
            raise MapFileError(
                f"map {cfg.map!r}: start_poses has {layout.num_start_poses} poses,"
                f" num_robots={cfg.num_robots} needs one each"
            )
        return layout, None

    def _bounding_size(self) -> tuple[float, float]:
        """(width, height) m of the map's bounding box: the fixed layout's, or the box a
        generator draws in (its ``width`` and ``height``). A public fact, as a floor plan's
        dimensions are; where a robot starts in the map is not."""
        if self._layout is not None:
            x0, y0, x1, y1 = self._layout.bounds
            return (x1 - x0, y1 - y0)
        width = getattr(self._generator, "width", None)
        height = getattr(self._generator, "height", None)
        if not isinstance(width, int | float) or not isinstance(height, int | float):
            raise ConfigError(
                f"map {self.config.map!r}: the generator declares no width and height, so the"
                " map's size is unknown"
            )
        return (float(width), float(height))

    def _make_obs_space(self) -> spaces.Space[Any]:
        """A fresh copy per agent (each agent's space is seeded on its own)."""
        enc = self._encoder
        vec = spaces.Box(enc.vector_space.low, enc.vector_space.high, dtype=np.float32)
        if enc.mode == "grid":
            grid = spaces.Box(0.0, 1.0, (3, enc.g, enc.g), dtype=np.float32)
            return spaces.Dict({"grid": grid, "vector": vec})
        return vec

    def _make_action_space(self) -> spaces.Space[Any]:
        rc = self.config.world.robot
        if self.config.action.mode == "discrete":
            return spaces.Discrete(len(self.config.action.discrete))
        v_lo = -rc.v_max if rc.allow_reverse else 0.0
        low = np.array([v_lo, -rc.omega_max], dtype=np.float32)
        high = np.array([rc.v_max, rc.omega_max], dtype=np.float32)
        return spaces.Box(low, high, dtype=np.float32)

    def public_facts(self) -> dict[str, Any]:
        """Static facts a policy may know (beam angles, limits, dt, observation layout, map);
        see :func:`~polyslam_env.environment.facts.public_facts`."""
        return public_facts(self.config, self._map_size)

    def radio_links(self) -> np.ndarray:  # (N, N) bool
        """Which robots are within the channel's ``range`` (the public fact ``radio_range``)
        of each other now, from their true positions: the radio medium's distance test, as
        the channel makes it for its own deliveries (``comms.channel.in_radio_range``), for a
        radio that a team's policies share (``policies.radio.Radio``), which delivers by it and
        keeps no position. Raises before the first ``reset``."""
        if self.episode is None:
            raise RuntimeError("radio_links: call reset() first")
        return in_radio_range(self.episode.world.poses, radio_range(self.config))

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        """``agent``'s observation space (the class docstring's Observations; the same for
        every robot); an unknown agent raises ``KeyError`` naming the agents."""
        return self._observation_spaces[self._check_agent(agent)]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        """``agent``'s action space: ``Box`` of (v, ω) in m/s and rad/s, or ``Discrete`` with
        ``action__mode="discrete"``; an unknown agent raises ``KeyError``."""
        return self._action_spaces[self._check_agent(agent)]

    def _check_agent(self, agent: str) -> str:
        if agent not in self._index:
            raise KeyError(f"unknown agent {agent!r}; agents are {', '.join(self.possible_agents)}")
        return agent

    # -- reset -----------------------------------------------------------------------------
    def _episode_seed(self, seed: int | None) -> int | None:
        """The seed of this episode: ``seed``, or the next of a seeded sequence, or None."""
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
                raise TypeError(f"seed: expected a non-negative integer or None, got {seed!r}")
            if seed < 0:
                raise ValueError(f"seed: must be >= 0, got {seed}")
            self._seeder = np.random.default_rng(seed)
            return seed
        if self._seeder is not None:
            return int(self._seeder.integers(2**63))
        return None

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Obs], dict[str, dict[str, Any]]]:
        """A new episode: new layout (generator maps), new pymunk world, fresh SLAMs."""
        rngs = make_rngs(self._episode_seed(seed))
        layout = self._layout
        if layout is None:
            assert self._generator is not None
            layout = self._generator(rngs["layout"])
        free = self._free
        if free is None:
            free = free_space_grid(layout, self.config.coverage_resolution)
        last = self.episode.world if self.episode is not None else None
        self.episode = state = stages.new_episode(self.config, rngs, layout, free, last)
        self.agents = self.possible_agents[:]
        observations = stages.observe(state, self._encoder, self._acting(), estimates(state))
        return observations, {a: {} for a in self.agents}

    def _acting(self) -> dict[str, int]:
        """The live agents and their robot indices."""
        return {agent: self._index[agent] for agent in self.agents}

    # -- step: the pipeline -----------------------------------------------------------------
    def step(
        self, actions: Mapping[str, Action]
    ) -> tuple[
        dict[str, Obs],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """Advance every live robot by one control period (see the class docstring)."""
        state = self.episode
        if state is None or not self.agents:
            raise RuntimeError("step() called with no live agents; call reset() first")
        acting = self._acting()
        commands = self._apply_actions(actions)
        state.step_count += 1
        result = stages.simulate(state.world, commands, self._faults.slip(state.step_count))
        events = stages.inject_faults(state, self._faults)
        state.sensing = stages.sense(state.world)
        slam_infos = stages.slam(state, result.odometry)
        exchanged = stages.exchange(state)
        robot_estimates = estimates(state)
        stages.record_histories(state, result, slam_infos, robot_estimates)
        observations = stages.observe(state, self._encoder, acting, robot_estimates)
        gains = stages.sweep_coverage(state)
        changes = stages.map_bookkeeping(state, acting, slam_infos, exchanged)
        terms = reward_terms(acting, result.collided, gains, changes)
        rewards = combine(terms, self.config.reward)
        failed = stages.fail_robots(state, acting, self._faults.fail_at)
        events += [FaultEvent("fail", i, state.step_count) for i in sorted(failed)]
        terminations, truncations = stages.done(state, self.config, acting, failed)
        infos = stages.infos(state, acting, terms, terminations, truncations, events)
        self.agents = [a for a in acting if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, infos

    def _apply_actions(self, actions: Mapping[str, Action]) -> np.ndarray:  # (N, 2)
        """Validate the actions and turn them into (v, ω) commands (clipped by the world)."""
        for agent in actions:
            self._check_agent(agent)
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise KeyError(f"no action for live agent(s) {', '.join(missing)}")
        commands = np.zeros((self.config.num_robots, 2))
        for agent in self.agents:  # actions of agents that already left are ignored
            commands[self._index[agent]] = self._command(agent, actions[agent])
        return commands

    def _command(self, agent: str, action: Action) -> np.ndarray | tuple[float, float]:  # (2,)
        if (
            type(action) is np.ndarray
            and action.shape == (2,)
            and action.dtype.kind == "f"
            and not self._is_discrete
        ):  # the common case, checked without numpy calls: a float (v, omega) array
            v, w = action.tolist()
            if math.isfinite(v) and math.isfinite(w):
                return v, w
        if action is None:
            raise ValueError(f"action of {agent}: None for a live agent")
        a = np.asarray(action)
        if not np.issubdtype(a.dtype, np.number):
            raise ValueError(f"action of {agent}: expected numbers, got {action!r}")
        if np.iscomplexobj(a):
            raise ValueError(f"action of {agent}: expected real numbers, got {action!r}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action of {agent}: not finite, got {action!r}")
        if self.config.action.mode == "discrete":
            k = len(self._discrete)
            if (
                a.size != 1
                or float(a.reshape(-1)[0]) % 1 != 0
                or not 0 <= int(a.reshape(-1)[0]) < k
            ):
                raise ValueError(
                    f"action of {agent}: expected an integer in 0..{k - 1}, got {action!r}"
                )
            return np.asarray(self._discrete[int(a.reshape(-1)[0])])
        if a.shape not in ((2,), (1, 2), (2, 1)):
            raise ValueError(f"action of {agent}: expected (v, omega), got shape {a.shape}")
        return a.astype(float).reshape(2)

    # -- rendering -------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """Draw the current state (``human``: a window, returns None; ``rgb_array``: an image)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; nothing to draw")
            return None
        if self.episode is None:
            raise RuntimeError("render() called before reset()")
        layout = self.episode.world.layout
        if self._renderer is None or self._renderer_layout is not layout:
            from polyslam_env.render.renderer import (
                Renderer,
            )  # lazy: pygame loads only when rendering

            if self._renderer is not None:
                self._renderer.close()
            self._renderer = Renderer(
                layout, self.config.num_robots, self.render_mode, self.config.world
            )
            self._renderer_layout = layout
        return self._renderer.render(self.render_state())

    def render_state(self) -> RenderState:
        """A snapshot of the episode for the renderer (ground truth and estimates, absolute).

        Estimates and maps are placed by each robot's **true** start, as the map metrics are:
        the offset of its frame from where it really started is unobservable, so a picture in
        the nominal frame would show that offset as a mapping error on every wall. The
        ellipse is then the filter's own covariance relative to the true start."""
        state = self.episode
        if state is None:
            raise RuntimeError("render_state() called before reset()")
        n = self.config.num_robots
        starts = [h.true[0] for h in state.histories]
        est, own = estimates(state)
        team = state.slam
        relative = [team.pose_cov_relative(i) for i in range(n)]
        cov = np.array([own[i] if c is None else c for i, c in enumerate(relative)])
        est_abs = np.array(
            [metrics.pose_to_absolute(est[i : i + 1], starts[i])[0] for i in range(n)]
        )
        cov_abs = np.array(
            [metrics.cov_to_absolute(cov[i : i + 1], starts[i])[0] for i in range(n)]
        )
        maps = [team.render_map(i, starts[i]) for i in range(n)]
        grid = state.coverage
        return RenderState(
            true_poses=state.world.poses,
            est_poses_abs=est_abs,
            est_covs_abs=cov_abs,
            maps_abs=maps,
            true_paths=[h.true_path() for h in state.histories],
            est_paths=[h.est_path_abs() for h in state.histories],
            links=list(state.links),
            coverage=grid.swept & grid.free,
            coverage_origin=grid.origin,
            coverage_resolution=grid.resolution,
            active=state.world.active.copy(),
            step=state.step_count,
            info_text=f"coverage {100 * grid.coverage:.1f} %",
        )

    def close(self) -> None:
        """Close the render window, if any (calling it again does nothing)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
            self._renderer_layout = None


# -- constructors ---------------------------------------------------------------------------
def parallel_env(
    config: EnvConfig | Mapping[str, Any] | str | Path | None = None,
    render_mode: str | None = None,
    **overrides: Any,
) -> PolySlamParallelEnv:
    """The parallel env; ``config`` an EnvConfig, dict or YAML path, plus ``a__b=`` overrides."""
    return PolySlamParallelEnv(config, render_mode=render_mode, **overrides)


def env(
    config: EnvConfig | Mapping[str, Any] | str | Path | None = None,
    render_mode: str | None = None,
    **overrides: Any,
) -> AECEnv[str, Obs, Action]:
    """The AEC version: ``parallel_to_aec`` (order enforcing) plus, for discrete actions, an
    out-of-bounds assertion."""
    aec = parallel_to_aec(parallel_env(config, render_mode=render_mode, **overrides))
    if aec.unwrapped.config.action.mode == "discrete":
        aec = wrappers.AssertOutOfBoundsWrapper(aec)
    return aec

"""The PettingZoo parallel environment ``polyslam_v0`` (SPEC §6).

``step`` is a pipeline of named stages: apply actions → simulate → sense → SLAM → exchange →
observe → reward → done. Observations come from on-board knowledge only
(:mod:`polyslam_env.environment.observations`); rewards may use ground truth; rendering reads a
:class:`~polyslam_env.render.state.RenderState` and never feeds observations.
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
from polyslam_env.comms.exchange import ExchangeStep, RendezvousExchange
from polyslam_env.core.errors import MapFileError
from polyslam_env.core.seeding import make_rngs
from polyslam_env.environment.config import EnvConfig, resolve_config
from polyslam_env.environment.facts import public_facts
from polyslam_env.environment.observations import (
    BeliefGrid,
    MapSampler,
    ObservationEncoder,
    RobotView,
    sweep_beliefs,
)
from polyslam_env.metrics.episode import RobotHistory, final_robot_metrics, team_metrics
from polyslam_env.render.state import RenderState
from polyslam_env.slam.robot import PolySlam, SlamStepInfo
from polyslam_env.world.generators import LayoutGenerator, make_generator
from polyslam_env.world.grid import FreeGrid, free_space_grid
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import StepResult, World
from polyslam_env.world.sensors import Detection

if TYPE_CHECKING:
    from polyslam_env.render.renderer import Renderer

__all__ = ["REWARD_TERMS", "PolySlamParallelEnv", "env", "parallel_env"]

Obs = np.ndarray | dict[str, np.ndarray]
Action = Any
#: Names of the reward terms, in the order they appear in ``infos[agent]["reward_terms"]``.
REWARD_TERMS: tuple[str, ...] = ("coverage", "mapping", "bytes", "collision", "time")
#: Sampling step (m) and tolerance (m) of the completeness behind the ``mapping`` term.
MAPPING_STEP, MAPPING_TOL = 0.05, 0.05


class PolySlamParallelEnv(ParallelEnv[str, Obs, Action]):
    """A team of robots explores a 2D world, each running its own polynomial EKF SLAM.

    ## Description
    ``N`` differential-drive robots (pymunk physics) carry range beams and a 360° camera. Every
    robot runs its own polynomial-landmark EKF SLAM in its own start frame; when two robots
    see each other (rendezvous) they exchange the polynomials extracted since their last
    meeting over a lossy channel whose bytes are counted. Agents are ``robot_0 … robot_{N−1}``.

    ## Action Space
    ``continuous``: ``Box([v_lo, −ω_max], [v_max, ω_max], float32)`` with ``v_lo = −v_max``
    (or 0 without reverse), units m/s and rad/s. Out-of-range values are **clipped** to the
    limits; NaN/inf raise ``ValueError`` naming the agent. ``discrete``: ``Discrete(K)``, action
    ``a`` drives ``action.discrete[a] · (v_max, ω_max)``; an index outside ``0..K−1`` raises.
    Actions for agents that already left are ignored; an unknown agent name raises
    ``KeyError``, as does a missing action for a live agent.

    ## Observation Space
    Only on-board knowledge, float32, all values in [−1, 1]. ``vector`` mode, a flat ``Box``:
    ranges/r_max (no return → 1), a no-return flag per beam, the pose estimate
    ``(x/s, y/s, cos θ, sin θ)`` in the robot's start frame (``s = observation.pose_scale``,
    clipped), pose standard deviations ``(σx/1 m, σy/1 m, σθ/π)`` clipped to 1, the
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
    ``bytes`` −bytes sent this step / 1000; ``collision`` −1 on a step with a collision;
    ``time`` −1. Reward = Σ weight · term (``reward.*``); with ``reward.shared`` every robot
    gets the mean over the robots that acted this step.

    ## Episode End
    Termination for all when the team coverage reaches ``coverage_target``; truncation for all
    at ``max_steps``. A fault ``(robot, step)`` disables the robot at the end of env step
    ``step``: it is terminated and leaves ``agents``, stays as an obstacle, and the others go
    on. At an agent's last step ``infos[agent]`` also holds ``"metrics"`` (per robot: nees,
    nees_paper, nu, nu_mean, completeness, coverage, bytes_sent, bytes_received, rendezvous,
    slam_time_ms (wall time, not reproducible), collisions, path_length) and ``"team"``
    (coverage, steps_to_50, steps_to_90, overlap).

    ## Arguments
    ``parallel_env(config=None, render_mode=None, **overrides)``: ``config`` an
    :class:`~polyslam_env.environment.config.EnvConfig`, a dict or a YAML path; overrides use ``__``
    for nested keys (``reward__coverage=2.0``). ``render_mode`` is ``"human"``,
    ``"rgb_array"`` or None. ``reset(seed)`` makes the episode bit-identical for a seed; a
    reset without seed after a seeded one continues a seeded sequence of episodes.

    ## Version History
    * v0: initial version.
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
        self._encoder = ObservationEncoder(cfg)
        self._observation_spaces = {a: self._make_obs_space() for a in self.possible_agents}
        self._action_spaces = {a: self._make_action_space() for a in self.possible_agents}
        self._discrete = np.array(cfg.action.discrete) * (
            cfg.world.robot.v_max,
            cfg.world.robot.omega_max,
        )  # (K, 2) physical (v, ω)
        self._fault_at = {robot: step for robot, step in cfg.faults}
        self._seeder: np.random.Generator | None = None
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
        return public_facts(self.config)

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._observation_spaces[self._check_agent(agent)]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._action_spaces[self._check_agent(agent)]

    def _check_agent(self, agent: str) -> str:
        if agent not in self._index:
            raise KeyError(f"unknown agent {agent!r}; agents are {', '.join(self.possible_agents)}")
        return agent

    # -- reset -----------------------------------------------------------------------------
    def _episode_seed(self, seed: int | None) -> int | None:
        """The seed of this episode: ``seed``, or the next of a seeded sequence, or None."""
        if seed is not None:
            self._seeder = np.random.default_rng(seed)
            return seed
        if self._seeder is not None:
            return int(self._seeder.integers(2**63))
        return None

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Obs], dict[str, dict[str, Any]]]:
        """A new episode: new layout (generator maps), new pymunk world, fresh SLAMs."""
        cfg = self.config
        n = cfg.num_robots
        self._rngs = make_rngs(self._episode_seed(seed))
        layout = self._layout if self._layout is not None else self._draw_layout()
        free = (
            self._free
            if self._free is not None
            else free_space_grid(layout, cfg.coverage_resolution)
        )
        self.world = World(layout, cfg.world, n, self._rngs)
        self.coverage = metrics.CoverageGrid(free.mask, free.origin, free.resolution)
        self.start_poses = self.world.poses  # (N, 3), each robot's frame in the absolute frame
        wc = cfg.world
        self._angles = np.asarray(wc.range_sensor.angles)  # (B,)
        self.slams = (
            [PolySlam(cfg.slam, self._angles, wc.range_sensor.max_range) for _ in range(n)]
            if cfg.slam_enabled
            else []
        )
        self.exchange = self._make_exchange()
        oc = cfg.observation
        self._beliefs = [
            BeliefGrid(oc.belief_size, oc.belief_resolution, wc.range_sensor.max_range)
            for _ in range(n)
        ]
        self._samplers = [MapSampler(0.5 * oc.grid_resolution) for _ in range(n)]
        self._histories = [RobotHistory(self.start_poses[i], *self._estimate(i)) for i in range(n)]
        self._last_rendezvous: list[int | None] = [None] * n
        self._completeness = [0.0] * n
        self._bytes_sent = [0] * n
        self._links: list[tuple[int, int]] = []
        self.step_count = 0
        self.agents = self.possible_agents[:]
        self._scans = self.world.scan()  # (N, B)
        self._detections = self.world.camera()
        self._sweep_coverage(self._scans)
        self._coverage_series = [self.coverage.coverage]
        observations = self._observe(self.agents, self._estimates())
        return observations, {a: {} for a in self.agents}

    def _draw_layout(self) -> Layout:
        assert self._generator is not None
        return self._generator(self._rngs["layout"])

    def _make_exchange(self) -> RendezvousExchange | None:
        cfg = self.config
        if cfg.channel is None or not cfg.slam_enabled:
            return None
        wc = cfg.world
        return RendezvousExchange(
            cfg.channel,
            cfg.num_robots,
            self._rngs["channel"],
            wc.camera.sigma_d,
            wc.camera.sigma_bearing,
            cfg.slam.order,
            cfg.slam.auto_order,
            max_range=wc.range_sensor.max_range,
        )

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
        if not self.agents:
            raise RuntimeError("step() called with no live agents; call reset() first")
        acting = self.agents[:]
        commands = self._apply_actions(actions)
        self.step_count += 1
        result = self._simulate(commands)
        scans, detections = self._sense()
        slam_infos = self._run_slam(result, scans)
        exchanged = self._exchange(detections)
        estimates = self._estimates()
        self._record(result, scans, slam_infos, estimates)
        observations = self._observe(acting, estimates)
        terms = self._reward_terms(acting, result, scans, slam_infos, exchanged)
        rewards = self._combine(terms)
        terminations, truncations = self._done(acting)
        infos = self._infos(acting, terms, terminations, truncations)
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

    def _command(self, agent: str, action: Action) -> np.ndarray:  # (2,)
        if action is None:
            raise ValueError(f"action of {agent}: None for a live agent")
        a = np.asarray(action)
        if not np.issubdtype(a.dtype, np.number):
            raise ValueError(f"action of {agent}: expected numbers, got {action!r}")
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

    def _simulate(self, commands: np.ndarray) -> StepResult:
        return self.world.step(commands)

    def _sense(self) -> tuple[np.ndarray, list[list[Detection]]]:
        """Noisy ranges (N, B) and camera detections of every robot (failed ones see none)."""
        self._scans = self.world.scan()
        self._detections = self.world.camera()
        return self._scans, self._detections

    def _run_slam(self, result: StepResult, scans: np.ndarray) -> list[SlamStepInfo | None]:
        """One SLAM step per active robot (None for failed robots or without SLAM)."""
        out: list[SlamStepInfo | None] = [None] * self.config.num_robots
        for i, slam in enumerate(self.slams):
            if self.world.active[i]:
                out[i] = slam.step(result.odometry[i], scans[i])
        return out

    def _exchange(self, detections: list[list[Detection]]) -> ExchangeStep | None:
        """Rendezvous map exchange; also keeps the mutual-sighting links for rendering."""
        self._links = _mutual_pairs(detections)
        if self.exchange is None:
            return None
        for i, slam in enumerate(self.slams):
            if self.world.active[i]:
                self.exchange.record_scan(i, slam.pose, self._scans[i], self._angles)
        out = self.exchange.step(self.step_count, self.slams, detections, self.world.active)
        for i, j in out.new_rendezvous:
            self._last_rendezvous[i] = self._last_rendezvous[j] = self.step_count
        return out

    def _record(
        self,
        result: StepResult,
        scans: np.ndarray,
        slam_infos: list[SlamStepInfo | None],
        estimates: list[tuple[np.ndarray, np.ndarray]],
    ) -> None:
        """Histories for the end-of-episode metrics (the belief grids are swept in _observe)."""
        poses = self.world.poses
        phi = poses[:, 2:3] + self._angles  # (N, B)
        hits = np.stack(  # (N, B, 2) beam end points, true poses (inf without return)
            [poses[:, 0:1] + scans * np.cos(phi), poses[:, 1:2] + scans * np.sin(phi)], axis=-1
        )
        ok = np.isfinite(scans)  # (N, B)
        for i in map(int, np.flatnonzero(self.world.active)):
            est, cov = estimates[i]
            info = slam_infos[i]
            self._histories[i].record(
                poses[i],
                est,
                cov,
                hits[i][ok[i]],
                None if info is None else info.time_s,
                bool(result.collided[i]),
                bool(info is not None and info.diverging),
            )

    def _estimates(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every robot's :meth:`_estimate`, taken once per step after SLAM and exchange."""
        return [self._estimate(i) for i in range(self.config.num_robots)]

    def _estimate(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Robot i's pose (3,) and covariance (3, 3) in its start frame (truth without SLAM)."""
        if self.slams:
            return self.slams[i].pose, self.slams[i].pose_cov
        return _to_frame(self.world.poses[i], self.start_poses[i]), np.zeros((3, 3))

    # -- observe ---------------------------------------------------------------------------
    def _observe(
        self, agents: list[str], estimates: list[tuple[np.ndarray, np.ndarray]]
    ) -> dict[str, Obs]:
        robots = [self._index[agent] for agent in agents]
        sweeping = [i for i in robots if self.world.active[i]]
        if sweeping:  # each robot's beams into its own belief grid, with its estimated pose
            poses = np.array([estimates[i][0] for i in sweeping])  # (K, 3)
            grids = [self._beliefs[i] for i in sweeping]
            sweep_beliefs(grids, poses, self._angles, self._scans[sweeping])
        return {
            agent: self._encoder.encode(self._view(i, *estimates[i]))
            for agent, i in zip(agents, robots, strict=True)
        }

    def _view(self, i: int, pose: np.ndarray, cov: np.ndarray) -> RobotView:
        """What robot i knows, with its estimated pose (3,) and covariance (3, 3)."""
        last = self._last_rendezvous[i]
        count = self.exchange.counters(i)["rendezvous"] if self.exchange is not None else 0
        return RobotView(
            ranges=self._scans[i],
            pose=pose,
            pose_std=np.sqrt(np.maximum(np.diag(cov), 0.0)),
            map_points=self._samplers[i].points(self.slams[i]) if self.slams else np.zeros((0, 2)),
            belief=self._beliefs[i],
            detections=self._detections[i],
            steps_since_rendezvous=None if last is None else self.step_count - last,
            rendezvous=count,
            step=self.step_count,
        )

    # -- reward ----------------------------------------------------------------------------
    def _sweep_coverage(self, scans: np.ndarray) -> np.ndarray:  # (N,) m²
        """Sweep every active robot's beams (true poses) into the team coverage grid; return
        the area of free cells first swept by the team now, per robot."""
        grid = self.coverage
        poses = self.world.poses
        max_range = self.config.world.range_sensor.max_range
        active = np.flatnonzero(self.world.active).tolist()
        scan_cells = grid.scan_cells(
            poses[active, :2], poses[active, 2:3] + self._angles, scans[active], max_range
        )
        cells = dict(zip(active, scan_cells, strict=True))
        # Gains against the grid as it was before this step (counted before anything is marked),
        # so a cell first swept by two robots at once counts for both.
        gains = np.zeros(self.config.num_robots)
        for i, c in cells.items():
            gains[i] = grid.new_free_cells(c) * grid.resolution**2
        for i, c in cells.items():
            grid.mark(c, robot=i)
        return gains

    def _reward_terms(
        self,
        acting: list[str],
        result: StepResult,
        scans: np.ndarray,
        slam_infos: list[SlamStepInfo | None],
        exchanged: ExchangeStep | None,
    ) -> dict[str, dict[str, float]]:
        gains = self._sweep_coverage(scans)
        self._coverage_series.append(self.coverage.coverage)
        received = {d.receiver for d in exchanged.delivered} if exchanged is not None else set()
        out: dict[str, dict[str, float]] = {}
        for agent in acting:
            i = self._index[agent]
            out[agent] = {
                "coverage": float(gains[i]),
                "mapping": self._mapping_term(i, slam_infos[i], i in received),
                "bytes": -self._bytes_this_step(i) / 1000.0,
                "collision": -1.0 if result.collided[i] else 0.0,
                "time": -1.0,
            }
        return out

    def _mapping_term(self, i: int, info: SlamStepInfo | None, received: bool) -> float:
        """Change of robot i's map completeness, evaluated only when its map changed."""
        if info is None or not (info.created or info.refit or info.merged or received):
            return 0.0
        comp = metrics.completeness(
            self.slams[i].polynomials(),
            self.start_poses[i],
            self.world.layout,
            tol=MAPPING_TOL,
            step=MAPPING_STEP,
        )
        delta, self._completeness[i] = comp - self._completeness[i], comp
        return delta

    def _bytes_this_step(self, i: int) -> int:
        if self.exchange is None:
            return 0
        total = self.exchange.counters(i)["bytes_sent"]
        delta, self._bytes_sent[i] = total - self._bytes_sent[i], total
        return delta

    def _combine(self, terms: dict[str, dict[str, float]]) -> dict[str, float]:
        """Σ weight · term per agent; the team mean for everyone in shared mode."""
        rc = self.config.reward
        rewards = {
            agent: float(sum(getattr(rc, name) * value for name, value in t.items()))
            for agent, t in terms.items()
        }
        if rc.shared and rewards:
            mean = float(np.mean(list(rewards.values())))
            rewards = dict.fromkeys(rewards, mean)
        return rewards

    # -- done ------------------------------------------------------------------------------
    def _done(self, acting: list[str]) -> tuple[dict[str, bool], dict[str, bool]]:
        """Coverage target → all terminated; faults → that robot; max_steps → all truncated."""
        reached = self.coverage.coverage >= self.config.coverage_target
        truncated = self.step_count >= self.config.max_steps
        terminations, truncations = {}, {}
        for agent in acting:
            i = self._index[agent]
            failed = self._fault_at.get(i) == self.step_count
            if failed:
                self.world.disable(i)
            terminations[agent] = bool(reached or failed)
            truncations[agent] = bool(truncated)
        return terminations, truncations

    def _infos(
        self,
        acting: list[str],
        terms: dict[str, dict[str, float]],
        terminations: dict[str, bool],
        truncations: dict[str, bool],
    ) -> dict[str, dict[str, Any]]:
        infos: dict[str, dict[str, Any]] = {}
        team: dict[str, Any] | None = None
        for agent in acting:
            info: dict[str, Any] = {"reward_terms": terms[agent], "step": self.step_count}
            if terminations[agent] or truncations[agent]:
                if team is None:
                    team = team_metrics(self._coverage_series, self.coverage)
                info["metrics"] = self._final_metrics(self._index[agent])
                info["team"] = dict(team)
            infos[agent] = info
        return infos

    def _final_metrics(self, i: int) -> dict[str, float]:
        counters = self.exchange.counters(i) if self.exchange is not None else {}
        return final_robot_metrics(
            self._histories[i],
            self.slams[i].polynomials() if self.slams else None,
            self.world.layout,
            self.coverage.robot_coverage(i),
            counters,
        )

    # -- rendering -------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """Draw the current state (``human``: a window, returns None; ``rgb_array``: an image)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; nothing to draw")
            return None
        if not hasattr(self, "world"):
            raise RuntimeError("render() called before reset()")
        if self._renderer is None or self._renderer_layout is not self.world.layout:
            from polyslam_env.render.renderer import (
                Renderer,
            )  # lazy: pygame loads only when rendering

            if self._renderer is not None:
                self._renderer.close()
            self._renderer = Renderer(
                self.world.layout, self.config.num_robots, self.render_mode, self.config.world
            )
            self._renderer_layout = self.world.layout
        return self._renderer.render(self.render_state())

    def render_state(self) -> RenderState:
        """A snapshot of the episode for the renderer (ground truth and estimates, absolute)."""
        n = self.config.num_robots
        est = np.array([self._estimate(i)[0] for i in range(n)])
        cov = np.array([self._estimate(i)[1] for i in range(n)])
        est_abs = np.array(
            [metrics.pose_to_absolute(est[i : i + 1], self.start_poses[i])[0] for i in range(n)]
        )
        cov_abs = np.array(
            [metrics.cov_to_absolute(cov[i : i + 1], self.start_poses[i])[0] for i in range(n)]
        )
        maps = [
            metrics.map_points(self.slams[i].polynomials(), self.start_poses[i], 0.02)
            if self.slams
            else []
            for i in range(n)
        ]
        grid = self.coverage
        return RenderState(
            true_poses=self.world.poses,
            est_poses_abs=est_abs,
            est_covs_abs=cov_abs,
            maps_abs=maps,
            true_paths=[h.true_path() for h in self._histories],
            est_paths=[h.est_path_abs() for h in self._histories],
            links=list(self._links),
            coverage=grid.swept & grid.free,
            coverage_origin=grid.origin,
            coverage_resolution=grid.resolution,
            active=self.world.active.copy(),
            step=self.step_count,
            info_text=f"coverage {100 * grid.coverage:.1f} %",
        )

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
            self._renderer_layout = None


# -- helpers --------------------------------------------------------------------------------
def _mutual_pairs(detections: list[list[Detection]]) -> list[tuple[int, int]]:
    """Pairs (i < j) that see each other."""
    seen = {(i, d.target) for i, dets in enumerate(detections) for d in dets}
    return sorted((i, j) for i, j in seen if i < j and (j, i) in seen)


def _to_frame(pose: np.ndarray, frame: np.ndarray) -> np.ndarray:  # (3,)
    """An absolute pose (3,) expressed in the frame whose absolute pose is ``frame`` (3,)."""
    c, s = math.cos(frame[2]), math.sin(frame[2])
    dx, dy = pose[0] - frame[0], pose[1] - frame[1]
    dth = math.remainder(pose[2] - frame[2], 2 * math.pi)
    return np.array([c * dx + s * dy, -s * dx + c * dy, dth])


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

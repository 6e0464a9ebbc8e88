"""Configuration of the PettingZoo environment (SPEC §6): nested frozen dataclasses.

:class:`EnvConfig` gathers the world, the SLAM, the channel, rewards, observations, actions and
episode settings. :func:`resolve_config` turns what users pass to ``parallel_env`` (nothing, an
``EnvConfig``, a dict, or a YAML path, plus ``a__b=value`` keyword overrides) into one validated
``EnvConfig``; unknown keys and bad values raise :class:`ConfigError` naming them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from polyslam_env.comms.channel import ChannelConfig
from polyslam_env.core.config import Config, check_choice, check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.config import PRESETS, SlamConfig, slam_preset
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.generators import GENERATORS

__all__ = [
    "GENERATOR_PREFIX",
    "ActionConfig",
    "EnvConfig",
    "FaultConfig",
    "ObservationConfig",
    "RewardConfig",
    "map_reach",
    "resolve_config",
]

#: A ``map`` value ``"generator:<name>"`` draws a new layout at every reset.
GENERATOR_PREFIX = "generator:"

#: Default discrete actions as fractions of (v_max, omega_max): stop, forward, forward-left,
#: forward-right, turn left, turn right, back.
DEFAULT_DISCRETE: tuple[tuple[float, float], ...] = (
    (0.0, 0.0),
    (1.0, 0.0),
    (0.5, 0.5),
    (0.5, -0.5),
    (0.0, 1.0),
    (0.0, -1.0),
    (-0.5, 0.0),
)


@dataclass(frozen=True)
class RewardConfig(Config):
    """Weights of the named reward terms (see the env docstring for each term's definition)."""

    coverage: float = 1.0  # per m² of newly swept free space
    mapping: float = 1.0  # per unit change of the robot's map completeness
    # per m² of change of the robot's map error ∫δ ds (the term is −change; same unit as the
    # coverage term: 1 m of map 1 m off, or 10 m of map 10 cm off, weighs like 1 m² swept)
    map_error: float = 1.0
    bytes: float = 0.1  # per kB sent (the term is −bytes/1000)
    collision: float = 0.5  # the term is −1 on a step with a collision
    time: float = 0.01  # the term is −1 every step
    shared: bool = False  # True: every robot receives the team mean reward

    def validate(self) -> None:
        for name in ("coverage", "mapping", "map_error", "bytes", "collision", "time"):
            check_range(f"reward.{name}", getattr(self, name), -1e6, 1e6)


#: m; the pose scale of maps that fit in it (the fixed scale before maps of any size), kept
#: there so that small-map observations and policies trained on them stay as they were.
MIN_POSE_SCALE = 20.0
#: Most belief cells a side (memory: two bool grids of this side squared per robot).
MAX_BELIEF_CELLS = 4096


def map_reach(map_size: tuple[float, float], max_range: float) -> float:
    """m: how far from its start (its frame's origin) a robot may place anything it senses.

    The start and every point of the map lie in the map's bounding box of ``map_size``
    (width, height), so they are at most its diagonal apart; a beam ends at a wall inside
    the box; ``max_range`` more is the margin for the drift of the pose estimate. The robot's
    frame has any heading, so the reach holds in every direction.
    """
    return math.hypot(*map_size) + max_range


@dataclass(frozen=True)
class ObservationConfig(Config):
    """What the observation contains and how big its local map is.

    ``belief_size`` and ``pose_scale`` default to ``None``: derived from the map's size (its
    bounding box, a public fact like a floor plan's dimensions; where a robot starts in it is
    not) so that every start and every map size fits, see :meth:`belief_side` and
    :meth:`position_scale`.
    """

    mode: Literal["vector", "grid"] = "vector"  # a flat vector, or image channels + vector
    grid_size: int = 11  # G: local egocentric grid is G × G cells
    grid_resolution: float = 0.2  # m per local grid cell
    belief_size: float | None = None  # m, side of each robot's own grid around its start
    belief_resolution: float = 0.1  # m per belief cell
    max_detections: int | None = None  # camera slots; None = num_robots − 1
    pose_scale: float | None = None  # m; the position estimate is divided by it (then clipped)
    rendezvous_cap: int = 10  # the rendezvous count is reported as min(count, cap) / cap

    def validate(self) -> None:
        if not 1 <= self.grid_size <= 101 or self.grid_size % 2 == 0:
            raise ConfigError(
                f"observation.grid_size: must be an odd integer in 1..101, got {self.grid_size!r}"
            )
        check_positive("observation.grid_resolution", self.grid_resolution)
        check_positive("observation.belief_resolution", self.belief_resolution)
        if self.belief_size is not None:
            check_positive("observation.belief_size", self.belief_size)
            self._check_belief_cells(self.belief_size, "")
        if self.max_detections is not None and self.max_detections < 0:
            raise ConfigError(
                f"observation.max_detections: must be >= 0 or null, got {self.max_detections!r}"
            )
        if self.pose_scale is not None:
            check_positive("observation.pose_scale", self.pose_scale)
        if self.rendezvous_cap < 1:
            raise ConfigError(
                f"observation.rendezvous_cap: must be >= 1, got {self.rendezvous_cap!r}"
            )

    def _check_belief_cells(self, side: float, why: str) -> None:
        if side / self.belief_resolution > MAX_BELIEF_CELLS:
            raise ConfigError(
                f"observation.belief_size: {side:g} m{why} at {self.belief_resolution} m"
                f" is more than {MAX_BELIEF_CELLS} cells a side"
            )

    def belief_side(self, map_size: tuple[float, float], max_range: float) -> float:
        """m: side of each robot's belief grid: ``belief_size``, or for ``None`` twice the
        map's reach (:func:`map_reach`) rounded up to an even number of cells, so the grid
        centred on any start holds the whole map.
        A derived side too large for ``MAX_BELIEF_CELLS`` raises :class:`ConfigError`."""
        if self.belief_size is not None:
            return self.belief_size
        # an even number of cells, so cell edges fall on multiples of the resolution from
        # the start, as with any even count (the 16 m of fixed-size grids: 160 cells)
        cells = 2 * math.ceil(map_reach(map_size, max_range) / self.belief_resolution)
        side = cells * self.belief_resolution
        self._check_belief_cells(side, f" (null: twice the reach of a {_size(map_size)} map)")
        return side

    def position_scale(self, map_size: tuple[float, float], max_range: float) -> float:
        """m: the observed position is the estimate divided by this (then clipped to ±1):
        ``pose_scale``, or for ``None`` the larger of ``MIN_POSE_SCALE`` and the map's reach
        (:func:`map_reach`), so no honest estimate is clipped on a map of any size."""
        if self.pose_scale is not None:
            return self.pose_scale
        return max(MIN_POSE_SCALE, map_reach(map_size, max_range))


def _size(map_size: tuple[float, float]) -> str:
    return f"{map_size[0]:g} × {map_size[1]:g} m"


@dataclass(frozen=True)
class ActionConfig(Config):
    """Continuous (v, ω) in physical units, or an index into a table of (v, ω) fractions."""

    mode: Literal["continuous", "discrete"] = "continuous"  # (v, ω) in m/s, rad/s, or an index
    discrete: tuple[tuple[float, float], ...] = DEFAULT_DISCRETE  # fractions of (v_max, ω_max)

    def validate(self) -> None:
        if not self.discrete:
            raise ConfigError("action.discrete: at least one action is needed")
        for i, (v, w) in enumerate(self.discrete):
            check_range(f"action.discrete[{i}][0]", v, -1.0, 1.0)
            check_range(f"action.discrete[{i}][1]", w, -1.0, 1.0)


#: The fault kinds of :class:`FaultConfig`.
FAULT_KINDS: tuple[str, ...] = ("fail", "kidnap", "slip")


@dataclass(frozen=True)
class FaultConfig(Config):
    """One injected fault of robot ``robot`` at env step ``step`` (1-based).

    * ``fail``: the robot stops for good at the end of step ``step`` (it leaves ``agents``);
    * ``kidnap``: after the motion of step ``step`` the robot's *true* pose jumps by
      ``distance`` m in a random direction (stream ``faults``) to a free spot and turns by
      ``angle`` rad; its odometry does not report the jump;
    * ``slip``: during steps ``step … step + steps − 1`` the wheels slip: the robot moves
      ``scale`` times the commanded motion while its odometry reports the commanded one
      (true motion = scale × odometry).
    """

    kind: Literal["fail", "kidnap", "slip"] = "fail"  # what happens (see the class docstring)
    robot: int = 0  # which robot, 0-based
    step: int = 1  # env step (1-based) it happens in (slip: the first slipping step)
    distance: float = 0.0  # m, kidnap only
    angle: float = 0.0  # rad, kidnap only
    scale: float = 1.0  # slip only: true motion / reported motion, in (0, 1]
    steps: int = 1  # slip only: number of slipping steps

    def validate(self) -> None:
        if self.kind == "kidnap":
            check_positive("distance", self.distance)
            check_range("angle", self.angle, -math.pi, math.pi)
        else:
            for name in ("distance", "angle"):
                if getattr(self, name) != 0.0:
                    raise ConfigError(f"{name}: only for kind 'kidnap', not {self.kind!r}")
        if self.kind == "slip":
            if not (math.isfinite(self.scale) and 0.0 < self.scale <= 1.0):
                raise ConfigError(f"scale: must be in (0, 1], got {self.scale!r}")
            if self.steps < 1:
                raise ConfigError(f"steps: must be >= 1, got {self.steps!r}")
        else:
            for name, default in (("scale", 1.0), ("steps", 1)):
                if getattr(self, name) != default:
                    raise ConfigError(f"{name}: only for kind 'slip', not {self.kind!r}")

    @property
    def last_step(self) -> int:
        """The last step the fault acts in (``step + steps − 1`` for slip, else ``step``)."""
        return self.step + self.steps - 1


@dataclass(frozen=True)
class EnvConfig(Config):
    """Everything that defines an episode of ``polyslam_v0``."""

    map: str = "paper"  # built-in name, path to a YAML map, or "generator:<name>" (GENERATORS)
    map_params: Any = None  # mapping of generator parameters (generator maps only)
    num_robots: int = 3  # robots in the team, 1..64 (the map needs a start pose for each)
    max_steps: int = 500  # truncation
    world: WorldConfig = field(default_factory=WorldConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    slam_preset: str | None = None  # a named SlamConfig preset; replaces ``slam``
    slam_enabled: bool = True  # False: ground-truth pose mode (no SLAM, no map exchange)
    channel: ChannelConfig | None = field(default_factory=ChannelConfig)  # None: no exchange
    reward: RewardConfig = field(default_factory=RewardConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    action: ActionConfig = field(default_factory=ActionConfig)
    coverage_target: float | None = 0.95  # team coverage that terminates; None: never
    coverage_resolution: float = 0.1  # m, cell side of the coverage grid
    initial_error: bool = True  # true start drawn from N(0, P0) around the frame origin
    # (robot, step) pairs (= kind "fail") or FaultConfig mappings; pairs become FaultConfigs
    faults: tuple[FaultConfig | tuple[int, int], ...] = ()

    def __post_init__(self) -> None:
        if self.slam_preset is not None:
            preset = slam_preset(self.slam_preset)
            if self.slam not in (SlamConfig(), preset):
                raise ConfigError(
                    f"slam_preset: {self.slam_preset!r} given together with custom slam"
                    " parameters; give one or the other"
                )
            object.__setattr__(self, "slam", preset)
        faults = tuple(
            f if isinstance(f, FaultConfig) else _pair_fault(i, f)
            for i, f in enumerate(self.faults)
        )
        object.__setattr__(self, "faults", faults)
        super().__post_init__()

    @property
    def generator_name(self) -> str | None:
        """The layout generator's name for ``map="generator:<name>"``, else None."""
        if self.map.startswith(GENERATOR_PREFIX):
            return self.map[len(GENERATOR_PREFIX) :]
        return None

    @property
    def num_detections(self) -> int:
        """Camera slots in the observation."""
        m = self.observation.max_detections
        return self.num_robots - 1 if m is None else m

    def validate(self) -> None:
        if not self.map:
            raise ConfigError("map: must be a map name, a path or 'generator:<name>', got ''")
        gen = self.generator_name
        if gen is not None:
            check_choice("map", gen, tuple(sorted(GENERATORS)))
        if self.map_params is not None:
            if gen is None:
                raise ConfigError(f"map_params: only for generator maps, but map is {self.map!r}")
            if not isinstance(self.map_params, Mapping):
                raise ConfigError(f"map_params: expected a mapping, got {self.map_params!r}")
        if self.slam_preset is not None:
            check_choice("slam_preset", self.slam_preset, tuple(PRESETS))
        if not 1 <= self.num_robots <= 64:
            raise ConfigError(f"num_robots: must be in 1..64, got {self.num_robots!r}")
        if self.max_steps < 1:
            raise ConfigError(f"max_steps: must be >= 1, got {self.max_steps!r}")
        if self.coverage_target is not None:
            check_range("coverage_target", self.coverage_target, 0.0, 1.0)
        check_positive("coverage_resolution", self.coverage_resolution)
        self._validate_backend()
        if (
            self.channel is not None
            and self.channel.mode == "alignment"
            and self.channel.features == "pillars"
        ):
            if self.world.pillar_sensor.enabled and not self.world.pillar_sensor.identities:
                raise ConfigError(
                    "channel.mode: 'alignment' builds its pillar maps by pillar identity; it"
                    " needs world.pillar_sensor.identities: true"
                )
            if not self.world.pillar_sensor.enabled:
                raise ConfigError(
                    "channel.mode: 'alignment' with channel.features: 'pillars' aligns pillar"
                    " maps; it needs world.pillar_sensor.enabled: true (or channel.features:"
                    " 'walls', the corners of the wall map)"
                )
        self._validate_faults()

    @property
    def fault_list(self) -> tuple[FaultConfig, ...]:
        """``faults``, every entry a :class:`FaultConfig` (pairs are turned into them on
        construction; this property only narrows the type)."""
        return tuple(f for f in self.faults if isinstance(f, FaultConfig))

    def _validate_backend(self) -> None:
        """A point back-end needs the pillar sensor; MBLCC needs the channel (its consensus),
        known starts and the default mode; multirobot_known_start known starts. seif with
        ``channel.mode: alignment`` fuses maps between robots (comms/seif_exchange.py);
        fastslam2, em_fastslam, seif in the default mode and the centralised
        multirobot_known_start exchange nothing in the env: the channel stays unused (bytes
        0)."""
        backend = self.slam.backend
        if backend == "polynomial" or not self.slam_enabled:
            return
        if not self.world.pillar_sensor.enabled:
            raise ConfigError(
                f"slam.backend: {backend!r} maps pillars; it needs world.pillar_sensor.enabled:"
                " true (and a map with pillars)"
            )
        if backend == "mblcc" and self.channel is None:
            raise ConfigError(
                "slam.backend: 'mblcc' corrects landmarks with the others' estimates over the"
                " channel; set channel (or use em_fastslam, the same filter without consensus)"
            )
        team = backend in ("mblcc", "multirobot_known_start")
        if team and not self.world.pillar_sensor.identities:
            raise ConfigError(
                f"slam.backend: {backend!r} pairs the robots' landmarks by pillar identity;"
                " it needs world.pillar_sensor.identities: true"
            )
        if team and self.initial_error:
            raise ConfigError(
                f"slam.backend: {backend!r} assumes known start poses (seed 003): it maps the"
                " robots' landmarks through the nominal starts; set initial_error: false"
            )
        if backend == "mblcc" and self.channel is not None and self.channel.mode != "rendezvous":
            raise ConfigError(
                f"channel.mode: {self.channel.mode!r} merges polynomial maps; slam.backend"
                " 'mblcc' sends its consensus messages in the default mode 'rendezvous'"
            )

    def _validate_faults(self) -> None:
        """Robot and step ranges, one ``fail`` per robot and nothing after it, slip windows of
        one robot disjoint."""
        failed_at: dict[int, int] = {}
        for i, f in enumerate(self.fault_list):
            if f.kind == "fail" and f.robot in failed_at:
                raise ConfigError(f"faults[{i}]: robot {f.robot} fails more than once")
            if f.kind == "fail":
                failed_at[f.robot] = f.step
        windows: dict[int, list[tuple[int, int]]] = {}
        for i, f in enumerate(self.fault_list):
            if not 0 <= f.robot < self.num_robots:
                raise ConfigError(
                    f"faults[{i}].robot: {f.robot!r} is not in 0..{self.num_robots - 1}"
                )
            if f.step < 1:
                raise ConfigError(f"faults[{i}].step: must be >= 1, got {f.step!r}")
            if f.last_step > self.max_steps:
                raise ConfigError(
                    f"faults[{i}].step: {f.kind} at step {f.step}"
                    + (f" for {f.steps} steps" if f.kind == "slip" else "")
                    + f" goes beyond max_steps={self.max_steps}; the fault would never happen"
                )
            end = failed_at.get(f.robot)
            if f.kind != "fail" and end is not None and f.last_step > end:
                raise ConfigError(
                    f"faults[{i}].step: robot {f.robot} has failed at step {end}, before this"
                    f" {f.kind} ends (step {f.last_step})"
                )
            if f.kind == "slip":
                for lo, hi in windows.get(f.robot, []):
                    if f.step <= hi and lo <= f.last_step:
                        raise ConfigError(
                            f"faults[{i}].step: slip of robot {f.robot} over steps"
                            f" {f.step}..{f.last_step} overlaps another slip ({lo}..{hi})"
                        )
                windows.setdefault(f.robot, []).append((f.step, f.last_step))


def _pair_fault(i: int, pair: tuple[int, int]) -> FaultConfig:
    """A ``(robot, step)`` pair as the ``fail`` fault it stands for."""
    try:
        robot, step = pair
    except (TypeError, ValueError):
        raise ConfigError(
            f"faults[{i}]: expected (robot, step) or a fault mapping, got {pair!r}"
        ) from None
    return FaultConfig(kind="fail", robot=int(robot), step=int(step))


def resolve_config(
    config: EnvConfig | Mapping[str, Any] | str | Path | None = None, **overrides: Any
) -> EnvConfig:
    """One validated :class:`EnvConfig` from any accepted form plus ``a__b=value`` overrides.

    ``max_cycles`` (PettingZoo's usual name) is accepted as an alias of ``max_steps``; giving
    both with different values is a :class:`ConfigError`.
    """
    if "max_cycles" in overrides:
        cycles = overrides.pop("max_cycles")
        steps = overrides.setdefault("max_steps", cycles)
        if steps != cycles:
            raise ConfigError(
                f"max_cycles: an alias of max_steps, but max_cycles={cycles!r} and"
                f" max_steps={steps!r}; give one of them"
            )
    if config is None:
        base = EnvConfig()
    elif isinstance(config, EnvConfig):
        base = config
    elif isinstance(config, Mapping):
        base = EnvConfig.from_dict(config)
    elif isinstance(config, str | Path):
        base = EnvConfig.from_yaml(config)
    else:
        raise ConfigError(
            f"config: expected an EnvConfig, a mapping or a YAML path, got {type(config).__name__}"
        )
    return base.replace(**overrides)

"""Precomputed robot paths: per robot, one (v, ω) command per control step (SPEC §2, §7).

The paper (§4) drives its three robots along precomputed paths of ``k_f = 200`` steps; the
``paper`` paths (``configs/paths/paper.yaml``) are those, designed by
``scripts/design_paper_paths.py`` on the ``paper`` map. Schema (YAML or JSON)::

    name: paper
    map: paper         # built-in map name (or a map file path)
    dt: 1.0            # control period the commands were designed for, s
    robots:            # one list of [v, omega] per robot (m/s, rad/s), all the same length
      - [[0.05, 0.0], [0.05, 0.1], ...]

Any other top-level key is an error; every error names the file and the field. The robots start
at the map's ``start_poses`` (robot i at ``start_poses[i]``): the paths store no poses of their
own, so a map and its paths cannot disagree on them.

:func:`replay_paths` drives a :class:`~polyslam_env.world.physics.World` with the commands and
records the true trajectory, camera visibility and beam hits; the design script and the tests
check the paths' promises (who meets whom, no collisions, boundary seen) on it. True motion does
not depend on the seed (noise enters odometry and sensors only), so one replay holds for all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.resources import builtin_names, configs_dir, resolve_file
from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World

KEYS = ("name", "map", "dt", "robots")


def paths_dir() -> Path:
    """The folder of the built-in paths (``configs/paths``)."""
    return configs_dir() / "paths"


@dataclass(frozen=True, eq=False)
class Paths:
    """Open-loop commands for a team: ``commands[i, k]`` is robot i's (v, ω) at step k."""

    name: str
    map: str  # built-in map name or map file path
    dt: float  # s, control period the commands assume
    commands: np.ndarray  # (N, K, 2) float, read-only

    def __post_init__(self) -> None:
        cmd = np.array(self.commands, dtype=float)  # a private copy
        if cmd.ndim != 3 or cmd.shape[2] != 2 or cmd.shape[0] < 1 or cmd.shape[1] < 1:
            raise ConfigError(f"commands: expected shape (N>=1, K>=1, 2), got {cmd.shape}")
        if not np.all(np.isfinite(cmd)):
            raise ConfigError("commands: all values must be finite")
        if not (isinstance(self.dt, int | float) and math.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f"dt: must be a finite number > 0, got {self.dt!r}")
        cmd.setflags(write=False)
        object.__setattr__(self, "commands", cmd)
        object.__setattr__(self, "dt", float(self.dt))

    @property
    def num_robots(self) -> int:
        return int(self.commands.shape[0])

    @property
    def num_steps(self) -> int:
        return int(self.commands.shape[1])

    def step_commands(self, k: int) -> np.ndarray:  # (N, 2)
        """The team's commands at step k (what ``World.step`` takes)."""
        return np.asarray(self.commands[:, k, :])


def builtin_paths() -> list[str]:
    """Names of the paths shipped in ``configs/paths``."""
    return builtin_names(paths_dir())


def resolve_paths_file(name_or_path: str | Path) -> Path:
    """A built-in paths name (``"paper"``) or a path to a paths file."""
    return resolve_file(name_or_path, paths_dir(), "paths", ConfigError)


def load_paths(name_or_path: str | Path) -> Paths:
    """Load and validate a paths file, or built-in paths by name."""
    path = resolve_paths_file(name_or_path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))  # JSON is a subset of YAML
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise ConfigError(f"{path}: cannot read paths file ({err})") from None
    return paths_from_dict(data, source=str(path))


def paths_from_dict(data: Any, *, source: str = "<paths>") -> Paths:
    """Validate plain paths data (the file schema) and build :class:`Paths`."""

    def fail(field_name: str, msg: str) -> ConfigError:
        return ConfigError(f"{source}: {field_name}: {msg}")

    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping with keys {', '.join(KEYS)}")
    unknown = sorted(set(map(str, data)) - set(KEYS))
    if unknown:
        raise fail(unknown[0], f"unknown key (valid keys: {', '.join(KEYS)})")
    for key in KEYS:
        if key not in data or data[key] is None:
            raise fail(key, "missing")
    for key in ("name", "map"):
        if not isinstance(data[key], str) or not data[key]:
            raise fail(key, f"expected a non-empty string, got {data[key]!r}")
    dt = _number(data["dt"], "dt", fail)
    if dt <= 0:
        raise fail("dt", f"must be > 0, got {dt!r}")
    return Paths(data["name"], data["map"], dt, _commands(data["robots"], fail))


def _number(v: Any, field_name: str, fail: Any) -> float:
    """A finite int or float (not bool), else an error naming the field."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise fail(field_name, f"expected a number, got {v!r}")
    if not math.isfinite(v):
        raise fail(field_name, f"must be finite, got {v!r}")
    return float(v)


def _commands(raw: Any, fail: Any) -> np.ndarray:  # (N, K, 2)
    """The ``robots`` field: a non-empty list of equally long lists of [v, omega]."""
    if not isinstance(raw, list) or not raw:
        raise fail("robots", "expected a non-empty list (one list of [v, omega] per robot)")
    out = []
    for i, robot in enumerate(raw):
        if not isinstance(robot, list) or not robot:
            raise fail(f"robots[{i}]", f"expected a non-empty list of [v, omega], got {robot!r}")
        if len(robot) != len(raw[0]):
            raise fail(
                f"robots[{i}]", f"has {len(robot)} steps, robots[0] has {len(raw[0])} (ragged)"
            )
        rows = np.zeros((len(robot), 2))  # (K, 2)
        for k, item in enumerate(robot):
            if not isinstance(item, list | tuple) or len(item) != 2:
                raise fail(f"robots[{i}][{k}]", f"expected [v, omega], got {item!r}")
            rows[k] = [_number(v, f"robots[{i}][{k}][{j}]", fail) for j, v in enumerate(item)]
        out.append(rows)
    return np.stack(out)


def paths_to_yaml(paths: Paths, header: str = "", per_line: int = 5, decimals: int = 4) -> str:
    """The file text of ``paths``: commands rounded to ``decimals``, ``per_line`` pairs a line.

    ``header`` lines are written as ``#`` comments at the top.
    """
    lines = [f"# {h}".rstrip() for h in header.splitlines()]
    lines += [f"name: {paths.name}", f"map: {paths.map}", f"dt: {paths.dt!r}", "robots:"]
    for robot in np.round(paths.commands, decimals):
        pairs = [f"[{_fmt(v, decimals)}, {_fmt(w, decimals)}]" for v, w in robot]
        rows = [", ".join(pairs[i : i + per_line]) for i in range(0, len(pairs), per_line)]
        lines.append("  - [" + ",\n     ".join(rows) + "]")
    return "\n".join(lines) + "\n"


def _fmt(x: float, decimals: int) -> str:
    """Fixed-point text without trailing zeros (``0.05``, ``-1.0``), never ``-0.0``.

    Not ``repr``: it writes ``1e-05``, which YAML 1.1 (PyYAML) reads as a string.
    """
    text = f"{x:.{decimals}f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if float(text) == 0.0 else text


def save_paths(paths: Paths, path: str | Path, header: str = "") -> None:
    """Write ``paths`` in the file schema (commands rounded to 4 decimals)."""
    Path(path).write_text(paths_to_yaml(paths, header), encoding="utf-8")


# -- replay -----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Replay:
    """What the team did when driven by a :class:`Paths` (true, noise-free quantities).

    Sample k is the state after k steps (k = 0 is the start), so K steps give K + 1 samples.
    """

    layout: Layout
    poses: np.ndarray  # (K+1, N, 3) true poses
    visible: np.ndarray  # (K+1, N, N) bool, camera visibility (row sees column)
    collided: np.ndarray  # (K, N) bool, StepResult.collided of each step
    commands: np.ndarray  # (K, N, 2) the clipped commands the world applied
    hits: np.ndarray  # (K+1, N, B, 2) absolute beam hit points, NaN for no return
    guard_reverts: int  # World.guard_reverts at the end (0 for a clean run)
    beam_angles: np.ndarray = field(repr=False)  # (B,) rad

    def pair_distances(self) -> np.ndarray:  # (K+1, N, N)
        """Centre-to-centre distances between robots at every sample."""
        rel = self.poses[:, :, None, :2] - self.poses[:, None, :, :2]
        return np.asarray(np.hypot(rel[..., 0], rel[..., 1]))

    def mutual(self, i: int, j: int) -> np.ndarray:  # (K+1,) bool
        """Whether robots i and j see each other (both directions) at every sample."""
        return np.asarray(self.visible[:, i, j] & self.visible[:, j, i])

    def meetings(self, i: int, j: int) -> list[tuple[int, int]]:
        """Contiguous windows (first, last sample, inclusive) in which i and j see each other."""
        return contiguous_runs(self.mutual(i, j))

    def robot_hits(self, i: int) -> np.ndarray:  # (H, 2)
        """All finite hit points of robot i's beams over the run."""
        pts = self.hits[:, i].reshape(-1, 2)
        return np.asarray(pts[np.all(np.isfinite(pts), axis=1)])


def contiguous_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True in a (K,) bool mask as (first, last) indices, inclusive."""
    padded = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))  # starts and one-past-ends, alternating
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def replay_paths(
    paths: Paths,
    layout: Layout | None = None,
    config: WorldConfig | None = None,
    seed: int = 0,
) -> Replay:
    """Drive a fresh :class:`World` with ``paths`` from the map's start poses; record the truth.

    ``layout`` defaults to ``load_map(paths.map)``; ``config`` to ``WorldConfig(dt=paths.dt)``.
    """
    layout = load_map(paths.map) if layout is None else layout
    cfg = WorldConfig(dt=paths.dt) if config is None else config
    if not math.isclose(cfg.dt, paths.dt):
        raise ConfigError(f"dt: paths {paths.name!r} need dt = {paths.dt}, world has {cfg.dt}")
    world = World(layout, cfg, paths.num_robots, make_rngs(seed))
    angles = np.asarray(cfg.range_sensor.angles, dtype=float)  # (B,)
    poses, visible, hits = [world.poses], [_visible(world)], [_hit_points(world, angles)]
    collided, applied = [], []
    for k in range(paths.num_steps):
        result = world.step(paths.step_commands(k))
        collided.append(result.collided)
        applied.append(result.commands)
        poses.append(world.poses)
        visible.append(_visible(world))
        hits.append(_hit_points(world, angles))
    return Replay(
        layout=layout,
        poses=np.stack(poses),
        visible=np.stack(visible),
        collided=np.stack(collided),
        commands=np.stack(applied),
        hits=np.stack(hits),
        guard_reverts=world.guard_reverts,
        beam_angles=angles,
    )


def _visible(world: World) -> np.ndarray:  # (N, N) bool
    """Noise-free camera visibility of the world's current state."""
    mask, _, _ = world.camera_sensor.visible(
        world.poses, world.active, world.segments, world.pillars
    )
    return np.asarray(mask)


def _hit_points(world: World, angles: np.ndarray) -> np.ndarray:  # (N, B, 2)
    """True beam hit points in the absolute frame; NaN where a beam has no return."""
    pose = world.poses  # (N, 3)
    r = world.true_scan()  # (N, B)
    r = np.where(np.isfinite(r), r, np.nan)
    phi = pose[:, 2:3] + angles[None, :]  # (N, B)
    return np.stack([pose[:, 0:1] + r * np.cos(phi), pose[:, 1:2] + r * np.sin(phi)], axis=-1)

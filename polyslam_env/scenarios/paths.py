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

This module is the file format only (it imports nothing but ``core``, so policies may use it);
:func:`polyslam_env.world.replay.replay_paths` drives a world with the commands.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.io import parse_yaml
from polyslam_env.core.resources import builtin_names, configs_dir, resolve_file

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
        data = parse_yaml(path.read_text(encoding="utf-8"))  # JSON is a subset of YAML
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

"""Helpers shared by the subcommands: tables and progress."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polyslam_env.core.errors import OutputError
from polyslam_env.core.names import robot_name


def fmt(value: float) -> str:
    """A number for a table: 3 decimals in the everyday range, scientific outside, n/a for NaN."""
    if value != value:  # NaN
        return "n/a"
    if value == 0 or 1e-2 <= abs(value) < 1e4:
        return f"{value:.3f}"
    return f"{value:.2e}"


def format_table(
    rows: Sequence[dict[str, float]], keys: Sequence[str], names: Sequence[str]
) -> str:
    """A plain-text table: one column per row of ``rows`` (robots), one line per key."""
    width = max(len(k) for k in keys) + 2
    head = " " * width + "".join(f"{n:>12}" for n in names)
    lines = [head, "-" * len(head)]
    for k in keys:
        lines.append(f"{k:<{width}}" + "".join(f"{fmt(float(r[k])):>12}" for r in rows))
    return "\n".join(lines)


def agent_label(index: int) -> str:
    """A robot's name in every table and metrics file: the env's agent name ``robot_<i>``."""
    return robot_name(index)


def check_output_folder(path: str | Path, flag: str) -> Path:
    """``path`` if it is, or can become, a folder; else :class:`OutputError` before any work
    (a regular file at ``path`` or among its parents)."""
    path = Path(path)
    for p in (path, *path.parents):
        if p.exists():
            if not p.is_dir():
                where = "is a file" if p == path else f"is under {p}, which is a file"
                raise OutputError(f"{flag}: {path} {where}, expected a folder")
            break
    return path


def check_output_file(path: str | Path, flag: str) -> Path:
    """``path`` if a file can be written there; else :class:`OutputError` before any work
    (a folder at ``path``, or a regular file among its parents)."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{flag}: {path} is a folder, expected a file name")
    check_output_folder(path.parent, flag)
    return path


def show_progress(quiet: bool = False) -> bool:
    """Whether to draw progress bars: on a terminal, unless asked to be quiet."""
    return not quiet and sys.stderr.isatty()


def progress_bar(total: int, desc: str, unit: str, quiet: bool = False, leave: bool = True) -> Any:
    """A tqdm bar for long work, drawn only when :func:`show_progress` says so (tqdm is
    imported here, so that ``polyslam --help`` does not load it)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=not show_progress(quiet), leave=leave)

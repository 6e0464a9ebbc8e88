"""Helpers shared by the subcommands: tables, progress, and where a study runs."""

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


#: A study's results log in its output folder (see :mod:`polyslam_env.apps.joblog`).
RESULTS_LOG = "episodes.jsonl"


def add_study_arguments(parser: Any, workers_default: str) -> None:
    """``--workers``, ``--address`` and ``--resume``: where a study's episodes run and
    whether it goes on from its results log (:func:`study_runner` reads them)."""
    parser.add_argument("--workers", type=int, help=f"local processes (default: {workers_default})")
    parser.add_argument(
        "--address",
        help="run each episode as a task on the Ray cluster at this address (host:port of"
        " `ray start --head`, or auto); default: $RAY_ADDRESS when set and --workers is not"
        " given, else local processes. Needs the [ray] extra",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help=f"go on with the study in --out: skip the episodes its results log"
        f" ({RESULTS_LOG}, one line per finished episode) already has; refused if the log"
        " is of other options. Without it the log starts anew",
    )


def study_runner(
    args: Any, out: str | Path | None, workers: int, desc: str, noun: str = "episode"
) -> Any:
    """The :class:`~polyslam_env.apps.jobs.Runner` of :func:`add_study_arguments`' flags:
    ``args.workers`` (else ``workers``) local processes, or the Ray cluster at ``--address``
    (else ``RAY_ADDRESS`` unless ``--workers`` is given); the results log in ``out``, if
    any; a progress bar unless ``args.quiet``. Bad combinations are a one-line error, and a
    missing ``ray`` extra too (``ModuleNotFoundError``), before any work."""
    import os

    from polyslam_env.apps.jobs import Runner
    from polyslam_env.core.errors import PolyslamError

    address = args.address
    if address and args.workers is not None:
        raise PolyslamError(
            "--workers counts local processes; with --address the cluster's CPUs run the"
            " episodes: give one of them"
        )
    if address is None and args.workers is None:
        address = os.environ.get("RAY_ADDRESS") or None
    if address:
        from polyslam_env.apps.cluster import require_ray

        require_ray()
    if args.resume and out is None:
        raise PolyslamError("--resume: needs --out, the folder of the study's results log")
    log = None if out is None else check_output_folder(out, "--out") / RESULTS_LOG
    return Runner(
        workers=args.workers or workers,
        address=address,
        log=log,
        resume=args.resume,
        bar=show_progress(args.quiet),
        desc=desc,
        noun=noun,
    )


def where_text(runner: Any) -> str:
    """Where a study's episodes ran, for its closing line."""
    if runner.address:
        return f"on the Ray cluster at {runner.address}"
    return f"{runner.workers} worker{'s' if runner.workers != 1 else ''}"


def report_failed(runner: Any) -> None:
    """One line per job that failed on both tries (each was reported as it failed)."""
    for failed in runner.failed:
        print(
            f"{runner.noun} {failed['index']} (seed {failed['seed']}) failed: {failed['error']}"
            " (left out of the table; listed in summary.json)"
        )

"""The ``polyslam`` command: one subcommand per module in :mod:`polyslam_env.cli`.

Errors in the user's input (a bad map file, an unknown key in a config file, a bad value, a
missing checkpoint) are reported in one line naming the problem, exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import Any

from polyslam_env.cli import COMMANDS
from polyslam_env.core.errors import Interrupted, PolyslamError

#: Optional dependencies and how to get them (the extras in pyproject.toml).
EXTRAS = {
    "torch": "pip install torch==2.13.0 && pip install 'polyslam[rl]'",
    "stable_baselines3": "pip install torch==2.13.0 && pip install 'polyslam[rl]'",
    "supersuit": "pip install torch==2.13.0 && pip install 'polyslam[rl]'",
    "tensorboard": "pip install torch==2.13.0 && pip install 'polyslam[rl]'",
    "imageio": "pip install 'polyslam[video]' (or save a .gif, which needs nothing more)",
    "mpe2": "pip install 'polyslam[bench]'",
    "ray": "pip install 'polyslam[ray]'",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="polyslam",
        description="Multi-robot exploration with polynomial EKF SLAM in the loop.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"polyslam_env.cli.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args: Any = parser.parse_args(argv)
    for flag in ("robots", "steps", "episodes", "runs", "workers", "timesteps"):
        value = getattr(args, flag, None)
        if value is not None and value < 1:
            parser.error(f"--{flag}: must be >= 1, got {value}")
    seed = getattr(args, "seed", None)
    if seed is not None and seed < 0:
        parser.error(f"--seed: must be >= 0, got {seed}")
    try:
        return int(args.func(args))
    except (PolyslamError, FileNotFoundError) as err:
        print(f"polyslam: error: {err}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as err:
        root = (err.name or "").split(".")[0]
        if root not in EXTRAS:
            raise
        print(f"polyslam: error: {args.command} needs {root}: {EXTRAS[root]}", file=sys.stderr)
        return 2
    except Interrupted as stop:
        print(f"polyslam: {stop}", file=sys.stderr)
        return stop.code
    except KeyboardInterrupt:
        print("polyslam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""Subcommands of the ``polyslam`` command, one module each.

Each module defines ``register(subparsers)``, which adds its parser and sets ``func`` to a
function taking the parsed arguments and returning an exit code. Modules must import heavy
dependencies (torch, pygame, ray) inside ``func``, so that ``polyslam --help`` stays fast and
works without the optional extras.
"""

#: The command modules, in the order ``polyslam --help`` lists them.
COMMANDS = (
    "simulate",
    "maps",
    "run",
    "evaluate",
    "reproduce",
    "fidelity",
    "train",
    "benchmark",
)

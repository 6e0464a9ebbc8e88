"""polyslam: multi-robot exploration with polynomial-landmark EKF SLAM in the loop.

The public API: ``parallel_env`` (the PettingZoo parallel env), ``env`` (its AEC version) and
``EnvConfig``. They are imported on first use (PEP 562 module ``__getattr__``), so ``import
polyslam_env`` stays light; the env pulls in pymunk, PettingZoo and scipy. Importing the package
also registers the Gymnasium id ``polyslam/Team-v0`` (an entry-point string, no env import).

The parts, one folder each (docs/design/architecture.md draws the arrows between them):
``core`` shared basics · ``world`` pymunk world and sensors · ``slam`` the per-robot EKF SLAM ·
``comms`` rendezvous exchange · ``metrics`` · ``environment`` the PettingZoo env ·
``render`` pictures · ``scenarios`` shipped path files · ``apps`` what the CLI runs · ``cli``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from polyslam_env.core.errors import ConfigError, MapFileError, PolyslamError

if TYPE_CHECKING:
    from polyslam_env.environment.config import EnvConfig
    from polyslam_env.environment.parallel import env, parallel_env

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "EnvConfig",
    "MapFileError",
    "PolyslamError",
    "__version__",
    "env",
    "parallel_env",
]

#: Exported names imported on first use, and the module each comes from.
_LAZY = {
    "env": "polyslam_env.environment.parallel",
    "parallel_env": "polyslam_env.environment.parallel",
    "EnvConfig": "polyslam_env.environment.config",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'polyslam_env' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


# Gymnasium ids (``polyslam/Team-v0``): a registry entry with an entry-point string, no env import.
from polyslam_env.environment.team import register_envs as _register_envs  # noqa: E402

_register_envs()

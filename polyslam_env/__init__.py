"""polyslam: multi-robot exploration with polynomial-landmark EKF SLAM in the loop.

``parallel_env``, ``env`` and ``EnvConfig`` are imported on first use, so ``import
polyslam_env`` stays light (the env pulls in pymunk, PettingZoo and scipy). ``polyslam_env.env``
is the AEC constructor, as PettingZoo expects; the module of the same name is reached with
``from polyslam_env.env import ...`` (``import polyslam_env.env as m`` gives the function).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from polyslam_env.errors import ConfigError, MapFileError, PolyslamError

if TYPE_CHECKING:
    from polyslam_env.env import env, parallel_env
    from polyslam_env.env_config import EnvConfig

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
    "env": "polyslam_env.env",
    "parallel_env": "polyslam_env.env",
    "EnvConfig": "polyslam_env.env_config",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'polyslam_env' has no attribute {name!r}")


class _Package(types.ModuleType):
    """Keeps ``polyslam_env.env`` the constructor: the import system sets a package attribute
    to each submodule it loads, which would hide the function behind the module ``env.py``."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

# Gymnasium ids (``polyslam/Team-v0``): a registry entry with an entry-point string, no env import.
from polyslam_env.gym_env import register_envs as _register_envs  # noqa: E402

_register_envs()

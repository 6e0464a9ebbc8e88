"""Loading a checkpoint that ``polyslam train`` wrote (an SB3 PPO ``.zip``), shared by the
learned policies (:mod:`policies.ppo`, :mod:`policies.drive`). SB3 is imported on the first load.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

from policies.base import CheckpointError

__all__ = ["load_checkpoint"]

#: Loaded models by (resolved path, modification time): robots of a team share one network.
_CACHE: dict[tuple[str, int], Any] = {}


def load_checkpoint(path: str | Path) -> Any:
    """The SB3 PPO model in ``path`` (cached); :class:`CheckpointError` if missing or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {str(path)!r}: no such file")
    key = (str(path.resolve()), path.stat().st_mtime_ns)
    if key not in _CACHE:
        if not zipfile.is_zipfile(path):
            raise CheckpointError(f"checkpoint {str(path)!r}: not an SB3 .zip file")
        from stable_baselines3 import PPO

        try:
            _CACHE[key] = PPO.load(path, device="cpu")
        except Exception as err:  # SB3 raises many kinds on a damaged archive
            raise CheckpointError(
                f"checkpoint {str(path)!r}: cannot load ({type(err).__name__}: {err})"
            ) from None
    return _CACHE[key]

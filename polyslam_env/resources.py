"""Where the shipped configuration files (``configs/``) live.

In a source checkout or an editable install they are the repository's ``configs/`` folder;
a regular ``pip install .`` ships the same folder as the package ``polyslam_env._configs``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path


def configs_dir() -> Path:
    """The folder holding ``maps/``, ``paper.yaml`` and the other shipped presets."""
    source = Path(__file__).resolve().parent.parent / "configs"
    if (source / "maps").is_dir():
        return source
    spec = importlib.util.find_spec("polyslam_env._configs")
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    raise FileNotFoundError("polyslam's configs/ folder is missing: reinstall the package")


def maps_dir() -> Path:
    return configs_dir() / "maps"

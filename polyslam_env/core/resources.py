"""Where the shipped configuration files (``configs/``) live.

In a source checkout or an editable install they are the repository's ``configs/`` folder;
a regular ``pip install .`` ships the same folder as the package ``polyslam_env._configs``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path


def configs_dir() -> Path:
    """The folder holding ``maps/``, ``paper.yaml`` and the other shipped presets."""
    source = Path(__file__).resolve().parents[2] / "configs"
    if (source / "maps").is_dir():
        return source
    spec = importlib.util.find_spec("polyslam_env._configs")
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    raise FileNotFoundError("polyslam's configs/ folder is missing: reinstall the package")


def maps_dir() -> Path:
    return configs_dir() / "maps"


def builtin_names(folder: Path) -> list[str]:
    """Stems of the YAML files shipped in ``folder`` (empty if it does not exist)."""
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []


def resolve_file(name_or_path: str | Path, folder: Path, kind: str, error: type[Exception]) -> Path:
    """A built-in name (a YAML file in ``folder``) or a path to a file; else ``error``.

    Anything that looks like a path (a YAML/JSON suffix, a slash, an existing file) must be a
    file; otherwise the name must be built in. ``kind`` names the thing in messages.
    """
    text = str(name_or_path)
    path = Path(text)
    if path.suffix.lower() in (".yaml", ".yml", ".json") or path.exists() or "/" in text:
        if not path.is_file():
            raise error(f"{path}: {kind} file not found")
        return path
    builtin = folder / f"{text}.yaml"
    if builtin.is_file():
        return builtin
    names = ", ".join(builtin_names(folder)) or "none"
    raise error(f"unknown {kind} {text!r}: not a file and not built-in (built-in: {names})")

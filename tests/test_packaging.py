"""The wheel ships every package and the configs/ folder."""

from __future__ import annotations

import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent


def test_pyproject__lists_every_package_folder() -> None:
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("polyslam_env", "policies")
        for p in (ROOT / top).rglob("__init__.py")
    }
    assert found - listed == set(), "add these packages to pyproject.toml [tool.setuptools]"
    assert "polyslam_env._configs" in listed


def test_pyproject__ships_maps_and_paths() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert data["package-dir"]["polyslam_env._configs"] == "configs"
    patterns = data["package-data"]["polyslam_env._configs"]
    assert {"maps/*.yaml", "paths/*.yaml"} <= set(patterns)
    assert list((ROOT / "configs" / "maps").glob("*.yaml"))
    assert list((ROOT / "configs" / "paths").glob("*.yaml"))


def test_pyproject__ships_the_learned_policy() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "checkpoints/*.zip" in data["package-data"]["policies"]
    for name in ("ppo_goals.zip", "ppo_drive.zip"):
        assert (ROOT / "policies" / "checkpoints" / name).is_file()

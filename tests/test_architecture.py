"""The arrows between the package's parts run one way (docs/design/architecture.md).

Every ``import`` in ``polyslam_env/`` and ``policies/`` is read with :mod:`ast` (imports inside
functions included: a lazy import is still an arrow) and checked against the table below.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Part → the parts it may import (itself always). ``polyslam_env`` alone is the package root.
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "scenarios": {"core"},
    "world": {"core", "scenarios"},
    "slam": {"core"},
    "comms": {"core", "slam"},
    "metrics": {"core", "slam", "world"},
    "render": {"core", "slam", "world", "metrics"},
    "environment": {"core", "slam", "world", "comms", "metrics", "render"},
    "apps": {"core", "scenarios", "slam", "world", "comms", "metrics", "render", "environment"}
    | {"policies", "polyslam_env"},
    "cli": {"core", "scenarios", "slam", "world", "comms", "metrics", "render", "environment"}
    | {"apps", "policies", "polyslam_env"},
    "policies": {"core", "scenarios"},
    "polyslam_env": {"core", "environment"},
}
#: Third-party packages only some parts may import.
EXCLUSIVE: dict[str, set[str]] = {
    "pymunk": {"world", "apps"},  # apps: the benchmark times bare pymunk as a reference
    "pygame": {"render"},
    "numba": {"core"},  # only core/jit.py: one place sets the compile options
    "torch": {"apps", "policies"},
    "stable_baselines3": {"apps", "policies", "environment"},  # environment: the SB3 adapter
    "supersuit": {"environment", "apps"},
    "pettingzoo": {"environment", "apps"},
    "ray": {"apps"},
}


def _part(module: str) -> str | None:
    """The part a dotted module name belongs to (None for third-party modules)."""
    top, _, rest = module.partition(".")
    if top == "policies":
        return "policies"
    if top != "polyslam_env":
        return None
    sub = rest.split(".")[0]
    return sub if sub in ALLOWED else "polyslam_env"


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in a file; ``from x import y`` also yields ``x.y``."""
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module != "polyslam_env":  # from the root: the names say which part
                out.append((node.lineno, node.module))
            out += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return out


def _sources() -> list[tuple[str, Path]]:
    files = sorted((ROOT / "polyslam_env").rglob("*.py")) + sorted(
        (ROOT / "policies").rglob("*.py")
    )
    return [(_part(".".join(p.relative_to(ROOT).with_suffix("").parts)) or "", p) for p in files]


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name


def violations() -> list[str]:
    found = []
    for part, path in _sources():
        for line, module in _imports(path):
            target = _part(module)
            name = f"{_shown(path)}:{line} imports {module}"
            if target is not None and target != part and target not in ALLOWED[part]:
                if not (part != "polyslam_env" and module == "polyslam_env" and target == part):
                    found.append(f"{name} ({part} -> {target})")
            top = module.split(".")[0]
            if top in EXCLUSIVE and part not in EXCLUSIVE[top]:
                found.append(f"{name} (only {sorted(EXCLUSIVE[top])} may import {top})")
    return found


def test_imports__follow_the_layer_table() -> None:
    assert violations() == []


def test_every_part_is_in_the_table() -> None:
    parts = {p.name for p in (ROOT / "polyslam_env").iterdir() if (p / "__init__.py").is_file()}
    assert parts - {"_configs"} <= set(ALLOWED), parts - set(ALLOWED)


@pytest.mark.parametrize(
    ("part", "forbidden"),
    [
        ("slam", "polyslam_env.world"),
        ("world", "polyslam_env.slam"),
        ("policies", "polyslam_env.environment"),
        ("core", "pymunk"),
    ],
)
def test_checker__catches_a_forbidden_arrow(
    part: str, forbidden: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check is not vacuous: a planted forbidden import is reported."""
    planted = tmp_path / "planted.py"
    planted.write_text(f"def f():\n    import {forbidden}\n")
    real = _sources()
    monkeypatch.setattr(sys.modules[__name__], "_sources", lambda: [*real, (part, planted)])
    assert any("planted.py:2" in v for v in violations())


def test_slam__imports_alone_without_world_env_or_physics() -> None:
    """``slam/`` is usable alone: importing it loads none of the other parts, pymunk or
    PettingZoo. (The package root registers the Gymnasium id, so gymnasium itself loads.)"""
    code = (
        "import sys, polyslam_env.slam.robot;"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('pymunk', 'pettingzoo', 'pygame')"
        " or m.startswith(('polyslam_env.world', 'polyslam_env.environment.parallel',"
        " 'polyslam_env.comms', 'polyslam_env.metrics', 'polyslam_env.render'))];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr

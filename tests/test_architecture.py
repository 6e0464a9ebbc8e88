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
    "llvmlite": {"core"},  # numba's code generator: core/jit.py's fma intrinsic
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


def test_env__imports_without_scipy_stats() -> None:
    """Importing the env (what every worker process of ``reproduce``, ``fidelity`` or a
    vectorised env does first) does not load ``scipy.stats``: about a second of each
    process's start. Import it inside the functions that need it."""
    code = (
        "import sys, polyslam_env.environment.parallel, polyslam_env.apps.reproduce;"
        "sys.exit(1 if 'scipy.stats' in sys.modules else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr


# -- no import circles ----------------------------------------------------------------------------
def _module(path: Path, root: Path) -> str:
    """The dotted name of a source file under ``root`` (a package's ``__init__`` is the
    package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_only_lines(path: Path) -> set[int]:
    """Lines of the imports under ``if TYPE_CHECKING:`` (read by type checkers, never run)."""
    lines: set[int] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.If):
            continue
        test = node.test
        name = test.id if isinstance(test, ast.Name) else getattr(test, "attr", None)
        if name == "TYPE_CHECKING":
            for inner in node.body:
                lines |= {n.lineno for n in ast.walk(inner) if isinstance(n, ast.stmt)}
    return lines


def _module_graph(sources: list[Path], root: Path) -> dict[str, set[str]]:
    """Module → the package's modules it imports when run (anywhere in it: a lazy import is an
    arrow; one under ``if TYPE_CHECKING:`` never runs and is not); ``from x import y`` is an
    arrow to ``x.y`` when that is a module, else to ``x``."""
    names = {_module(p, root) for p in sources}
    graph: dict[str, set[str]] = {}
    for path in sources:
        me = _module(path, root)
        typing_only = _type_only_lines(path)
        found = {
            m for line, m in _imports(path) if m in names and m != me and line not in typing_only
        }
        # ``from x import y`` yields both x and x.y: the arrow goes to x.y alone when y is one
        graph[me] = {m for m in found if not any(o.startswith(m + ".") for o in found)}
    return graph


def import_circles(sources: list[Path], root: Path = ROOT) -> list[list[str]]:
    """The strongly connected components of more than one module of ``sources`` (files under
    ``root``), by Tarjan's algorithm."""
    graph = _module_graph(sources, root)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = [stack.pop()]
            while component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return circles


def test_imports__form_no_circle() -> None:
    """No module imports, directly or through others, a module that imports it back: the
    arrows between modules run one way, as between parts."""
    assert import_circles([p for _, p in _sources()]) == []


def test_circle_check__catches_a_planted_circle(tmp_path: Path) -> None:
    """The check is not vacuous: two planted modules importing each other (one lazily) are
    reported; a one-way pair is not, nor a pair closed only by a type checker's import (a
    helper typed against its owner: never run)."""
    package = tmp_path / "polyslam_env"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("import polyslam_env.b\n")
    (package / "b.py").write_text("def f():\n    from polyslam_env import a\n")
    (package / "c.py").write_text("from polyslam_env.a import x\n")
    (package / "d.py").write_text("from polyslam_env.e import y\n")
    (package / "e.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from polyslam_env.d import z\n"
    )
    files = sorted(package.glob("*.py"))
    assert import_circles(files, tmp_path) == [["polyslam_env.a", "polyslam_env.b"]]
    (package / "e.py").write_text("def g():\n    from polyslam_env.d import z\n")  # run: a circle
    assert import_circles(files, tmp_path) == [
        ["polyslam_env.a", "polyslam_env.b"],
        ["polyslam_env.d", "polyslam_env.e"],
    ]

"""core is the bottom layer: it imports nothing of the package but core."""

from __future__ import annotations

import ast
from pathlib import Path

import polyslam_env.core


def test_core__imports_nothing_of_the_package_but_core() -> None:
    folder = Path(polyslam_env.core.__file__).parent
    outside = []
    for path in sorted(folder.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and node.level == 0
                else []
            )
            for name in names:
                top = name.split(".")
                if top[0] in ("polyslam_env", "policies") and top[:2] != ["polyslam_env", "core"]:
                    outside.append(f"{path.name}: {name}")
    assert outside == []

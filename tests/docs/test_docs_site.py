"""The README and the docs site: short README, its commands those CI runs, every page in the
nav, every config key documented, every object of the API reference with a docstring."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.scripts_module import load_script

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
CI = ROOT / ".ci" / "run"
DOCS = ROOT / "docs"
hooks = load_script("docs_hooks")


def fenced_commands(text: str) -> list[str]:
    """The lines of the ```bash blocks of a Markdown text."""
    blocks = re.findall(r"```bash\n(.*?)```", text, re.DOTALL)
    return [line for block in blocks for line in block.splitlines() if line.strip()]


def test_readme__at_most_400_lines() -> None:
    assert len(README.read_text().splitlines()) <= 400


def test_readme__test_command_is_the_one_ci_runs() -> None:
    ci = CI.read_text().splitlines()
    marker = next(i for i, line in enumerate(ci) if "keep the two identical" in line)
    ci_command = next(line for line in ci[marker + 1 :] if not line.startswith("#"))
    assert ci_command in fenced_commands(README.read_text())


def test_readme__main_command_parses_and_docs_build_is_cis() -> None:
    from polyslam_env.cli.main import build_parser

    commands = fenced_commands(README.read_text())
    main = next(c for c in commands if "polyslam run" in c)
    setup, run = main.split(" && ")
    assert setup == "pip install -e ."
    args = build_parser().parse_args(run.split()[1:])  # argparse exits on a bad command
    assert args.func.__name__ == "run"
    assert "mkdocs build --strict" in CI.read_text()
    assert 'pip install -e ".[docs]" && mkdocs build --strict' in README.read_text()


def nav_pages(nav: Any) -> list[str]:
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [p for item in nav for p in nav_pages(item)]
    if isinstance(nav, dict):
        return [p for value in nav.values() for p in nav_pages(value)]
    return []


def mkdocs_config() -> dict[str, Any]:
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text())


def test_site__every_page_is_in_the_nav_and_every_nav_entry_exists() -> None:
    nav = set(nav_pages(mkdocs_config()["nav"]))
    pages = {
        str(p.relative_to(DOCS))
        for p in DOCS.rglob("*.md")
        if not str(p.relative_to(DOCS)).startswith("notes/")
    }
    assert pages == nav


def test_config_reference__lists_every_key_of_the_config_tree_with_a_comment() -> None:
    # An independent walk: the keys of EnvConfig().to_dict() (and of one fault entry, a list
    # that is empty by default) against the keys the reference is generated from.
    from polyslam_env.environment.config import EnvConfig, FaultConfig

    def walk(data: dict[str, Any], prefix: str) -> set[str]:
        keys = set()
        for name, value in data.items():
            keys.add(prefix + name)
            if isinstance(value, dict):
                keys |= walk(value, f"{prefix}{name}.")
        return keys

    expected = walk(EnvConfig().to_dict(), "") | walk(FaultConfig().to_dict(), "faults[].")
    listed = {k.key: k for k in hooks.config_keys()}
    assert set(listed) == expected
    assert not [k for k, v in listed.items() if not v.doc]
    reference = hooks.config_reference()
    for key in expected:
        section, _, name = key.rpartition(".")
        assert f"### `{section or 'top level'}`" in reference and f"| `{name}` |" in reference
    assert hooks.CONFIG_MARK in (DOCS / "guide" / "configuration.md").read_text()


def test_field_comments__above_and_trailing() -> None:
    from dataclasses import dataclass

    @dataclass
    class Example:
        # above one
        # above two
        a: int = 1  # trailing
        b: int = 2
        c: int = 3  # only trailing

    assert hooks.field_comments(Example) == {
        "a": "above one above two trailing",
        "b": "",
        "c": "only trailing",
    }


def test_api_reference__every_rendered_object_has_a_docstring() -> None:
    pytest.importorskip("griffe")
    assert hooks.undocumented(DOCS) == []


def test_api_reference__an_undocumented_object_is_found(tmp_path: Path) -> None:
    pytest.importorskip("griffe")
    page = tmp_path / "api.md"
    # PolySlamParallelEnv's helper below has no docstring: listing it must be caught
    page.write_text(
        "::: polyslam_env.environment.parallel.PolySlamParallelEnv\n"
        "    options:\n      members:\n        - _check_agent\n"
    )
    assert hooks.undocumented(tmp_path) == [
        "polyslam_env.environment.parallel.PolySlamParallelEnv._check_agent"
    ]

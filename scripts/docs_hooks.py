"""MkDocs hooks of the docs site (``mkdocs.yml``: ``hooks``), and the checks they run.

* The configuration reference is written at build time from the config dataclasses
  (:func:`config_reference`): a page's ``<!-- config-keys -->`` line becomes one table per
  section, every field with its type, default and the comment that documents it in the source,
  so the page cannot drift from the code. A field without a comment is a build warning.
* Every object the API reference renders (``::: name`` lines, their public members) must have
  a docstring (:func:`undocumented`): mkdocstrings silently leaves out an object without one,
  so the hook warns, and ``mkdocs build --strict`` fails.

``tests/docs/test_docs_site.py`` runs both checks too, without building the site.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import logging
import re
import textwrap
import types
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: The line of a page that the configuration reference replaces.
CONFIG_MARK = "<!-- config-keys -->"
#: A mkdocstrings directive: ``::: dotted.name`` at the start of a line.
DIRECTIVE = re.compile(r"^::: *([\w.]+) *$", re.MULTILINE)

log = logging.getLogger("mkdocs.hooks.polyslam")


# -- the configuration reference -------------------------------------------------------------
class ConfigKey(typing.NamedTuple):
    """One field of the env's configuration tree."""

    key: str  # dotted, from EnvConfig: "world.range_sensor.max_range"
    type: str
    default: str
    doc: str  # the comments on and above the field's line in its class


def field_comments(cls: type) -> dict[str, str]:
    """Field name → its comment in ``cls``'s source: the comment lines right above the field
    and the comment at the end of its line(s), joined."""
    source = textwrap.dedent(inspect.getsource(cls))
    lines = source.splitlines()
    body = ast.parse(source).body[0]
    assert isinstance(body, ast.ClassDef)
    out: dict[str, str] = {}
    previous_end = body.lineno  # the class line (decorators come before it)
    for stmt in body.body:
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            above = []
            for line in reversed(lines[previous_end : stmt.lineno - 1]):
                text = line.strip()
                if not text.startswith("#"):
                    break
                above.append(text.lstrip("#").strip())
            trailing = [
                line.split("  # ", 1)[1].strip()
                for line in lines[stmt.lineno - 1 : stmt.end_lineno]
                if "  # " in line
            ]
            parts = [*reversed(above), *trailing]
            out[stmt.target.id] = " ".join(p for p in parts if p and p != "fmt: skip")
        previous_end = stmt.end_lineno or stmt.lineno
    return out


def _config_class(hint: Any) -> type | None:
    """The Config class a field's type names (``X``, ``X | None``, ``tuple[X | …, ...]``)."""
    from polyslam_env.core.config import Config

    if isinstance(hint, type) and issubclass(hint, Config):
        return hint
    if typing.get_origin(hint) in (typing.Union, types.UnionType, tuple):
        for arg in typing.get_args(hint):
            found = _config_class(arg)
            if found is not None:
                return found
    return None


def _type_name(hint: Any) -> str:
    text = str(hint) if not isinstance(hint, type) else hint.__name__
    text = re.sub(r"\b(?:\w+\.)+(\w+)", r"\1", text)  # typing.Literal, comms.channel.X
    return text.replace("NoneType", "None")


def _default(f: dataclasses.Field[Any]) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "required"
    from polyslam_env.core.config import Config

    if isinstance(value, Config):
        return "(section)"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "…"


def config_keys(cls: type | None = None, prefix: str = "") -> Iterator[ConfigKey]:
    """Every field of the configuration tree under ``cls`` (default: ``EnvConfig``), depth
    first in source order; a field that holds a config section is listed, then its fields."""
    if cls is None:
        from polyslam_env.environment.config import EnvConfig

        cls = EnvConfig
    hints = typing.get_type_hints(cls)
    docs = field_comments(cls)
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        key = f"{prefix}{f.name}"
        section = _config_class(hint)
        doc = docs.get(f.name, "")
        if section is not None and not doc:
            doc = (inspect.getdoc(section) or "").split("\n\n")[0].replace("\n", " ")
        yield ConfigKey(key, _type_name(hint), _default(f), doc)
        if section is not None:
            many = typing.get_origin(hint) is tuple
            yield from config_keys(section, f"{key}[]." if many else f"{key}.")


def _cell(text: str) -> str:
    """``text`` for a Markdown table cell: no pipes, no line breaks, no HTML."""
    return text.replace("|", "\\|").replace("\n", " ").replace("<", "&lt;").replace(">", "&gt;")


def config_reference() -> str:
    """The configuration reference as Markdown: one table per config section."""
    sections: dict[str, list[ConfigKey]] = {}
    for k in config_keys():
        sections.setdefault(k.key.rpartition(".")[0], []).append(k)  # "faults[]": each entry
    out = []
    for section, keys in sections.items():
        out.append(f"### `{section or 'top level'}`\n")
        out.append("| key | type | default | what it is |\n|---|---|---|---|")
        for k in keys:
            name = k.key.rpartition(".")[2]
            cells = (f"`{name}`", f"`{_cell(k.type)}`", f"`{_cell(k.default)}`", _cell(k.doc))
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


# -- every rendered object documented --------------------------------------------------------
def api_directives(docs: Path = DOCS) -> list[tuple[str, Any]]:
    """The objects the pages under ``docs`` render, ``::: name`` lines, each with its
    ``members`` option (None: every public member; False: none; a list: those)."""
    import yaml

    out = []
    for page in sorted(docs.rglob("*.md")):
        lines = page.read_text().splitlines()
        for i, line in enumerate(lines):
            match = DIRECTIVE.match(line)
            if not match:
                continue
            block = []
            for follow in lines[i + 1 :]:
                if not follow.startswith("    "):
                    break
                block.append(follow)
            options = (yaml.safe_load(textwrap.dedent("\n".join(block))) or {}).get("options", {})
            out.append((match.group(1), options.get("members")))
    return out


def _public_members(obj: Any) -> Iterator[Any]:
    """What mkdocstrings renders below ``obj`` with ``filters: public`` and no inherited
    members: public functions and classes, and the properties of classes."""
    for member in obj.members.values():
        if member.is_alias or member.name.startswith("_") or not member.is_public:
            continue
        if member.inherited:
            continue
        if member.kind.value in ("function", "class") or "property" in member.labels:
            yield member


def _rendered(obj: Any, members: Any = None) -> Iterator[Any]:
    """``obj`` and what mkdocstrings renders below it: ``members`` (a list of names, False
    for none, None for every public member), recursively."""
    yield obj
    if members is False or obj.kind.value not in ("module", "class"):
        return
    if members is not None:
        unknown = [m for m in members if m not in obj.members]
        if unknown:
            raise KeyError(f"{obj.path} has no member {unknown[0]!r} (listed in the API reference)")
    chosen = _public_members(obj) if members is None else (obj.members[m] for m in members)
    for member in chosen:
        member = member.final_target if member.is_alias else member
        if member.kind.value != "attribute" or "property" in member.labels:
            yield from _rendered(member)  # (data is documented by its #: comment, if any)


def undocumented(docs: Path = DOCS) -> list[str]:
    """Paths of the objects the API reference renders (:func:`api_directives`) that have no
    docstring."""
    import griffe

    roots = {
        name: griffe.load(name, search_paths=[str(ROOT)], resolve_aliases=True)
        for name in ("polyslam_env", "policies")
    }
    missing = set()
    for ident, members in api_directives(docs):
        head, _, rest = ident.partition(".")
        obj = roots[head][rest] if rest else roots[head]
        obj = obj.final_target if obj.is_alias else obj
        missing.update(o.path for o in _rendered(obj, members) if not o.has_docstring)
    return sorted(missing)


# -- MkDocs hooks ------------------------------------------------------------------------------
def on_pre_build(config: Any, **kwargs: Any) -> None:
    """Warn (strict: fail) on every rendered object without a docstring and every config key
    without a comment."""
    for path in undocumented(Path(config["docs_dir"])):
        log.warning("API reference: %s has no docstring", path)
    for k in config_keys():
        if not k.doc:
            log.warning("configuration reference: %s has no comment in its class", k.key)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any, **kwargs: Any) -> str:
    """Write the configuration reference where a page asks for it."""
    if CONFIG_MARK in markdown:
        return markdown.replace(CONFIG_MARK, config_reference())
    return markdown

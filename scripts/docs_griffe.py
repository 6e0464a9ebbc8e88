"""A griffe extension for the docs site (``mkdocs.yml``): the docstrings' Sphinx roles as code.

The package's docstrings name objects with Sphinx roles (``:class:`~polyslam_env.x.Y```,
``:func:`f```), which Markdown would print as they are. This turns each into inline code of
the name it shows (``Y`` for a ``~`` target, the whole target otherwise, or the role's own
text for ``:func:`text <target>```).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

#: ``:role:`target``` or ``:role:`text <target>``` (with an optional ``py:`` domain).
ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|const|ref):`([^`]+)`")


def plain(text: str) -> str:
    """``text`` with every Sphinx role replaced by inline code of the name it shows."""

    def code(match: re.Match[str]) -> str:
        target = match.group(1).strip()
        if "<" in target and target.endswith(">"):
            return f"`{target.split('<', 1)[0].strip()}`"
        if target.startswith("~"):
            return f"`{target[1:].rsplit('.', 1)[-1]}`"
        return f"`{target}`"

    return ROLE.sub(code, text)


class SphinxRoles(griffe.Extension):
    """Rewrite the roles of every loaded object's docstring (:func:`plain`)."""

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)

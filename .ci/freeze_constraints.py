"""Write the constraints file CI installs from: the installed version of every distribution
that installing ``polyslam[EXTRAS]`` pulls in.

The golden episodes (``tests/test_golden.py``) hold bit for bit only with the numpy, scipy,
pymunk, numba … they were recorded with, so CI pins those. Run this on the machine the goldens
were recorded on, after ``pip install torch==2.13.0 && pip install -e ".[EXTRAS]"``:

    python .ci/freeze_constraints.py            # writes .ci/constraints.txt

It walks the requirements of ``pyproject.toml`` (with the extras) through the installed
distributions' own requirements, markers evaluated for this interpreter, so a package that is
installed here but that the install does not pull in is not listed. It fails, naming the
package, when a requirement is not installed or its installed version does not satisfy it.
"""

from __future__ import annotations

import argparse
import sys
from importlib import metadata
from pathlib import Path

import tomllib
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]
EXTRAS = "dev,rl,video,ray,bench,docs"


def _requirements(pyproject: Path, extras: list[str]) -> list[Requirement]:
    project = tomllib.loads(pyproject.read_text())["project"]
    reqs = [Requirement(r) for r in project["dependencies"]]
    for extra in extras:
        if extra not in project["optional-dependencies"]:
            raise SystemExit(f"{pyproject}: no extra {extra!r}")
        reqs += [Requirement(r) for r in project["optional-dependencies"][extra]]
    return reqs


def _applies(req: Requirement, extras: set[str]) -> bool:
    if req.marker is None:
        return True
    return any(req.marker.evaluate({"extra": e}) for e in sorted(extras | {""}))


def closure(reqs: list[Requirement]) -> dict[str, str]:
    """{canonical name: installed version} of ``reqs`` and everything they require."""
    pinned: dict[str, str] = {}
    todo = [(r, set(r.extras)) for r in reqs]
    seen: set[tuple[str, frozenset[str]]] = set()
    while todo:
        req, extras = todo.pop()
        name = canonicalize_name(req.name)
        key = (name, frozenset(extras))
        if key in seen:
            continue
        seen.add(key)
        try:
            dist = metadata.distribution(req.name)
        except metadata.PackageNotFoundError:
            raise SystemExit(f"{req.name}: required ({req}) but not installed") from None
        version = dist.version
        if not req.specifier.contains(version, prereleases=True):
            raise SystemExit(f"{req.name}: installed {version} does not satisfy {req}")
        pinned[name] = version
        for text in dist.requires or []:
            sub = Requirement(text)
            if _applies(sub, extras):
                todo.append((sub, set(sub.extras)))
    return pinned


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--extras", default=EXTRAS, help=f"comma-separated ({EXTRAS})")
    parser.add_argument("--out", type=Path, default=ROOT / ".ci" / "constraints.txt")
    args = parser.parse_args(argv)
    extras = [e for e in args.extras.split(",") if e]
    pinned = closure(_requirements(ROOT / "pyproject.toml", extras))
    # torch is installed first as `pip install torch==2.13.0` (the CPU build's local version
    # "+cpu" is matched by "==2.13.0"); the constraint names the public version.
    lines = [f"{name}=={version.split('+')[0]}" for name, version in sorted(pinned.items())]
    header = (
        "# Versions the golden episodes were recorded with (tests/test_golden.py): the closure\n"
        f"# of polyslam[{','.join(extras)}] as installed; regenerate with\n"
        "# `python .ci/freeze_constraints.py` (docs/design/testing.md).\n"
    )
    args.out.write_text(header + "\n".join(lines) + "\n")
    print(f"{args.out}: {len(lines)} packages", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

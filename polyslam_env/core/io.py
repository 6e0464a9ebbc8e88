"""Writing results atomically: a reader (or a Ctrl-C) never sees half a file; reading YAML
with libyaml's parser (:func:`parse_yaml`)."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import yaml

from polyslam_env.core.errors import OutputError

#: PyYAML's safe loader on libyaml's C parser when PyYAML was built with it (about 8× faster:
#: the paper's paths file took 0.4 s to parse in pure Python, longer than a paper episode's
#: SLAM, in every worker process of ``polyslam reproduce``), else the pure-Python one. Both
#: build their values with the same Python constructors, so the data are the same.
_SAFE_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def parse_yaml(text: str) -> Any:
    """``yaml.safe_load(text)`` through :data:`_SAFE_LOADER`; raises ``yaml.YAMLError``."""
    return yaml.load(text, Loader=_SAFE_LOADER)


def _clean(value: Any) -> Any:
    """JSON has no NaN or inf: write them as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def ordinary_permissions(path: str | Path) -> None:
    """Give ``path`` the mode a plain ``open(..., "w")`` would (0666 less the umask);
    ``tempfile.mkstemp`` makes 0600, which would leave results unreadable to others."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def write_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write to a temporary file in the same folder, then rename it over ``path``.

    A write the system refuses (a folder at ``path``, a regular file among its parents, a
    full disk, no permission) raises :class:`OutputError` naming ``path``.
    """
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:
        raise OutputError(f"{path}: cannot write ({err.strerror or err})") from None
    try:
        ordinary_permissions(tmp)
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write ({err.strerror or err})") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json(path: str | Path, data: Any) -> Path:
    """Atomic JSON with NaN/inf as null, indented for people."""
    return write_atomic(path, json.dumps(_clean(data), indent=2, sort_keys=False) + "\n")

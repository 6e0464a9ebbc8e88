"""The one entry point to numba: :func:`njit` compiles a hot numerical kernel, cached on disk.

Kernels are plain Python loops over numpy arrays, compiled with ``nopython=True`` and
``cache=True`` and never with ``fastmath`` (results stay bit-identical across runs). Only this
module imports numba (``tests/test_architecture.py`` checks it), so the compile options are set in
one place.

The cache lives next to the source (``__pycache__``) when that folder is writable, otherwise in
numba's per-user cache folder. When neither is writable (a read-only install under a read-only
home), it goes to a per-user folder under the system temp directory.
"""

from __future__ import annotations

import inspect
import os
import tempfile
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["fallback_cache_dir", "njit"]

F = TypeVar("F", bound=Callable[..., Any])


def fallback_cache_dir() -> str:
    """A writable per-user cache folder under the system temp directory."""
    user = os.getuid() if hasattr(os, "getuid") else os.getlogin()
    return os.path.join(tempfile.gettempdir(), f"polyslam-numba-{user}")


def njit(fn: F) -> F:
    """Compile ``fn`` with numba (nopython, cached on disk, no fastmath).

    A function with no source file (defined in ``exec``'d text) cannot be cached; it is compiled
    once per process instead.
    """
    if not os.path.isfile(inspect.getfile(fn)):
        return cast(F, numba.njit(cache=False)(fn))
    try:
        return cast(F, numba.njit(cache=True)(fn))
    except RuntimeError:  # no writable cache folder next to the source or in the user's home
        numba.config.CACHE_DIR = fallback_cache_dir()  # type: ignore[attr-defined]
        return cast(F, numba.njit(cache=True)(fn))

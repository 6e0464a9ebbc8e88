"""BLAS threads around small linear algebra.

The SLAM's per-step products are small ((3+n) × k with k ≤ 5 beams), yet OpenBLAS splits
some of them (the update's rank-k products past ~300 landmarks) over all cores. Its worker
threads spin while they wait, so on a machine with any other load — a second env process, a
learner — a step that takes 1 ms single-threaded was measured at 16 ms (2 cores, 300
landmarks). :func:`blas_threads` caps the BLAS libraries numpy loaded (through threadpoolctl,
a few µs per use) and restores them on exit, so the rest of the process keeps its setting.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from typing import Any

from threadpoolctl import ThreadpoolController


@functools.cache
def _blas_libraries() -> list[Any]:
    """threadpoolctl's controllers of the BLAS libraries loaded now (numpy's, at first use)."""
    return list(ThreadpoolController().select(user_api="blas").lib_controllers)


@contextlib.contextmanager
def blas_threads(limit: int) -> Iterator[None]:
    """Run the block with at most ``limit`` BLAS threads; 0 leaves the setting alone."""
    if limit <= 0:
        yield
        return
    changed = []
    for lib in _blas_libraries():
        before = lib.num_threads
        if before > limit:
            lib.set_num_threads(limit)
            changed.append((lib, before))
    try:
        yield
    finally:
        for lib, before in changed:
            lib.set_num_threads(before)

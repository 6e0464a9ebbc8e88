"""Running a study's independent jobs, in order, in one process or a pool of workers."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

__all__ = ["run_jobs"]

J = TypeVar("J")
R = TypeVar("R")


def run_jobs(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
    chunksize: int = 1,
) -> list[R]:
    """``[fn(job) for job in jobs]``, in ``workers`` processes when more than one (``fn`` and
    the jobs must then pickle); ``progress(k)`` is called after each of the k results, in
    order. ``chunksize`` jobs go to a worker at a time (many short jobs: fewer round trips)."""
    if workers <= 1:
        return _collect(map(fn, jobs), progress)
    with ProcessPoolExecutor(workers) as pool:
        return _collect(pool.map(fn, jobs, chunksize=chunksize), progress)


def _collect(outputs: Iterable[R], progress: Callable[[int], None] | None) -> list[R]:
    results: list[R] = []
    for result in outputs:
        results.append(result)
        if progress:
            progress(len(results))
    return results

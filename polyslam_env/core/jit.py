"""The one entry point to numba: :func:`njit` compiles a hot numerical kernel, cached on disk.

Kernels are plain Python loops over numpy arrays, compiled with ``nopython=True`` and
``cache=True`` and never with ``fastmath`` (results stay bit-identical across runs). Only this
module imports numba (``tests/test_architecture.py`` checks it), so the compile options are set in
one place.

The cache lives next to the source (``__pycache__``) when that folder is writable, otherwise in
numba's per-user cache folder. When neither is writable (a read-only install under a read-only
home), it goes to a per-user folder under the system temp directory.

:func:`compile_seconds` is the wall time this process has spent so far making kernels ready:
compiling them, or loading them from that cache, on first use of each argument types. A caller
that times work doing its first calls (``polyslam run``'s ``slam_time_ms``) reads it before and
after to tell that one-off cost apart.
"""

from __future__ import annotations

import functools
import inspect
import os
import tempfile
import time
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["compile_seconds", "fallback_cache_dir", "fma", "njit"]

F = TypeVar("F", bound=Callable[..., Any])


def fallback_cache_dir() -> str:
    """A writable per-user cache folder under the system temp directory."""
    user = os.getuid() if hasattr(os, "getuid") else os.getlogin()
    return os.path.join(tempfile.gettempdir(), f"polyslam-numba-{user}")


class _CompileClock:
    """Seconds spent in the kernels' ``compile`` (a compile, or a load from the disk cache),
    counted once when one kernel's compile compiles the kernels it calls."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.depth = 0

    def timed(self, compile_fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(compile_fn)
        def compile_timed(*args: Any, **kwargs: Any) -> Any:
            self.depth += 1
            start = time.perf_counter()
            try:
                return compile_fn(*args, **kwargs)
            finally:
                self.depth -= 1
                if self.depth == 0:
                    self.seconds += time.perf_counter() - start

        return compile_timed


_CLOCK = _CompileClock()


def compile_seconds() -> float:
    """Wall seconds this process has spent so far compiling kernels made by :func:`njit` or
    loading them from numba's disk cache (each kernel, each new argument types, once)."""
    return _CLOCK.seconds


def njit(fn: F) -> F:
    """Compile ``fn`` with numba (nopython, cached on disk, no fastmath).

    A function with no source file (defined in ``exec``'d text) cannot be cached; it is compiled
    once per process instead. The time its compiles (and cache loads) take is counted in
    :func:`compile_seconds`.
    """
    if not os.path.isfile(inspect.getfile(fn)):
        return cast(F, _clocked(numba.njit(cache=False)(fn)))
    try:
        return cast(F, _clocked(numba.njit(cache=True)(fn)))
    except RuntimeError:  # no writable cache folder next to the source or in the user's home
        numba.config.CACHE_DIR = fallback_cache_dir()  # type: ignore[attr-defined]
        return cast(F, _clocked(numba.njit(cache=True)(fn)))


def _clocked(dispatcher: Any) -> Any:
    """``dispatcher`` with its ``compile`` timed by the process's clock. numba calls
    ``self.compile`` for every new argument types, from a Python call or from another kernel's
    typing, and it loads from the disk cache inside it, so this sees both."""
    dispatcher.compile = _CLOCK.timed(dispatcher.compile)
    return dispatcher


@intrinsic
def _llvm_fma(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """LLVM's ``llvm.fma.f64`` on three float64 (the arguments are cast to float64)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        double = ir.DoubleType()
        fnty = ir.FunctionType(double, [double, double, double])
        fn = builder.module.declare_intrinsic("llvm.fma", [double], fnty)
        return builder.call(fn, args)

    return sig, codegen


@njit
def fma(a: float, b: float, c: float) -> float:
    """``a·b + c`` rounded once (IEEE 754's fused multiply-add; Python 3.13's ``math.fma``):
    the processor's instruction where it has one, else a correctly rounded library call, so
    the same number everywhere. For a kernel that must compute a product as an FMA-based BLAS
    does (OpenBLAS's Haswell and later kernels: a chain of FMAs along the inner dimension)."""
    out: float = _llvm_fma(a, b, c)  # type: ignore[call-arg]  # numba passes the typing context
    return out


@njit
def _block_sum(a: np.ndarray, start: int, n: int) -> float:
    """numpy's sum of at most 128 contiguous terms: in order below 8, else eight running sums
    combined pairwise, then the tail in order."""
    if n < 8:
        total = 0.0
        for i in range(n):
            total += a[start + i]
        return total
    r = np.empty(8)
    for j in range(8):
        r[j] = a[start + j]
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[start + i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += a[start + i]
        i += 1
    return total


@njit
def sum_like_numpy(a: np.ndarray, start: int, n: int) -> float:
    """``a[start:start + n].sum()`` of a contiguous float64 row in numpy's own order, bit for
    bit: up to 128 terms one block (:func:`_block_sum`); past that the two halves (the first a
    multiple of 8) summed alike and added (numpy's pairwise summation, ``pairwise_sum`` in its
    ``loops_utils``). For a kernel that replaces a numpy ``.sum()`` and must give its bits.

    The halving is walked with an explicit stack, not by recursion: a cached recursive kernel
    called from another module's cached kernel jumps to a null pointer when loaded (numba
    0.6x; seen as a segfault of the golden episodes)."""
    if n <= 128:
        return _block_sum(a, start, n)
    # frames (start, length, combine?): a split pushes its combine, then its right, then its
    # left half, so the left half is summed first, as the recursion does
    frame = np.empty((192, 3), dtype=np.int64)
    values = np.empty(64)
    top, count = 0, 0
    frame[0, 0], frame[0, 1], frame[0, 2] = start, n, 0
    top = 1
    while top > 0:
        top -= 1
        s, m, combine = frame[top, 0], frame[top, 1], frame[top, 2]
        if combine:
            count -= 1
            values[count - 1] = values[count - 1] + values[count]
        elif m <= 128:
            values[count] = _block_sum(a, s, m)
            count += 1
        else:
            half = m // 2
            half -= half % 8
            frame[top, 0], frame[top, 1], frame[top, 2] = s, m, 1
            frame[top + 1, 0], frame[top + 1, 1], frame[top + 1, 2] = s + half, m - half, 0
            frame[top + 2, 0], frame[top + 2, 1], frame[top + 2, 2] = s, half, 0
            top += 3
    return values[0]

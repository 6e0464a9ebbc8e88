"""The numba entry point: compiled kernels, and their disk cache in a read-only install."""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from polyslam_env.core.jit import fallback_cache_dir, fma, njit, sum_like_numpy

PACKAGE = Path(__file__).resolve().parents[2] / "polyslam_env"

#: A module defining a kernel through the package's entry point; the child process prints how
#: the call went: its result, numba's cache hits and misses, and where the cache went.
PROBE = """
import numpy as np
from polyslam_env.core.jit import njit


@njit
def weighted_sum(x, w):
    total = 0.0
    for i in range(x.size):
        total += x[i] * w[i]
    return total
"""
RUN_PROBE = """
import json, numba, numpy as np, probe
value = probe.weighted_sum(np.arange(4.0), np.full(4, 0.5))
stats = probe.weighted_sum.stats
print(json.dumps({"value": value, "hits": sum(stats.cache_hits.values()),
                  "misses": sum(stats.cache_misses.values()),
                  "cache_dir": numba.config.CACHE_DIR}))
"""


def test_njit__compiled_kernel_matches_python() -> None:
    def dot(x: np.ndarray, w: np.ndarray) -> float:
        total = 0.0
        for i in range(x.size):
            total += x[i] * w[i]
        return total

    kernel = njit(dot)
    x, w = np.random.default_rng(0).normal(size=(2, 50))
    assert kernel(x, w) == dot(x, w)  # the same operations in the same order: bit-identical


def test_njit__function_without_source_file_compiles_uncached() -> None:
    scope: dict[str, object] = {}
    exec("def twice(x):\n    return 2.0 * x\n", scope)
    kernel = njit(scope["twice"])  # type: ignore[arg-type]
    assert kernel(1.5) == 3.0


def _drop_file_override_capabilities() -> None:
    """In the child before exec, as root: drop the capabilities that let root ignore file
    permissions (CAP_DAC_OVERRIDE 1, CAP_DAC_READ_SEARCH 2, CAP_FOWNER 3) from the bounding
    set, so the program it runs obeys ``chmod a-w`` like any user."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2, 3):
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP) failed")


def _can_drop_capabilities() -> bool:
    """Whether a child can drop them here (needs Linux and CAP_SETPCAP)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        probe = subprocess.run(
            ["true"], preexec_fn=_drop_file_override_capabilities, check=False, capture_output=True
        )
    except (OSError, subprocess.SubprocessError):  # prctl refused in the child
        return False
    return probe.returncode == 0


@pytest.fixture
def read_only_install() -> Iterator[tuple[Path, Path, Path]]:
    """(site, home, tmp): a copy of the package plus the probe module in ``site``, both
    read-only; a read-only ``home``; a writable ``tmp`` (the system temp dir of the child)."""
    root = Path(tempfile.mkdtemp(prefix="polyslam-ro-"))
    site, home, tmp = root / "site", root / "home", root / "tmp"
    shutil.copytree(PACKAGE, site / "polyslam_env", ignore=shutil.ignore_patterns("__pycache__"))
    (site / "probe.py").write_text(PROBE)
    home.mkdir()
    tmp.mkdir()
    for path in (site, home):
        for p in [path, *path.rglob("*")]:
            p.chmod(p.stat().st_mode & ~0o222)
    try:
        yield site, home, tmp
    finally:
        for p in [site, home, *site.rglob("*")]:
            p.chmod(p.stat().st_mode | 0o200)
        shutil.rmtree(root)


def _run_probe(site: Path, home: Path, tmp: Path) -> dict[str, object]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "PYTHONPATH")
    }
    env.update(HOME=str(home), TMPDIR=str(tmp), PYTHONPATH=str(site), PYTHONDONTWRITEBYTECODE="1")
    as_root = hasattr(os, "geteuid") and os.geteuid() == 0
    out = subprocess.run(
        [sys.executable, "-c", RUN_PROBE],
        env=env,
        cwd=str(home),
        capture_output=True,
        text=True,
        check=True,
        preexec_fn=_drop_file_override_capabilities if as_root else None,
    )
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def test_njit__read_only_install_caches_in_a_temp_folder(
    read_only_install: tuple[Path, Path, Path],
) -> None:
    """Installed read-only under a read-only home, numba has no cache folder of its own: the
    kernel still compiles, caches under the system temp dir, and a second process loads it."""
    if hasattr(os, "geteuid") and os.geteuid() == 0 and not _can_drop_capabilities():
        pytest.skip("running as root without CAP_SETPCAP: chmod a-w cannot bind this process")
    site, home, tmp = read_only_install
    assert not os.access(site / "polyslam_env" / "core", os.W_OK) or os.geteuid() == 0
    first = _run_probe(site, home, tmp)
    second = _run_probe(site, home, tmp)
    expected = str(tmp / Path(fallback_cache_dir()).name)
    assert first == {"value": 3.0, "hits": 0, "misses": 1, "cache_dir": expected}
    assert second == {"value": 3.0, "hits": 1, "misses": 0, "cache_dir": expected}
    assert list(Path(expected).rglob("*.nbi")), "no numba index file in the fallback folder"
    assert not list(site.rglob("*.nbi")) and not list(home.rglob("*"))  # nothing written there


def test_compile_seconds__counts_a_kernels_first_compile_once() -> None:
    # A kernel compiled in this process (exec'd: never in the disk cache): its first call's
    # compile is counted, a second call with the same types adds nothing, and a kernel
    # compiled while typing another (a nested compile) is counted once, not twice.
    import time

    from polyslam_env.core.jit import compile_seconds

    scope: dict[str, object] = {"njit": njit}
    exec(
        "@njit\ndef inner(x):\n    return x + 1.5\n\n"
        "@njit\ndef outer(x):\n    return inner(x) * 2.0\n",
        scope,
    )
    outer = scope["outer"]
    before = compile_seconds()
    start = time.perf_counter()
    assert outer(1.0) == 5.0  # type: ignore[operator]
    first_call = time.perf_counter() - start
    counted = compile_seconds() - before
    assert 0.0 < counted <= first_call  # nested: counted once, within the call's wall time
    assert counted > 0.5 * first_call  # the first call is mostly compiling
    again = compile_seconds()
    assert outer(2.0) == 7.0  # type: ignore[operator]
    assert compile_seconds() == again


def test_fma__rounds_once_as_the_exact_product_plus_sum() -> None:
    """The oracle: a·b + c in exact rationals, rounded once (Python's float of a Fraction is
    correctly rounded); a plain a·b + c rounds twice and differs in some of these."""
    rng = np.random.default_rng(4)
    values = rng.normal(size=(2000, 3)) * rng.choice([1e-8, 1.0, 1e8], size=(2000, 3))
    twice = 0
    for a, b, c in values.tolist():
        exact = float(Fraction(a) * Fraction(b) + Fraction(c))
        assert fma(a, b, c) == exact
        twice += a * b + c != exact
    assert twice > 0  # the cases tell a fused from an unfused multiply-add


def test_sum_like_numpy__bit_identical_to_numpy_sum_at_every_block_boundary() -> None:
    """numpy's pairwise summation changes shape at 8 terms (running sums) and past 128 (halves,
    the first a multiple of 8): lengths around each boundary, and slices not at the start,
    with magnitudes spread over 12 decades so that a different order shows in the last bits."""
    rng = np.random.default_rng(5)
    lengths = [0, 1, 7, 8, 9, 15, 16, 127, 128, 129, 135, 136, 255, 256, 257, 1000, 4099]
    for n in lengths:
        for _ in range(20):
            row = rng.normal(size=n + 13) * 10.0 ** rng.uniform(-6, 6, n + 13)
            start = int(rng.integers(0, 13))
            want = row[start : start + n].sum()
            assert sum_like_numpy(row, start, n) == want, (n, start)
    # the test can tell orders apart: on these rows a plain running sum misses numpy's bits
    rows = [rng.normal(size=300) * 10.0 ** rng.uniform(-6, 6, 300) for _ in range(50)]
    assert any(running_sum(r.tolist()) != r.sum() for r in rows)


def running_sum(values: list[float]) -> float:
    """Left to right, one rounding per term (Python 3.12's ``sum`` compensates: not that)."""
    total = 0.0
    for v in values:
        total += v
    return total

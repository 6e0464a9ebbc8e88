"""A real Ray head for the tests that need one (`ray start --head` on a free local port).

The Ray tests need the ``ray`` extra and are skipped without it. They hold a machine-wide
file lock so that no two run at once (pytest-xdist workers, other checkouts): ``ray stop
--force``, which stops a head, stops every Ray process on the machine.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

NEEDS_RAY = "needs the [ray] extra: pip install 'polyslam[ray]'"
HEAD_FLAGS = ("--disable-usage-stats", "--include-dashboard=false")
LOCK = Path(tempfile.gettempdir()) / "polyslam-ray-tests.lock"


@contextmanager
def ray_lock() -> Iterator[None]:
    """Ray installed (else skip), and no other Ray test running while inside."""
    pytest.importorskip("ray", reason=NEEDS_RAY)
    with open(LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _ray_cli() -> str:
    here = Path(sys.executable).with_name("ray")
    found = str(here) if here.exists() else shutil.which("ray")
    if found is None:
        pytest.skip("the `ray` command is not on PATH")
    return found


@contextmanager
def ray_head(monkeypatch: pytest.MonkeyPatch, cpus: int = 2) -> Iterator[str]:
    """A separate Ray head node with ``cpus`` CPUs; its address; always stopped. Take
    :func:`ray_lock` first."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    # Ray ≥ 2.5x: `ray start` turns token authentication on when ~/.ray/auth_token exists
    # (any earlier local ray.init() writes one), and a driver given an explicit address does
    # not, unless RAY_AUTH_MODE says so (the mismatch's one-line error:
    # test_join_error__names_the_token_fix). The head inherits this process's mode: the one
    # an earlier local ray.init() here set (token, kept: this process's Ray caches it), else
    # none for both.
    if os.environ.get("RAY_AUTH_MODE") is None:
        monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    ray, port = _ray_cli(), _free_port()
    try:
        subprocess.run(
            [ray, "start", "--head", f"--port={port}", f"--num-cpus={cpus}", *HEAD_FLAGS],
            check=True,
            capture_output=True,
            timeout=120,
        )
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True, timeout=120)

"""BLAS threads are capped around the SLAM step and restored afterwards."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from polyslam_env.core.blas import blas_threads
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.robot import PolySlam


def _blas_threads_now() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


@pytest.fixture(autouse=True)
def two_blas_threads() -> Iterator[None]:
    """Start every test from 2 BLAS threads, so that a cap to 1 is visible on any machine."""
    with threadpool_limits(limits=2, user_api="blas"):
        assert all(n == 2 for n in _blas_threads_now())
        yield


def test_blas_threads__caps_inside_and_restores_after() -> None:
    before = _blas_threads_now()
    assert before  # numpy's BLAS is visible to threadpoolctl
    with blas_threads(1):
        assert all(n == 1 for n in _blas_threads_now())
    assert _blas_threads_now() == before
    with blas_threads(0):  # 0: leave the process setting alone
        assert _blas_threads_now() == before


def test_blas_threads__restores_after_an_error() -> None:
    before = _blas_threads_now()
    try:
        with blas_threads(1):
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert _blas_threads_now() == before


def test_slam_step__runs_with_the_configured_blas_threads(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    seen: list[list[int]] = []
    original = PolySlam._step

    def spy(self: PolySlam, odometry: np.ndarray, ranges: np.ndarray):  # type: ignore[no-untyped-def]
        seen.append(_blas_threads_now())
        return original(self, odometry, ranges)

    monkeypatch.setattr(PolySlam, "_step", spy)
    before = _blas_threads_now()
    slam = PolySlam(SlamConfig(), np.zeros(1), 2.0)
    slam.step(np.zeros(3), np.array([1.0]))
    assert seen[-1] == [1] * len(before)
    loose = PolySlam(SlamConfig(blas_threads=0), np.zeros(1), 2.0)
    loose.step(np.zeros(3), np.array([1.0]))
    assert seen[-1] == before
    assert _blas_threads_now() == before

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


def test_slam_step__changes_its_map_with_the_configured_blas_threads(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The step's BLAS calls are the map changes' products (the compiled calls use none): a
    first scan of a wall 2 m ahead creates a landmark, with BLAS on ``blas_threads``."""
    seen: list[list[int]] = []
    original = PolySlam._change_map

    def spy(self: PolySlam, rho: float, fresh: int):  # type: ignore[no-untyped-def]
        seen.append(_blas_threads_now())
        return original(self, rho, fresh)

    monkeypatch.setattr(PolySlam, "_change_map", spy)
    before = _blas_threads_now()
    angles = np.linspace(-0.6, 0.6, 17)
    wall = 2.0 / np.cos(angles)  # ranges to a wall 2 m ahead
    slam = PolySlam(SlamConfig(), angles, 4.0)
    slam.step(np.zeros(3), wall)
    assert slam.n_landmarks == 1 and seen[-1] == [1] * len(before)
    loose = PolySlam(SlamConfig(blas_threads=0), angles, 4.0)
    loose.step(np.zeros(3), wall)
    assert len(seen) == 2 and seen[-1] == before
    assert _blas_threads_now() == before

"""The compiled controller against its readable oracles (``reference.py``)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from policies import controller
from tests.policies import reference

RES, N = 0.1, 40
ORIGIN = -0.5 * N * RES
DISK = controller._robot_disk(0.065, RES)


def _obstacles(seed: int, density: float) -> np.ndarray:  # (N, N) bool
    return np.random.default_rng(seed).random((N, N)) < density


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    density=st.sampled_from([0.0, 0.01, 0.05, 0.2]),
    pose=st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-math.pi, math.pi)),
    v=st.floats(0.0, 0.3),
    omega=st.one_of(st.just(0.0), st.floats(-1.5, 1.5)),
)
def test_safe_speed__matches_readable(
    seed: int, density: float, pose: tuple[float, float, float], v: float, omega: float
) -> None:
    obst = _obstacles(seed, density)
    p = np.array(pose)
    times = np.linspace(0.25, 1.0, 4) * 1.0
    got = controller.safe_speed(p, v, omega, times, DISK, obst.reshape(-1), ORIGIN, RES, N)
    assert got == reference.safe_speed(obst, ORIGIN, RES, DISK, 1.0, p, v, omega)


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    beams=st.integers(1, 33),
    no_return=st.floats(0.0, 0.5),
)
def test_speed_cap__matches_readable(seed: int, beams: int, no_return: float) -> None:
    rng = np.random.default_rng(seed)
    angles = np.sort(rng.uniform(-math.pi, math.pi, beams))
    ranges = np.where(rng.random(beams) < no_return, np.inf, rng.uniform(0.0, 2.0, beams))
    got = controller.speed_cap(angles, ranges, 0.065, 0.3, 1.0)
    assert got == reference.speed_cap(angles, ranges, 0.065, 0.3, 1.0)


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    length=st.integers(1, 40),
    lookahead=st.floats(0.05, 1.0),
)
def test_lookahead__matches_readable(seed: int, length: int, lookahead: float) -> None:
    rng = np.random.default_rng(seed)
    path = np.cumsum(rng.uniform(-0.15, 0.15, (length, 2)), axis=0)
    pose = np.array([*rng.uniform(-0.5, 0.5, 2), 0.0])
    got = path[controller._lookahead(path, pose[0], pose[1], lookahead)]
    assert np.array_equal(got, reference.lookahead_target(path, pose, lookahead))

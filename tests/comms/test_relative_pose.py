"""Rendezvous relative pose and map transform: ground truth, Jacobians, NEES consistency.

The SE(2) algebra they build on is tested in tests/core/test_geometry.py.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.comms.relative_pose import (
    frame_transform,
    frame_transform_with_jacobian,
    relative_pose,
    relative_pose_covariance,
    relative_pose_with_jacobian,
    wrap_angle,
)
from polyslam_env.core.geometry import compose, inverse, transform_points

coord = st.floats(-5.0, 5.0, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)
poses = st.tuples(coord, coord, angle).map(np.array)


def _random_pose(rng: np.random.Generator, extent: float = 5.0) -> np.ndarray:
    return np.array([*rng.uniform(-extent, extent, 2), rng.uniform(-np.pi, np.pi)])


def _measure(x_j: np.ndarray, x_l: np.ndarray) -> tuple[float, float, float]:
    """Noiseless camera measurements: range and each robot's bearing to the other."""
    dx, dy = x_l[:2] - x_j[:2]
    d = float(np.hypot(dx, dy))
    alpha_j = float(wrap_angle(np.arctan2(dy, dx) - x_j[2]))
    alpha_l = float(wrap_angle(np.arctan2(-dy, -dx) - x_l[2]))
    return d, alpha_j, alpha_l


def _pose_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = a - b
    out[2] = float(wrap_angle(out[2]))
    return out


def _numeric_jacobian(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    eps = 1e-6
    cols = []
    for i in range(len(x)):
        step = np.zeros_like(x)
        step[i] = eps
        cols.append(_pose_diff(f(x + step), f(x - step)) / (2 * eps))
    return np.stack(cols, axis=1)


# Central differences with eps = 1e-6 on O(1) trig functions: truncation ~eps² ≈ 1e-12 times
# coordinates up to ~10, rounding ~1e-16/eps ≈ 1e-10; 1e-7 leaves a wide margin.
JAC_TOL = 1e-7


def test_relative_pose__matches_ground_truth_both_orders() -> None:
    rng = np.random.default_rng(0)
    for _ in range(500):
        x_j, x_l = _random_pose(rng), _random_pose(rng)
        d, a_j, a_l = _measure(x_j, x_l)
        # 1e-9: pure trig on metre-scale values, exact up to a few ulps.
        np.testing.assert_allclose(
            _pose_diff(relative_pose(d, a_j, a_l), compose(inverse(x_j), x_l)), 0, atol=1e-9
        )
        np.testing.assert_allclose(
            _pose_diff(relative_pose(d, a_l, a_j), compose(inverse(x_l), x_j)), 0, atol=1e-9
        )


def test_relative_pose__heading_is_wrapped() -> None:
    pose = relative_pose(1.0, 3.0, -3.0)  # π + 6 must wrap
    assert -np.pi <= pose[2] < np.pi


def test_relative_pose__noise_consistent_with_propagated_covariance() -> None:
    rng = np.random.default_rng(1)
    sigma_d, sigma_b = 0.01, np.radians(1.0)  # paper camera noise
    nees = []
    for _ in range(4):
        x_j, x_l = _random_pose(rng, 1.0), _random_pose(rng, 1.0)
        d, a_j, a_l = _measure(x_j, x_l)
        truth = compose(inverse(x_j), x_l)
        cov = relative_pose_covariance(d, a_j, a_l, sigma_d, sigma_b)
        for _ in range(1000):
            noisy = relative_pose(
                d + sigma_d * rng.standard_normal(),
                a_j + sigma_b * rng.standard_normal(),
                a_l + sigma_b * rng.standard_normal(),
            )
            e = _pose_diff(noisy, truth)
            nees.append(e @ np.linalg.solve(cov, e))
    # Mean of 4000 χ²(3) draws has std sqrt(6/4000) ≈ 0.039; ±0.25 is > 6σ, and the
    # linearisation bias at 1° bearing noise is orders of magnitude smaller.
    assert abs(np.mean(nees) - 3.0) < 0.25


def test_frame_transform__recovers_true_start_frame_transform() -> None:
    rng = np.random.default_rng(2)
    for _ in range(200):
        x_j0, x_l0 = _random_pose(rng), _random_pose(rng)  # absolute start poses
        x_j, x_l = _random_pose(rng), _random_pose(rng)  # absolute current poses
        est_j = compose(inverse(x_j0), x_j)  # noiseless estimates in own start frames
        est_l = compose(inverse(x_l0), x_l)
        rel = relative_pose(*_measure(x_j, x_l))
        t = frame_transform(est_j, rel, est_l)
        # 1e-9: a chain of a few SE(2) products on metre-scale values.
        np.testing.assert_allclose(_pose_diff(t, compose(inverse(x_j0), x_l0)), 0, atol=1e-9)
        # A point in l's start frame lands on the same world point through either route.
        p_l0 = rng.uniform(-3, 3, (5, 2))
        np.testing.assert_allclose(
            transform_points(transform_points(p_l0, t), x_j0),
            transform_points(p_l0, x_l0),
            atol=1e-9,
        )


@settings(max_examples=60, deadline=None)
@given(d=st.floats(0.05, 3.0), a_j=angle, a_l=angle)
def test_relative_pose_jacobian__matches_finite_differences(
    d: float, a_j: float, a_l: float
) -> None:
    _, jac = relative_pose_with_jacobian(d, a_j, a_l)
    num = _numeric_jacobian(lambda z: relative_pose(*z), np.array([d, a_j, a_l]))
    np.testing.assert_allclose(jac, num, atol=JAC_TOL)


@settings(max_examples=60, deadline=None)
@given(pj=poses, rel=poses, pl=poses)
def test_frame_transform_jacobian__matches_finite_differences(
    pj: np.ndarray, rel: np.ndarray, pl: np.ndarray
) -> None:
    _, jac = frame_transform_with_jacobian(pj, rel, pl)
    assert jac.shape == (3, 9)

    def f(z: np.ndarray) -> np.ndarray:
        return frame_transform(z[:3], z[3:6], z[6:])

    num = _numeric_jacobian(f, np.concatenate([pj, rel, pl]))
    np.testing.assert_allclose(jac, num, atol=JAC_TOL)


def test_rendezvous_transform__is_the_numpy_oracle_bit_for_bit() -> None:
    """The exchange's compiled transform of a delivery (T, its Jacobians, the noise's
    covariance) against the numpy it replaced (``tests/comms/reference_geometry.py``), every
    float's bits, on random poses and measurements and on the exact zeros and ±π a robot at
    its start or an unmoved receiver gives (they settle the signs of exact zeros)."""
    from polyslam_env.comms.exchange import map_transform
    from polyslam_env.comms.relative_pose import delivery_transform
    from tests.comms import reference_geometry as ref

    rng = np.random.default_rng(7)
    special = [0.0, -0.0, np.pi, -np.pi, 0.5 * np.pi]
    for case in range(3000):
        receiver, sighting, sender = (_random_pose(rng, 20.0) for _ in range(3))
        d = float(rng.uniform(0.05, 3.0))
        a_r, a_s = (float(a) for a in rng.uniform(-np.pi, np.pi, 2))
        var = rng.uniform(0.0, 1e-3, 3)
        if case % 3 == 0:  # delivered at the step it was sent: no motion
            sighting = receiver.copy()
        if case % 5 == 0:  # headings, bearings and positions at exact zeros and ±π
            receiver[2], sighting[2], sender[2] = rng.choice(special, 3)
            a_r, a_s = (float(a) for a in rng.choice(special, 2))
            sender[: int(rng.integers(0, 3))] = 0.0
        if case % 7 == 0:
            var[int(rng.integers(0, 3))] = 0.0
        sd, sb = float(rng.uniform(0.001, 0.1)), float(rng.uniform(0.001, 0.1))
        got = delivery_transform(receiver, sighting, d, a_r, a_s, sender, sd**2, sb**2, var)
        want = ref.delivery_transform(receiver, sighting, d, a_r, a_s, sender, sd, sb, var)
        for g, w in zip(got, want, strict=True):
            assert g.shape == w.shape
            assert np.ascontiguousarray(g).tobytes() == np.ascontiguousarray(w).tobytes()
        motion = rng.normal(0.0, 0.3, 3) if case % 2 else np.zeros(3)
        got3 = map_transform(receiver, motion, d, a_r, a_s, sender)
        want3 = ref.map_transform(receiver, motion, d, a_r, a_s, sender)
        for g, w in zip(got3, want3, strict=True):
            assert np.ascontiguousarray(g).tobytes() == np.ascontiguousarray(w).tobytes()

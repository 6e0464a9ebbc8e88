"""Closed-form geometry helpers against numpy's general routines, SE(2) against matrices."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.core.geometry import (
    beam_endpoints,
    between,
    compose,
    compose_inverse,
    compose_with_jacobians,
    inverse,
    inverse_with_jacobian,
    rotation,
    symmetric_eigvals3,
    transform_covariance,
    transform_points,
    wrap_angle,
    wrap_remainder,
    wrap_scalar,
)
from tests.core import reference
from tests.slam.finite_differences import FD_ATOL, FD_RTOL, fd_jacobian


def _random_symmetric(rng: np.random.Generator, kind: str) -> np.ndarray:
    if kind == "indefinite":
        a = rng.normal(size=(3, 3))
        return a + a.T
    if kind == "covariance":  # pose covariances: metres² and rad², very different scales
        a = rng.normal(size=(3, 3)) * np.array([0.05, 0.05, 0.02])
        return a @ a.T + np.diag([1e-6, 1e-6, 1e-8])
    if kind == "repeated":  # two equal eigenvalues in a random basis (σx = σy in P0)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        values = rng.normal(size=2)
        return (q * np.array([values[0], values[0], values[1]])) @ q.T
    a = np.diag(rng.normal(size=3))  # exactly diagonal
    return a


@pytest.mark.parametrize("kind", ["indefinite", "covariance", "diagonal"])
def test_symmetric_eigvals3__match_eigvalsh(kind: str) -> None:
    rng = np.random.default_rng(11)
    for _ in range(200):
        a = _random_symmetric(rng, kind)
        got = np.array(symmetric_eigvals3(a))
        want = np.linalg.eigvalsh(a)
        # 1e-12 of ‖A‖: both are backward stable, so a few hundred ulps at most; the
        # distinct eigenvalues of random matrices keep acos away from its steep ends
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_symmetric_eigvals3__repeated_pair_within_documented_accuracy() -> None:
    rng = np.random.default_rng(12)
    for _ in range(200):
        a = _random_symmetric(rng, "repeated")
        got = np.array(symmetric_eigvals3(a))
        want = np.linalg.eigvalsh(a)
        spread = np.abs(want).max()
        # the pair: ~√eps of the spread (the docstring's 1e-8·p, with room for p ≤ ‖A‖)
        np.testing.assert_allclose(got, want, rtol=0, atol=5e-8 * spread)


def test_wrap_scalar__equals_wrap_angle() -> None:
    angles = np.concatenate([np.linspace(-20.0, 20.0, 4001), [np.pi, -np.pi, 0.0, 3 * np.pi]])
    want = wrap_angle(angles)
    got = np.array([wrap_scalar(float(a)) for a in angles])
    np.testing.assert_array_equal(got, want)  # the same formula on the same floats
    assert wrap_scalar(-np.pi) == np.pi  # (−π, π]


def test_wrap_remainder__exact_and_closed_interval() -> None:
    assert wrap_remainder(1e-20) == 1e-20  # wrap_angle rounds this to 0
    assert wrap_remainder(3 * math.pi) in (math.pi, -math.pi)
    angles = np.linspace(-20.0, 20.0, 4001)
    got = np.array([wrap_remainder(float(a)) for a in angles])
    assert np.all(np.abs(got) <= math.pi)
    np.testing.assert_allclose(np.cos(got), np.cos(angles), atol=1e-12)  # same angle mod 2π


# -- SE(2) --------------------------------------------------------------------------------------
coord = st.floats(-5.0, 5.0, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)
poses = st.tuples(coord, coord, angle).map(np.array)


def _matrix(pose: np.ndarray) -> np.ndarray:  # (3, 3), the oracle: T = [[R, t], [0, 1]]
    x, y, th = pose
    out = np.eye(3)
    out[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
    out[:2, 2] = x, y
    return out


def _pose_of(matrix: np.ndarray) -> np.ndarray:  # (3,)
    return np.array([matrix[0, 2], matrix[1, 2], math.atan2(matrix[1, 0], matrix[0, 0])])


def _pose_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.asarray(a - b, dtype=float)
    out[..., 2] = wrap_angle(out[..., 2])
    return out


def _random_poses(rng: np.random.Generator, n: int) -> np.ndarray:  # (n, 3)
    return np.column_stack([rng.uniform(-5, 5, (n, 2)), rng.uniform(-10, 10, n)])


@settings(max_examples=60, deadline=None)
@given(a=poses, b=poses)
def test_se2__matches_matrix_forms(a: np.ndarray, b: np.ndarray) -> None:
    # 1e-9: products of unit-scale trig values with coordinates up to 10.
    ma, mb = _matrix(a), _matrix(b)
    np.testing.assert_allclose(_pose_diff(compose(a, b), _pose_of(ma @ mb)), 0, atol=1e-9)
    np.testing.assert_allclose(_pose_diff(inverse(a), _pose_of(np.linalg.inv(ma))), 0, atol=1e-9)
    between_ab = _pose_of(np.linalg.inv(ma) @ mb)
    np.testing.assert_allclose(_pose_diff(between(a, b), between_ab), 0, atol=1e-9)
    right = _pose_of(ma @ np.linalg.inv(mb))
    np.testing.assert_allclose(_pose_diff(compose_inverse(a, b), right), 0, atol=1e-9)
    pts = np.array([[0.3, -1.2], [2.0, 0.5]])
    homog = (ma @ np.vstack([pts.T, np.ones(2)]))[:2].T
    np.testing.assert_allclose(transform_points(pts, a), homog, atol=1e-9)
    np.testing.assert_allclose(rotation(a[2]), ma[:2, :2], atol=1e-15)


def test_se2__headings_wrapped_except_compose_inverse() -> None:
    rng = np.random.default_rng(3)
    a, b = _random_poses(rng, 500), _random_poses(rng, 500)
    for out in (compose(a, b), inverse(a), between(a, b)):
        assert np.all((out[:, 2] > -np.pi) & (out[:, 2] <= np.pi))
    np.testing.assert_array_equal(compose_inverse(a, b)[:, 2], a[:, 2] - b[:, 2])


def test_se2__vectorised_rows_equal_single_poses_bit_for_bit() -> None:
    rng = np.random.default_rng(4)
    a, b = _random_poses(rng, 200), _random_poses(rng, 200)
    for func in (compose, between, compose_inverse):
        rows = np.array([func(a[k], b[k]) for k in range(len(a))])
        np.testing.assert_array_equal(func(a, b), rows)
        np.testing.assert_array_equal(func(a[0], b), np.array([func(a[0], q) for q in b]))
    np.testing.assert_array_equal(inverse(a), np.array([inverse(p) for p in a]))


def test_wrap_angle__compiled_equals_the_numpy_oracle_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    edges = [0.0, -0.0, math.pi, -math.pi, 3 * math.pi, 2 * math.pi, 1e-20, -1e-20, 1e300]
    x = np.concatenate([rng.uniform(-50.0, 50.0, 20000), edges, [math.nan, math.inf]])
    with np.errstate(invalid="ignore"):  # numpy warns on inf; NaN either way
        cases = [x, x[:-1].reshape(-1, 2)[:, 1], np.asfortranarray(x[:20000].reshape(100, 200))]
        for angle in [*cases, 0.5, np.float64(-7.0), np.array(7.0), [1.0, 9.0], 3, np.zeros(0)]:
            got, want = wrap_angle(angle), reference.wrap_angle(angle)
            assert got.shape == want.shape and got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(np.signbit(got), np.signbit(want))


def test_between__compiled_rows_equal_the_numpy_oracle_bit_for_bit() -> None:
    rng = np.random.default_rng(6)
    a, b = _random_poses(rng, 500), _random_poses(rng, 500)
    a[:5, 2] = [0.0, -0.0, math.pi, -math.pi, 3 * math.pi]  # wrap's edges
    b[5:10, 2] = a[5:10, 2] + 1e-20  # tiny differences: wrap_angle rounds, wrap_remainder keeps
    cases = [(a, b), (a[0], b), (a, b[0]), (a[0], b[0]), (a.reshape(5, 100, 3), b[:100])]
    for p, q in cases:
        for wrap in (wrap_angle, wrap_remainder):
            want = reference.between(p, q, reference.wrap_angle if wrap is wrap_angle else wrap)
            np.testing.assert_array_equal(between(p, q, wrap), want)
    np.testing.assert_array_equal(between(np.asfortranarray(a), b), reference.between(a, b))


def _to_frame(pose: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """environment/parallel.py's ``_to_frame`` as recorded, the oracle for :func:`between`."""
    c, s = math.cos(frame[2]), math.sin(frame[2])
    dx, dy = pose[0] - frame[0], pose[1] - frame[1]
    dth = math.remainder(pose[2] - frame[2], 2 * math.pi)
    return np.array([c * dx + s * dy, -s * dx + c * dy, dth])


def _frame_of(true_start: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """apps/simulate.py's ``_frame_of`` as recorded, the oracle for :func:`compose_inverse`."""
    theta = true_start[2] - offset[2]
    c, s = np.cos(theta), np.sin(theta)
    x = true_start[0] - (c * offset[0] - s * offset[1])
    y = true_start[1] - (s * offset[0] + c * offset[1])
    return np.array([x, y, theta])


def test_between_and_compose_inverse__reproduce_the_env_and_simulate_helpers_exactly() -> None:
    rng = np.random.default_rng(5)
    a, b = _random_poses(rng, 2000), _random_poses(rng, 2000)
    b[:10, 2] = a[:10, 2] + 1e-20  # tiny heading differences: wrap_remainder keeps them
    for p, q in zip(a, b, strict=True):
        np.testing.assert_array_equal(between(q, p, wrap=wrap_remainder), _to_frame(p, q))
        np.testing.assert_array_equal(compose_inverse(p, q), _frame_of(p, q))


def _fd_pose_jacobian(func: Callable[[np.ndarray], np.ndarray], x0: np.ndarray) -> np.ndarray:
    """Central differences of a pose-valued function, its heading taken relative to f(x0)."""
    base = func(x0)
    rows = [fd_jacobian(lambda z, i=i: float(_pose_diff(func(z), base)[i]), x0) for i in range(3)]
    return np.array(rows)


@settings(max_examples=60, deadline=None)
@given(a=poses, b=poses)
def test_compose_and_inverse_jacobians__match_finite_differences(
    a: np.ndarray, b: np.ndarray
) -> None:
    out, j_a, j_b = compose_with_jacobians(a, b)
    np.testing.assert_array_equal(out, compose(a, b))
    num_a = _fd_pose_jacobian(lambda z: compose(z, b), a)
    np.testing.assert_allclose(j_a, num_a, rtol=FD_RTOL, atol=FD_ATOL)
    num_b = _fd_pose_jacobian(lambda z: compose(a, z), b)
    np.testing.assert_allclose(j_b, num_b, rtol=FD_RTOL, atol=FD_ATOL)
    inv, j_inv = inverse_with_jacobian(a)
    np.testing.assert_array_equal(inv, inverse(a))
    np.testing.assert_allclose(j_inv, _fd_pose_jacobian(inverse, a), rtol=FD_RTOL, atol=FD_ATOL)


def test_transform_covariance__is_the_linear_map_of_compose() -> None:
    rng = np.random.default_rng(6)
    for _ in range(100):
        frame, pose = _random_poses(rng, 2)
        g = rng.normal(size=(3, 3))
        cov = g @ g.T
        _, _, j_b = compose_with_jacobians(frame, pose)  # ∂(frame ⊕ pose)/∂pose
        got = transform_covariance(cov, frame)
        np.testing.assert_allclose(got, j_b @ cov @ j_b.T, rtol=1e-12, atol=1e-12)
        assert np.linalg.eigvalsh(0.5 * (got + got.T)).min() >= -1e-12
    covs = rng.normal(size=(4, 3, 3))
    np.testing.assert_array_equal(
        transform_covariance(covs, frame), np.array([transform_covariance(c, frame) for c in covs])
    )


def test_se2__rejects_wrong_shapes() -> None:
    with pytest.raises(ValueError, match="shape"):
        compose(np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="shape"):
        between(np.zeros(3), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="shape"):
        compose_with_jacobians(np.zeros((2, 3)), np.zeros(3))


def test_beam_endpoints__match_a_per_beam_loop_and_broadcast() -> None:
    rng = np.random.default_rng(5)
    poses = rng.uniform(-3, 3, size=(4, 3))  # (N, 3)
    angles = poses[:, 2:3] + rng.uniform(-np.pi, np.pi, size=(4, 5))  # (N, B) absolute
    ranges = rng.uniform(0, 2, size=(4, 5))
    ranges[1, 2] = np.inf
    ends = beam_endpoints(poses[:, None, :2], angles, ranges)  # (N, B, 2)
    assert ends.shape == (4, 5, 2)
    for i in range(4):
        for b in range(5):
            phi, r = angles[i, b], ranges[i, b]
            if np.isfinite(r):
                expect = [poses[i, 0] + r * math.cos(phi), poses[i, 1] + r * math.sin(phi)]
                # numpy's and libm's cos may differ by an ulp: a few 1e-16 m on metres
                np.testing.assert_allclose(ends[i, b], expect, rtol=0, atol=1e-12)
    assert not np.all(np.isfinite(ends[1, 2]))  # no return: no finite end point
    one = beam_endpoints(poses[0, :2], angles[0], ranges[0])  # (B, 2): one origin
    np.testing.assert_array_equal(one, ends[0])

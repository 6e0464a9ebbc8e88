"""The small compiled pieces of the map's bookkeeping against their readable oracles, bit for
bit (``tests/slam/reference_association.py``; the association itself is checked in
``test_association.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.core.geometry import symmetric_eigvals3
from polyslam_env.slam import map_kernels
from polyslam_env.slam.maintenance import fit_inverse_table as _fit_inverse_table
from polyslam_env.slam.polynomial import Polynomial
from tests.slam import reference_association as oracle
from tests.slam import reference_floats as oracle_floats


def test_symmetric_eigvals3__bit_identical_to_python_floats() -> None:
    rng = np.random.default_rng(0)
    for k in range(3000):
        a = rng.normal(size=(3, 3)) * rng.choice([1e-6, 1e-3, 1.0, 100.0], size=(3, 3))
        a = a + a.T
        if k % 5 == 0:
            a = np.diag(np.diag(a))  # the sorted-diagonal branch
        if k % 7 == 0:
            a[1, 0] = a[0, 1] = 0.0
        assert symmetric_eigvals3(a) == oracle.symmetric_eigvals3(a)


@settings(max_examples=200, deadline=None)
@given(
    coeffs=st.lists(st.floats(-3.0, 3.0), min_size=2, max_size=10),
    lo=st.floats(-20.0, 20.0),
    width=st.floats(0.0, 5.0),
    pad=st.integers(0, 6),
)
def test_eta_range__bit_identical_to_numpy_shape_range(
    coeffs: list[float], lo: float, width: float, pad: int
) -> None:
    """Widths from 2 to 16 coefficients: numpy sums a short row in order and eight or more
    in running sums (``core.jit.sum_like_numpy``)."""
    shape = np.zeros(len(coeffs) + pad)
    shape[1 : len(coeffs)] = coeffs[1:]
    want = oracle.shape_range(shape[None], np.array([lo]), np.array([lo + width]))[0]
    assert map_kernels.eta_range(shape, lo, lo + width) == tuple(want.tolist())


@settings(max_examples=200, deadline=None)
@given(
    coeffs=st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=6),
    lo=st.floats(-10.0, 10.0),
    width=st.floats(0.0, 4.0),
)
def test_rotation_fit_var__bit_identical_to_python(
    coeffs: list[float], lo: float, width: float
) -> None:
    """numpy's polynomial slope and Python's ``** 2`` (libm's pow, not a multiplication)."""
    poly = Polynomial(1, np.array(coeffs), lo, lo + width)
    order = max(len(np.trim_zeros(np.array(coeffs[1:]), "b")), 1)
    inverse = _fit_inverse_table(16, 5)
    shape = np.zeros(len(coeffs))
    shape[1:] = coeffs[1:]
    got = map_kernels.rotation_fit_var(shape, order, poly.lo, poly.hi, inverse, 4e-4, 2.0)
    assert got == oracle.rotation_fit_var(poly, inverse, 4e-4)
    assert map_kernels.slope_at(shape, order, 0.5 * (poly.lo + poly.hi)) == float(
        poly.slope(0.5 * (poly.lo + poly.hi))
    )


def test_prediction_weight__floors_an_exact_pose() -> None:
    assert map_kernels.prediction_weight(np.zeros((3, 3))) == pytest.approx(1e12)
    cov = np.diag([4e-4, 1e-4, 1e-6])
    assert map_kernels.prediction_weight(cov) == 1.0 / 4e-4


def test_equally_spaced__bit_identical_to_points_at_of_linspace() -> None:
    """Random shapes of order 1–3 in either variate, extents including a point: the
    compiled samples are ``Polynomial.points_at(np.linspace(lo, hi, n))`` exactly."""
    rng = np.random.default_rng(21)
    for _ in range(300):
        order, variate = int(rng.integers(1, 4)), int(rng.integers(1, 3))
        lo = float(rng.normal(scale=5.0))
        hi = lo if rng.random() < 0.1 else lo + float(rng.exponential(2.0))
        poly = Polynomial(variate, rng.normal(size=order + 1), lo, hi)
        for n in (1, 2, 5, 12):
            want = poly.points_at(np.linspace(lo, hi, n))
            got = map_kernels.equally_spaced(poly.coeffs, variate, lo, hi, n)
            assert got.tobytes() == want.tobytes()


def _carry_exact(real: np.ndarray, n: int, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """The oracle of ``carry_points``: each output a chain of correctly rounded fused
    multiply-adds along the seven inputs (exact rationals, one rounding per step), as
    OpenBLAS's FMA gemm kernels compute the (n, 7) × (7, 7) product the carry replaced."""
    d = float(after[2] - before[2])
    c, s = math.cos(d), math.sin(d)
    motion = [[0.0] * 7 for _ in range(7)]
    for a, b in ((0, 1), (2, 3), (4, 5)):
        motion[a][a], motion[a][b], motion[b][a], motion[b][b] = c, s, -s, c
    motion[6][6] = 1.0
    shift_in = [before[0], before[1], 0.0, 0.0, before[0], before[1], 0.0]
    shift_out = [after[0], after[1], 0.0, 0.0, after[0], after[1], d]
    out = real.copy()
    for i in range(n):
        row = [float(real[k, i] - shift_in[k]) for k in range(7)]
        for j in range(7):
            acc = 0.0
            for k in range(7):
                acc = oracle_floats.fma_exact(row[k], motion[k][j], acc)
            out[j, i] = acc + shift_out[j]
    return out


def test_carry_points__equals_a_chain_of_exact_fused_multiply_adds() -> None:
    rng = np.random.default_rng(11)
    for trial in range(40):
        n = int(rng.integers(2, 30))
        real = np.zeros((9, 32))
        real[:7, :n] = rng.normal(size=(7, n)) * 10.0
        real[:7, :n][rng.random((7, n)) < 0.1] = 0.0  # axis-aligned directions, etc.
        before = rng.normal(size=3)
        after = before + rng.normal(size=3) * (0.05, 0.05, 0.0 if trial % 4 == 0 else 0.01)
        want = _carry_exact(real, n, before, after)
        d = float(after[2] - before[2])
        map_kernels.carry_points(real, n, before, after, math.cos(d), math.sin(d))
        np.testing.assert_array_equal(real[:7], want[:7], strict=True)

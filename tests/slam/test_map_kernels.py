"""The small compiled pieces of the map's bookkeeping against their readable oracles, bit for
bit (``tests/slam/reference_association.py``; the association itself is checked in
``test_association.py``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.core.geometry import symmetric_eigvals3
from polyslam_env.slam import map_kernels
from polyslam_env.slam.maintenance import fit_inverse_table as _fit_inverse_table
from polyslam_env.slam.polynomial import Polynomial
from tests.slam import reference_association as oracle


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
    in running sums (``map_kernels._sum_like_numpy``)."""
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

"""Polynomial evaluation: the compiled point, row-wise and Taylor forms against numpy's polyval."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import Polynomial as NpPoly

from polyslam_env.slam import kernels
from polyslam_env.slam.polynomial import Polynomial, polyval, polyval_rows
from tests.slam import reference_floats
from tests.slam.reference import taylor_at


def value_and_slope(coeffs: list[float], x: float, c0: float | None = None) -> tuple[float, float]:
    """:func:`kernels.horner` on a list."""
    c = np.array(coeffs, dtype=float)
    return kernels.horner(c, len(coeffs) - 1, x, c[0] if c0 is None else c0)


def taylor_shift(coeffs: list[float], x0: float) -> list[float]:
    """:func:`kernels.taylor_shift` on a list."""
    out = np.empty(len(coeffs))
    kernels.taylor_shift(np.array(coeffs, dtype=float), len(coeffs) - 1, x0, out)
    return out.tolist()


coefficients = st.lists(st.floats(-5.0, 5.0), min_size=2, max_size=6)


@settings(max_examples=200, deadline=None)
@given(coeffs=coefficients, x=st.floats(-4.0, 4.0), c0=st.floats(-3.0, 3.0))
def test_value_and_slope__matches_polyval(coeffs: list[float], x: float, c0: float) -> None:
    value, slope = value_and_slope(coeffs, x)
    # Horner in the same order as numpy's polyval: the value is the very same float
    assert value == float(polyval(x, np.array(coeffs)))
    # the slope's Horner runs alongside (not on polyder's coefficients): rounding only
    assert slope == pytest.approx(float(polyval(x, np.array(coeffs), derivative=1)), abs=1e-9)
    shifted = [c0, *coeffs[1:]]
    assert value_and_slope(coeffs, x, c0) == value_and_slope(shifted, x)
    # the float version the SLAM ran before compiling: the very same floats
    assert value_and_slope(coeffs, x, c0) == reference_floats.value_and_slope(coeffs, x, c0)


def test_polyval_rows__bit_identical_to_polyval_per_row() -> None:
    rng = np.random.default_rng(0)
    coeffs = rng.normal(size=(7, 4))
    coeffs[2, 2:] = 0.0  # a lower-order row, zero-padded
    x = rng.normal(0.0, 3.0, size=(7, 11))
    got = polyval_rows(coeffs, x)
    for row in range(7):
        np.testing.assert_array_equal(got[row], polyval(x[row], coeffs[row]))


@settings(max_examples=200, deadline=None)
@given(coeffs=coefficients, x0=st.floats(-4.0, 4.0), u=st.floats(-1.0, 1.0))
def test_taylor_shift__expands_about_x0(coeffs: list[float], x0: float, u: float) -> None:
    taylor = taylor_shift(coeffs, x0)
    want = NpPoly(coeffs)(x0 + u)
    scale = max(1.0, float(np.abs(coeffs).sum()) * max(1.0, abs(x0) + 1.0) ** len(coeffs))
    assert float(NpPoly(taylor)(u)) == pytest.approx(want, abs=1e-12 * scale)
    # and the same floats as the vectorised oracle (zero-padded rows, as the table keeps)
    padded = np.zeros((1, 6))
    padded[0, : len(coeffs)] = coeffs
    oracle = taylor_at(padded, np.array([x0]))[0]
    np.testing.assert_array_equal(taylor_shift(padded[0].tolist(), x0), oracle)
    assert taylor == reference_floats.taylor_shift(coeffs, x0)


@settings(max_examples=200, deadline=None)
@given(
    coeffs=st.lists(st.floats(-5.0, 5.0), min_size=1, max_size=7),
    x=st.lists(st.floats(-4.0, 4.0), min_size=1, max_size=5),
    derivative=st.integers(0, 7),
)
def test_polyval__bit_identical_to_numpys(
    coeffs: list[float], x: list[float], derivative: int
) -> None:
    # polyval repeats numpy's operations without their checks: the very same floats, for a
    # scalar (a Python or a numpy float: polyval's float path), a list and an array, any
    # derivative (one past the order gives numpy's zero)
    c = np.array(coeffs)
    want = np.polynomial.polynomial.polyder(c, derivative) if derivative else c
    for at in (x[0], np.float64(x[0]), x, np.array(x)):
        expected = np.polynomial.polynomial.polyval(at, want)
        got = polyval(at, c, derivative)
        np.testing.assert_array_equal(got, expected, strict=True)
        assert np.signbit(got).tolist() == np.signbit(expected).tolist()


@pytest.mark.parametrize("variate", [1, 2])
def test_to_xy__same_as_numpy_stack(variate: int) -> None:
    """(ξ, η) to (x¹, x²) as ``np.stack`` on the last axis puts them, for 0-d, 1-d and 2-d
    arrays; different shapes are refused in one line."""
    rng = np.random.default_rng(variate)
    poly = Polynomial(variate, np.array([0.5, 0.1, 0.0, 0.0]), -1.0, 1.0)
    for shape in ((), (5,), (3, 4)):
        xi, eta = rng.normal(size=shape), rng.normal(size=shape)
        pair = [xi, eta] if variate == 1 else [eta, xi]
        np.testing.assert_array_equal(poly.to_xy(xi, eta), np.stack(pair, axis=-1))
    with pytest.raises(ValueError, match="same shape"):
        poly.to_xy(np.zeros(3), np.zeros(4))

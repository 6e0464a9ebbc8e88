"""Piecewise-linear approximation of polynomials: chord error bound, vertex economy, resampling."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.comms import polyline
from polyslam_env.comms.polyline import piecewise_linear, polyline_points
from polyslam_env.core.geometry import transform_points
from polyslam_env.slam.polynomial import Polynomial

# Distances are computed in float64 on metre-scale values: 1e-9 m of slack covers rounding.
EPS = 1e-9


def _dist_to_polyline(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Distance (n,) from each point (n, 2) to the nearest segment of the chain (V, 2)."""
    a, b = vertices[:-1][None], vertices[1:][None]  # (1, V-1, 2)
    p = points[:, None]  # (n, 1, 2)
    ab = b - a
    u = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-300), 0, 1)
    return np.min(np.linalg.norm(p - (a + u[..., None] * ab), axis=-1), axis=1)


def _ideal_chords(poly: Polynomial, tol: float) -> float:
    """Chord count of an ideal approximation: ∫ sqrt(κ / (8 tol)) ds (sagitta κL²/8 = tol)."""
    xi = np.linspace(poly.lo, poly.hi, 20001)
    d1 = poly.slope(xi)
    d2 = np.polynomial.polynomial.polyval(xi, np.polynomial.polynomial.polyder(poly.coeffs, 2))
    speed = np.sqrt(1 + d1**2)
    f = np.sqrt(np.abs(d2) / speed**3 / (8 * tol)) * speed
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(xi)))


polys = st.builds(
    lambda variate, coeffs, lo, width: Polynomial(variate, np.array(coeffs), lo, lo + width),
    st.sampled_from([1, 2]),
    st.lists(st.floats(-1.5, 1.5), min_size=2, max_size=5),  # orders 1..4
    st.floats(-2.0, 2.0),
    st.floats(0.05, 2.5),
)


@settings(max_examples=60, deadline=None)
@given(poly=polys, tol=st.sampled_from([0.002, 0.005, 0.02]))
def test_piecewise_linear__dense_curve_within_chord_tol(poly: Polynomial, tol: float) -> None:
    vertices = piecewise_linear(poly, chord_tol=tol)
    dense = poly.points_at(np.linspace(poly.lo, poly.hi, 4001))
    assert np.max(_dist_to_polyline(dense, vertices)) <= tol + EPS
    # vertices are on the curve, ordered from Q_m to Q_M
    xi, eta = poly.from_xy(vertices)
    np.testing.assert_allclose(eta, poly.value(xi), atol=EPS)
    np.testing.assert_allclose(vertices[[0, -1]], poly.endpoints(), atol=EPS)
    assert np.all(np.diff(xi) > 0)


@settings(max_examples=60, deadline=None)
@given(poly=polys)
def test_piecewise_linear__uses_few_vertices(poly: Polynomial) -> None:
    tol = 0.005
    chords = len(piecewise_linear(poly, tol)) - 1
    # Aiming at 0.8 tol costs a factor 1/sqrt(0.8) ≈ 1.12 over the ideal count, rounding up
    # and the occasional halving of a failing chord a little more; 1.5× + 2 bounds both.
    assert chords <= 1.5 * _ideal_chords(poly, tol) + 2


def test_piecewise_linear__straight_line_is_one_chord() -> None:
    vertices = piecewise_linear(Polynomial(2, np.array([0.3, -0.7]), -1.0, 2.0))
    assert vertices.shape == (2, 2)


def test_piecewise_linear__curved_wall_counts_match_sagitta_rule() -> None:
    # y = x² on [-1, 1]: a strongly curved wall, ideally ~12 chords at 5 mm
    poly = Polynomial(1, np.array([0.0, 0.0, 1.0]), -1.0, 1.0)
    ideal = _ideal_chords(poly, 0.005)
    chords = len(piecewise_linear(poly, 0.005)) - 1
    # within [ideal, 1.3 ideal]: fewer would break the tolerance, more would waste bytes.
    assert ideal - 1 <= chords <= 1.3 * ideal + 1


def test_piecewise_linear__degenerate_extent_and_bad_tolerance() -> None:
    poly = Polynomial(1, np.array([1.0, 0.5, 0.2]), 0.4, 0.4)
    vertices = piecewise_linear(poly)
    assert vertices.shape == (2, 2)
    np.testing.assert_array_equal(vertices[0], vertices[1])
    with pytest.raises(ValueError, match="chord_tol"):
        piecewise_linear(poly, chord_tol=0.0)


def test_piecewise_linear__rigid_map_keeps_the_bound() -> None:
    rng = np.random.default_rng(0)
    poly = Polynomial(1, np.array([0.2, -0.4, 0.9, -0.5]), -0.8, 1.2)
    pose = np.array([1.5, -2.0, 2.3])
    moved = transform_points(piecewise_linear(poly, 0.005), pose)
    dense = transform_points(poly.points_at(np.sort(rng.uniform(poly.lo, poly.hi, 3000))), pose)
    assert np.max(_dist_to_polyline(dense, moved)) <= 0.005 + EPS


@pytest.mark.parametrize("spacing", [0.01, 0.05, 0.3])
def test_polyline_points__even_spacing_on_chain(spacing: float) -> None:
    vertices = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [1.0, 0.5], [0.2, 1.1]])
    pts = polyline_points(vertices, spacing)
    gaps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    length = 1.0 + 0.5 + 1.0
    np.testing.assert_allclose(pts[[0, -1]], vertices[[0, -1]], atol=EPS)
    assert np.all(gaps <= spacing + EPS)
    assert len(pts) == int(np.ceil(length / spacing)) + 1
    assert np.max(_dist_to_polyline(pts, vertices)) <= EPS  # all points on the chain


def test_polyline_points__single_point_and_errors() -> None:
    np.testing.assert_array_equal(polyline_points(np.array([[1.0, 2.0]] * 3), 0.1), [[1.0, 2.0]])
    with pytest.raises(ValueError, match="spacing"):
        polyline_points(np.zeros((2, 2)), -1.0)


def test_piecewise_linear__negligible_leading_coefficient_is_not_a_crash() -> None:
    """Hypothesis found b3 = 2.2e-313 (subnormal): the companion matrix overflowed to inf."""
    poly = Polynomial(1, np.array([0.0, 0.0, 1.0, 2.22507386e-313]), 0.0, 1.0)
    vertices = piecewise_linear(poly, chord_tol=0.002)
    dense = poly.points_at(np.linspace(0.0, 1.0, 2001))
    assert np.all(np.isfinite(vertices)) and len(vertices) > 2
    np.testing.assert_allclose(vertices[[0, -1]], dense[[0, -1]])


def test_max_perpendicular_cubic__is_the_per_chord_roots_for_every_chord() -> None:
    """The closed-form chord errors (orders ≤ 3) against the companion-matrix roots of
    ``_max_perpendicular`` chord by chord, on random curves and knots: equal to EPS (both
    evaluate the error at the same critical points, found by different root finders)."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        order = int(rng.integers(1, 4))
        coeffs = rng.normal(0, 1, order + 1) * rng.choice([1.0, 1e-9, 1e-15], order + 1)
        lo = float(rng.uniform(-3, 3))
        poly = Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + float(rng.uniform(0.1, 4)))
        xi = np.sort(np.concatenate([[poly.lo, poly.hi], rng.uniform(poly.lo, poly.hi, 6)]))
        fast = polyline._max_perpendicular_cubic(poly, xi)
        slow = [polyline._max_perpendicular(poly, a, b) for a, b in itertools.pairwise(xi)]
        np.testing.assert_allclose(fast, slow, rtol=0, atol=EPS)


def test_chain_points__compiled_chain_is_the_numpy_one_bit_for_bit() -> None:
    """``polyline.chain_points`` (the compiled kernel, orders ≤ 3) against the numpy
    ``polyline_points(piecewise_linear(…))`` it replaces, the oracle: every point equal bit for
    bit, on random curves of every order ≤ 3 with coefficients from metre scale down to
    negligible (1e-15, as the trimmed leading terms), straight lines (the kernel's shortcut:
    padded with zeros or −0, steep or flat), degenerate extents,
    several tolerances and spacings; and an order-4 curve takes the numpy path."""
    rng = np.random.default_rng(41)
    cases = [Polynomial(1, np.array([0.3, -0.2]), 0.5, 0.5),  # one point
             Polynomial(2, np.array([0.3, -0.7, 0.0, 0.0]), -1.0, 2.0),  # padded line
             Polynomial(1, np.array([0.0, 0.0, 1.0, 2.22507386e-313]), 0.0, 1.0),
             Polynomial(1, np.array([0.3, 0.02, -0.0, 0.0]), -1.0, 2.0),  # line, a −0 tail
             Polynomial(2, np.array([-1.0, 1e3]), 0.2, 0.3),  # steep lines
             Polynomial(1, np.array([0.5, -50.0, 0.0]), -0.01, 0.01),
             Polynomial(1, np.array([0.5, 1e-300, 0.0, 0.0]), -4.0, -1.0)]  # fmt: skip
    for _ in range(400):
        order = int(rng.integers(1, 4))
        coeffs = rng.normal(0, 1, order + 1) * rng.choice([1.0, 0.05, 1e-9, 1e-15], order + 1)
        lo = float(rng.uniform(-3, 3))
        cases.append(Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + rng.uniform(0.01, 4)))
    for k, poly in enumerate(cases):
        tol, spacing = [(0.005, 0.05), (0.002, 0.01), (0.02, 0.3)][k % 3]
        fast = polyline.chain_points(poly, tol, spacing)
        slow = polyline_points(piecewise_linear(poly, tol), spacing)
        assert fast.shape == slow.shape and fast.tobytes() == slow.tobytes(), poly
    quartic = Polynomial(1, np.array([0.1, 0.2, -0.3, 0.1, 0.05]), -1.0, 1.0)
    slow = polyline_points(piecewise_linear(quartic, 0.005), 0.05)
    assert polyline.chain_points(quartic, 0.005, 0.05).tobytes() == slow.tobytes()
    with pytest.raises(ValueError, match="spacing must be > 0"):
        polyline.chain_points(cases[1], 0.005, 0.0)

"""The vectorised measurement oracle (tests/slam/reference.py): ray casting against brute force,
Jacobians against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.polynomial import Polynomial as NpPoly

from polyslam_env.slam.landmarks import PackedPolynomials
from polyslam_env.slam.polynomial import Polynomial
from tests.slam.reference import expected_ranges_and_jacobian, ray_intersections

BEAMS = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])
SIN_10 = np.sin(np.deg2rad(10.0))


# -- brute force ---------------------------------------------------------------------------------
def brute_force_candidates(
    pose: np.ndarray, phi: float, poly: Polynomial, c0: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All complex roots t of F for one beam and polynomial (numpy composition + np.roots),
    with the ξ of their real parts and the incidence sine |D|/√(1+B'²) there."""
    c, s = np.cos(phi), np.sin(phi)
    if poly.variate == 1:
        xi0, eta0, dxi, deta = pose[0], pose[1], c, s
    else:
        xi0, eta0, dxi, deta = pose[1], pose[0], s, c
    shape = NpPoly(np.concatenate([[0.0], poly.shape]))
    f = NpPoly([eta0 - c0, deta]) - shape(NpPoly([xi0, dxi]))
    coef = f.coef[::-1]  # highest power first for np.roots
    # np.roots trims only exact zeros; a leading coefficient ~1e-300 would overflow its
    # companion matrix. Trimming below 1e-14 of the largest drops roots at |t| > 1e4 m.
    big = np.abs(coef) > 1e-14 * np.abs(coef).max() if np.any(coef != 0) else coef != 0
    coef = coef[np.argmax(big) :] if big.any() else coef[:0]
    roots = np.roots(coef) if coef.size > 1 else np.array([], dtype=complex)
    xi = xi0 + roots.real * dxi
    slope = shape.deriv()(xi)
    return roots, xi, np.abs(deta - slope * dxi) / np.sqrt(1.0 + slope**2)


def brute_force_range(
    pose: np.ndarray, phi: float, polys: list[Polynomial], c0s: np.ndarray, max_range: float
) -> tuple[float, int, bool]:
    """(range, index, ambiguous): plain loops. Ambiguous when a root sits on a decision edge
    or is (nearly) multiple, i.e. near-tangent: there, whether it is real is ill-posed."""
    best, best_i, ambiguous = np.inf, -1, False
    for i, (poly, c0) in enumerate(zip(polys, c0s, strict=True)):
        roots, xi, sine = brute_force_candidates(pose, phi, poly, c0)
        for r, x, sin_inc in zip(roots, xi, sine, strict=True):
            t = r.real
            near_edge = min(abs(t), abs(t - max_range), abs(x - poly.lo), abs(x - poly.hi)) < 1e-6
            tangent = abs(r.imag) < 1e-2 and sin_inc < 1e-3
            if near_edge or tangent or 1e-9 < abs(r.imag) < 1e-4:
                ambiguous = True
            if abs(r.imag) <= 1e-9 and 0 < t <= max_range and poly.lo <= x <= poly.hi and t < best:
                best, best_i = t, i
    return best, best_i, ambiguous


# -- strategies ------------------------------------------------------------------------------
@st.composite
def polynomials(draw: st.DrawFn, order: int = 3) -> Polynomial:
    variate = draw(st.sampled_from([1, 2]))
    coeffs = [draw(st.floats(-2.0, 2.0))]
    coeffs += [draw(st.floats(-1.0, 1.0)) / i for i in range(1, order + 1)]
    lo = draw(st.floats(-3.0, 2.0))
    width = draw(st.floats(0.1, 4.0))
    return Polynomial(variate, np.array(coeffs), lo, lo + width)


poses = st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-np.pi, np.pi)).map(
    np.array
)
beam_sets = st.one_of(
    st.just(BEAMS), st.lists(st.floats(-np.pi, np.pi), min_size=1, max_size=6).map(np.array)
)


# -- ray casting --------------------------------------------------------------------------------
@settings(max_examples=150, deadline=None)
@given(
    polys=st.lists(polynomials(), min_size=1, max_size=4),
    pose=poses,
    beams=beam_sets,
    max_range=st.floats(0.5, 3.0),
)
def test_ray_intersections__match_brute_force_roots(
    polys: list[Polynomial], pose: np.ndarray, beams: np.ndarray, max_range: float
) -> None:
    c0s = np.array([p.c0 for p in polys])
    hits = ray_intersections(pose, beams, polys, c0s, max_range)
    for j, beta in enumerate(beams):
        t, _, ambiguous = brute_force_range(pose, pose[2] + beta, polys, c0s, max_range)
        assume(not ambiguous)
        if np.isinf(t):
            assert np.isinf(hits.ranges[j]) and hits.index[j] == -1
            continue
        # 1e-9 m: both sides are accurate to ~1e-12 away from multiple roots (excluded above).
        assert hits.ranges[j] == pytest.approx(t, abs=1e-9)
        hit_poly = polys[hits.index[j]]
        xy = pose[:2] + hits.ranges[j] * np.array([np.cos(pose[2] + beta), np.sin(pose[2] + beta)])
        xi, eta = hit_poly.from_xy(xy)
        # 1e-8 m: the hit point lies on the polynomial it reports, up to root accuracy × slope.
        assert float(hit_poly.value(xi)) == pytest.approx(float(eta), abs=1e-8)
        # …and that polynomial alone attains the minimum (ties make the index ambiguous).
        own, _, _ = brute_force_range(
            pose, pose[2] + beta, [hit_poly], c0s[[hits.index[j]]], max_range
        )
        assert own == pytest.approx(t, abs=1e-9)  # same accuracy as above


@pytest.mark.parametrize("b3", [1e-2, 1e-4, 1e-6, 1e-9, 1e-13])
@pytest.mark.parametrize("theta", [np.pi / 2 - 1e-3, np.pi / 2 - 0.2, 0.3])
def test_ray_intersections__small_leading_coefficient_matches_brute_force(
    b3: float, theta: float
) -> None:
    # A tiny cubic term (nearly a parabola, or a beam nearly along the η axis) makes the
    # closed-form cubic ill-conditioned; the solver must still find the small roots.
    poly = Polynomial(1, np.array([0.8, -0.3, 0.5, b3]), -3.0, 3.0)
    pose = np.array([0.2, -0.4, theta])
    beams = np.deg2rad([0.0, 30.0, -30.0, 60.0, -60.0])
    hits = ray_intersections(pose, beams, [poly], np.array([0.8]), 3.0)
    compared = 0
    for j, beta in enumerate(beams):
        t, _, ambiguous = brute_force_range(pose, theta + beta, [poly], np.array([0.8]), 3.0)
        if not ambiguous:
            # 1e-9 m as in the property test above
            assert hits.ranges[j] == pytest.approx(t, abs=1e-9)
            compared += 1
    assert compared >= 3


@settings(max_examples=40, deadline=None)
@given(polys=st.lists(polynomials(order=5), min_size=1, max_size=3), pose=poses)
def test_ray_intersections__higher_order_matches_brute_force(
    polys: list[Polynomial], pose: np.ndarray
) -> None:
    c0s = np.array([p.c0 for p in polys])
    hits = ray_intersections(pose, BEAMS, polys, c0s, 2.0)
    for j, beta in enumerate(BEAMS):
        t, _, ambiguous = brute_force_range(pose, pose[2] + beta, polys, c0s, 2.0)
        assume(not ambiguous)
        # 1e-9 m: companion eigenvalues + one Newton step, well-separated roots
        assert hits.ranges[j] == pytest.approx(t, abs=1e-9)


def _line(variate: int, c0: float, slope: float, lo: float, hi: float) -> Polynomial:
    return Polynomial(variate, np.array([c0, slope, 0.0, 0.0]), lo, hi)


def _cast(pose: list[float], beams: list[float], polys: list[Polynomial], r: float = 2.0):  # type: ignore[no-untyped-def]
    return ray_intersections(
        np.array(pose), np.array(beams), polys, np.array([p.c0 for p in polys]), r
    )


def test_ray_intersections__nearest_polynomial_wins() -> None:
    walls = [_line(1, 1.5, 0.0, -5, 5), _line(1, 0.5, 0.0, -5, 5), _line(2, 1.0, 0.0, -5, 5)]
    hits = _cast([0.0, 0.0, 0.0], [np.pi / 2, 0.0, np.pi], walls)
    # exact lines: ranges are exact up to rounding (1e-12)
    np.testing.assert_allclose(hits.ranges[:2], [0.5, 1.0], atol=1e-12)
    assert list(hits.index) == [1, 2, -1]
    assert np.isinf(hits.ranges[2])


def test_ray_intersections__ignores_roots_outside_extent_and_beyond_range() -> None:
    short = _line(1, 1.0, 0.0, 0.5, 2.0)  # y = 1 only for x in [0.5, 2]
    hits = _cast([0.0, 0.0, 0.0], [np.pi / 2, np.pi / 4], [short], r=2.0)
    assert hits.index[0] == -1  # straight up meets y = 1 at x = 0: outside the extent
    assert hits.ranges[1] == pytest.approx(np.sqrt(2.0), abs=1e-12)  # at x = 1: inside
    far = _cast([0.0, 0.0, 0.0], [np.pi / 2], [_line(1, 2.5, 0.0, -5, 5)], r=2.0)
    assert far.index[0] == -1 and np.isinf(far.ranges[0])


def test_ray_intersections__takes_farther_root_when_nearer_is_outside_extent() -> None:
    # y = x² on x ∈ [0.5, 3]; the beam along y = 0.25 from x = −2 meets x = −0.5 (outside)
    # before x = 0.5 (inside).
    parabola = Polynomial(1, np.array([0.0, 0.0, 1.0, 0.0]), 0.5, 3.0)
    hits = _cast([-2.0, 0.25, 0.0], [0.0], [parabola], r=3.0)
    assert hits.ranges[0] == pytest.approx(2.5, abs=1e-12)  # double precision on exact roots


def test_ray_intersections__axis_parallel_beam_drops_degree() -> None:
    # A beam at exactly 90° on an x¹-variate cubic: F is linear in t (cos φ ≈ 6e-17).
    cubic = Polynomial(1, np.array([1.0, 0.3, -0.2, 0.1]), -2.0, 2.0)
    hits = _cast([0.4, -0.5, np.pi / 2], [0.0], [cubic], r=3.0)
    expected = float(cubic.value(0.4)) + 0.5
    assert hits.ranges[0] == pytest.approx(expected, abs=1e-12)  # linear root, exact


def test_expected_ranges__tangent_ray_is_found_but_invalid() -> None:
    # y = 0.5 + x²: the beam along y = 0.5 touches the vertex at t = 1 (double root), and a
    # beam 1 mm above crosses it twice at a grazing angle; both are flagged, neither used.
    parabola = Polynomial(1, np.array([0.5, 0.0, 1.0, 0.0]), -2.0, 2.0)
    for y0 in (0.5, 0.501):
        mean = np.array([-1.0, y0, 0.0, 0.5])
        z_hat, H, valid, index = expected_ranges_and_jacobian(mean, [parabola], np.zeros(1), 2.0)
        assert index[0] == 0 and not valid[0]
        # the first root is 1 − √(y0 − 0.5) (0.968 m for 1 mm); tangent roots carry √eps error
        assert z_hat[0] == pytest.approx(1.0 - np.sqrt(y0 - 0.5), abs=1e-6)
        assert not H[0].any()
    miss = np.array([-1.0, 0.499, 0.0, 0.5])  # 1 mm below the vertex: no return
    _, _, valid, index = expected_ranges_and_jacobian(miss, [parabola], np.zeros(1), 2.0)
    assert index[0] == -1 and not valid[0]


def test_expected_ranges__empty_map_has_no_returns() -> None:
    z_hat, H, valid, index = expected_ranges_and_jacobian(np.zeros(3), [], BEAMS, 2.0)
    assert np.isinf(z_hat).all() and not valid.any() and (index == -1).all()
    assert H.shape == (5, 3)


def test_packed_polynomials__same_result_as_list() -> None:
    rng = np.random.default_rng(3)
    polys = [
        Polynomial(int(rng.integers(1, 3)), rng.normal(0, [1, 0.5, 0.3, 0.1][: o + 1]), -2, 2)
        for o in (1, 2, 3, 3)
    ]
    mean = np.concatenate([[0.1, -0.2, 0.4], [p.c0 for p in polys]])
    a = expected_ranges_and_jacobian(mean, polys, BEAMS, 2.0)
    b = expected_ranges_and_jacobian(mean, PackedPolynomials.from_polynomials(polys), BEAMS, 2.0)
    np.testing.assert_array_equal(a.z_hat, b.z_hat)
    np.testing.assert_array_equal(a.H, b.H)


# -- Jacobians ---------------------------------------------------------------------------------
@st.composite
def valid_hits(draw: st.DrawFn) -> tuple[list[Polynomial], np.ndarray, float]:
    """Two polynomials and a pose whose beam ``beta`` meets the first one non-tangentially."""
    target = draw(polynomials())
    other = draw(polynomials())
    width = target.hi - target.lo
    xi = target.lo + width * draw(st.floats(0.1, 0.9))
    q = target.points_at(np.array([xi]))[0]
    tangent = target.to_xy(np.array(1.0), target.slope(xi))  # d(x,y)/dξ
    psi = np.arctan2(tangent[1], tangent[0])
    incidence = draw(st.floats(np.deg2rad(20.0), np.deg2rad(160.0)))
    phi = psi + draw(st.sampled_from([1.0, -1.0])) * incidence
    t = draw(st.floats(0.2, 1.8))
    beta = draw(st.sampled_from(list(BEAMS)))
    pose = np.array([q[0] - t * np.cos(phi), q[1] - t * np.sin(phi), phi - beta])
    return [target, other], pose, float(beta)


@settings(max_examples=150, deadline=None)
@given(case=valid_hits())
def test_expected_ranges_jacobian__matches_finite_differences(
    case: tuple[list[Polynomial], np.ndarray, float],
) -> None:
    polys, pose, beta = case
    mean = np.concatenate([pose, [p.c0 for p in polys]])
    beams, max_range = np.array([beta]), 2.0
    hits = ray_intersections(pose, beams, polys, mean[3:], max_range)
    assume(hits.index[0] >= 0 and hits.incidence_sine[0] > np.sin(np.deg2rad(15.0)))
    poly = polys[hits.index[0]]
    assume(min(hits.xi[0] - poly.lo, poly.hi - hits.xi[0], max_range - hits.ranges[0]) > 1e-3)
    _, H, valid, index = expected_ranges_and_jacobian(mean, polys, beams, max_range)
    assert valid[0]
    step = 1e-6  # central differences: truncation ~ step² · h''' ≪ 1e-9, rounding ~ 1e-10
    for col in (0, 1, 2, 3 + index[0]):
        delta = np.zeros_like(mean)
        delta[col] = step
        plus = expected_ranges_and_jacobian(mean + delta, polys, beams, max_range)
        minus = expected_ranges_and_jacobian(mean - delta, polys, beams, max_range)
        assume(plus.poly_index[0] == minus.poly_index[0] == index[0])
        numeric = (plus.z_hat[0] - minus.z_hat[0]) / (2 * step)
        # 1e-6: |h''| ≲ 1e3 for ≥ 15° incidence leaves a central-difference error ≪ 1e-6
        assert H[0, col] == pytest.approx(numeric, rel=1e-6, abs=1e-6), f"column {col}"
    other_col = 3 + 1 - index[0]
    assert H[0, other_col] == 0.0  # a beam depends only on the c0 it hits


@settings(max_examples=60, deadline=None)
@given(case=valid_hits())
def test_expected_ranges__validity_follows_incidence_angle(
    case: tuple[list[Polynomial], np.ndarray, float],
) -> None:
    polys, pose, beta = case
    mean = np.concatenate([pose, [p.c0 for p in polys]])
    z_hat, _, valid, index = expected_ranges_and_jacobian(mean, polys, np.array([beta]), 2.0)
    assume(index[0] >= 0)
    poly, phi = polys[index[0]], pose[2] + beta
    direction = np.array([np.cos(phi), np.sin(phi)])
    xi, _ = poly.from_xy(pose[:2] + z_hat[0] * direction)
    tangent = poly.to_xy(np.array(1.0), poly.slope(xi))
    cross = direction[0] * tangent[1] - direction[1] * tangent[0]
    sine = abs(cross) / np.linalg.norm(tangent)
    assume(abs(sine - SIN_10) > 1e-9)  # exactly on the threshold either answer is right
    assert valid[0] == (sine >= SIN_10)

"""The SLAM's per-beam measurement model equals the vectorised oracle (same algorithm, floats)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.measurement import BeamHit, cast
from polyslam_env.slam.polynomial import Polynomial
from tests.slam.reference import expected_ranges_and_jacobian, ray_intersections
from tests.slam.test_reference import (
    BEAMS,
    beam_sets,
    brute_force_range,
    polynomials,
    poses,
    valid_hits,
)


def _rows(polys: list[Polynomial]) -> LandmarkTable:
    arrays = LandmarkTable()
    for p in polys:
        arrays.append(p, pivot=0.5 * (p.lo + p.hi), xi_var=0.0, model_var=0.0, fit_half=1.0)
    return arrays


def assert_same_hits(
    pose: np.ndarray,
    beams: np.ndarray,
    polys: list[Polynomial],
    max_range: float,
    skip_ambiguous: bool = True,
) -> None:
    """Both casts agree on every beam that has no root on a decision edge (t ≈ 0, t ≈ r_max,
    ξ ≈ an end) and no near-double root: there either answer is right, and which one comes
    out depends on the last bit of cos/acos/cbrt (libm's here, numpy's there)."""
    c0s = np.array([p.c0 for p in polys])
    if skip_ambiguous:
        for beta in beams:
            assume(not brute_force_range(pose, pose[2] + beta, polys, c0s, max_range)[2])
    want = ray_intersections(pose, beams, polys, c0s, max_range)
    arrays = _rows(polys)
    x, y, theta = pose.tolist()
    args = (x, y, theta, beams.tolist(), list(range(len(polys))), arrays.rows(), c0s.tolist())
    got = cast(*args, max_range)
    boxed = cast(*args, max_range, arrays.boxes(c0s).tolist())
    assert boxed == got  # the boxes only skip pairs that cannot hit: the very same answer
    for j, hit in enumerate(got):
        if hit is None:
            assert want.index[j] == -1 and np.isinf(want.ranges[j])
            continue
        assert hit.landmark == want.index[j]
        assert hit.variate == want.variate[j]
        # 1e-12 (m, or dimensionless): the same operations on the same numbers; only libm's
        # and numpy's cos/acos/cbrt may differ in the last bit, which Newton's polish damps.
        assert hit.t == pytest.approx(want.ranges[j], abs=1e-12)
        assert hit.slope == pytest.approx(want.slope[j], abs=1e-9)
        assert hit.denom == pytest.approx(want.denom[j], abs=1e-9)
        assert hit.phi == pytest.approx(want.phi[j], abs=1e-15)
        assert hit.xi == pytest.approx(want.xi[j], abs=1e-12)  # as t
        assert hit.incidence_sine == pytest.approx(want.incidence_sine[j], abs=1e-9)  # as D
    # The update's rows of H equal the vectorised Jacobian (itself checked against finite
    # differences in test_reference.py); 1e-6 relative: 1/D amplifies the 1e-9 of D
    # near the tangent limit (|D| ≥ sin 10° · √(1 + B'²) for valid rows).
    state = np.concatenate([pose, c0s])
    jac = expected_ranges_and_jacobian(state, polys, beams, max_range)
    for j, hit in enumerate(got):
        if hit is None or not jac.valid[j]:
            continue
        (h_x, h_y, h_theta), inv_d = hit.jacobian()
        row = np.zeros(state.size)
        row[:3] = h_x, h_y, h_theta
        row[3 + hit.landmark] = inv_d
        np.testing.assert_allclose(row, jac.H[j], rtol=1e-6, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    polys=st.lists(polynomials(), min_size=1, max_size=5),
    pose=poses,
    beams=beam_sets,
    max_range=st.floats(0.5, 3.0),
)
def test_cast__equals_vectorised_ray_intersections(
    polys: list[Polynomial], pose: np.ndarray, beams: np.ndarray, max_range: float
) -> None:
    assert_same_hits(pose, beams, polys, max_range)


@settings(max_examples=40, deadline=None)
@given(polys=st.lists(polynomials(order=5), min_size=1, max_size=3), pose=poses)
def test_cast__higher_orders_equal_vectorised(polys: list[Polynomial], pose: np.ndarray) -> None:
    assert_same_hits(pose, BEAMS, polys, 2.0)


@pytest.mark.parametrize("b3", [1e-2, 1e-4, 1e-6, 1e-9, 1e-13, 0.0])
@pytest.mark.parametrize("theta", [math.pi / 2 - 1e-3, math.pi / 2 - 0.2, 0.3, math.pi / 2])
def test_cast__stiff_and_degenerate_rows_equal_vectorised(b3: float, theta: float) -> None:
    # tiny leading terms take the lower-degree path plus Newton; a beam exactly along the
    # η axis makes every power of dξ vanish; a straight wall padded to a cubic (b3 = 0).
    polys = [
        Polynomial(1, np.array([0.8, -0.3, 0.5, b3]), -3.0, 3.0),
        Polynomial(2, np.array([1.1, 0.0, 0.0, 0.0]), -3.0, 3.0),
        Polynomial(1, np.array([-0.7, 0.0]), -3.0, 3.0),
    ]
    pose = np.array([0.2, -0.4, theta])
    beams = np.deg2rad([0.0, 30.0, -30.0, 60.0, -60.0, 90.0, 180.0])
    assert_same_hits(pose, beams, polys, 3.0, skip_ambiguous=False)


def test_cast__only_candidates_are_cast() -> None:
    near = Polynomial(1, np.array([0.5, 0.0]), -1.0, 1.0)
    far = Polynomial(1, np.array([1.0, 0.0]), -1.0, 1.0)
    rows = _rows([near, far]).rows()
    (both,) = cast(0.0, 0.0, math.pi / 2, [0.0], [0, 1], rows, [0.5, 1.0], 2.0)
    (only_far,) = cast(0.0, 0.0, math.pi / 2, [0.0], [1], rows, [0.5, 1.0], 2.0)
    (none,) = cast(0.0, 0.0, math.pi / 2, [0.0], [], rows, [0.5, 1.0], 2.0)
    assert both is not None and both.landmark == 0 and both.t == pytest.approx(0.5)
    assert only_far is not None and only_far.landmark == 1 and only_far.t == pytest.approx(1.0)
    assert none is None


@settings(max_examples=150, deadline=None)
@given(case=valid_hits())
def test_beam_hit_jacobian__matches_finite_differences(
    case: tuple[list[Polynomial], np.ndarray, float],
) -> None:
    polys, pose, beta = case
    rows = _rows(polys).rows()
    mean = np.concatenate([pose, [p.c0 for p in polys]])
    max_range, every = 2.0, list(range(len(polys)))

    def hit_at(state: np.ndarray) -> BeamHit | None:
        x, y, theta = state[:3].tolist()
        return cast(x, y, theta, [beta], every, rows, state[3:].tolist(), max_range)[0]

    hit = hit_at(mean)
    assume(hit is not None and hit.incidence_sine > np.sin(np.deg2rad(15.0)))
    assert hit is not None
    poly = polys[hit.landmark]
    assume(min(hit.xi - poly.lo, poly.hi - hit.xi, max_range - hit.t) > 1e-3)
    (h_x, h_y, h_theta), inv_d = hit.jacobian()
    step = 1e-6  # central differences: truncation ~ step² · h''' ≪ 1e-9, rounding ~ 1e-10
    for col, want in ((0, h_x), (1, h_y), (2, h_theta), (3 + hit.landmark, inv_d)):
        delta = np.zeros_like(mean)
        delta[col] = step
        plus, minus = hit_at(mean + delta), hit_at(mean - delta)
        assume(plus is not None and minus is not None)
        assert plus is not None and minus is not None
        assume(plus.landmark == minus.landmark == hit.landmark)
        numeric = (plus.t - minus.t) / (2 * step)
        # 1e-6: |h''| ≲ 1e3 for ≥ 15° incidence leaves a central-difference error ≪ 1e-6
        assert want == pytest.approx(numeric, rel=1e-6, abs=1e-6), f"column {col}"

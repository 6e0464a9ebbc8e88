"""The SLAM's measurement model (compiled, a scan per call) equals the vectorised oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.measurement import BeamHit, cast, range_rows
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
    rows = range_rows(x, y, theta, beams, np.zeros(beams.size), *args[5:], max_range, 0.0, 0.0)
    row_of: dict[int, int] = {}  # beam → its row (every hit has one with min_sine = 0)
    for j, hit in enumerate(got):
        if hit is not None:
            row_of[j] = len(row_of)
    assert rows.innovation.size == len(row_of)
    ties: set[int] = set()
    for j, hit in enumerate(got):
        if hit is None:
            assert want.index[j] == -1 and np.isinf(want.ranges[j])
            continue
        if hit.landmark != want.index[j]:  # two landmarks tie (e.g. mirror images): either
            assert hit.t == pytest.approx(want.ranges[j], abs=1e-12)
            ties.add(j)
            continue
        assert hit.variate == want.variate[j]
        # 1e-12 (m, or dimensionless): the same operations on the same numbers; only libm's
        # and numpy's cos/acos/cbrt may differ in the last bit, which Newton's polish damps.
        assert hit.t == pytest.approx(want.ranges[j], abs=1e-12)
        assert hit.slope == pytest.approx(want.slope[j], abs=1e-9)
        assert hit.denom == pytest.approx(want.denom[j], abs=1e-9)
        assert hit.phi == pytest.approx(want.phi[j], abs=1e-15)
        assert hit.xi == pytest.approx(want.xi[j], abs=1e-12)  # as t
        assert _sine(hit) == pytest.approx(want.incidence_sine[j], abs=1e-9)  # as D
        assert rows.innovation[row_of[j]] == -hit.t
    # The update's rows of H equal the vectorised Jacobian (itself checked against finite
    # differences in test_reference.py); 1e-6 relative: 1/D amplifies the 1e-9 of D
    # near the tangent limit (|D| ≥ sin 10° · √(1 + B'²) for valid rows).
    state = np.concatenate([pose, c0s])
    jac = expected_ranges_and_jacobian(state, polys, beams, max_range)
    for j, hit in enumerate(got):
        if hit is None or not jac.valid[j] or j in ties:
            continue
        k = row_of[j]
        assert rows.c0_index[k] == 3 + hit.landmark
        row = np.zeros(state.size)
        row[:3] = rows.h_pose[k]
        row[3 + hit.landmark] = rows.h_c0[k]
        np.testing.assert_allclose(row, jac.H[j], rtol=1e-6, atol=1e-9)


def _sine(hit: BeamHit) -> float:
    """|sin| of the angle between beam and curve, |D| / √(1 + B'²)."""
    return abs(hit.denom) / math.sqrt(1.0 + hit.slope * hit.slope)


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
def test_range_rows_jacobian__matches_finite_differences(
    case: tuple[list[Polynomial], np.ndarray, float],
) -> None:
    polys, pose, beta = case
    shapes = _rows(polys).arrays()
    mean = np.concatenate([pose, [p.c0 for p in polys]])
    max_range, every = 2.0, list(range(len(polys)))

    def hit_at(state: np.ndarray) -> BeamHit | None:
        x, y, theta = state[:3].tolist()
        return cast(x, y, theta, [beta], every, shapes, state[3:], max_range)[0]

    hit = hit_at(mean)
    assume(hit is not None and _sine(hit) > np.sin(np.deg2rad(15.0)))
    assert hit is not None
    poly = polys[hit.landmark]
    assume(min(hit.xi - poly.lo, poly.hi - hit.xi, max_range - hit.t) > 1e-3)
    x, y, theta = pose.tolist()
    rows = range_rows(x, y, theta, [beta], [0.0], shapes, mean[3:], max_range, 0.0, 0.0)
    (h_x, h_y, h_theta), inv_d = rows.h_pose[0], float(rows.h_c0[0])
    assert rows.c0_index[0] == 3 + hit.landmark
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


def test_range_rows__skip_near_tangent_hits() -> None:
    # a beam along y = 0.5 · x meets the wall x² = 0.5 at 26.6° incidence: kept at 10°,
    # skipped at 30°; the beam straight up meets it at 90°.
    wall = Polynomial(1, np.array([0.5, 0.0]), -5.0, 5.0)
    shapes = _rows([wall]).arrays()
    beams = [math.atan(0.5), math.pi / 2]
    angle = math.atan2(0.5, 1.0)
    assert math.degrees(angle) == pytest.approx(26.565, abs=1e-3)
    kept = range_rows(-1.0, 0.0, 0.0, beams, [1.0, 1.0], shapes, [0.5], 3.0, 0.17, 0.0)
    skipped = range_rows(-1.0, 0.0, 0.0, beams, [1.0, 1.0], shapes, [0.5], 3.0, 0.5, 4e-4)
    assert kept.innovation.size == 2 and skipped.innovation.size == 1
    assert skipped.h_pose[0].tolist() == [0.0, -1.0, pytest.approx(0.0, abs=1e-12)]
    assert skipped.variance.tolist() == [4e-4]

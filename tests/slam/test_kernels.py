"""The compiled SLAM kernels against the readable versions they replaced (reference_floats.py).

Bit for bit where the kernel does the same operations in the same order (the measurement model
up to order 3, the rows of H and R, the association error, the prediction, the boxes, Python's
hypot); to rounding where it cannot: companion roots of orders 4–5 (complex LAPACK instead of
real), the NIS and the update (plain loops instead of BLAS's fused, blocked products).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from polyslam_env.apps.benchmark import make_inputs, make_slam, make_walls
from polyslam_env.slam import ekf, kernels, step_kernels
from polyslam_env.slam.association import nearest_by_error
from polyslam_env.slam.columns import N_INDEX, ORDER, USES
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.landmarks import LandmarkTable, boxes_near
from polyslam_env.slam.maintenance import fit_inverse_table as _fit_inverse_table
from polyslam_env.slam.measurement import cast
from polyslam_env.slam.polynomial import Polynomial
from tests.slam import reference_floats as ref
from tests.slam.test_ekf import assert_symmetric_psd, random_spd
from tests.slam.test_reference import beam_sets, brute_force_range, polynomials, poses

#: Every field of a hit is the very same float: the same operations in the same order, and
#: numba calls the same libm for cos, sin, acos and cbrt as CPython.
EXACT = 0.0


def _table(polys: list[Polynomial], rng: np.random.Generator | None = None) -> LandmarkTable:
    """The polynomials in a table; with ``rng``, random frozen-shape scalars."""
    table = LandmarkTable()
    for p in polys:
        if rng is None:
            table.append(p, pivot=0.5 * (p.lo + p.hi), xi_var=0.0, model_var=0.0, fit_half=1.0)
        else:
            table.append(
                p,
                pivot=float(rng.uniform(p.lo, p.hi)),
                xi_var=float(rng.uniform(0.0, 1e-3)),
                model_var=float(rng.uniform(0.0, 1e-3)),
                fit_half=float(rng.uniform(0.1, 2.0)),
            )
    return table


def _cast_both(
    polys: list[Polynomial], pose: np.ndarray, beams: np.ndarray, max_range: float, boxed: bool
) -> tuple[list[tuple[float, ...] | None], list[tuple[float, ...] | None]]:
    table = _table(polys)
    c0s = np.array([p.c0 for p in polys])
    x, y, theta = pose.tolist()
    every = list(range(len(polys)))
    boxes = table.boxes(c0s) if boxed else None
    got = cast(x, y, theta, beams, every, table.arrays(), c0s, max_range, boxes)
    box_list = None if boxes is None else boxes.tolist()
    want = ref.cast(
        x, y, theta, beams.tolist(), every, table.rows(), c0s.tolist(), max_range, box_list
    )
    return [None if h is None else tuple(h) for h in got], [
        None if h is None else tuple(h) for h in want
    ]


# -- measurement model ----------------------------------------------------------------------------
@settings(max_examples=300, deadline=None)
@given(
    polys=st.lists(polynomials(), min_size=1, max_size=6),
    pose=poses,
    beams=beam_sets,
    max_range=st.floats(0.5, 3.0),
    boxed=st.booleans(),
)
def test_cast_scan__bit_identical_to_float_oracle(
    polys: list[Polynomial], pose: np.ndarray, beams: np.ndarray, max_range: float, boxed: bool
) -> None:
    got, want = _cast_both(polys, pose, beams, max_range, boxed)
    assert got == want  # tuples of floats: EXACT equality, including the landmark and variate


@settings(max_examples=60, deadline=None)
@given(polys=st.lists(polynomials(order=5), min_size=1, max_size=3), pose=poses)
def test_cast_scan__orders_4_5_equal_oracle_to_rounding(
    polys: list[Polynomial], pose: np.ndarray
) -> None:
    beams = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])
    c0s = np.array([p.c0 for p in polys])
    for beta in beams:  # a root on a decision edge may go either way with other rounding
        assume(not brute_force_range(pose, pose[2] + beta, polys, c0s, 2.0)[2])
        # two landmarks hit at the same range (they cross there): either is right
        each = [brute_force_range(pose, pose[2] + beta, [p], c0s[i : i + 1], 2.0)[0]
                for i, p in enumerate(polys)]  # fmt: skip
        near = sorted(t for t in each if np.isfinite(t))
        assume(all(b - a > 1e-9 for a, b in itertools.pairwise(near)))
    got, want = _cast_both(polys, pose, beams, 2.0, boxed=True)
    for g, w in zip(got, want, strict=True):
        assert (g is None) == (w is None)
        if g is not None and w is not None:
            assert g[1] == w[1] and g[5] == w[5]  # landmark, variate
            # 1e-12: eigenvalues from zgeev instead of dgeev differ by ~1e-15 before the
            # Newton polish; the slope and D are polynomials in t of O(1) coefficients
            np.testing.assert_allclose(g, w, rtol=0.0, atol=1e-12)


def test_cast_scan__edge_cases_equal_oracle() -> None:
    walls = [
        Polynomial(1, np.array([0.5, 0.0]), 0.0, 1.0),  # y = 0.5 on x ∈ [0, 1]
        Polynomial(2, np.array([1.0, 0.0]), -0.5, 0.5),  # x = 1 on y ∈ [−0.5, 0.5]
        Polynomial(1, np.array([-0.5, 0.0, 1.0]), -0.5, 0.5),  # y = −0.5 + x²: tangent at 0
    ]
    cases = [
        (np.array([-1.0, 0.5, 0.0]), [0.0]),  # along the wall y = 0.5 (on its box edge)
        (np.array([-1.0, 0.5 + 1e-3, 0.0]), [0.0]),  # along the box's widened edge
        (np.array([0.0, 0.0, 0.0]), [-math.pi / 2]),  # straight down onto the parabola's apex
        (np.array([-1.0, -0.5, 0.0]), [0.0]),  # grazing the parabola: a double root at x = 0
        (np.array([1.0, -1.0, math.pi / 2]), [0.0]),  # along x = 1 (the other wall's edge)
        (np.array([0.2, 0.1, 0.3]), np.linspace(-math.pi, math.pi, 13)),
        (np.array([5.0, 5.0, 0.0]), [0.0, 1.0]),  # nothing in range
    ]
    for pose, beams in cases:
        for boxed in (False, True):
            got, want = _cast_both(walls, pose, np.asarray(beams, dtype=float), 2.0, boxed)
            assert got == want, (pose, beams)
    tangent, _ = _cast_both(walls, np.array([-1.0, -0.5, 0.0]), np.array([0.0]), 2.0, True)
    assert tangent[0] is not None and tangent[0][1] == 2  # the grazing beam is found


def test_cast_scan__no_landmarks_and_no_candidates() -> None:
    empty = LandmarkTable()
    assert cast(0.0, 0.0, 0.0, [0.0, 1.0], [], empty.arrays(), np.zeros(0), 2.0) == [None, None]
    wall = _table([Polynomial(1, np.array([0.5, 0.0]), -1.0, 1.0)])
    assert cast(0.0, 0.0, math.pi / 2, [0.0], [], wall.arrays(), [0.5], 2.0) == [None]


def test_cast_scan__300_landmarks_equal_oracle() -> None:
    rng = np.random.default_rng(11)
    walls = make_walls(300, rng)
    for _ in range(20):
        pose = np.array([rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(-np.pi, np.pi)])
        beams = rng.uniform(-np.pi, np.pi, 7)
        got, want = _cast_both(walls, pose, beams, float(rng.uniform(2.0, 8.0)), True)
        assert got == want


# -- the rows of H and R --------------------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(
    polys=st.lists(polynomials(), min_size=1, max_size=6),
    pose=poses,
    beams=beam_sets,
    seed=st.integers(0, 2**32 - 1),
    follows=st.booleans(),
    rotation_states=st.booleans(),
    shift=st.booleans(),
)
def test_beam_rows__bit_identical_to_oracle(
    polys: list[Polynomial],
    pose: np.ndarray,
    beams: np.ndarray,
    seed: int,
    follows: bool,
    rotation_states: bool,
    shift: bool,
) -> None:
    rng = np.random.default_rng(seed)
    table = _table(polys, rng)
    # shape_shift "pose": carried slopes (some unknown: received), the pose's variance now
    # below or above each landmark's at its fit (both branches of the prediction)
    slopes = rng.normal(0.0, 1.0, len(polys))
    slopes[rng.uniform(size=len(polys)) < 0.25] = np.nan
    table.shift_slope[:] = slopes
    pose_var = rng.uniform(0.0, 2e-3, 2)
    c0s = np.array([p.c0 for p in polys])
    ranges = rng.uniform(0.1, 2.0, beams.size)
    boxes = table.boxes(c0s)
    x, y, theta = pose.tolist()
    alpha_base = 3 + len(polys) if rotation_states else -1
    model = ref.RowModel(min_sine=math.sin(math.radians(10.0)), range_sigma=0.02,
                         shape_follows_pose=follows, eps_z=10, alpha_base=alpha_base,
                         shift_with_pose=shift, pose_var=tuple(pose_var.tolist()))  # fmt: skip
    reach = float(rng.uniform(1.0, 6.0))
    every = ref.boxes_near(boxes, np.array([x, x, y, y]), reach)  # the landmarks within reach
    order = rng.permutation(beams.size)  # any subset of beams, in any order
    subset = order[: rng.integers(1, beams.size + 1)]
    turn_var = rng.uniform(0.0, 1e-4, len(polys))  # rad², the heading change since the fit
    want = ref.beam_rows(
        x, y, theta, beams[subset], ranges[subset], every.tolist(), table.rows(), c0s, 2.5,
        boxes[every].tolist(), model, turn_var.tolist(), slopes.tolist(),
    )  # fmt: skip
    width, k = table.shape.shape[1], subset.size
    got = (
        np.empty(k), np.empty((k, 3)), np.empty(k, dtype=np.int64), np.empty(k),
        np.empty(k, dtype=np.int64), np.empty(k), np.empty(k), np.empty(k), np.empty((k, 4)),
    )  # fmt: skip
    used = kernels.beam_rows(
        x, y, theta, beams, ranges, subset, reach, *table.arrays(), c0s, boxes, 2.5,
        model.min_sine, model.range_sigma**2, table.model_var, follows, shift, table.pivot,
        table.xi_var, pose_var, table.shift_slope, turn_var, table.fit_half,
        _fit_inverse_table(model.eps_z + 1, width - 1), model.eps_z + 1, alpha_base, *got,
    )  # fmt: skip
    if want is None:
        assert used == 0
        return
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g[:used], w)  # EXACT


def test_shape_fit_var__bit_identical_to_oracle_over_many_positions() -> None:
    # t ** i is libm's pow in CPython; the kernel must not turn it into products
    rng = np.random.default_rng(5)
    table = _fit_inverse_table(11, 5)
    for alpha_base in (-1, 7):  # the slope's part kept, or left to the rotation state
        model = ref.RowModel(0.0, 0.02, True, 10, alpha_base)
        for order in range(1, 6):
            shape = np.concatenate([[0.0], rng.normal(size=order)])
            for t in np.concatenate([rng.normal(0.0, 2.0, 300), [0.0, 1.0, -1.0, 1e-9]]):
                want = ref.shape_fit_var(tuple(shape.tolist()), float(t), model)
                got = kernels._shape_fit_var(
                    shape, order, float(t), table, 11, model.range_sigma**2, alpha_base >= 0
                )
                assert got == want


@settings(max_examples=100, deadline=None)
@given(
    polys=st.lists(polynomials(), min_size=1, max_size=4),
    pose=poses,
    beams=beam_sets,
    seed=st.integers(0, 2**32 - 1),
    follows=st.booleans(),
    rotation_states=st.booleans(),
)
def test_frozen_offset_var__is_what_beam_rows_adds_to_r_at_the_hit(
    polys: list[Polynomial],
    pose: np.ndarray,
    beams: np.ndarray,
    seed: int,
    follows: bool,
    rotation_states: bool,
) -> None:
    """The map's frozen variance (``PolySlam.map_frozen_variance``) is the update's: at each
    beam's hit, R − σ² = frozen_offset_var / D² (shape_shift "noise"; with "pose" the beam
    predicts part of the shift from the current pose, which the map does not). Relative
    1e-9: the same terms, added in another order, at the hit's ξ rebuilt from its range."""
    rng = np.random.default_rng(seed)
    table = _table(polys, rng)
    c0s = np.array([p.c0 for p in polys])
    n, width = len(polys), table.shape.shape[1]
    alpha_base = 3 + n if rotation_states else -1
    turn_var = rng.uniform(0.0, 1e-4, n)
    fit_inverse = _fit_inverse_table(16, width - 1)
    x, y, theta = pose.tolist()
    checked = 0
    for b in range(beams.size):
        used, rows = _rows_of(table, c0s, pose, beams, alpha_base, follows, np.array([b]), turn_var)
        if used == 0:
            continue
        j, inv_d, t = int(rows[2][0]) - 3, rows[3][0], -rows[0][0]
        phi = theta + beams[b]
        xi = x + t * math.cos(phi) if polys[j].variate == 1 else y + t * math.sin(phi)
        out = np.empty(1)
        kernels.frozen_offset_var(
            table.shape[j], int(table.order[j]), np.array([xi]), table.pivot[j],
            table.fit_half[j], table.model_var[j], table.xi_var[j], table.shift_slope[j],
            turn_var[j], fit_inverse, 16, 4e-4, follows, False, rotation_states, out,
        )  # fmt: skip
        extra = rows[6][0] - 4e-4
        np.testing.assert_allclose(out[0] * inv_d * inv_d, extra, rtol=1e-9, atol=1e-15)
        checked += 1
    assume(checked > 0)


# -- association error ----------------------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(
    polys=st.lists(polynomials(), min_size=1, max_size=6),
    seed=st.integers(0, 2**32 - 1),
    squared=st.booleans(),
)
def test_nearest_by_error__bit_identical_to_oracle(
    polys: list[Polynomial], seed: int, squared: bool
) -> None:
    rng = np.random.default_rng(seed)
    table = _table(polys)
    c0s = np.array([p.c0 for p in polys])
    xy = rng.uniform(-4.0, 4.0, (8, 2))
    candidates = np.flatnonzero(rng.random(len(polys)) < 0.7)
    want = ref.nearest_by_error(
        xy.tolist(), candidates.tolist(), table.rows(), c0s.tolist(), squared
    )
    best, err = np.empty(8, dtype=np.int64), np.empty(8)
    kernels.nearest_by_error(xy, candidates, *table.arrays(), c0s, squared, best, err)
    assert list(zip(best.tolist(), err.tolist(), strict=True)) == want  # EXACT


def test_hypot__bit_identical_to_python() -> None:
    rng = np.random.default_rng(3)
    values = rng.normal(size=(20000, 2)) * 10.0 ** rng.uniform(-300, 300, (20000, 1))
    special = [0.0, -0.0, 5e-324, -5e-324, 1e-310, 1e308, math.inf, -math.inf, math.nan, 3.0]
    values = np.concatenate([values, [[a, b] for a in special for b in special]])
    for a, b in values.tolist():
        got, want = kernels.hypot(a, b), math.hypot(a, b)
        assert got == want or (math.isnan(got) and math.isnan(want)), (a, b)


# -- EKF ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("first", [None, (0.3, -0.2)])
@pytest.mark.parametrize("n_state", [3, 8, 40])
def test_predict__bit_identical_to_oracle(first: tuple[float, float] | None, n_state: int) -> None:
    rng = np.random.default_rng(n_state)
    for _ in range(20):
        mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
        mean[2] = rng.uniform(-10.0, 10.0)
        odometry, w = rng.normal(size=3) * 0.1, random_spd(rng, 3, 1e-4)
        want_mean, want_cov = mean.copy(), cov.copy()
        ref.predict_inplace(want_mean, want_cov, odometry, w, first)
        ekf.predict_inplace(mean, cov, odometry, w, first)
        np.testing.assert_array_equal(mean, want_mean)
        np.testing.assert_array_equal(cov, want_cov)


Rows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _rows(rng: np.random.Generator, k: int, n_state: int) -> Rows:
    innovation = 0.05 * rng.normal(size=k)
    innovation[0] = 5.0  # an outlier the gate drops
    return (
        innovation,
        rng.normal(size=(k, 3)),
        rng.integers(3, n_state, size=k),  # two rows may share a landmark
        rng.normal(size=k),
        rng.uniform(1e-4, 1e-3, size=k),
    )


@pytest.mark.parametrize("n_state", [4, 33, 303])
def test_normalised_innovations__equal_oracle_to_rounding(n_state: int) -> None:
    rng = np.random.default_rng(n_state)
    cov = random_spd(rng, n_state, 0.01)
    rows = _rows(rng, 5, n_state)
    # 1e-13 relative: S_ii summed in the same order, BLAS may fuse the 3×3 products
    np.testing.assert_allclose(
        ekf.normalised_innovations(cov, *rows), ref.normalised_innovations(cov, *rows), rtol=1e-13
    )


@pytest.mark.parametrize("n_state", [4, 33, 303])
@pytest.mark.parametrize("seed", [0, 1])
def test_update_sparse__equals_numpy_oracle_to_rounding(n_state: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
    rows = _rows(rng, 5, n_state)
    want_mean, want_cov = mean.copy(), cov.copy()
    want = ref.update_sparse_inplace(want_mean, want_cov, *rows)
    got = ekf.update_sparse_inplace(mean, cov, *rows)
    np.testing.assert_array_equal(got[0], want[0])
    assert not got[0][0] and got[0][1:].any()
    # 1e-12 relative: the same quantities in another association order (no BLAS, the
    # direct K Wᵀ + W Kᵀ instead of the polarised Z₊Z₊ᵀ − Z₋Z₋ᵀ), S well-conditioned
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
    np.testing.assert_allclose(mean, want_mean, rtol=1e-12, atol=1e-14)
    scale = float(np.abs(want_cov).max())
    np.testing.assert_allclose(cov, want_cov, rtol=0.0, atol=1e-12 * scale)
    assert_symmetric_psd(cov)


def _rotation_rows(rng: np.random.Generator, k: int, n_lm: int) -> tuple[np.ndarray, ...]:
    """Rows on a state [pose, c0 × n_lm, α × n_lm]: each row's α is its landmark's, or none
    (−1, a row whose shape term vanished)."""
    innovation, h_pose, c0_index, h_c0, r = _rows(rng, k, 3 + n_lm)
    alpha_index = c0_index + n_lm
    alpha_index[rng.random(k) < 0.3] = -1
    h_alpha = np.where(alpha_index >= 0, rng.normal(size=k), 0.0)
    return innovation, h_pose, c0_index, h_c0, r, alpha_index, h_alpha


@pytest.mark.parametrize("n_lm", [1, 15, 150])
@pytest.mark.parametrize("considered", [False, True])
def test_update_sparse__with_rotation_states__equals_numpy_oracle(
    n_lm: int, considered: bool
) -> None:
    """Rows that also touch a shape rotation, estimated or considered (Schmidt: the entries
    from 3 + n_lm on get no gain): the compiled update equals the numpy oracle to rounding,
    and a considered block keeps its mean and its own covariance exactly."""
    rng = np.random.default_rng(n_lm)
    n_state = 3 + 2 * n_lm
    mean, cov = rng.normal(size=n_state), random_spd(rng, n_state, 0.01)
    *rows, alpha_index, h_alpha = _rotation_rows(rng, 5, n_lm)
    consider = 3 + n_lm if considered else None
    want_mean, want_cov = mean.copy(), cov.copy()
    kw = {"alpha_index": alpha_index, "h_alpha": h_alpha, "consider_from": consider}
    want = ref.update_sparse_inplace(want_mean, want_cov, *rows, **kw)
    got_mean, got_cov = mean.copy(), cov.copy()
    got = ekf.update_sparse_inplace(got_mean, got_cov, *rows, **kw)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[0][1:].any()
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
    np.testing.assert_allclose(got_mean, want_mean, rtol=1e-12, atol=1e-14)
    scale = float(np.abs(want_cov).max())
    np.testing.assert_allclose(got_cov, want_cov, rtol=0.0, atol=1e-12 * scale)
    assert_symmetric_psd(got_cov)
    nis = ekf.normalised_innovations(cov, *rows, alpha_index=alpha_index, h_alpha=h_alpha)
    np.testing.assert_allclose(nis, ref.normalised_innovations(cov, *rows, alpha_index, h_alpha),
                               rtol=1e-12)  # fmt: skip
    np.testing.assert_allclose(nis, got[1], rtol=1e-12)  # the screen's NIS is the update's
    if considered:
        block = slice(3 + n_lm, n_state)
        np.testing.assert_array_equal(got_mean[block], mean[block])
        np.testing.assert_array_equal(got_cov[block, block], cov[block, block])


@pytest.mark.parametrize(
    ("n_state", "consider_from", "rows"),
    [(31, 17, 5), (31, 31, 5), (31, 3, 5), (8, 5, 5), (31, 16, 5), (8, 2, 3), (31, 1, 5)]
    + [(31, 0, 5), (32, 16, 7), (32, 17, 10), (61, 31, 5), (60, 32, 5), (3, 3, 2)]
    + [(31, 17, rows) for rows in (1, 2, 3, 4, 6, 8, 9, 10, 11, 12, 13)],
)
def test_joseph_blocks__bit_identical_to_the_full_update(
    n_state: int, consider_from: int, rows: int
) -> None:
    """Leaving the considered block out and the cross block's zero products out changes no
    bit: K's considered rows are exact zeros; nor does one pass for up to five rows of K,
    padded with zero rows, nor summing more rows four and two per pass (1 to 13 rows), nor
    two rows of P at a time (an even and an odd number of estimated rows, none or all of them
    considered). The lower triangle (but the pose block) is neither read nor written (nan
    there stays nan and reaches nothing) until :func:`kernels.mirror_lower`."""
    rng = np.random.default_rng(n_state + consider_from + rows)
    cov = random_spd(rng, n_state, 0.01)
    if consider_from < n_state:  # a signed zero in the considered block keeps its sign
        cov[consider_from, consider_from] = -0.0
    kt, wt = rng.normal(size=(rows, n_state)), rng.normal(size=(rows, n_state))
    kt[:, consider_from:] = 0.0
    wt[:, 2] = -0.0  # signed zeros in W must not leak through either
    want, got = cov.copy(), cov.copy()
    ref.joseph_full(want, kt, wt)
    stale = np.tril(np.ones(got.shape, dtype=bool), -1)  # the lower triangle
    stale[:, consider_from:] = False  # but the considered block's
    stale[:3, :3] = False  # and the pose block's
    got[stale] = np.nan  # the kernel must not read it
    kernels.joseph_blocks(got, kt, wt, consider_from)
    assert np.isnan(got[stale]).all()
    kernels.mirror_lower(got, consider_from)
    assert want.tobytes() == got.tobytes()


def test_on_seen_face__a_cast_from_behind_is_out() -> None:
    """Every case of the rule against its reading: a ray crossing a curve towards +η (D > 0)
    comes from the −η side; a landmark seen only from the other side is met from behind."""
    sides = np.array([-1, 0, 1], dtype=np.int64)
    for j in (-1, 0, 1, 2):
        for d in (-0.7, -0.0, 0.0, 0.4):
            out = np.empty(1, np.bool_)
            kernels.on_seen_face(np.array([j]), np.array([d]), sides, out)
            ray_side = -1 if d > 0 else (1 if d < 0 else 0)
            behind = j >= 0 and sides[j] != 0 and ray_side != 0 and sides[j] != ray_side
            assert bool(out[0]) is not behind, (j, d)


def test_update_scan__one_cast_equals_two_casts_bit_for_bit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The update's sigma-point test and its rows share one scan model and one cast at the
    mean: every update of a paper-map team episode (random actions, 3 robots, 300 steps) and
    of 60 steps among 30 random walls gives the floats of the composition that cast twice
    (``ref.update_scan_two_casts``), including updates where the sigma points dropped beams."""
    from polyslam_env.apps.benchmark_harness import ENV_CONFIG, random_stepper
    from polyslam_env.environment.parallel import parallel_env
    from polyslam_env.slam.columns import (
        P_END_SIGMA,
        P_MAX_RANGE,
        P_MIN_SINE,
        P_REACH,
        SIDE,
        VARIATE,
    )

    compiled = kernels.update_scan
    seen = {"updates": 0, "dropped": 0, "faces": 0}
    flip: dict[str, int] = {}

    def checked(
        mean: np.ndarray, cov: np.ndarray, angles: np.ndarray, ranges: np.ndarray,
        beams: np.ndarray, assigned: np.ndarray, real: np.ndarray, index: np.ndarray, *rest: Any,
    ) -> int:  # fmt: skip
        shape, n, params, switches, _, step = rest
        if flip:
            index[SIDE, flip.pop("wall")] = 1
        steady = np.empty(beams.size, np.bool_)
        near, _, _ = kernels._scan_model(mean, real, index, n, params, switches, step)
        kept = kernels.steady_beams(
            mean, cov, angles, beams, assigned, params[P_REACH], index[VARIATE, :n],
            index[ORDER, :n], shape[:n], real[kernels.LO, :n], real[kernels.HI, :n], near,
            params[P_MAX_RANGE], params[P_MIN_SINE], n, params[P_END_SIGMA], steady,
        )  # fmt: skip
        seen["updates"] += 1
        seen["dropped"] += int(kept < beams.size)
        facing, _ = ref.seen_face_beams(
            mean, angles, beams, assigned, real, index, shape, n, params, switches, step
        )
        seen["faces"] += int(facing.size < beams.size)
        want_mean, want_cov, want_index = mean.copy(), cov.copy(), index.copy()
        want = ref.update_scan_two_casts(
            want_mean, want_cov, angles, ranges, beams, assigned, real, want_index, *rest
        )
        got = compiled(mean, cov, angles, ranges, beams, assigned, real, index, *rest)
        assert got == want
        assert mean.tobytes() == want_mean.tobytes() and cov.tobytes() == want_cov.tobytes()
        assert index.tobytes() == want_index.tobytes()
        return got

    monkeypatch.setattr(step_kernels, "finish_step", step_kernels.finish_step.py_func)
    monkeypatch.setattr(kernels, "update_scan", checked)
    step = random_stepper(parallel_env(**ENV_CONFIG), 0)
    for _ in range(300):
        step()
    rng = np.random.default_rng(1)
    walls = make_walls(30, rng)
    slam = make_slam(walls, SlamConfig(seen_faces=True))
    # after the first step's association, the wall at y = +0.5 as if seen only from above:
    # the beams associated with it meet it from behind, and the update leaves them out
    flip["wall"] = 0
    for odometry, ranges in make_inputs(walls, 60, rng):
        slam.step(odometry, ranges)
    assert seen["updates"] > 500 and seen["dropped"] > 0 and seen["faces"] > 0, seen


def test_slam_steps__compiled_update_tracks_numpy_update_over_a_short_horizon(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The one kernel that is not bit-identical moves a SLAM run by rounding only: 100
    steps with 30 landmarks (every beam updates every step) stay within 1e-12 (relative to the
    state's size) of the same run with the numpy update."""
    rng = np.random.default_rng(0)
    walls = make_walls(30, rng)
    inputs = make_inputs(walls, 100, rng)
    compiled = make_slam(walls)
    for odometry, ranges in inputs:
        compiled.step(odometry, ranges)
    # the step's second call run as Python, with the numpy update in place of the compiled one
    monkeypatch.setattr(step_kernels, "finish_step", step_kernels.finish_step.py_func)
    monkeypatch.setattr(kernels, "update_scan", ref.update_scan)
    numpy_run = make_slam(walls)
    for odometry, ranges in inputs:
        numpy_run.step(odometry, ranges)
    np.testing.assert_allclose(compiled.mean, numpy_run.mean, rtol=0.0, atol=1e-12)
    scale = float(np.abs(numpy_run.cov).max())
    np.testing.assert_allclose(compiled.cov, numpy_run.cov, rtol=0.0, atol=1e-12 * scale)


# -- boxes ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [0, 1, 30, 300])
def test_boxes__bit_identical_to_oracle(n: int) -> None:
    rng = np.random.default_rng(n)
    walls = make_walls(max(n, 3), rng)[:n]
    table = _table(walls)
    c0s = rng.normal(size=n)
    want = ref.boxes(c0s, table.variate, table.lo, table.hi, table.eta_range)
    got = table.boxes(c0s)
    np.testing.assert_array_equal(got, want)
    for _ in range(10):
        box = (
            np.sort(rng.uniform(-12.0, 12.0, 2)).tolist()
            + np.sort(rng.uniform(-12, 12, 2)).tolist()
        )
        distance = float(rng.uniform(0.0, 5.0))
        np.testing.assert_array_equal(
            boxes_near(got, np.array(box), distance), ref.boxes_near(got, np.array(box), distance)
        )


def test_nearest_by_error__rejects_candidates_outside_the_map() -> None:
    table = _table([Polynomial(1, np.array([0.5, 0.0]), -1.0, 1.0)])
    with pytest.raises(IndexError, match="candidate"):
        nearest_by_error([[0.0, 0.0]], [1], table.arrays(), [0.5])
    assert nearest_by_error([[0.0, 0.0]], [0], table.arrays(), [0.5]) == [(0, 0.5)]


# -- R of one update: the landmark's error the beams on it share ------------------------------
def test_share_landmark_error__matches_oracle_and_bounds_the_joint_covariance() -> None:
    """Rows with variance σ_r² + s_i², grouped by landmark: the kernel's diagonal equals the
    oracle's (σ_r² + n s_i² for n rows on one landmark) and bounds each group's true
    covariance σ_r² I + s sᵀ (PSD difference, to rounding); a lone row keeps its variance."""
    rng = np.random.default_rng(11)
    noise = 0.02**2
    for _ in range(50):
        k = int(rng.integers(1, 12))
        c0_index = rng.integers(3, 8, k).astype(np.int64)
        shared = rng.uniform(0.0, 5e-4, k)
        own = noise + shared
        got = own.copy()
        kernels.share_landmark_error(c0_index, got, noise, np.ones(8))
        np.testing.assert_allclose(got, ref.share_landmark_error(c0_index, own, noise), rtol=1e-15)
        for lm in np.unique(c0_index):
            on = c0_index == lm
            s = np.sqrt(own[on] - noise)
            if on.sum() == 1:
                assert got[on][0] == own[on][0]
            gap = np.diag(got[on]) - (noise * np.eye(on.sum()) + np.outer(s, s))
            assert np.linalg.eigvalsh(gap).min() >= -1e-15


# -- beams whose hit may pass a landmark's end -----------------------------------------------------
def _rows_of(
    table: LandmarkTable,
    c0s: np.ndarray,
    pose: np.ndarray,
    angles: np.ndarray,
    alpha_base: int,
    follows: bool = True,
    wanted: np.ndarray | None = None,
    turn_var: np.ndarray | None = None,
) -> tuple[int, tuple[np.ndarray, ...]]:
    """Every beam's row on ``table`` (kernels.beam_rows, zero readings), or the ``wanted``
    beams' only; ``turn_var`` each landmark's heading drift since its fit (default 0)."""
    wanted = np.arange(angles.size) if wanted is None else wanted
    turn_var = np.zeros(len(table)) if turn_var is None else turn_var
    k = wanted.size
    rows = (
        np.empty(k), np.empty((k, 3)), np.empty(k, dtype=np.int64), np.empty(k),
        np.empty(k, dtype=np.int64), np.empty(k), np.empty(k), np.empty(k), np.empty((k, 4)),
    )  # fmt: skip
    used = kernels.beam_rows(
        *pose.tolist(), angles, np.zeros(angles.size), wanted, math.inf, *table.arrays(), c0s,
        table.boxes(c0s), 10.0, math.sin(math.radians(10.0)), 4e-4, table.model_var, follows,
        False, table.pivot, table.xi_var, np.zeros(2), table.shift_slope, turn_var,
        table.fit_half,
        _fit_inverse_table(16, table.shape.shape[1] - 1), 16, alpha_base, *rows,
    )  # fmt: skip
    return used, rows


@settings(max_examples=100, deadline=None)
@given(polys=st.lists(polynomials(), min_size=1, max_size=4), pose=poses, beams=beam_sets,
       seed=st.integers(0, 2**32 - 1), rotation_states=st.booleans())  # fmt: skip
def test_ends_in_doubt__equals_dense_oracle(
    polys: list[Polynomial], pose: np.ndarray, beams: np.ndarray, seed: int, rotation_states: bool
) -> None:
    """σ_ξ of each row's hit from the kernel's sparse J P Jᵀ equals the oracle's dense one (to
    rounding: keep differs from the oracle's only within 1e-9 of the threshold)."""
    rng = np.random.default_rng(seed)
    table = _table(polys, rng)
    c0s = np.array([p.c0 for p in polys])
    n = len(polys)
    alpha_base = 3 + n if rotation_states else -1
    used, rows = _rows_of(table, c0s, pose, beams, alpha_base)
    assume(used > 0)
    _, h_pose, c0_index, h_c0, alpha_index, h_alpha, _, room, grad = (r[:used] for r in rows)
    cov = random_spd(rng, 3 + 2 * n, 1e-3)
    var = ref.xi_variances(cov, h_pose, c0_index, h_c0, alpha_index, h_alpha, grad)
    for end_sigma in (0.5, 2.0):
        keep = np.empty(used, np.bool_)
        kept = kernels.ends_in_doubt(
            cov, h_pose, c0_index, h_c0, alpha_index, h_alpha, room, grad, end_sigma, keep
        )
        want = room >= end_sigma * np.sqrt(var)
        near = np.abs(room - end_sigma * np.sqrt(var)) <= 1e-9
        assert np.array_equal(keep[~near], want[~near]) and kept == keep.sum()


@settings(max_examples=100, deadline=None)
@given(polys=st.lists(polynomials(), min_size=1, max_size=4), pose=poses, beams=beam_sets,
       seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-5, 1e-3, 1e-1]))  # fmt: skip
def test_steady_beams__equals_sigma_point_oracle(
    polys: list[Polynomial], pose: np.ndarray, beams: np.ndarray, seed: int, scale: float
) -> None:
    """A beam is dropped exactly when the float oracle's cast at the mean hits another
    landmark than the one it was assigned to (−1: any), or when it hits landmark j at the mean
    (above the tangent limit) and the cast from one of the 8 sigma points, the mean ± 2 times
    a column of the Cholesky factor of P over (x, y, θ, c0_j), does not hit j above that
    limit."""
    rng = np.random.default_rng(seed)
    table = _table(polys)
    c0s = np.array([p.c0 for p in polys])
    n, max_range, min_sine, spread = len(polys), 10.0, math.sin(math.radians(10.0)), 2.0
    cov = random_spd(rng, 3 + n, scale)
    mean = np.concatenate([pose, c0s])
    keep = np.empty(beams.size, np.bool_)
    assigned = rng.integers(-1, n, beams.size)
    kept = kernels.steady_beams(
        mean, cov, beams, np.arange(beams.size), assigned, math.inf, *table.arrays(),
        table.boxes(c0s), max_range, min_sine, n, spread, keep,
    )  # fmt: skip
    every, rows = list(range(n)), table.rows()

    def usable_hit(x: float, y: float, theta: float, angle: float, c0: np.ndarray) -> int:
        """The landmark the beam hits above the tangent limit, −1 for none."""
        hit = ref.cast(x, y, theta, [angle], every, rows, c0.tolist(), max_range)[0]
        if hit is None or abs(hit.denom) / math.hypot(1.0, hit.slope) < min_sine:
            return -1
        return hit.landmark

    for b, angle in enumerate(beams.tolist()):
        hit = ref.cast(*pose.tolist(), [angle], every, rows, c0s.tolist(), max_range)[0]
        if hit is not None and assigned[b] >= 0 and hit.landmark != assigned[b]:
            assert not keep[b], (b, hit.landmark, assigned[b])
            continue
        j = usable_hit(*pose.tolist(), angle, c0s)
        want = True
        if j >= 0:
            index = [0, 1, 2, 3 + j]
            factor = _cholesky(cov[np.ix_(index, index)].tolist())
            for sign, column in itertools.product((spread, -spread), range(4)):
                d = sign * factor[:, column]
                c0 = c0s.copy()
                c0[j] += d[3]
                if usable_hit(*(pose + d[:3]).tolist(), angle, c0) != j:
                    want = False
        assert keep[b] == want, (b, j)
    assert kept == keep.sum()


def _cholesky(p: list[list[float]]) -> np.ndarray:
    """L with L Lᵀ = p, in Python floats, element by element in the textbook order (the
    kernel's; LAPACK's blocked order rounds differently, and a sigma point's ray that grazes an
    extent's end then lands on the other side of it)."""
    n = len(p)
    out = [[0.0] * n for _ in range(n)]
    for j in range(n):
        diag = p[j][j]
        for k in range(j):
            diag -= out[j][k] * out[j][k]
        out[j][j] = math.sqrt(diag)
        for i in range(j + 1, n):
            acc = p[i][j]
            for k in range(j):
                acc -= out[i][k] * out[j][k]
            out[i][j] = acc / out[j][j]
    return np.array(out)


@pytest.mark.parametrize("variate", [1, 2])
def test_beam_rows__xi_gradient_equals_finite_differences(variate: int) -> None:
    """∂ξ*/∂(x, y, θ, c0) = xi_grad[:3] + dξ·h (the rows ``ends_in_doubt`` builds J from)
    equals the central difference of the hit's ξ* (the oracle's brute cast) with the pose or
    c0 moved by ±1e-6: truncation O(ε²·ξ''') and rounding O(1e-16/ε) ≈ 1e-10, below 1e-6."""
    poly = Polynomial(variate, np.array([0.9, 0.15, -0.2, 0.05]), -1.5, 1.5)
    table = _table([poly])
    c0 = np.array([poly.c0])
    pose = np.array([0.1, -0.2, 0.3]) if variate == 1 else np.array([-0.2, 0.1, 1.6])
    angles = np.linspace(-0.9, 0.9, 7) + (math.pi / 2 - pose[2] if variate == 1 else -pose[2])
    used, rows = _rows_of(table, c0, pose, angles, -1, follows=False)  # the geometry alone
    assert used >= 4, "the pose must see the curve with several beams"
    _, h_pose, _, h_c0, _, _, _, _, grad = (r[:used] for r in rows)

    def xis(p: np.ndarray, c: float) -> list[float]:
        hits = ref.cast(*p.tolist(), angles.tolist(), [0], table.rows(), [c], 10.0)
        return [h.xi for h in hits if h is not None]

    eps = 1e-6
    analytic = np.column_stack([grad[:, :3] + grad[:, 3:] * h_pose, grad[:, 3] * h_c0])
    for a in range(4):
        step = np.zeros(3)
        if a < 3:
            step[a] = eps
        dc = eps if a == 3 else 0.0
        plus, minus = xis(pose + step, c0[0] + dc), xis(pose - step, c0[0] - dc)
        assert len(plus) == len(minus) == used
        numeric = (np.array(plus) - np.array(minus)) / (2 * eps)
        np.testing.assert_allclose(analytic[:, a], numeric, rtol=1e-6, atol=1e-6)


def _weights_over_updates(index: np.ndarray, mode: int, updates: int) -> np.ndarray:
    """(updates, n): each landmark's ``reuse_factors`` weight in updates 1 … ``updates``, its
    uses counted between them as ``update_scan`` counts them (one per update it enters)."""
    rows = []
    for _ in range(updates):
        out = np.empty(index.shape[1])
        kernels.reuse_factors(index, index.shape[1], mode, out)
        rows.append(out)
        index[USES] += 1
    return np.array(rows)


def test_reuse_factors__bound_one_frozen_error_over_all_the_updates_it_enters() -> None:
    """A landmark's own error e (variance s²) is the same in every update its beams enter:
    over U updates the rows' errors have covariance s² 11ᵀ. With the kernel's weights
    (u(u + 1) in the u-th) the diagonal s²·w_u bounds it (PSD difference) for every U, and
    with share_landmark_error's n rows per update too; counting each update as fresh noise
    (weights 1, as before ``slam.reuse_bound``) does not, from U = 2 on. Lines are left alone
    under "curved", nothing under "none"."""
    s2 = 1e-4
    index = np.zeros((N_INDEX, 3), dtype=np.int64)
    index[ORDER] = [1, 2, 3]
    weights = _weights_over_updates(index.copy(), 1, 60)  # "curved"
    np.testing.assert_array_equal(weights[:, 0], 1.0)
    np.testing.assert_array_equal(weights[:, 1], weights[:, 2])
    for updates in (1, 2, 5, 60):
        for per_update in (1, 3):  # rows on the landmark in each update
            w = np.repeat(weights[:updates, 1], per_update) * per_update
            gap = s2 * np.diag(w) - s2 * np.ones((w.size, w.size))
            assert np.linalg.eigvalsh(gap)[0] >= -1e-12 * s2 * w.max(), (updates, per_update)
            fresh = np.full(w.size, float(per_update))  # every update fresh noise
            gap = s2 * np.diag(fresh) - s2 * np.ones((w.size, w.size))
            assert (np.linalg.eigvalsh(gap)[0] < 0) == (updates > 1)
    assert np.all(_weights_over_updates(index.copy(), 2, 5)[:, 0] > 1.0)  # "all": lines too
    np.testing.assert_array_equal(_weights_over_updates(index.copy(), 0, 5), 1.0)  # "none"

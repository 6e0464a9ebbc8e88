"""Tests of polyslam_env.metrics: NEES, mapping error ν, completeness and coverage."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from polyslam_env import metrics as M
from polyslam_env.core.geometry import transform_points
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.layout import Layout, point_segment_distance

SIDE = 4.0
PERIMETER = 4 * SIDE


def square_room(pillars: np.ndarray | None = None) -> Layout:
    wall = np.array([[0.0, 0.0], [SIDE, 0.0], [SIDE, SIDE], [0.0, SIDE], [0.0, 0.0]])
    return Layout("square", (wall,), pillars=np.zeros((0, 3)) if pillars is None else pillars)


def to_robot_frame(poses_abs: np.ndarray, start_pose: np.ndarray) -> np.ndarray:  # (K, 3)
    """Inverse of pose_to_absolute, written independently for the tests."""
    c, s = math.cos(start_pose[2]), math.sin(start_pose[2])
    dx, dy = poses_abs[:, 0] - start_pose[0], poses_abs[:, 1] - start_pose[1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, poses_abs[:, 2] - start_pose[2]])


def spd_from(factors: np.ndarray) -> np.ndarray:  # (k, 3, 3)
    """Pose covariances A Aᵀ + 1e-4 I from factors (k, 3, 3) of unit scale, rows scaled to
    5 cm, 5 cm and 0.02 rad."""
    a = factors * np.array([0.05, 0.05, 0.02])[:, None]
    return np.asarray(a @ np.swapaxes(a, 1, 2) + 1e-4 * np.eye(3))


def random_spd(rng: np.random.Generator, k: int) -> np.ndarray:  # (k, 3, 3)
    return spd_from(rng.normal(size=(k, 3, 3)))


# -- frames and NEES ------------------------------------------------------------------------
def test_nees__zero_when_estimate_equals_truth() -> None:
    rng = np.random.default_rng(0)
    start = np.array([1.0, -2.0, 2.5])
    truth = np.column_stack([rng.uniform(0, 4, (50, 2)), rng.uniform(-np.pi, np.pi, 50)])
    est = to_robot_frame(truth, start)
    covs = random_spd(rng, 50)
    # 1e-20: the residual is only float round-off (~1e-16 m) squared over variances ~1e-3
    assert M.nees(truth, est, covs, start) < 1e-20
    assert M.nees_paper(truth, est, covs, start) < 1e-20


def test_nees__mean_is_dof_for_errors_drawn_from_covariance() -> None:
    rng = np.random.default_rng(1)
    k = 20000
    start = np.array([0.5, 0.2, -1.1])
    covs = random_spd(rng, k)
    est = np.column_stack([rng.uniform(-1, 1, (k, 2)), rng.uniform(-1, 1, k)])
    cov_abs = M.cov_to_absolute(covs, start)
    err = np.einsum("kij,kj->ki", np.linalg.cholesky(cov_abs), rng.normal(size=(k, 3)))
    truth = M.pose_to_absolute(est, start) + err
    # The mean of k χ²(3) draws has std √(2·3/k) ≈ 0.017; 5 std keeps false failures negligible.
    assert abs(M.nees(truth, est, covs, start) - 3.0) < 5 * math.sqrt(6 / k)


def test_nees__rotated_start_pose_matches_hand_computed_value() -> None:
    start = np.array([1.0, 2.0, np.pi / 2])
    est = np.array([[1.0, 0.0, 0.0]])  # absolute (1, 3, π/2)
    cov = np.diag([0.01, 0.04, 0.01])[None]  # robot-frame y variance becomes absolute x
    truth = np.array([[1.1, 3.0, np.pi / 2]])  # error (0.1, 0, 0) along absolute x
    np.testing.assert_allclose(M.pose_to_absolute(est, start), [[1.0, 3.0, np.pi / 2]], atol=1e-12)
    # rtol 1e-9: exact arithmetic apart from cos(π/2) ≈ 6e-17 round-off
    assert M.nees(truth, est, cov, start) == pytest.approx(0.01 / 0.04, rel=1e-9)
    assert M.nees_paper(truth, est, cov, start) == pytest.approx(0.01 * 0.04, rel=1e-9)


def test_nees__heading_error_near_two_pi_counts_as_small() -> None:
    eps, sigma = 1e-3, 0.01
    truth = np.array([[0.0, 0.0, 2 * np.pi - eps]])
    est = np.zeros((1, 3))
    cov = np.diag([1.0, 1.0, sigma**2])[None]
    # rel 1e-6: 2π − ε loses ~1e-16 absolute to round-off, i.e. ~1e-13 relative to ε
    assert M.nees(truth, est, cov, np.zeros(3)) == pytest.approx((eps / sigma) ** 2, rel=1e-6)


def test_wrap_angle__lands_in_half_open_interval() -> None:
    a = np.array([np.pi, -np.pi, 3 * np.pi, 0.0, -0.5, 7.0])
    w = M.wrap_angle(a)
    assert np.all((w > -np.pi) & (w <= np.pi))
    # 1e-12: a few ulps of 2π-multiples
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    assert w[1] == pytest.approx(np.pi)


def _floats(shape: tuple[int, ...], lo: float, hi: float) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(np.float64, shape, elements=st.floats(lo, hi))


@settings(deadline=None, max_examples=30)
@given(
    x0=st.floats(-5, 5),
    y0=st.floats(-5, 5),
    th=st.floats(-np.pi, np.pi),
    est=_floats((5, 3), -3.0, 3.0),
    noise=_floats((5, 3), 0.01, 0.1),
    signs=hnp.arrays(np.bool_, (5, 3)),
    factors=_floats((5, 3, 3), -2.0, 2.0),
)
def test_nees__invariant_to_start_pose(
    x0: float,
    y0: float,
    th: float,
    est: np.ndarray,
    noise: np.ndarray,
    signs: np.ndarray,
    factors: np.ndarray,
) -> None:
    # errors of 1–10 cm either way: the relative tolerance below needs them away from 0
    truth_rel = est + np.where(signs, noise, -noise)
    covs = spd_from(factors)
    start = np.array([x0, y0, th])
    truth_abs = M.pose_to_absolute(truth_rel, start)
    base = M.nees_series(truth_rel, est, covs, np.zeros(3))
    # rel 1e-6: rotating by θ0 and wrapping loses ~1e-15 rad per entry on errors ~0.05
    np.testing.assert_allclose(M.nees_series(truth_abs, est, covs, start), base, rtol=1e-6)
    np.testing.assert_allclose(
        M.nees_paper_series(truth_abs, est, covs, start),
        M.nees_paper_series(truth_rel, est, covs, np.zeros(3)),
        rtol=1e-6,
    )


def test_nees_paper__equals_explicit_quadratic_form() -> None:
    rng = np.random.default_rng(2)
    est = rng.normal(size=(4, 3))
    truth = est + rng.normal(scale=0.01, size=(4, 3))
    covs = random_spd(rng, 4)
    expected = np.mean([(t - e) @ c @ (t - e) for t, e, c in zip(truth, est, covs, strict=True)])
    # rel 1e-9: same sums in a different order
    assert M.nees_paper(truth, est, covs, np.zeros(3)) == pytest.approx(expected, rel=1e-9)


def test_nees__rejects_mismatched_shapes() -> None:
    with pytest.raises(ValueError, match="shapes disagree"):
        M.nees(np.zeros((3, 3)), np.zeros((2, 3)), np.tile(np.eye(3), (2, 1, 1)), np.zeros(3))


def test_nees_band__matches_chi2_table_and_narrows_with_runs() -> None:
    lo, hi = M.nees_band(3, 1, 0.95)
    # χ²(3) 2.5 % and 97.5 % quantiles from tables, printed to 3 decimals
    assert lo == pytest.approx(0.216, abs=1e-3)
    assert hi == pytest.approx(9.348, abs=1e-3)
    lo50, hi50 = M.nees_band(3, 50, 0.95)
    assert lo < lo50 < 3.0 < hi50 < hi


# -- boundary, mapping error, completeness ----------------------------------------------------
def test_boundary_samples__weights_sum_to_length_and_points_lie_on_boundary() -> None:
    layout = square_room(np.array([[2.0, 2.0, 0.3]]))
    pts, w = M.boundary_samples(layout, 0.01)
    # 1e-9: sums of ~1700 lengths each exact to ~1e-16
    assert w.sum() == pytest.approx(layout.boundary_length(), rel=1e-9)
    assert w.max() <= 0.01 + 1e-12
    # pillar samples sit on the circle (clearance 0); 1e-12 is round-off
    assert np.abs(layout.clearance(pts)).max() < 1e-12
    assert M.boundary_points(layout, 0.01) is pts  # cached


def test_map__polynomial_on_a_wall_has_zero_error() -> None:
    layout = square_room()
    poly = Polynomial(1, np.zeros(4), 0.5, 3.5)
    # ≤ 1 mm: the documented accuracy of distance_to_boundary
    assert M.nu_mean([poly], np.zeros(3), layout) <= 1e-3
    assert M.nu([poly], np.zeros(3), layout) <= 1e-3 * len(poly.sample_arclength(0.01))


def test_map__offset_polynomial_has_error_of_the_offset() -> None:
    layout = square_room()
    poly = Polynomial(1, np.array([0.1, 0.0, 0.0, 0.0]), 0.5, 3.5)
    n_pts = len(poly.sample_arclength(0.01))
    # 1 mm: the documented accuracy of distance_to_boundary (here it is exact)
    assert M.nu_mean([poly], np.zeros(3), layout) == pytest.approx(0.1, abs=1e-3)
    assert M.nu([poly], np.zeros(3), layout) == pytest.approx(0.1 * n_pts, abs=1e-3 * n_pts)


def test_map__nu_averages_per_polynomial_sums() -> None:
    layout = square_room()
    polys = [
        Polynomial(1, np.array([0.1, 0.0]), 0.5, 1.5),
        Polynomial(2, np.array([3.8, 0.0]), 1.0, 3.0),  # x = 3.8: 0.2 from the right wall
    ]
    ds = M.map_distances(polys, np.zeros(3), layout)
    assert [len(d) for d in ds] == [len(p.sample_arclength(0.01)) for p in polys]
    expected = (0.1 * len(ds[0]) + 0.2 * len(ds[1])) / 2
    # 1e-3 per point: the documented distance accuracy
    assert M.nu(polys, np.zeros(3), layout) == pytest.approx(expected, abs=1e-3 * 300)


def test_map__empty_map_conventions() -> None:
    layout = square_room()
    assert M.nu([], np.zeros(3), layout) == 0.0
    assert M.nu_mean([], np.zeros(3), layout) == 0.0  # with has_map 0 beside it
    assert M.has_map([]) == 0.0
    assert M.completeness([], np.zeros(3), layout) == 0.0
    assert M.map_distances([], np.zeros(3), layout) == []


def test_completeness__one_wall_of_four_is_a_quarter() -> None:
    layout = square_room()
    tol, step = 0.05, 0.01
    poly = Polynomial(1, np.zeros(2), 0.0, SIDE)
    c = M.completeness([poly], np.zeros(3), layout, tol=tol, step=step)
    # Besides the wall itself, the neighbouring walls count for `tol` at each end; each of the
    # 2 ends of that band is decided per boundary piece, off by at most one `step`.
    assert abs(c - 0.25) <= (2 * tol + 2 * step) / PERIMETER
    assert abs(c - (SIDE + 2 * tol) / PERIMETER) <= 2 * step / PERIMETER


def test_map__robot_frame_polynomial_lands_on_the_right_wall() -> None:
    layout = square_room()
    start = np.array([1.0, 0.5, np.pi / 2])
    # in the start frame, absolute (x, y) = (1 − v, 0.5 + u): v = −3 is x = 4, u ∈ [0.5, 2.5]
    poly = Polynomial(1, np.array([-3.0, 0.0]), 0.5, 2.5)
    assert M.nu_mean([poly], start, layout) <= 1e-3  # documented distance accuracy
    pts = M.map_points([poly], start)[0]
    # 1e-12: round-off of cos(π/2)
    np.testing.assert_allclose(pts[:, 0], SIDE, atol=1e-12)
    c = M.completeness([poly], start, layout)
    # a 2 m stretch mid-wall grows by tol = 0.05 at both ends; each end is off by ≤ one step
    assert c == pytest.approx((2.0 + 2 * 0.05) / PERIMETER, abs=2 * 0.01 / PERIMETER)
    # the same polynomial read without the start pose lands elsewhere
    assert M.nu_mean([poly], np.zeros(3), layout) > 0.5


def brute_force_distances(points: np.ndarray, layout: Layout) -> np.ndarray:  # (N,)
    d = point_segment_distance(points, layout.segments).min(axis=1)
    for x, y, r in layout.pillars:
        d = np.minimum(d, np.abs(np.hypot(points[:, 0] - x, points[:, 1] - y) - r))
    return d


@settings(deadline=None, max_examples=25)
@given(
    variate=st.sampled_from([1, 2]),
    th=st.floats(-np.pi, np.pi),
    lo=st.floats(-1.5, 1.0),
    length=st.floats(0.1, 2.0),
    c0=st.floats(-1.5, 1.5),
    higher=st.tuples(st.floats(-1.5, 1.5), st.floats(-0.6, 0.6), st.floats(-0.3, 0.3)),
    at=st.tuples(st.floats(0.5, 3.5), st.floats(0.5, 3.5)),
)
def test_map_distances__match_brute_force(
    variate: int,
    th: float,
    lo: float,
    length: float,
    c0: float,
    higher: tuple[float, float, float],
    at: tuple[float, float],
) -> None:
    """A cubic (slope, curvature and cubic term up to 3σ of the normal draws this replaced)
    placed anywhere in a square room with two pillars."""
    layout = square_room(np.array([[1.5, 2.5, 0.2], [3.0, 1.0, 0.1]]))
    polys = [Polynomial(variate, np.array([c0, *higher]), lo, lo + length)]
    start = np.array([*at, th])
    got = np.concatenate(M.map_distances(polys, start, layout))
    pts = np.vstack(M.map_points(polys, start))
    want = brute_force_distances(pts, layout)
    # documented: never below the exact distance, at most 1 mm above; 1e-12 is round-off
    assert np.all(got >= want - 1e-12)
    assert np.all(got <= want + 1e-3)


def test_distance_to_boundary__exact_on_a_many_segment_map() -> None:
    rng = np.random.default_rng(3)
    walls = tuple(
        np.cumsum(rng.normal(0, 0.1, (60, 2)), axis=0) + rng.uniform(0, 6, 2) for _ in range(5)
    )
    layout = Layout("walk", walls)
    pts = rng.uniform(-1, 7, (500, 2))
    want = brute_force_distances(pts, layout)
    got = M.distance_to_boundary(pts, layout)
    # documented: never below the exact distance, at most 1 mm above; 1e-12 is round-off
    assert np.all(got >= want - 1e-12)
    assert np.all(got <= want + 1e-3)


def test_hit_fraction__covers_the_hit_stretch_and_ignores_no_returns() -> None:
    layout = square_room()
    xs = np.arange(1.0, 2.0 + 1e-9, 0.02)
    hits = np.vstack([np.column_stack([xs, np.full_like(xs, SIDE)]), [[np.inf, np.inf]]])
    f = M.hit_fraction(hits, layout, tol=0.05)
    # the hit stretch (1 m) grows by tol at both ends; each end is off by at most one step
    assert f == pytest.approx((1.0 + 2 * 0.05) / PERIMETER, abs=2 * 0.01 / PERIMETER)
    assert M.hit_fraction(np.zeros((0, 2)), layout) == 0.0


# -- coverage -------------------------------------------------------------------------------
def chord_in_cell(o: np.ndarray, a: float, length: float, box: tuple[float, ...]) -> float:
    """Length of the segment o + t(cos a, sin a), t ∈ [0, length], inside the box; −1 if none."""
    d = (math.cos(a), math.sin(a))
    t0, t1 = 0.0, length
    for axis, (lo, hi) in enumerate(((box[0], box[2]), (box[1], box[3]))):
        if abs(d[axis]) < 1e-15:
            if not lo <= o[axis] <= hi:
                return -1.0
            continue
        ta, tb = sorted(((lo - o[axis]) / d[axis], (hi - o[axis]) / d[axis]))
        t0, t1 = max(t0, ta), min(t1, tb)
    return t1 - t0 if t1 >= t0 else -1.0


def brute_force_sweep(
    free: np.ndarray, origin: tuple[float, float], res: float, beams: list[tuple]
) -> np.ndarray:  # (H, W)
    """Per cell, the longest chord of any beam inside it (−1 if none touches it)."""
    h, w = free.shape
    best = np.full((h, w), -1.0)
    for o, a, length in beams:
        for i in range(h):
            for j in range(w):
                box = (origin[0] + j * res, origin[1] + i * res)
                box = (*box, box[0] + res, box[1] + res)
                best[i, j] = max(best[i, j], chord_in_cell(o, a, length, box))
    return best


def test_coverage_grid__agrees_with_brute_force_cell_check() -> None:
    rng = np.random.default_rng(4)
    res, origin = 0.1, (-0.3, 0.2)
    free = rng.uniform(size=(12, 14)) > 0.2
    grid = M.CoverageGrid(free, origin, res)
    beams = []
    for _ in range(6):
        o = rng.uniform([origin[0], origin[1]], [origin[0] + 1.4, origin[1] + 1.2], (3, 2))
        a = rng.uniform(-np.pi, np.pi, 3)
        r = np.array([rng.uniform(0.1, 0.8), np.inf, np.nan])
        grid.sweep(o, a, r, max_range=0.9)
        beams += [(o[k], a[k], min(r[k], 0.9) if np.isfinite(r[k]) else 0.9) for k in range(3)]
    best = brute_force_sweep(free, origin, res, beams)
    # 1e-9: round-off of the chord lengths; res/2 is the sampling step along each beam
    assert np.all(best[grid.swept] >= -1e-9), "marked a cell no beam touches"
    assert np.all(grid.swept[best > res / 2 + 1e-9]), "missed a cell a beam crosses over res/2"
    assert grid.coverage == np.count_nonzero(grid.swept & free) / np.count_nonzero(free)


def test_coverage_grid__monotone_and_gain_counts_new_free_cells() -> None:
    rng = np.random.default_rng(5)
    free = np.ones((40, 60), dtype=bool)
    free[10:30, 25] = False
    grid = M.CoverageGrid(free, (0.0, 0.0), 0.05)
    prev = 0.0
    for step in range(30):
        grid.sweep(rng.uniform(0, 3, (15, 2)), rng.uniform(-3, 3, 15), rng.uniform(0, 1, 15), 1.0)
        assert grid.coverage >= prev
        assert grid.gain == round((grid.coverage - prev) * free.sum())
        assert grid.gain >= 0, step
        prev = grid.coverage
    assert 0.0 < grid.coverage <= 1.0


def test_coverage_grid__overlap_of_two_robots() -> None:
    grid = M.CoverageGrid(np.ones((10, 10), dtype=bool), (0.0, 0.0), 1.0)
    start = np.array([[0.5, 0.5]])
    grid.sweep(start, np.array([0.0]), np.array([9.0]), max_range=20.0, robot=0)  # row 0
    grid.sweep(start, np.array([np.pi / 2]), np.array([np.inf]), max_range=9.0, robot=1)  # col 0
    assert grid.robot_coverage(0) == pytest.approx(0.10)  # 10 of 100 cells
    assert grid.coverage == pytest.approx(0.19)  # the shared corner cell counts once
    assert grid.overlap() == pytest.approx(1 / 19)
    assert grid.gain == 9


def test_coverage_grid__overlap_matches_mask_arithmetic() -> None:
    rng = np.random.default_rng(6)
    free = rng.uniform(size=(30, 30)) > 0.1
    grid = M.CoverageGrid(free, (0.0, 0.0), 0.1)
    for k in range(20):
        grid.sweep(rng.uniform(0, 3, (5, 2)), rng.uniform(-3, 3, 5), np.full(5, np.inf), 0.8, k % 3)
    count = sum(m.astype(int) for m in grid.robot_swept.values())
    expected = np.count_nonzero((count >= 2) & free) / np.count_nonzero(grid.swept & free)
    assert grid.overlap() == pytest.approx(expected)


def test_coverage_grid__beam_cells_then_mark_equals_sweep() -> None:
    rng = np.random.default_rng(7)
    free = rng.uniform(size=(30, 40)) > 0.2
    by_sweep = M.CoverageGrid(free, (0.0, 0.0), 0.1)
    by_parts = M.CoverageGrid(free, (0.0, 0.0), 0.1)
    for k in range(25):
        origin = rng.uniform(0, 3, 2)
        a = rng.uniform(-3, 3, 5)
        r = np.where(rng.uniform(size=5) < 0.3, np.inf, rng.uniform(0, 1.2, 5))
        gain = by_sweep.sweep(np.tile(origin, (5, 1)), a, r, 1.0, k % 3)
        cells = by_parts.beam_cells(origin, a, r, 1.0)  # one (2,) origin for all beams
        distinct_free = np.unique(cells[free.reshape(-1)[cells]])
        expected_new = np.count_nonzero(~by_parts.swept.reshape(-1)[distinct_free])
        assert by_parts.new_free_cells(cells) == expected_new
        assert by_parts.mark(cells, k % 3) == gain == expected_new
    assert np.array_equal(by_sweep.swept, by_parts.swept)
    assert by_sweep.coverage == by_parts.coverage
    for robot in range(3):
        assert np.array_equal(by_sweep.robot_swept[robot], by_parts.robot_swept[robot])


def test_coverage_grid__scan_cells_of_several_scans_equal_beam_cells_of_each() -> None:
    rng = np.random.default_rng(10)
    grid = M.CoverageGrid(np.ones((30, 40), dtype=bool), (0.0, 0.0), 0.1)
    origins = rng.uniform(0, 3, (4, 2))
    angles = rng.uniform(-3, 3, (4, 5))
    ranges = rng.uniform(0, 1.5, (4, 5))
    ranges[1] = np.inf  # scans of different lengths get different sample counts
    ranges[2, :] = 0.05
    together = grid.scan_cells(origins, angles, ranges, 1.0)
    for k, cells in enumerate(together):
        alone = grid.beam_cells(origins[k], angles[k], ranges[k], 1.0)
        assert np.array_equal(np.unique(cells), np.unique(alone))
    assert grid.scan_cells(np.zeros((0, 2)), np.zeros((0, 5)), np.zeros((0, 5)), 1.0) == []


def test_coverage_grid__rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="boolean"):
        M.CoverageGrid(np.ones((3, 3)), (0.0, 0.0), 0.1)
    grid = M.CoverageGrid(np.ones((3, 3), dtype=bool), (0.0, 0.0), 0.1)
    with pytest.raises(ValueError, match="ranges"):
        grid.sweep(np.zeros((1, 2)), np.zeros(1), np.array([-1.0]), 1.0)


def test_time_to_fraction__first_crossing_or_none() -> None:
    series = np.array([0.0, 0.3, 0.5, 0.4, 0.9])
    assert M.time_to_fraction(series, 0.5) == 2
    assert M.time_to_fraction(series, 0.9) == 4
    assert M.time_to_fraction(series, 0.95) is None


def _random_polynomials(rng: np.random.Generator, count: int) -> list[Polynomial]:
    """Orders 1–4, both variates, a few zero extents."""
    scale = np.array([1.0, 1.0, 0.3, 0.1, 0.05])
    polys = []
    for _ in range(count):
        m = int(rng.integers(1, 5))
        lo = rng.uniform(-3, 3)
        hi = lo + (0.0 if rng.uniform() < 0.1 else rng.uniform(0, 3))
        polys.append(
            Polynomial(int(rng.integers(1, 3)), rng.normal(size=m + 1) * scale[: m + 1], lo, hi)
        )
    return polys


@pytest.mark.parametrize("step", [0.01, 0.05])
def test_sample_arclength_batch__bit_identical_to_each_polynomials_own_sampling(
    step: float,
) -> None:
    rng = np.random.default_rng(8)
    for count in (0, 1, 2, 7, 30):
        polys = _random_polynomials(rng, count)
        batch = M.sample_arclength_batch(polys, step)
        assert len(batch) == len(polys)
        for poly, pts in zip(polys, batch, strict=True):
            assert np.array_equal(pts, poly.sample_arclength(step))


def test_map_points__equal_each_polynomials_samples_moved_to_the_absolute_frame() -> None:
    polys = _random_polynomials(np.random.default_rng(11), 12)
    start = np.array([1.5, -0.7, 2.3])
    for poly, pts in zip(polys, M.map_points(polys, start, 0.05), strict=True):
        assert np.array_equal(pts, transform_points(poly.sample_arclength(0.05), start))
    assert M.map_points([], start) == []


def test_coverage_grid__a_deep_copy_sweeps_its_own_masks() -> None:
    grid = M.CoverageGrid(np.ones((10, 10), dtype=bool), (0.0, 0.0), 1.0)
    twin = copy.deepcopy(grid)
    twin.sweep(np.array([[0.5, 0.5]]), np.array([0.0]), np.array([5.0]), 9.0, robot=0)
    assert twin.swept.sum() == 6 and twin.coverage == pytest.approx(0.06)
    assert not grid.swept.any() and grid.coverage == 0.0

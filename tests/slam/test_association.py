"""Tests of approximation errors, the per-step association and the cluster / Q_bad fits."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from polyslam_env.slam import map_kernels, step_kernels
from polyslam_env.slam.association import (
    GAP_SPLIT,
    fit_cluster,
    nearest_by_error,
    qbad_refit_points,
)
from polyslam_env.slam.columns import (
    CLUSTER,
    G_GOOD,
    G_REQUEST,
    KIND,
    N_NEW,
    N_PER_BEAM,
    N_REFIT,
    N_VALUES,
    NEW,
    OWNER,
    PTH,
    QBAD,
    RANK,
    REFIT,
    SIZE,
    ST_EXTENTS,
    ST_SCREEN,
    UX,
    V_RHO,
    V_SIGMA,
    X,
)
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.divergence import SCREEN_WINDOW
from polyslam_env.slam.fitting import concat, fit_polynomial, polynomial_points, stored_points
from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.maintenance import fit_inverse_table as _fit_inverse_table
from polyslam_env.slam.measurement import cast
from polyslam_env.slam.model import step_model
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.stored import PointArrays, StoredPoints, point_arrays
from tests.slam import reference_association as oracle
from tests.slam.finite_differences import FD_ATOL, FD_RTOL, fd_jacobian
from tests.slam.reference import approximation_error


def points_at(xy: np.ndarray | list[tuple[float, float]], sigma: float = 0.02) -> PointArrays:
    """Stored points at ``xy`` (N, 2), beams along +x², weight 100."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return point_arrays(xy, np.tile([0.0, 1.0], (len(xy), 1)), sigma, 100.0, np.zeros(3))


def segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    t = np.clip(((q - a) @ (b - a)) / ((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(q - (a + t[:, None] * (b - a)), axis=1)


# -- approximation error -------------------------------------------------------------------
def brute_force_error(pts: np.ndarray, polys: list[Polynomial], c0s: list[float]) -> np.ndarray:
    out = np.zeros((len(pts), len(polys)))
    for i, q in enumerate(pts):
        for j, (p, c0) in enumerate(zip(polys, c0s, strict=True)):
            p = p.with_c0(c0)
            xi, eta = (q[0], q[1]) if p.variate == 1 else (q[1], q[0])
            if p.lo <= xi <= p.hi:
                out[i, j] = abs(eta - sum(c * xi**k for k, c in enumerate(p.coeffs)))
            else:
                out[i, j] = min(np.linalg.norm(e - q) for e in p.endpoints())
    return out


poly_strategy = st.builds(
    lambda v, c, lo, w: Polynomial(v, np.array(c), lo, lo + w),
    st.sampled_from([1, 2]),
    st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=4),
    st.floats(-3.0, 2.0),
    st.floats(0.0, 2.0),
)


def _xy(n: int, reach: float) -> st.SearchStrategy[np.ndarray]:
    """n points (n, 2) in the square ±``reach``."""
    return hnp.arrays(np.float64, (n, 2), elements=st.floats(-reach, reach))


#: offsets c0 of up to 8 landmarks (a test uses the first len(polys))
c0_strategy = hnp.arrays(np.float64, 8, elements=st.floats(-3.0, 3.0))


@settings(max_examples=40, deadline=None)
@given(
    polys=st.lists(poly_strategy, min_size=1, max_size=4),
    pts=_xy(15, 4.0),
    offsets=c0_strategy,
)
def test_approximation_error__matches_brute_force(
    polys: list[Polynomial], pts: np.ndarray, offsets: np.ndarray
) -> None:
    c0s = list(offsets[: len(polys)])
    err = approximation_error(pts, polys, c0s)
    ref = brute_force_error(pts, polys, c0s)
    np.testing.assert_allclose(err, ref, rtol=1e-10, atol=1e-10)  # same formula, round-off only
    np.testing.assert_allclose(
        approximation_error(pts, polys, c0s, squared=True), ref**2, rtol=1e-9, atol=1e-12
    )


@settings(max_examples=60, deadline=None)
@given(
    polys=st.lists(poly_strategy, min_size=1, max_size=5),
    pts=_xy(6, 4.0),
    offsets=c0_strategy,
    squared=st.booleans(),
)
def test_nearest_by_error__is_the_argmin_of_approximation_error(
    polys: list[Polynomial], pts: np.ndarray, offsets: np.ndarray, squared: bool
) -> None:
    arrays = table_of(polys)
    c0s = offsets[: len(polys)].copy()
    err = approximation_error(pts, arrays.packed(), c0s, squared)
    got = nearest_by_error(
        pts.tolist(), list(range(len(polys))), arrays.rows(), c0s.tolist(), squared
    )
    for i, (best, eps) in enumerate(got):
        # 1e-12: the same formula in floats (libm's hypot may round the last bit differently)
        assert eps == pytest.approx(err[i].min(), rel=1e-12, abs=1e-15)
        assert err[i, best] == pytest.approx(err[i].min(), rel=1e-12, abs=1e-15)
    assert nearest_by_error(pts.tolist(), [], arrays.rows(), c0s.tolist()) == [(-1, np.inf)] * 6


def test_approximation_error__empty_map_has_no_columns() -> None:
    assert approximation_error(np.zeros((3, 2)), [], []).shape == (3, 0)


# -- association ---------------------------------------------------------------------------------
FLAT = Polynomial(1, np.array([1.0, 0.0, 0.0, 0.0]), 0.0, 2.0)  # x² = 1 on x¹ ∈ [0, 2]
RHO, SIGMA = 0.125, 0.25  # exact binary fractions: 1 + ε is exact at the boundaries


def table_of(
    polys: list[Polynomial],
    rng: np.random.Generator | None = None,
    sides: Sequence[int] | None = None,
) -> LandmarkTable:
    table = LandmarkTable()
    for k, p in enumerate(polys):
        pivot = 0.5 * (p.lo + p.hi) if rng is None else float(rng.uniform(p.lo, p.hi))
        side = 0 if sides is None else sides[k]
        table.append(p, pivot=pivot, xi_var=0.0, model_var=0.0, fit_half=1.0, step=k, side=side)
    return table


class Associated(NamedTuple):
    """What one run of the compiled association left: per beam, the id of the landmark it
    updates (−1: none), and this step's refit requests (landmark id, request number)."""

    good: np.ndarray
    refit_ids: list[int]

    def refits(self, points: StoredPoints) -> list[tuple[int, int]]:
        return [(lid, r) for r, lid in enumerate(self.refit_ids)]


def associate(
    config: SlamConfig,
    table: LandmarkTable,
    points: StoredPoints,
    mean: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    rho: float = RHO,
    sigma: float = SIGMA,
    cov: np.ndarray | None = None,
    step: int = 1,
) -> Associated:
    """One run of the compiled association (``step_kernels.associate_step``, as PolySlam's
    step runs it) at thresholds ρ_k, σ_k (the state's c0s after the pose in ``mean``)."""
    model = step_model(config, angles, 3.0)
    cov = np.eye(mean.size) * 1e-4 if cov is None else cov
    fit_inverse = _fit_inverse_table(config.eps_z + 1, max(config.order, 5))
    per_beam = np.full((N_PER_BEAM, angles.size), -1, dtype=np.int64)
    status, values = np.zeros(ST_SCREEN + SCREEN_WINDOW, np.int64), np.zeros(N_VALUES)
    values[V_RHO], values[V_SIGMA] = rho, sigma
    points.reserve(angles.size)
    step_kernels.associate_step(
        mean, cov, np.asarray(ranges, dtype=float), model.beams, *table.buffers, len(table),
        *points.buffers, model.params, model.switches, fit_inverse, step, per_beam, status,
        values,
    )  # fmt: skip
    if status[ST_EXTENTS]:
        table.extents_changed()
    requests = per_beam[G_REQUEST, : points.counters[N_REFIT]].tolist()
    return Associated(per_beam[G_GOOD].copy(), requests)


def straight_up(xs: list[float], ys: list[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A pose at (x, 0) heading +x¹ per target and beams at +90° of length y: each point lands
    exactly on (x, y) (cos 90° is 6e-17, far below the ulp of x). One robot per beam is not
    possible, so every target must share x: returns (pose, ranges, angles)."""
    assert len(set(xs)) == 1
    return np.array([xs[0], 0.0, 0.0]), np.array(ys), np.full(len(ys), np.pi / 2)


def one_landmark(eps_m: int = 5, eps_z: int = 10) -> tuple[SlamConfig, LandmarkTable]:
    config = SlamConfig(eps_m=eps_m, eps_z=eps_z, cluster_radius=0.35, stretch_ends=False)
    return config, table_of([FLAT])


def test_associate__three_cases_at_the_threshold_boundaries() -> None:
    config, table = one_landmark()
    points = StoredPoints()
    pose, ranges, angles = straight_up(
        [1.0] * 4,
        [1.0 + RHO, 1.0 + RHO + 1e-12, 1.0 - SIGMA, 1.0 + SIGMA + 1e-12],  # good, bad, bad, none
    )
    mean = np.concatenate([pose, [1.0]])
    association = associate(config, table, points, mean, ranges, angles)
    assert association.good.tolist() == [0, -1, -1, -1]
    assert len(points.qbad(0)) == 2 and points.qbad(0).beam.tolist() == [1, 2]
    clusters = points.clusters()
    assert len(clusters) == 1 and clusters[0].beam.tolist() == [3]
    assert points.counters[N_REFIT] == points.counters[N_NEW] == 0


def test_associate__uses_the_state_c0_not_the_stored_one() -> None:
    config, table = one_landmark()
    pose, ranges, angles = straight_up([1.0], [1.5])
    association = associate(
        config, table, StoredPoints(), np.concatenate([pose, [1.5]]), ranges, angles
    )
    assert association.good.tolist() == [0]


def test_associate__qbad_refit_after_eps_m_plus_one_bad_points() -> None:
    eps_m = 5
    config, table = one_landmark(eps_m=eps_m)
    points = StoredPoints()
    for k in range(eps_m + 1):
        pose, ranges, angles = straight_up([0.2 + 0.3 * k], [1.2])
        association = associate(
            config, table, points, np.concatenate([pose, [1.0]]), ranges, angles, step=k
        )
        assert association.refits(points) == ([(0, 0)] if k == eps_m else [])
    assert len(points.take(points.rows_of(REFIT, 0))) == eps_m + 1
    assert len(points.qbad(0)) == 0


def test_associate__cluster_becomes_landmark_after_eps_z_plus_one_points() -> None:
    eps_z = 10
    config = SlamConfig(eps_m=5, eps_z=eps_z, cluster_radius=0.35, stretch_ends=False)
    table, points = LandmarkTable(), StoredPoints()
    up = np.array([np.pi / 2])
    associate(config, table, points, np.array([5.0, 0.0, 0.0]), np.array([5.0]), up)
    for k in range(eps_z + 1):
        pose = np.array([0.03 * k, 0.0, 0.0])
        associate(config, table, points, pose, np.array([0.0 + 1e-3]), up, step=k)
        assert points.counters[N_NEW] == (1 if k == eps_z else 0)
    assert len(points.take(points.rows_of(NEW, 0))) == eps_z + 1
    clusters = points.clusters()
    assert len(clusters) == 1 and clusters[0].xy.tolist() == [[5.0, 5.0]]


def clusters_with(*groups: list[tuple[float, float]]) -> StoredPoints:
    points = StoredPoints()
    for group in groups:
        points.add_cluster(points_at(group))
    return points


def add_to_cluster(points: StoredPoints, xy: tuple[float, float], link: bool, eps_z: int) -> None:
    real = np.zeros(points.real.shape[0])
    real[:2] = xy
    points.reserve(1)
    map_kernels._add_to_cluster(*points.buffers, real, 0, 0, 0.35, link, eps_z)


def test_add_to_cluster__joins_the_cluster_with_most_neighbours() -> None:
    points = clusters_with([(0.0, 0.0)], [(0.5, 0.0), (0.55, 0.0)])
    add_to_cluster(points, (0.25, 0.0), False, 10)  # within R of all three: 1 vs 2 neighbours
    assert [len(c) for c in points.clusters()] == [1, 3]


def test_add_to_cluster__linked_a_point_near_two_clusters_makes_them_one() -> None:
    points = clusters_with([(0.0, 0.0)], [(5.0, 0.0)], [(0.5, 0.0), (0.55, 0.0)])
    add_to_cluster(points, (0.25, 0.0), True, 10)  # within R of the first and the third
    clusters = points.clusters()
    assert [len(c) for c in clusters] == [1, 4]
    assert clusters[0].xy.tolist() == [[5.0, 0.0]]
    # the joined cluster's points follow the new point, in their order
    assert clusters[1].xy[:, 0].tolist() == [0.5, 0.55, 0.25, 0.0]
    # and a linked cluster past ε_Z is handed over whole
    points = clusters_with([(0.0, 0.0), (0.1, 0.0)], [(0.5, 0.0), (0.6, 0.0)])
    add_to_cluster(points, (0.3, 0.0), True, 4)
    assert points.counters[N_NEW] == 1 and len(points.take(points.rows_of(NEW, 0))) == 5
    assert points.clusters() == []


def test_stored_points__give_back_drop_and_carry() -> None:
    points = clusters_with([(0.0, 0.0), (1.0, 0.0)], [(2.0, 0.0)])
    points.drop(points.rows_of(CLUSTER, 0)[:1])
    assert [c.xy[:, 0].tolist() for c in points.clusters()] == [[1.0], [2.0]]
    before, after = np.array([1.0, 2.0, 0.3]), np.array([1.05, 1.9, 0.35])
    points.carry(before, after)
    d = after[2] - before[2]
    rot = np.array([[np.cos(d), -np.sin(d)], [np.sin(d), np.cos(d)]])
    want = after[:2] + rot @ (np.array([1.0, 0.0]) - before[:2])
    # rounding of a 2×2 rotation of metre-sized vectors
    np.testing.assert_allclose(points.clusters()[0].xy[0], want, atol=1e-15)
    np.testing.assert_allclose(points.clusters()[0].direction[0], rot @ [0.0, 1.0], atol=1e-15)


def _carry_in_model_order(points: StoredPoints, before: np.ndarray, after: np.ndarray) -> None:
    """The oracle of ``StoredPoints.carry``: the same rigid motion, its product taken over the
    points sorted into the stored-point model's order (kind, holder, rank), as it was."""
    n, index = len(points), points.index
    order = np.lexsort((index[RANK, :n], index[OWNER, :n], index[KIND, :n]))
    bx, by, dtheta = float(before[0]), float(before[1]), float(after[2] - before[2])
    c, s = math.cos(dtheta), math.sin(dtheta)
    rows = np.ascontiguousarray(points.real[X : PTH + 1, order].T)
    rows = rows - np.array([bx, by, 0.0, 0.0, bx, by, 0.0])
    motion = np.zeros((7, 7))
    motion[0, :2] = motion[2, 2:4] = motion[4, 4:6] = c, s
    motion[1, :2] = motion[3, 2:4] = motion[5, 4:6] = -s, c
    motion[6, 6] = 1.0
    rows = rows @ motion
    rows += np.array([float(after[0]), float(after[1]), 0.0, 0.0, after[0], after[1], dtheta])
    points.real[X : PTH + 1, order] = rows.T


def test_carry__bit_identical_in_any_storage_order() -> None:
    """Each point's product with the motion does not depend on the other rows (BLAS computes
    every row alike), so carrying the points in storage order gives the bits of the model
    order's; 1 to 300 points of several clusters in shuffled storage."""
    rng = np.random.default_rng(11)
    for n in (1, 2, 5, 17, 300):
        groups = np.array_split(rng.normal(0.0, 20.0, size=(n, 2)), max(n // 4, 1))
        points = clusters_with(*[[tuple(p) for p in g.tolist()] for g in groups if len(g)])
        shuffled = rng.permutation(n)  # storage order no longer the model's (as joins make it)
        points.real[:, :n], points.index[:, :n] = (
            points.real[:, shuffled],
            points.index[:, shuffled],
        )
        points.real[UX : PTH + 1, :n] = rng.normal(0, 5, (PTH + 1 - UX, n))
        oracle = StoredPoints()
        oracle.reserve(len(points))
        oracle.real[:] = points.real[:, : oracle.real.shape[1]]
        oracle.index[:] = points.index[:, : oracle.index.shape[1]]
        oracle.counters[:] = points.counters
        before, after = rng.normal(0, 3, 3), rng.normal(0, 3, 3)
        points.carry(before, after)
        _carry_in_model_order(oracle, before, after)
        used = len(points)
        assert points.real[:, :used].tobytes() == oracle.real[:, :used].tobytes()


# -- the compiled association against the oracle ---------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(
    polys=st.lists(poly_strategy, min_size=0, max_size=6),
    seed=st.integers(0, 2**32 - 1),
    squared=st.booleans(),
    stretch=st.booleans(),
    link=st.booleans(),
    rotation=st.sampled_from(["considered", "heading"]),
    seen_faces=st.booleans(),
)
def test_associate_scan__equals_the_readable_association_over_steps(
    polys: list[Polynomial],
    seed: int,
    squared: bool,
    stretch: bool,
    link: bool,
    rotation: str,
    seen_faces: bool,
) -> None:
    """Bit for bit over five steps of random scans: good beams, Q_bad sets, clusters and
    requests (their points' beams and positions in order), and the stretched extents,
    evidence and η ranges; the landmarks' seen faces drawn at random (−1, 0, +1)."""
    rng = np.random.default_rng(seed)
    config = SlamConfig(
        eps_m=5, eps_z=6, squared_error=squared, stretch_ends=stretch, link_clusters=link,
        shape_rotation=rotation, seen_faces=seen_faces,
    )  # fmt: skip
    sides = rng.integers(-1, 2, len(polys)).tolist()
    table = table_of(polys, rng, sides)
    n = len(polys)
    state = 3 + (2 * n if config.rotation_states else n)
    a = rng.normal(size=(state, state)) * 0.01
    cov = a @ a.T + np.eye(state) * 1e-6
    mean = np.concatenate([rng.normal(0.0, 0.5, 3), rng.normal(0.0, 0.3, state - 3)])
    book = oracle.OracleMap(
        ids=list(table.ids), polys=list(table.polys), pivot=table.pivot.tolist(),
        changed_at=table.changed_at.tolist(), evidence=[(p.lo, p.hi) for p in polys],
        width=table.shape.shape[1],
    )  # fmt: skip
    turn_var_step = float(config.odom_cov[2, 2])
    fit_inverse = _fit_inverse_table(config.eps_z + 1, max(config.order, 5))

    def turn_var(i: int) -> float:
        if config.rotation_states:
            t = 3 + n + i
            return float(cov[t, t] + cov[2, 2] - 2.0 * cov[t, 2])
        return (
            oracle.rotation_fit_var(book.polys[i], fit_inverse, config.range_sigma**2)
            + (step - book.changed_at[i]) * turn_var_step
        )

    model = oracle.Model(
        config.range_sigma, squared, stretch, config.eps_m, config.eps_z, config.cluster_radius,
        link, turn_var, seen_faces, tuple(sides),
    )  # fmt: skip
    points = StoredPoints(capacity=4)  # grows
    angles = np.linspace(-np.pi, np.pi, 17, endpoint=False)
    rho, sigma = (0.05, 0.2) if not squared else (0.0025, 0.04)
    for step in range(6):
        mean[:3] += rng.normal(0.0, 0.2, 3)
        # beams that hit a landmark (cast at the mean) land near its curve, within a few ρ
        hits = cast(*mean[:3], angles, range(n), table.arrays(), mean[3 : 3 + n], 3.0)
        ranges = rng.uniform(0.2, 2.5, angles.size)
        for b, hit in enumerate(hits):
            if hit is not None:
                ranges[b] = hit.t + rng.normal(0.0, 0.06)
        ranges[rng.uniform(size=angles.size) < 0.15] = np.inf
        want = oracle.associate_step(book, mean, cov, ranges, angles, step, rho, sigma, model)
        got = associate(config, table, points, mean, ranges, angles, rho, sigma, cov, step)
        assert got.good.tolist() == [want.good_ids.get(b, -1) for b in range(angles.size)]
        assert got.refits(points) == [(lid, r) for r, (lid, _) in enumerate(want.refits)]
        for r, (_, expected) in enumerate(want.refits):
            assert_same_points(points.take(points.rows_of(REFIT, r)), expected)
        assert points.counters[N_NEW] == len(want.new_landmarks)
        for r, expected in enumerate(want.new_landmarks):
            assert_same_points(points.take(points.rows_of(NEW, r)), expected)
        clusters = points.clusters()
        assert len(clusters) == len(book.clusters)
        for cluster, expected in zip(clusters, book.clusters, strict=True):
            assert_same_points(cluster, expected)
        for lid in table.ids:
            assert_same_points(points.take(points.rows_of(QBAD, lid)), book.qbad[lid])
        assert table.lo.tolist() == [p.lo for p in book.polys]
        assert table.hi.tolist() == [p.hi for p in book.polys]
        assert [tuple(e) for e in table.evidence.tolist()] == book.evidence
        assert [tuple(e) for e in table.eta_range.tolist()] == book.eta
        # the requests are handed over (their fits are PolySlam's, not checked here)
        points.drop(np.flatnonzero(points.index[KIND, : len(points)] >= REFIT))


def assert_same_points(got: PointArrays, want: list[oracle.StoredPoint]) -> None:
    assert got.beam.tolist() == [p.beam for p in want]
    assert got.step.tolist() == [p.step for p in want]
    assert got.xy.tolist() == [p.xy.tolist() for p in want]
    assert got.direction.tolist() == [p.direction.tolist() for p in want]
    assert got.pose.tolist() == [p.pose.tolist() for p in want]
    assert got.weight.tolist() == [p.weight for p in want]


@settings(max_examples=60, deadline=None)
@given(
    polys=st.lists(poly_strategy, min_size=1, max_size=8),
    pose=hnp.arrays(np.float64, 3, elements=st.floats(-2.0, 2.0)),
    offsets=c0_strategy,
    turns=hnp.arrays(np.float64, 8, elements=st.floats(-1.0, 1.0)),
    ranges=hnp.arrays(np.float64, 9, elements=st.floats(0.1, 3.0)),
    squared=st.booleans(),
)
def test_associate__box_candidates_classify_like_the_whole_map(
    polys: list[Polynomial], pose: np.ndarray, offsets: np.ndarray, turns: np.ndarray,
    ranges: np.ndarray, squared: bool,
) -> None:  # fmt: skip
    # the kernel hands the error search only the landmarks whose box lies within σ_k of the
    # points' box; every point must land in the same case (good / bad / cluster) with the
    # same p* as against every landmark (without stretch_ends: its GAP_SPLIT reach is a
    # choice, not a bound)
    rho, sigma = (0.04, 0.3) if not squared else (0.0016, 0.09)
    config = SlamConfig(eps_m=50, eps_z=50, squared_error=squared, stretch_ends=False)
    table, points = table_of(polys), StoredPoints()
    n = len(polys)
    mean = np.concatenate([pose, offsets[:n], turns[:n]])  # c0s, then the turns α
    angles = np.linspace(-np.pi, np.pi, 9, endpoint=False)
    # the kernel classifies every point against the map as it was before the step and only
    # then stretches extents to this step's good points: the whole-map oracle reads the same
    # rows, taken before the call
    before = table.rows()
    got = associate(config, table, points, mean, ranges, angles, rho, sigma)
    xy = oracle.store_beams(mean[:3], np.eye(3) * 1e-4, ranges, angles, 0.02)
    everything = nearest_by_error(
        [p.xy.tolist() for p in xy], list(range(len(polys))), before,
        mean[3 : 3 + len(polys)], squared,
    )  # fmt: skip
    for b, (best, eps) in enumerate(everything):
        case = "good" if eps <= rho else ("bad" if eps <= sigma else "cluster")
        assert (got.good[b] >= 0) == (case == "good")
        if case == "good":
            assert got.good[b] == table.ids[best]
        if case == "bad":
            assert b in points.qbad(table.ids[best]).beam.tolist()
        if case == "cluster":
            assert any(b in c.beam.tolist() for c in points.clusters())


# -- Q_bad refit Jacobians ------------------------------------------------------------------
@pytest.mark.parametrize("variate", [1, 2])
def test_qbad_refit__jacobians_match_finite_differences(variate: int) -> None:
    rng = np.random.default_rng(11)
    old = Polynomial(variate, np.array([1.0, 0.1, -0.05, 0.01]), -0.5, 1.0)
    c0_index, c0_var, n_state = 4, 0.03**2, 6  # landmark 1 of 3
    state = np.array([0.2, 0.1, 0.3, 0.5, 1.02, -0.7])
    xi = np.linspace(0.8, 1.6, 6)  # bad points extend the wall beyond its extent
    eta = old.value(xi) + 0.12 + rng.normal(0, 0.01, 6)
    xy = np.column_stack([xi, eta] if variate == 1 else [eta, xi])
    qbad = point_arrays(xy, np.tile([0.6, 0.8], (len(xy), 1)), 0.02, 400.0, state[:3])
    anchor = state[:3]

    def refit(x: np.ndarray, e: np.ndarray | None = None, var: int | None = None) -> float:
        """g(X, noise): the same points as qbad_refit_points, rebuilt at a perturbed state."""
        moved = stored_points(qbad, anchor, n_state, pose=x[:3], noise=e)
        on_old = polynomial_points(
            old.with_c0(x[c0_index]), c0_index, c0_var, 5, old.lo, old.hi, n_state
        )
        return fit_polynomial(concat(moved, on_old), 3, var).c0

    fit = fit_polynomial(
        qbad_refit_points(qbad, old.with_c0(state[c0_index]), c0_index, c0_var, 5, anchor, n_state)
    )
    assert fit.poly.variate == variate and fit.poly.hi > old.hi
    fd_x = fd_jacobian(lambda x: refit(x, var=variate), state)
    fd_e = fd_jacobian(lambda e: refit(state, e, variate), np.zeros(len(qbad)))
    np.testing.assert_allclose(fit.Gx[0], fd_x, rtol=FD_RTOL, atol=FD_ATOL)
    np.testing.assert_allclose(fit.Gy[0], fd_e, rtol=FD_RTOL, atol=FD_ATOL)
    assert abs(fit.Gx[0, c0_index]) > 0.05 and np.abs(fit.Gx[0, :3]).max() > 0.05  # both enter
    # (with weights 400 vs 1111 per point the pose and the old c0 share the fit)
    assert fit.Gx[0, 3] == 0.0 and fit.Gx[0, 5] == 0.0  # other landmarks do not


# -- new landmarks from clusters --------------------------------------------------------------
def corner_points(
    alpha: float, noise: float, rng: np.random.Generator
) -> tuple[PointArrays, np.ndarray, np.ndarray, np.ndarray]:
    """A right-angle corner at c: 7 points on arm A (0.4 m), 5 on arm B (0.3 m)."""
    c = np.array([1.0, 0.5])
    d1 = np.array([np.cos(alpha), np.sin(alpha)])
    d2 = np.array([-d1[1], d1[0]])
    ta, tb = np.linspace(0.02, 0.4, 7), np.linspace(0.05, 0.3, 5)
    xy = np.vstack([c + ta[:, None] * d1, c + tb[:, None] * d2]) + rng.normal(0, noise, (12, 2))
    return points_at(xy), c, c + 0.4 * d1, c + 0.3 * d2


def one_wall_deviation(
    poly: Polynomial, c: np.ndarray, a_end: np.ndarray, b_end: np.ndarray
) -> float:
    """Largest distance of the polynomial from the nearer single wall (arm A or arm B)."""
    s = poly.sample_arclength(0.01)
    return min(segment_distance(s, c, a_end).max(), segment_distance(s, c, b_end).max())


@settings(max_examples=30, deadline=None)
@given(alpha=st.floats(0.0, 2 * np.pi))
def test_fit_cluster__noiseless_corner_is_not_cut(alpha: float) -> None:
    pts, c, a_end, b_end = corner_points(alpha, 0.0, np.random.default_rng(0))
    res = fit_cluster(pts, np.zeros(3), 3, max_rms=0.08)
    assert res.fit is not None
    assert one_wall_deviation(res.fit.poly, c, a_end, b_end) < 1e-6  # exact points on one line
    assert len(res.leftover) >= 3  # the other arm is kept for a later landmark


def test_fit_cluster__noisy_corner_stays_on_one_wall() -> None:
    ours, naive = [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        for alpha in np.linspace(0.0, 2 * np.pi, 24, endpoint=False):
            pts, c, a_end, b_end = corner_points(alpha, 0.02, rng)
            res = fit_cluster(pts, np.zeros(3), 3, max_rms=0.08)
            assert res.fit is not None
            ours.append(one_wall_deviation(res.fit.poly, c, a_end, b_end))
            cubic = fit_polynomial(stored_points(pts, np.zeros(3), 3)).poly
            naive.append(one_wall_deviation(cubic, c, a_end, b_end))
    # a cubic through 7 points with σ = 2 cm wiggles up to ~6 cm at its ends even when fitted
    # to one arm only (measured: 0.057 m); 0.15 m leaves room for that and is half the
    # ~0.3 m of the paper's single cubic, which spans both arms (median checked as contrast)
    assert max(ours) < 0.15
    assert np.median(naive) > 0.2


def test_fit_cluster__straight_and_gently_curved_walls_use_every_point() -> None:
    rng = np.random.default_rng(4)
    straight = points_at(np.column_stack([np.linspace(0, 0.6, 11), 0.3 + rng.normal(0, 0.02, 11)]))
    angle = np.linspace(-0.3, 0.3, 11)  # 0.6 m of a 1 m-radius arc
    arc = points_at(np.column_stack([np.sin(angle), 1.0 - np.cos(angle) + rng.normal(0, 0.01, 11)]))
    for pts in (straight, arc):
        res = fit_cluster(pts, np.zeros(3), 3, max_rms=0.08)
        assert res.fit is not None and len(res.used) == 11 and len(res.leftover) == 0


def test_fit_cluster__scattered_points_are_rejected() -> None:
    rng = np.random.default_rng(6)
    pts = points_at(rng.uniform(0.0, 0.5, (11, 2)))
    res = fit_cluster(pts, np.zeros(3), 3, max_rms=0.02, line_tol=0.01)
    assert res.fit is None and len(res.leftover) == 11


def test_fit_cluster__wall_points_across_a_doorway_gap_are_cut_there() -> None:
    """7 points on one side of a gap wider than GAP_SPLIT, 4 on the other (one line): the fit
    covers the larger run only and the other run is left over, whatever the order of points."""
    rng = np.random.default_rng(7)
    left = np.linspace(0.0, 0.48, 7)
    right = np.linspace(0.48 + GAP_SPLIT + 0.05, 0.48 + GAP_SPLIT + 0.29, 4)
    x = np.concatenate([right[:2], left, right[2:]])
    pts = points_at(np.column_stack([x, 0.3 + rng.normal(0, 0.005, len(x))]))
    res = fit_cluster(pts, np.zeros(3), 3, max_rms=0.08)
    assert res.fit is not None
    assert (res.fit.poly.lo, res.fit.poly.hi) == pytest.approx((0.0, 0.48))
    assert sorted(res.leftover.xy[:, 0].tolist()) == pytest.approx(sorted(right))
    # a gap just below the threshold is sampling, not a door: one fit over every point
    close = np.concatenate([left, left[-1] + GAP_SPLIT - 0.01 + np.linspace(0, 0.2, 4)])
    pts = points_at(np.column_stack([close, np.full(len(close), 0.3)]))
    res = fit_cluster(pts, np.zeros(3), 3, max_rms=0.08)
    assert res.fit is not None and len(res.leftover) == 0


def test_associate__box_candidates__two_zero_length_walls() -> None:
    """Hypothesis's case: a good point (beam 2) stretches wall 1's extent after the step's
    classification, which left beam 1 with wall 0 (0.0865 m against 0.0957 m); an oracle read
    from the stretched table put beam 1 0.0865 m from both and picked wall 1."""
    test = test_associate__box_candidates_classify_like_the_whole_map
    zero_length = [Polynomial(1, np.zeros(2), x, x) for x in (0.0, 0.140625)]
    test.hypothesis.inner_test(  # type: ignore[attr-defined]
        polys=zero_length,
        pose=np.full(3, 0.1328125), offsets=np.zeros(8), turns=np.zeros(8),
        ranges=np.full(9, 0.1015625), squared=False,
    )  # fmt: skip


def test_drop_qbad__several_landmarks_at_once() -> None:
    """A merge's two landmarks leave the stored points together: their Q_bad points go, and
    every other point (clusters, other landmarks' Q_bad, a cluster keyed like a dropped
    landmark) stays, in its row order."""
    rng = np.random.default_rng(4)
    points = StoredPoints()
    points.reserve(40)
    points.counters[SIZE] = 40
    points.real[:2, :40] = np.arange(80.0).reshape(2, 40)
    points.index[KIND, :40] = rng.choice([CLUSTER, QBAD], 40)
    points.index[OWNER, :40] = rng.integers(0, 5, 40)
    points.index[RANK, :40] = np.arange(40)
    kind, owner = points.index[KIND, :40].copy(), points.index[OWNER, :40].copy()
    stays = ~((kind == QBAD) & ((owner == 1) | (owner == 3)))
    want_real, want_index = points.real[:, :40][:, stays], points.index[:, :40][:, stays]
    points.drop_qbad(1, 3)
    n = len(points)
    assert n == int(stays.sum()) < 40
    assert np.array_equal(points.real[:, :n], want_real)
    assert np.array_equal(points.index[:, :n], want_index)

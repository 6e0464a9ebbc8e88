"""The observation kernels against their numpy oracle (``reference.py``): identical cells."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.environment import kernels
from polyslam_env.environment.config import resolve_config
from polyslam_env.environment.observations import (
    BeliefGrid,
    ObservationEncoder,
    RobotView,
    TeamView,
)
from polyslam_env.metrics.mapping import MapShapes, sample_shapes
from polyslam_env.slam import columns as col
from polyslam_env.world.sensors import Detection
from tests.environment import reference
from tests.slam.reference_floats import fma_exact


@pytest.mark.parametrize("slam_enabled", [True, False])
def test_local_cells__equal_the_oracle(slam_enabled: bool) -> None:
    config = resolve_config(None, slam_enabled=slam_enabled)
    encoder = ObservationEncoder(config, (10.0, 8.0))
    rng = np.random.default_rng(0)
    belief = BeliefGrid(12.0, 0.1, 2.0)
    for _ in range(100):
        belief.free[:] = rng.random(belief.free.shape) < 0.5
        belief.hit[:] = rng.random(belief.hit.shape) < 0.1
        pose = np.array([*rng.uniform(-7.0, 7.0, 2), rng.uniform(-4, 4)])  # near edges too
        points = pose[:2] + rng.uniform(-1.5, 1.5, (int(rng.integers(0, 40)), 2))
        view = RobotView(
            ranges=np.ones(5), pose=pose, pose_std=np.zeros(3), map_points=points, belief=belief,
            detections=[], steps_since_rendezvous=None, rendezvous=0, step=0,
        )  # fmt: skip
        occ, free = encoder.local_cells(view)
        want_occ, want_free = reference.local_cells(
            pose, points, belief, encoder.cell_centres, encoder.g, encoder.res, not slam_enabled
        )
        np.testing.assert_array_equal(occ, want_occ)
        np.testing.assert_array_equal(free, want_free)


@pytest.mark.parametrize("mode", ["vector", "grid"])
def test_vector__equals_the_oracle(mode: str) -> None:
    config = resolve_config(None, observation__mode=mode)
    encoder = ObservationEncoder(config, (10.0, 8.0))
    rng = np.random.default_rng(1)
    belief = BeliefGrid(12.0, 0.1, 2.0)
    belief.free[:] = rng.random(belief.free.shape) < 0.5
    for k in range(200):
        beams = len(config.world.range_sensor.angles_deg)
        ranges = rng.uniform(0.0, 3.0, beams)
        ranges[rng.random(beams) < 0.3] = np.inf
        pose = np.array([*rng.uniform(-30.0, 30.0, 2), rng.uniform(-4, 4)])  # some clipped
        tie = float(rng.uniform(0, 2))  # some detections at the same distance: ties by target
        detections = [
            Detection(int(j), tie if rng.random() < 0.3 else float(rng.uniform(0, 2)),
                      float(rng.uniform(-3, 3)))
            for j in sorted(rng.choice(6, int(rng.integers(0, 5)), replace=False).tolist())
        ]  # fmt: skip
        view = RobotView(
            ranges=ranges, pose=pose, pose_std=rng.uniform(0.0, 4.0, 3),
            map_points=np.zeros((0, 2)), belief=belief, detections=detections,
            steps_since_rendezvous=None if k % 3 else int(rng.integers(0, 500)),
            rendezvous=int(rng.integers(0, 20)), step=int(rng.integers(0, 600)),
        )  # fmt: skip
        cells = encoder.local_cells(view) if mode == "vector" else None
        np.testing.assert_array_equal(
            encoder.vector(view, cells), reference.vector(encoder, view, cells)
        )


def test_belief_grids__share_a_stack_that_survives_pickling() -> None:
    import pickle

    from polyslam_env.environment.config import ObservationConfig
    from polyslam_env.environment.observations import belief_grids, sweep_beliefs

    grids = belief_grids(ObservationConfig(), (0.0, 0.0, 4.0, 3.0), 1.5, 3)
    copies = pickle.loads(pickle.dumps(grids))
    poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 1.0], [-1.0, 0.0, 3.0]])
    angles, ranges = np.array([0.0, 1.0]), np.array([[1.0, np.inf], [0.5, 0.7], [np.inf, 1.2]])
    for team in (grids, copies):
        assert all(g.stack is team[0].stack for g in team)
        sweep_beliefs(team, poses, angles, ranges)
        alone = [BeliefGrid(g.n * g.resolution, g.resolution, 1.5) for g in team]
        for g, a, pose, r in zip(team, alone, poses, ranges, strict=True):
            a.sweep(pose, angles, r)
            np.testing.assert_array_equal(g.free, a.free)
            np.testing.assert_array_equal(g.hit, a.hit)
            assert g.free.any() and np.shares_memory(g.free, g.stack[0])


def test_encode_team__equals_each_view_alone_and_the_oracle() -> None:
    from polyslam_env.environment.config import ObservationConfig
    from polyslam_env.environment.observations import belief_grids

    config = resolve_config(None, slam_enabled=True)
    encoder = ObservationEncoder(config, (10.0, 8.0))
    rng = np.random.default_rng(3)
    grids = belief_grids(ObservationConfig(), (0.0, 0.0, 10.0, 8.0), 2.0, 4)
    for g in grids:
        g.free[:] = rng.random(g.free.shape) < 0.5
    views = []
    for k, g in enumerate(grids):
        pose = np.array([*rng.uniform(-5.0, 5.0, 2), rng.uniform(-4, 4)])
        points = pose[:2] + rng.uniform(-1.5, 1.5, (3 * k, 2))  # the first has no map
        views.append(
            RobotView(
                ranges=rng.uniform(0.0, 3.0, len(config.world.range_sensor.angles_deg)),
                pose=pose,
                pose_std=rng.uniform(0, 2, 3),
                map_points=points,
                belief=g,
                detections=[],
                steps_since_rendezvous=k,
                rendezvous=k,
                step=10 * k,
            )
        )
    team = encoder.encode_team(TeamView.of(views))
    for view, got in zip(views, team, strict=True):
        np.testing.assert_array_equal(got, encoder.encode(view))
        cells = reference.local_cells(
            view.pose, view.map_points, view.belief, encoder.cell_centres, encoder.g,
            encoder.res, False,
        )  # fmt: skip
        np.testing.assert_array_equal(got, reference.vector(encoder, view, cells))


def test_local_cells__places_by_exact_fma_chains_and_a_lone_point_as_numpy() -> None:
    """Cell centres R(θ)ᵀ + xy and ego points (p − xy) R(θ) of a team, bit for bit, as the
    kernel places them (``kernels.placed_centre``, ``kernels.ego_point``): entries against
    exact fused multiply-add chains (what numpy's gemm gave on an FMA BLAS); a robot with one
    point (``ObservationEncoder._lone_points``) against numpy's own product."""
    config = resolve_config(None, slam_enabled=True)
    encoder = ObservationEncoder(config, (10.0, 8.0))
    cc = encoder.cell_centres[::7]  # a sample of the grid's cells, (0, 0) among them
    rng = np.random.default_rng(5)
    counts = [0, 1, 2, 9]
    poses = np.column_stack([rng.uniform(-5.0, 5.0, (4, 2)), rng.uniform(-4.0, 4.0, 4)])
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    points = rng.uniform(-6.0, 6.0, (int(starts[-1]), 2))
    team = TeamView(
        ranges=np.ones((4, 2)), poses=poses, pose_stds=np.zeros((4, 3)), map_points=points,
        map_starts=starts, belief=BeliefGrid(12.0, 0.1, 2.0), belief_rows=np.zeros(4, np.int64),
        seen=np.zeros((4, 4), bool), distance=np.zeros((4, 4)), bearing=np.zeros((4, 4)),
        since=np.zeros(4, np.int64), rendezvous=np.zeros(4, np.int64), step=np.zeros(4, np.int64),
    )  # fmt: skip
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    lone = ObservationEncoder._lone_points(team, c, s)
    for k in range(4):
        x, y = float(poses[k, 0]), float(poses[k, 1])
        ck, sk = float(c[k]), float(s[k])
        rot_t = [[ck, sk], [-sk, ck]]  # R(θ)ᵀ; R(θ) is its transpose
        for a, b in cc.tolist():
            got = kernels.placed_centre(a, b, ck, sk, x, y)
            for j in range(2):
                chain = fma_exact(b, rot_t[1][j], fma_exact(a, rot_t[0][j], 0.0))
                assert got[j] == chain + poses[k, j]
        for m in range(starts[k], starts[k + 1]):
            d = points[m] - poses[k, :2]
            if counts[k] == 1:
                want = (points[m : m + 1] - poses[k, :2]) @ np.array([[c[k], -s[k]], [s[k], c[k]]])
                np.testing.assert_array_equal(lone[k], want[0])
                continue
            got = kernels.ego_point(float(points[m, 0]), float(points[m, 1]), ck, sk, x, y)
            for j in range(2):
                chain = fma_exact(
                    float(d[1]), rot_t[j][1], fma_exact(float(d[0]), rot_t[j][0], 0.0)
                )
                assert got[j] == chain


def test_resample_map__keeps_rows_by_id_in_any_order_and_samples_the_rest() -> None:
    """The sampler's cache through a run of table changes (rows reordered, removed, added, a
    stamp moved): the points equal the curves sampled afresh (the c0s stay, so kept points
    are exact), kept rows keep their pool rows unless the pool was compacted, and only the
    stale rows are appended."""
    rng = np.random.default_rng(7)
    cap = 8
    real = np.zeros((col.N_REAL, cap))
    index = np.zeros((col.N_INDEX, cap), dtype=np.int64)
    shape = np.zeros((cap, 3))
    curves = {}  # id → (variate, lo, hi, b1, b2, c0)
    cache = np.zeros((kernels.N_CACHE, cap), dtype=np.int64)
    cache_c0 = np.zeros(cap)
    pool, used, cached = np.zeros((0, 2)), 0, 0
    tables = [([0, 1, 2], [0, 0, 0]), ([2, 0, 1], [0, 0, 0]), ([2, 1], [0, 1]),
              ([2, 3, 1, 4], [0, 0, 1, 0]), ([4, 3, 2, 1], [0, 0, 0, 1]),
              ([4, 3, 2, 1], [1, 1, 0, 2]), ([4, 3, 2, 1], [2, 2, 0, 2]), ([], [])]  # fmt: skip
    for ids, stamps in tables:
        mean = np.zeros(3 + len(ids))
        for r, (i, stamp) in enumerate(zip(ids, stamps, strict=True)):
            if i not in curves:
                lo = rng.uniform(-2.0, 1.0)
                curves[i] = (int(rng.integers(1, 3)), lo, lo + rng.uniform(0.0, 2.0),
                             *rng.uniform(-1.0, 1.0, 3))  # fmt: skip
            variate, lo, hi, b1, b2, c0 = curves[i]
            index[col.ID, r], index[col.STAMP, r], index[col.VARIATE, r] = i, stamp, variate
            real[col.LO, r], real[col.HI, r] = lo, hi
            shape[r] = 0.0, b1, b2
            mean[3 + r] = c0
        n = len(ids)
        was = {int(i): (int(s), int(a)) for i, s, a in cache[[0, 1, 3], :cached].T.tolist()}
        before, before_used = pool, used
        pool, used, total = kernels.resample_map(
            cache, cache_c0, cached, index, real, shape, mean, n, 0.1, 512, pool, used
        )
        cached = n
        out = np.empty((total, 2))
        kernels.shifted_points(pool, cache, cache_c0, n, mean, out)
        coeffs = shape[:n].copy()
        coeffs[:, 0] = mean[3:]
        fresh = MapShapes(index[col.VARIATE, :n], coeffs, real[col.LO, :n], real[col.HI, :n])
        want, _ = sample_shapes(fresh, 0.1)
        np.testing.assert_array_equal(out, want)
        np.testing.assert_array_equal(cache[kernels.CACHE_ID, :n], ids)
        for r, i in enumerate(ids):
            start = int(cache[kernels.CACHE_START, r])
            if i in was and was[i][0] == stamps[r] and pool is before:
                assert start == was[i][1]  # kept where it was
            elif pool is before:
                assert start >= before_used  # appended


def test_team_status__equals_the_oracle() -> None:
    """Standard deviations of random covariances (negative, −0, NaN and inf diagonals among
    them: clipped at 0 as numpy's maximum) and the rendezvous counters (never among them)."""
    rng = np.random.default_rng(11)
    covs = rng.normal(0.0, 1.0, (6, 3, 3))
    covs[0, 0, 0], covs[0, 1, 1], covs[0, 2, 2] = -0.0, np.nan, np.inf
    covs[1, 2, 2] = 0.0
    last = np.array([-1, 0, 5, 40, -1, 41], dtype=np.int64)
    stds, since, step = np.empty((6, 3)), np.empty(6, np.int64), np.empty(6, np.int64)
    kernels.team_status(covs, last, 41, -1, stds, since, step)
    want = reference.team_status(covs, last, 41, -1)
    for got, expected in zip((stds, since, step), want, strict=True):
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == expected.dtype
    assert not np.signbit(stds[~np.isnan(stds)]).any()

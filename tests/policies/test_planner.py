"""The compiled planner against its readable oracles (``reference.py``): the path search, the
way out of the inflated zone, the window's frontier and the gain, on random grids and at every
step of a real episode; and the planner's discount hook."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import polyslam_env
from policies import make_team, window_kernels
from policies import planner_kernels as kernels
from policies.base import PolicyContext
from policies.frontier import FrontierPolicy
from policies.ownmap import OwnMap
from policies.planner import MARGIN, FrontierPlanner, free_start, grid_path
from policies.reading import read
from tests.policies import reference

RES, INFLATE, CLOSE = 0.1, 0.155, 3  # the frontier defaults: radius 0.065 + margin 0.09


def _random_grid(seed: int, shape: tuple[int, int], p: float) -> np.ndarray:
    return np.random.default_rng(seed).random(shape) < p


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    h=st.integers(1, 24),
    w=st.integers(1, 24),
    density=st.floats(0.3, 1.0),
    levels=st.sampled_from([(1.0,), (1.0, 2.0), (1.0, 1.5, 5.0), None]),
)
def test_dijkstra__matches_scipy_with_its_tie_breaking(
    seed: int, h: int, w: int, density: float, levels: tuple[float, ...] | None
) -> None:
    """Equal path costs, predecessors included: few cost levels make many ties (a uniform
    cost makes every straight-or-diagonal detour tie), which scipy breaks by its heap order."""
    rng = np.random.default_rng(seed)
    passable = rng.random((h, w)) < density
    cost = rng.uniform(1.0, 5.0, (h, w)) if levels is None else rng.choice(levels, (h, w))
    start = (int(rng.integers(h)), int(rng.integers(w)))
    dist, pred = grid_path(passable, cost, start)
    want_dist, want_pred = reference.grid_path(passable, cost, start)
    assert np.array_equal(dist, want_dist)
    assert np.array_equal(pred, want_pred)


#: Cells the way out of the inflated zone reaches (the readable version needs them inside the
#: grid; the planner's window reaches MARGIN ≥ that beyond the robot).
ESCAPE = math.ceil(INFLATE / RES + 1.0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), h=st.integers(7, 16), w=st.integers(7, 16))
def test_free_start__matches_readable(seed: int, h: int, w: int) -> None:
    rng = np.random.default_rng(seed)
    obst = rng.random((h, w)) < 0.2
    obst[0, 0] = True
    clearance = reference.frontier_and_cost(~obst, obst, INFLATE, CLOSE, RES)[3]
    passable = clearance > INFLATE
    start = (int(rng.integers(ESCAPE, h - ESCAPE)), int(rng.integers(ESCAPE, w - ESCAPE)))
    mine, want = passable.copy(), passable.copy()
    free_start(mine, clearance, start, INFLATE / RES + 1.0)
    reference.free_start(want, clearance, start, INFLATE / RES + 1.0)
    assert np.array_equal(mine, want)


def _own_map(
    seed: int, n: int, p_known: float, p_obst: float, inside: tuple[slice, slice] | None = None
) -> OwnMap:
    """An own map of n × n cells with random known blobs and obstacles among them (only
    ``inside`` that window when given)."""
    rng = np.random.default_rng(seed)
    m = OwnMap(n * RES, RES, INFLATE, 3 * INFLATE, CLOSE)
    blobs = rng.random((n, n)) < p_known
    m.free[...] = blobs | np.roll(blobs, 1, axis=0) | np.roll(blobs, 1, axis=1)
    m.occ[...] = rng.random((n, n)) < p_obst
    m.hit[...] = rng.random((n, n)) < p_obst / 4
    m.occ[m.hit] &= rng.random(int(m.hit.sum())) < 0.5
    if inside is not None:
        outside = np.ones((n, n), dtype=bool)
        outside[inside] = False
        m.occ[outside] = m.hit[outside] = False
    m.rebuild()
    return m


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.sampled_from([14, 30, 60]),
    p_known=st.floats(0.05, 0.6),
    p_obst=st.sampled_from([0.0, 0.02, 0.1]),
    corners=st.tuples(st.floats(0, 1), st.floats(0, 1), st.floats(0, 1), st.floats(0, 1)),
)
def test_window_frontier__is_the_readable_planners_on_any_window(
    seed: int, n: int, p_known: float, p_obst: float, corners: tuple[float, ...]
) -> None:
    """Any window of any map, near the map's edge or not, with or without obstacles (scipy's
    distance transform then measures from a virtual cell), against scipy on the window; and
    the search over it (clearance, soft cost, way out, paths). The window holds every
    obstacle, as the planner's windows (the known cells' box and more) do."""
    a, b = sorted(int(v * n) for v in corners[:2])
    c, d = sorted(int(v * n) for v in corners[2:])
    r0, r1, c0, c1 = a, max(b, a + 2 * ESCAPE + 1), c, max(d, c + 2 * ESCAPE + 1)
    assume(r1 <= n and c1 <= n)
    window = (slice(r0, r1), slice(c0, c1))
    m = _own_map(seed, n, p_known, p_obst, window)
    free, obstacles = m.free[window], m.obstacles[window]
    got = np.empty((r1 - r0, c1 - c0), dtype=bool)
    window_kernels.window_frontier(m.layers, r0, r1, c0, c1, got)
    want = reference.frontier_and_cost(free, obstacles, INFLATE, CLOSE, RES)[0]
    assert np.array_equal(got, want)
    start = ((r1 - r0) // 2, (c1 - c0) // 2)
    dist, pred = np.full(got.size, np.inf), np.full(got.size, kernels.NO_PRED, dtype=np.int32)
    room = kernels.queue((r1 - r0 + 2) * (c1 - c0 + 2))
    scratch = (np.full(n * n, np.inf), np.full(n * n, -1, np.int8), np.full(n * n, -1, np.int32))
    kernels.search(
        m.layers, r0, r1, c0, c1, *start, INFLATE / RES + 1.0, False, room, *scratch,
        kernels.no_goals(), False, 1.0, dist, pred,
    )  # fmt: skip
    _, want_dist, want_pred = reference.search(free, obstacles, start, INFLATE, CLOSE, RES)
    assert np.array_equal(dist.reshape(got.shape), want_dist)
    assert np.array_equal(pred, want_pred)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    p_known=st.floats(0.05, 0.6),
    p_obst=st.sampled_from([0.0, 0.02, 0.1]),
    robot=st.tuples(st.floats(0, 1), st.floats(0, 1)),
)
def test_paths__search_on_the_maps_layers_is_the_readable_planners(
    seed: int, p_known: float, p_obst: float, robot: tuple[float, float]
) -> None:
    """The planner's own windows (the known cells' box and the robot, grown by MARGIN): its
    search runs on the map's layers, then leaves them (and its scratch) as they were."""
    n = 50
    box = (slice(12, 38), slice(10, 30))
    m = _own_map(seed, n, p_known, p_obst, box)
    outside = np.ones((n, n), dtype=bool)
    outside[box] = False
    m.free[outside] = False
    m.rebuild()
    row, col = 12 + int(robot[0] * 25), 10 + int(robot[1] * 19)
    pose = np.array([*m.centre(row, col), 0.0])
    planner = FrontierPlanner(m, INFLATE / RES + 1.0, "square", 10, 8.0, 0.8)
    layers = [a.copy() for a in (m.layers.passable, m.layers.d2)]
    paths = planner.paths(pose)
    assert paths is not None
    free, obstacles = m.free[paths.window], m.obstacles[paths.window]
    frontier, dist, pred = reference.search(free, obstacles, paths.start, INFLATE, CLOSE, RES)
    assert np.array_equal(paths.frontier, frontier)
    assert np.array_equal(paths.dist, dist * RES)
    assert np.array_equal(paths.pred, pred)
    assert all(
        np.array_equal(a, b) for a, b in zip(layers, (m.layers.passable, m.layers.d2), strict=True)
    )
    dist_map, came_map, goal_map = planner._scratch
    assert np.isinf(dist_map).all() and (came_map == -1).all() and (goal_map == -1).all()


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.sampled_from([14, 30, 60]),
    p_known=st.floats(0.05, 0.6),
    p_obst=st.sampled_from([0.0, 0.02, 0.1]),
    where=st.tuples(st.floats(0, 1), st.floats(0, 1)),
    reach=st.integers(0, 4),
)
def test_frontier_near__is_the_readable_planners_goal_test_over_the_square(
    seed: int, n: int, p_known: float, p_obst: float, where: tuple[float, float], reach: int
) -> None:
    """Whether the frontier left a goal's neighbourhood (the policy's replan test): true when
    a cell within ``reach`` (Chebyshev, inside the map) is a frontier by the readable planner
    on a window around that cell, obstacles anywhere, near the map's edge or not; with reach 0,
    the goal test of the cell alone (``still_frontier``)."""
    m = _own_map(seed, n, p_known, p_obst)
    r, c = min(int(where[0] * n), n - 1), min(int(where[1] * n), n - 1)
    half = 2 * CLOSE + 4 + math.ceil(INFLATE / RES)
    want = False
    for y in range(max(r - reach, 0), min(r + reach + 1, n)):
        for x in range(max(c - reach, 0), min(c + reach + 1, n)):
            y0, x0 = max(y - half, 0), max(x - half, 0)
            small = (slice(y0, y + half + 1), slice(x0, x + half + 1))
            frontier = reference.frontier_and_cost(
                m.free[small], m.obstacles[small], INFLATE, CLOSE, RES
            )[0]
            want = want or bool(frontier[y - y0, x - x0])
    planner = FrontierPlanner(m, INFLATE / RES + 1.0, "square", 10, 8.0, 0.8)
    assert planner.frontier_near((r, c), reach) == want
    if reach == 0:
        assert planner.still_frontier((r, c)) == want


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.sampled_from([14, 40]),
    p_known=st.floats(0.0, 0.9),
    cells=st.integers(1, 6),
)
def test_square_gain__is_scipys_uniform_filter_to_the_bit(
    seed: int, n: int, p_known: float, cells: int
) -> None:
    rng = np.random.default_rng(seed)
    known = rng.random((n, n)) < p_known
    r0, c0 = int(rng.integers(n)), int(rng.integers(n))
    r1, c1 = int(rng.integers(r0, n)) + 1, int(rng.integers(c0, n)) + 1
    pick = rng.random((r1 - r0, c1 - c0)) < 0.3
    rows, cols = np.nonzero(pick)
    got = window_kernels.square_gain(
        known.reshape(-1), n, r0, r1, c0, c1, 2 * cells + 1, rows, cols
    )
    want = reference.square_gain(known[r0:r1, c0:c1], cells)[rows, cols]
    assert got.dtype == np.float32 and np.array_equal(got, want)


# -- a real episode ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def episode() -> list[tuple[FrontierPolicy, np.ndarray, int]]:
    """(policy, pose it acted on, step) of two robots on an office floor, every step for 60
    steps; the checks run as the episode plays, on each robot's map as it is then."""
    env = polyslam_env.parallel_env(
        map="generator:office_floor", num_robots=2, max_steps=60, coverage_target=None
    )
    team = make_team("frontier", env)
    obs, _ = env.reset(seed=11)
    team.reset(11)
    rng = np.random.default_rng(11)
    checked = []
    step = 0
    while env.agents:
        actions = team.act(obs, rng)
        for agent, policy in team.policies.items():
            assert isinstance(policy, FrontierPolicy)
            _check_planner(policy, read(policy.context, obs[agent]).pose, step)
            checked.append((policy, obs[agent], step))
        obs, *_ = env.step(actions)
        step += 1
    return checked


def _check_planner(policy: FrontierPolicy, pose: np.ndarray, step: int) -> None:
    m = policy.map
    window = m.bbox(pose, MARGIN)
    free, obstacles = m.free[window], m.obstacles[window]
    paths = policy.planner.paths(pose)
    assert paths is not None
    frontier, dist, pred = reference.search(free, obstacles, paths.start, INFLATE, CLOSE, RES)
    assert paths.window == window
    assert np.array_equal(paths.frontier, frontier), step
    assert np.array_equal(paths.dist, dist * m.res), step
    assert np.array_equal(paths.pred, pred), step
    # the gain of the reachable frontier cells, on the window
    rows, cols = np.nonzero(frontier & np.isfinite(dist))
    if len(rows):
        (r0, r1), (c0, c1) = (window[0].start, window[0].stop), (window[1].start, window[1].stop)
        gain = window_kernels.square_gain(m.layers.known, m.n, r0, r1, c0, c1, 21, rows, cols)
        want = reference.square_gain(free | obstacles, 10)[rows, cols]
        assert np.array_equal(gain, want), step
    # the goal test of the readable planner: the frontier on a window around the goal
    if policy.goal is not None:
        r, c = policy.goal
        half = 2 * CLOSE + 4 + math.ceil(INFLATE / RES)
        r0, c0 = max(r - half, 0), max(c - half, 0)
        small = (slice(r0, r + half + 1), slice(c0, c + half + 1))
        want_f = reference.frontier_and_cost(m.free[small], m.obstacles[small], INFLATE, CLOSE, RES)
        assert policy.planner.still_frontier(policy.goal) == want_f[0][r - r0, c - c0], step


def test_planner__is_the_readable_one_at_every_step_of_an_episode(episode: list[Any]) -> None:
    assert len(episode) == 2 * 60  # every check ran (in the fixture, on the live maps)


def test_rank__the_discount_hook_scales_each_frontiers_utility() -> None:
    """A policy whose ``frontier_discount`` halves every frontier's utility ranks the same
    candidates at half the utility; one that zeroes the best frontier's picks another."""
    env = polyslam_env.parallel_env(map="generator:office_floor", num_robots=1, max_steps=40)
    ctx = PolicyContext.from_env(env, "robot_0")
    plain = FrontierPolicy(ctx)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs, *_ = env.step({"robot_0": plain.act(obs["robot_0"], rng)})
    pose = plain._sense(obs["robot_0"])[0]
    base = plain._search(pose)
    assert base is not None
    best = plain.map.centre(
        base.best()[0] + base.window[0].start, base.best()[1] + base.window[1].start
    )

    class Scaled(FrontierPolicy):
        factor = 0.5

        def frontier_discount(self, points: np.ndarray) -> np.ndarray:
            if self.factor > 0:
                return np.full(len(points), self.factor)
            return np.where(np.all(points == best, axis=1), 0.0, 1.0)

    scaled = Scaled.__new__(Scaled)
    scaled.__dict__.update(plain.__dict__)  # the same map, blacklist and claims
    search = scaled._search(pose)
    assert search is not None
    finite = np.isfinite(base.utility)
    assert np.array_equal(np.isfinite(search.utility), finite)
    assert np.array_equal(search.utility[finite], base.utility[finite] * 0.5)
    scaled.factor = 0.0
    search = scaled._search(pose)
    assert search is not None and search.best() != base.best()

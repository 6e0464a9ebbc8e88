"""The own map's incremental layers (clearance, passable, frontier) against scipy on the whole
map, after random edits (obstacles added and removed) and at every step of a real episode; and
the observation reading against the context's decoders."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import polyslam_env
from policies import make_team
from policies.base import PolicyContext
from policies.frontier import FrontierPolicy
from policies.ownmap import OwnMap
from policies.ownmap_kernels import update_layers
from policies.reading import read
from tests.policies import reference

RES, INFLATE, CLOSE = 0.1, 0.155, 3
#: Unknown cells around the map for scipy: its border rules reach 2 · 3 + 3 cells in.
PAD = 12


def _assert_layers(m: OwnMap) -> None:
    """The layers equal scipy's on the whole map: squared clearance where it is exact (and
    "far" where it is not), passable and frontier cells everywhere."""
    if not m.obstacles.any():
        assert (m.d2 == m.r2 + 1).all()
    else:
        d2, passable, frontier = reference.whole_map_layers(
            m.free, m.occ, m.hit, INFLATE, CLOSE, RES, PAD
        )
        exact = d2 <= m.r2
        assert np.array_equal(m.d2[exact], d2[exact].astype(np.int64))
        assert (m.d2[~exact] == m.r2 + 1).all()
        assert np.array_equal(m.passable, passable)
        assert np.array_equal(m.frontier, frontier)
    known = m.free | m.obstacles
    rows, cols = np.nonzero(known)
    if len(rows):
        assert tuple(m.layers.bbox) == (rows.min(), rows.max(), cols.min(), cols.max())


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), batches=st.integers(1, 6))
def test_layers__follow_random_edits_as_scipy_sees_them(seed: int, batches: int) -> None:
    """Batches of random changes — cells becoming free, occupied cells appearing and being
    cleared (the own polynomials move), beam hits — each folded in incrementally."""
    rng = np.random.default_rng(seed)
    n = 60  # the edits stay 2 · 3 + 3 cells from the map's edge (module ownmap_kernels)
    m = OwnMap(n * RES, RES, INFLATE, 3 * INFLATE, CLOSE)
    for _ in range(batches):
        centre = rng.integers(6 + 10, n - 6 - 10, 2)
        box = (slice(centre[0] - 6, centre[0] + 6), slice(centre[1] - 6, centre[1] + 6))
        before = np.stack([m.free, m.occ, m.hit]).copy()
        m.free[box] |= rng.random((12, 12)) < 0.5
        newly_occ = rng.random((12, 12)) < 0.08
        m.occ[box] |= newly_occ
        cleared = (rng.random((12, 12)) < 0.3) & m.occ[box]
        m.occ[box] &= ~cleared
        m.free[box] |= cleared  # a cleared occupied cell is free
        m.hit[box] |= rng.random((12, 12)) < 0.02
        changed = np.any(np.stack([m.free, m.occ, m.hit]) != before, axis=0)
        update_layers(np.flatnonzero(changed), m.layers)
        _assert_layers(m)


@pytest.fixture(scope="module")
def episode() -> int:
    """Three robots, 80 steps of a warehouse: the layers of every robot's map checked after
    every step; returns the steps checked."""
    env = polyslam_env.parallel_env(
        map="generator:warehouse", num_robots=3, max_steps=80, coverage_target=None
    )
    team = make_team("frontier", env)
    obs, _ = env.reset(seed=5)
    team.reset(5)
    rng = np.random.default_rng(5)
    steps = 0
    while env.agents:
        obs, *_ = env.step(team.act(obs, rng))
        for policy in team.policies.values():
            assert isinstance(policy, FrontierPolicy)
            if steps % 4 == 0:
                _assert_layers(policy.map)
        steps += 1
    return steps


def test_layers__are_scipys_through_an_episode(episode: int) -> None:
    assert episode == 80


def test_read__gives_what_the_context_decodes() -> None:
    """Every step until the robots have seen each other (at least 30)."""
    env = polyslam_env.parallel_env(map="generator:loop", num_robots=3, max_steps=300)
    team = make_team("frontier", env)
    contexts = {a: PolicyContext.from_env(env, a) for a in env.possible_agents}
    obs, _ = env.reset(seed=4)
    team.reset(4)
    rng = np.random.default_rng(4)
    seen = steps = 0
    while env.agents and (steps < 30 or seen == 0):
        for agent in env.agents:
            ctx = contexts[agent]
            got = read(ctx, obs[agent])
            local = ctx.local_grid(obs[agent])
            assert np.array_equal(got.pose, ctx.pose(obs[agent]))
            assert np.array_equal(got.ranges, ctx.ranges(obs[agent]))
            assert np.array_equal(got.occ, local[0]) and np.array_equal(got.free, local[1])
            assert np.array_equal(got.detections, ctx.detections(obs[agent]))
            seen += len(got.detections)
        obs, *_ = env.step(team.act(obs, rng))
        steps += 1
    assert seen > 0  # robots saw each other

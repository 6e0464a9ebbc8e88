"""Unit tests of the on-board observation pieces (belief grid, encoder) against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import MIN_POSE_SCALE, EnvConfig, ObservationConfig
from polyslam_env.environment.observations import BeliefGrid, belief_grids, sweep_beliefs
from polyslam_env.environment.parallel import PolySlamParallelEnv, parallel_env
from tests.environment.reference import MapSamplerOracle


def _brute_force_sweep(
    grid: BeliefGrid, pose: np.ndarray, angles: np.ndarray, ranges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(free, hit) (n, n) marked one beam sample at a time, as the docstring describes."""
    free = np.zeros((grid.n, grid.n), dtype=bool)
    hit = np.zeros_like(free)
    samples = grid._t.size

    def mark(mask: np.ndarray, x: float, y: float) -> None:
        col = math.floor((x - grid.origin) / grid.resolution)
        row = math.floor((y - grid.origin) / grid.resolution)
        if 0 <= row < grid.n and 0 <= col < grid.n:
            mask[row, col] = True

    for a, r in zip(angles, ranges, strict=True):
        phi = pose[2] + a
        c, s = math.cos(phi), math.sin(phi)
        finite = math.isfinite(r)
        reach = min(r, grid.max_range) if finite else grid.max_range
        length = max(reach - 0.5 * grid.resolution, 0.0) if finite else reach
        for k in range(samples):
            t = length * (k / (samples - 1))
            mark(free, pose[0] + t * c, pose[1] + t * s)
        if finite:
            mark(hit, pose[0] + reach * c, pose[1] + reach * s)
    return free, hit


def test_belief_grid__sweep_matches_brute_force_samples() -> None:
    rng = np.random.default_rng(3)
    grid = BeliefGrid(size=4.0, resolution=0.1, max_range=1.5)
    expected_free = np.zeros_like(grid.free)
    expected_hit = np.zeros_like(grid.hit)
    angles = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])
    for _ in range(30):
        pose = np.array([*rng.uniform(-2.5, 2.5, 2), rng.uniform(-np.pi, np.pi)])
        ranges = np.where(rng.uniform(size=5) < 0.3, np.inf, rng.uniform(0.0, 2.0, 5))
        grid.sweep(pose, angles, ranges)
        free, hit = _brute_force_sweep(grid, pose, angles, ranges)
        expected_free |= free
        expected_hit |= hit
    # Samples sitting exactly on a cell edge could round either way; none do in this draw.
    assert np.array_equal(grid.free, expected_free)
    assert np.array_equal(grid.hit, expected_hit)
    assert grid.free.any() and grid.hit.any()


def test_sweep_beliefs__several_robots_at_once_equal_separate_sweeps() -> None:
    rng = np.random.default_rng(5)
    angles = np.deg2rad([90.0, 45.0, 0.0, -45.0, -90.0])
    together = [BeliefGrid(4.0, 0.1, 1.5) for _ in range(3)]
    apart = [BeliefGrid(4.0, 0.1, 1.5) for _ in range(3)]
    for _ in range(10):
        poses = np.column_stack([rng.uniform(-2.5, 2.5, (3, 2)), rng.uniform(-4, 4, 3)])
        ranges = np.where(rng.uniform(size=(3, 5)) < 0.3, np.inf, rng.uniform(0, 2, (3, 5)))
        sweep_beliefs(together, poses, angles, ranges)
        for grid, pose, r in zip(apart, poses, ranges, strict=True):
            grid.sweep(pose, angles, r)
    for a, b in zip(together, apart, strict=True):
        assert np.array_equal(a.free, b.free) and np.array_equal(a.hit, b.hit)
    with pytest.raises(ValueError, match="same size"):
        sweep_beliefs([together[0], BeliefGrid(4.0, 0.2, 1.5)], poses[:2], angles, ranges[:2])


def test_observations__vector_mode_folds_the_grid_mode_channels() -> None:
    envs = {
        mode: parallel_env(map="two_rooms", num_robots=2, observation__mode=mode)
        for mode in ("vector", "grid")
    }
    obs = {mode: env.reset(seed=4)[0] for mode, env in envs.items()}
    rng = np.random.default_rng(4)
    layout = envs["vector"]._encoder.vector_layout
    g = envs["vector"]._encoder.g
    for _ in range(30):
        actions = {a: rng.uniform([0.0, -0.5], [0.2, 0.5]) for a in envs["vector"].agents}
        obs = {mode: env.step(actions)[0] for mode, env in envs.items()}
        for agent, vec in obs["vector"].items():
            grid, short = obs["grid"][agent]["grid"], obs["grid"][agent]["vector"]
            folded = grid[0] * 1.0 + grid[2] * 0.5  # occupied 1, unknown 0.5, free 0
            assert np.array_equal(vec[layout["local_map"]].reshape(g, g), folded)
            rest = np.delete(vec, np.arange(len(vec))[layout["local_map"]])
            assert np.array_equal(rest, short)


@settings(max_examples=200, deadline=None)
@given(
    size=st.tuples(st.floats(0.5, 60.0), st.floats(0.5, 60.0)),
    u=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0, 1)),
    heading=st.floats(-math.pi, math.pi),
    drift=st.tuples(st.floats(0.0, 0.999), st.floats(-math.pi, math.pi)),
)
def test_belief_grid__default_size_holds_the_map_seen_from_any_start(
    size: tuple[float, float],
    u: tuple[float, float, float, float],
    heading: float,
    drift: tuple[float, float],
) -> None:
    # Any start and any point of a w × h box, the point placed with an estimate that drifted
    # up to one max range (the margin the default size states), fall inside the grid.
    max_range = 2.0
    (grid,) = belief_grids(ObservationConfig(), (0.0, 0.0, *size), max_range, 1)
    w, h = size
    start, point = np.array([u[0] * w, u[1] * h]), np.array([u[2] * w, u[3] * h])
    c, s = math.cos(heading), math.sin(heading)
    own = (point - start) @ np.array([[c, -s], [s, c]])  # the point in the start frame
    own += drift[0] * max_range * np.array([math.cos(drift[1]), math.sin(drift[1])])
    assert grid.inside(own[None])[0]
    assert grid.n % 2 == 0  # cell edges on multiples of the resolution from the start


def test_belief_grid__env_grids_hold_every_wall_of_a_large_map_in_each_start_frame() -> None:
    params = {"width": 24, "height": 14, "min_room_size": 1.5, "max_room_size": 5}
    env = parallel_env(map="generator:rooms", map_params=params, num_robots=3)
    env.reset(seed=2)
    state = env.episode
    assert state is not None
    walls = np.vstack(state.world.layout.walls)  # (V, 2) absolute
    for grid, (x, y, th) in zip(state.beliefs, state.start_poses, strict=True):
        c, s = math.cos(th), math.sin(th)
        own = (walls - (x, y)) @ np.array([[c, -s], [s, c]])
        assert grid.inside(own).all()
    # the former fixed 16 m grid would not: the map's diagonal alone is 27.8 m
    assert not BeliefGrid(16.0, 0.1, 2.0).inside(np.array([[0.0, math.hypot(24, 14)]]))[0]


def test_observation_config__explicit_sizes_are_kept_and_null_ones_follow_the_map() -> None:
    oc = ObservationConfig()
    small, large = (6.0, 4.0), (24.0, 14.0)
    # 20 m (the fixed scale of small maps) where the reach (diagonal + range) is below it
    assert oc.position_scale(small, 2.0) == MIN_POSE_SCALE
    assert oc.position_scale(large, 2.0) == pytest.approx(math.hypot(24, 14) + 2.0)
    assert ObservationConfig(pose_scale=5.0).position_scale(large, 2.0) == 5.0
    assert ObservationConfig(belief_size=16.0).belief_side(large, 2.0) == 16.0
    assert BeliefGrid(16.0, 0.1, 2.0).n == 160
    env = parallel_env(map="generator:rooms", map_params={"width": 24, "height": 14})
    facts = env.public_facts()
    assert facts["map_size"] == large
    assert facts["pose_scale"] == oc.position_scale(large, 2.0)


def test_observation_config__a_derived_grid_too_large_is_a_one_line_error() -> None:
    with pytest.raises(ConfigError, match=r"observation\.belief_size: .*cells a side") as err:
        parallel_env(map="generator:rooms", map_params={"width": 300, "height": 300})
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match=r"observation\.belief_size"):
        ObservationConfig(belief_size=500.0)


def test_map_sampler__points_equal_the_readable_per_landmark_cache_bit_for_bit() -> None:
    """The sampler's arrays against :class:`~tests.environment.reference.MapSamplerOracle`
    (a dict per landmark) after every step of a seeded episode with landmarks created,
    refit, extended and merged away (asserted: the test must see rows vanish)."""
    env = PolySlamParallelEnv(EnvConfig.from_dict({"max_steps": 300}))
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    team = env.episode.slam
    oracles = [MapSamplerOracle(s.step) for s in team.samplers]  # type: ignore[attr-defined]
    seen = [set[int]() for _ in oracles]
    vanished = 0
    while env.agents:
        env.step({a: rng.uniform([0.2, -1.0], [1.0, 1.0]) for a in env.agents})
        for i, oracle in enumerate(oracles):
            slam = team.robots[i]
            np.testing.assert_array_equal(team.map_points(i), oracle.points(slam))
            ids = set(slam.table.ids)
            vanished += len(seen[i] - ids)
            seen[i] = ids
    assert vanished > 0

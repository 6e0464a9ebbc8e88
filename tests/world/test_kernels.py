"""The world's compiled kernels against their readable numpy oracles (``reference.py``).

The kernels do the same float operations in the same order as the oracles, so every test asks
for exact equality (``inf`` included), on random inputs and on the edge cases of ray casting:
rays through wall end points, parallel to walls, starting on a wall, hits at exactly the
maximum range; robots hidden behind robots (which do not occlude) and behind walls.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.core.seeding import make_rngs
from polyslam_env.world import kernels
from polyslam_env.world.config import CameraConfig, RangeSensorConfig, WorldConfig
from polyslam_env.world.maps import load_map
from polyslam_env.world.nearby import WallIndex, wall_index
from polyslam_env.world.physics import GUARD_TOLERANCE, World
from polyslam_env.world.sensors import Camera, RangeSensor, cast_rays
from tests.world import reference

NO_CIRC = np.zeros((0, 3))


def _random_walls(rng: np.random.Generator, n: int) -> np.ndarray:  # (n, 4)
    """Random segments plus axis-aligned ones and a few of zero length."""
    segs = rng.uniform(-3.0, 3.0, (n, 4))
    segs[: n // 4, 3] = segs[: n // 4, 1]  # horizontal
    segs[n // 4 : n // 2, 2] = segs[n // 4 : n // 2, 0]  # vertical
    segs[-2:, 2:] = segs[-2:, :2]  # points
    return segs


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("cell", [0.13, 0.5, 2.0])
def test_cast_rays__equals_the_oracle_on_random_rays(seed: int, cell: float) -> None:
    rng = np.random.default_rng(seed)
    segs = _random_walls(rng, 40)
    circles = np.column_stack([rng.uniform(-3, 3, (5, 2)), rng.uniform(0.05, 0.4, 5)])
    origins = rng.uniform(-3.5, 3.5, (400, 2))
    angles = rng.uniform(-4.0, 4.0, 400)
    exclude = rng.integers(-1, 5, 400)
    index = WallIndex.build(segs, cell)
    for max_range in (0.7, 2.5, math.inf):
        want = reference.cast_rays(origins, angles, segs, circles, max_range, exclude)
        got = cast_rays(origins, angles, index, circles, max_range, exclude)
        np.testing.assert_array_equal(got, want)


def test_cast_rays__edge_cases_equal_the_oracle() -> None:
    segs = np.array([[0.0, 0.0, 2.0, 0.0], [2.0, 0.0, 2.0, 2.0], [-1.0, 1.0, -1.0, 1.0]])
    origins, angles = [], []
    for ox, oy in [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (1.0, -1.0), (1.0, 1.0), (3.0, 1.0)]:
        for a in np.linspace(-math.pi, math.pi, 17):  # axis-parallel and diagonal included
            origins.append((ox, oy))
            angles.append(a)
    for ex, ey in [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (-1.0, 1.0)]:  # through end points
        origins.append((1.0, 1.0))
        angles.append(math.atan2(ey - 1.0, ex - 1.0))
    origins.append((1.0, 1.0))  # hit at exactly the maximum range
    angles.append(-math.pi / 2)
    o, a = np.array(origins), np.array(angles)
    for max_range in (1.0, 5.0):
        want = reference.cast_rays(o, a, segs, NO_CIRC, max_range)
        np.testing.assert_array_equal(cast_rays(o, a, segs, NO_CIRC, max_range), want)
    assert cast_rays(np.array([[1.0, 1.0]]), np.array([-math.pi / 2]), segs, NO_CIRC, 1.0)[0] == 1.0


@pytest.mark.parametrize("hit_robots", [False, True])
def test_beam_ranges__equal_the_oracle_on_the_paper_map(hit_robots: bool) -> None:
    layout = load_map("paper", robot_radius=0.065)
    rng = np.random.default_rng(3)
    lo, hi = layout.segments.reshape(-1, 2).min(0), layout.segments.reshape(-1, 2).max(0)
    cfg = RangeSensorConfig(angles_deg=(90.0, 30.0, 0.0, -45.0, -90.0), hit_robots=hit_robots)
    sensor = RangeSensor(cfg)
    pillars = np.array([[2.0, 2.0, 0.2], [5.0, 3.0, 0.1]])
    for _ in range(50):
        poses = np.column_stack([rng.uniform(lo, hi, (6, 2)), rng.uniform(-4, 4, 6)])
        want = reference.true_ranges(
            poses, sensor.angles, cfg.max_range, layout.segments, pillars, 0.065, hit_robots
        )
        got = sensor.true_ranges(poses, wall_index(layout), pillars, 0.065)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("fov_deg", [90.0, 360.0])
def test_camera_visible__equals_the_oracle(fov_deg: float) -> None:
    rng = np.random.default_rng(4)
    segs = _random_walls(rng, 12)
    pillars = np.array([[0.5, 0.5, 0.2]])
    cam = Camera(CameraConfig(range=3.0, fov_deg=fov_deg))
    index = WallIndex.build(segs)
    for _ in range(100):
        n = int(rng.integers(1, 7))
        poses = np.column_stack([rng.uniform(-3, 3, (n, 2)), rng.uniform(-4, 4, n)])
        active = rng.uniform(size=n) < 0.8
        want = reference.camera_visible(poses, active, segs, pillars, 3.0, fov_deg)
        got = cam.visible(poses, active, index, pillars)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)


def test_camera_visible__robots_behind_robots_are_seen_walls_hide() -> None:
    poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    wall = np.array([[-0.5, 0.5, 0.5, 0.5]])  # between robot 0 and robot 3
    active = np.ones(4, dtype=bool)
    cam = Camera(CameraConfig(range=3.0, fov_deg=360.0))
    mask, _, _ = cam.visible(poses, active, wall, NO_CIRC)
    want, _, _ = reference.camera_visible(poses, active, wall, NO_CIRC, 3.0, 360.0)
    np.testing.assert_array_equal(mask, want)
    assert mask[0, 2] and mask[2, 0]  # through robot 1
    assert not mask[0, 3] and not mask[3, 0]


def test_guard__equals_the_oracle_on_random_paths() -> None:
    layout = load_map("paper", robot_radius=0.065)
    cfg = WorldConfig()
    world = World(layout, cfg, 3, make_rngs(0))
    rng = np.random.default_rng(2)
    lo, hi = layout.segments.reshape(-1, 2).min(0), layout.segments.reshape(-1, 2).max(0)
    r, wr = cfg.robot.radius, cfg.wall_radius
    pillars = np.array([[3.0, 3.0, 0.3]])
    bad = np.empty(3, dtype=bool)
    crossings = deep = 0
    for _ in range(3000):
        start = np.column_stack([rng.uniform(lo, hi, (3, 2)), np.zeros(3)])
        step = rng.normal(size=(3, 2)) * rng.uniform(0.0, 0.6)
        end = start + np.column_stack([step, np.zeros(3)])
        active = rng.uniform(size=3) < 0.9
        crossed = reference.segments_cross(start[:, :2], end[:, :2], layout.segments)
        too_deep = reference.too_deep(end[:, :2], layout.segments, pillars, r, wr, GUARD_TOLERANCE)
        kernels.guard_violations(
            start, end, active, r + wr - GUARD_TOLERANCE, r - GUARD_TOLERANCE, *world._walls,
            pillars, bad,
        )  # fmt: skip
        np.testing.assert_array_equal(bad, (crossed | too_deep) & active)
        crossings += int(crossed.sum())
        deep += int(too_deep.sum())
    assert crossings > 50 and deep > 50  # both cases were exercised


def test_drive_forces__equal_the_oracle() -> None:
    rng = np.random.default_rng(5)
    cmd = np.column_stack([rng.uniform(-0.3, 0.3, 50), rng.uniform(-2, 2, 50)])
    cmd[:5, 1] = 0.0  # straight: sinc(0) = 1
    cmd[5:10, 0] = 0.0
    heading = rng.uniform(-10, 10, 50)
    out = np.empty((50, 20, 2))
    kernels.drive_forces(heading, cmd, 0.005, 20, 1.3, out)
    np.testing.assert_array_equal(out, reference.drive_forces(heading, cmd, 0.005, 20, 1.3))


def test_motion_end__equals_the_numpy_expressions() -> None:
    # heading θ + ω dt, and pushed = the end is off the start moved by Σ forces · h²/m
    rng = np.random.default_rng(7)
    n, substeps, dt, drift, tol = 40, 10, 1.0, 0.1**2 / 1.3, 1e-9
    pose = np.column_stack([rng.uniform(-5, 5, (n, 2)), rng.uniform(-9, 9, n)])
    cmd = rng.uniform(-1, 1, (n, 2))
    force = rng.normal(0, 2, (n, substeps, 2))
    end = np.empty((n, 3))
    end[:, :2] = pose[:, :2] + force.sum(axis=1) * drift  # free ends
    end[::3, :2] += rng.normal(0, 1e-3, (len(end[::3]), 2))  # pushed ones
    end[1::6, :2] += 1e-10  # within the tolerance
    touched = np.empty(n, dtype=bool)
    kernels.motion_end(pose, cmd, dt, force, drift, tol, end, touched)
    np.testing.assert_array_equal(end[:, 2], pose[:, 2] + cmd[:, 1] * dt)
    off = end[:, :2] - pose[:, :2] - force.sum(axis=1) * drift
    np.testing.assert_array_equal(touched, (off * off).sum(axis=1) > tol**2)
    assert touched[::3].all() and not touched[1::6].any()


@pytest.mark.parametrize("cell", [0.1, 0.5, 3.0])
def test_wall_index__lists_every_segment_that_meets_a_box(cell: float) -> None:
    rng = np.random.default_rng(6)
    segs = _random_walls(rng, 30)
    index = WallIndex.build(segs, cell)
    for _ in range(300):
        lo = rng.uniform(-4, 4, 2)
        hi = lo + rng.uniform(0, 1.5, 2)
        # A segment meets the box if a dense sample of it falls inside (a safe under-count).
        t = np.linspace(0.0, 1.0, 200)[:, None, None]
        pts = segs[None, :, :2] + t * (segs[None, :, 2:] - segs[None, :, :2])  # (200, S, 2)
        meets = ((pts >= lo) & (pts <= hi)).all(axis=-1).any(axis=0)
        assert set(np.flatnonzero(meets)) <= set(index.candidates(lo, hi).tolist())
    assert len(WallIndex.build(np.zeros((0, 4))).candidates(np.zeros(2), np.ones(2))) == 0


def test_wall_index__cached_per_layout_and_bad_cell_raises() -> None:
    layout = load_map("paper", robot_radius=0.065)
    assert wall_index(layout) is wall_index(layout)
    with pytest.raises(ValueError, match="cell"):
        WallIndex.build(layout.segments, 0.0)


def test_camera_noise__equals_the_oracle() -> None:
    rng = np.random.default_rng(7)
    dist = rng.uniform(0.0, 0.05, (9, 9))  # some noisy distances below 0
    bearing = rng.uniform(-math.pi, math.pi, (9, 9))
    bearing[0, :3] = (math.pi, -math.pi, 0.0)
    noise = rng.standard_normal((9, 9, 2))
    d, b = np.empty((9, 9)), np.empty((9, 9))
    kernels.camera_noise(dist, bearing, noise, 0.02, 0.5, d, b)
    want_d, want_b = reference.camera_noise(dist, bearing, noise, 0.02, 0.5)
    np.testing.assert_array_equal(d, want_d)
    np.testing.assert_array_equal(b, want_b)
    assert (d == 0.0).any()


def test_noisy_ranges__equal_the_oracle() -> None:
    """Ranges with noise clipped at 0 as numpy's maximum: no return (inf) stays inf, NaN stays
    NaN, a sum of −0 becomes 0."""
    rng = np.random.default_rng(9)
    true = rng.uniform(0.0, 0.05, (7, 5))  # some noisy ranges below 0
    true[0] = (np.inf, np.nan, 0.0, -0.0, 2.0)
    noise = rng.standard_normal((7, 5))
    noise[0, 2:4] = -0.0
    out = np.empty((7, 5))
    kernels.noisy_ranges(true, noise, 0.02, out)
    want = reference.noisy_ranges(true, noise, 0.02)
    np.testing.assert_array_equal(out, want)
    assert not np.signbit(out[~np.isnan(out)]).any()
    assert (out == 0.0).any()


def test_clip_commands__equals_numpy_clip_bit_for_bit() -> None:
    rng = np.random.default_rng(11)
    cmd = rng.uniform(-3.0, 3.0, (400, 2))
    cmd[:8] = [[0.0, -0.0], [-0.0, 0.0], [1.0, 2.0], [-1.0, -2.0], [0.5, 5.0], [-5.0, -0.5],
               [1e-300, -1e-300], [-1e-300, 1e-300]]  # fmt: skip
    active = rng.random(400) < 0.8
    for lo in (np.array([-1.0, -2.0]), np.array([0.0, -2.0])):
        hi = np.array([1.0, 2.0])
        out = np.empty_like(cmd)
        assert kernels.clip_commands(cmd, lo, hi, active, out) == -1
        expected = reference.clip_commands(cmd, lo, hi, active)
        np.testing.assert_array_equal(out, expected)
        np.testing.assert_array_equal(np.signbit(out), np.signbit(expected))
    cmd[7, 1], cmd[9, 0] = math.nan, math.inf
    assert kernels.clip_commands(cmd, lo, hi, active, np.empty_like(cmd)) == 7

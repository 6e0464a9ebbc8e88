"""Range beams and camera, checked against plain per-ray loops and hand-made geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import CameraConfig, RangeSensorConfig, WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World
from polyslam_env.world.sensors import Camera, RangeSensor, cast_rays


def brute_ray(
    o: np.ndarray,
    ang: float,
    segments: np.ndarray,
    circles: np.ndarray,
    max_range: float,
    skip: int = -1,
) -> float:
    """First hit along one ray, one obstacle at a time, by solving the 2×2 / quadratic."""
    d = np.array([math.cos(ang), math.sin(ang)])
    best = math.inf
    for x0, y0, x1, y1 in segments:
        a, e = np.array([x0, y0]), np.array([x1 - x0, y1 - y0])
        m = np.column_stack([d, -e])  # o + t d = a + u e
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        t, u = np.linalg.solve(m, a - o)
        if t >= 0 and 0 <= u <= 1:
            best = min(best, t)
    for k, (cx, cy, r) in enumerate(circles):
        if k == skip:
            continue
        f = o - np.array([cx, cy])
        b, c = float(f @ d), float(f @ f - r * r)
        if b * b - c < 0:
            continue
        t0, t1 = -b - math.sqrt(b * b - c), -b + math.sqrt(b * b - c)
        if t0 >= 0:
            best = min(best, t0)
        elif t1 >= 0:
            best = 0.0  # starts inside the circle
    return best if best <= max_range else math.inf


def _floats(shape: tuple[int, ...], lo: float, hi: float) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(np.float64, shape, elements=st.floats(lo, hi))


@settings(max_examples=30, deadline=None)
@given(
    segments=st.integers(0, 8).flatmap(lambda n: _floats((n, 4), -2.0, 2.0)),
    centres=_floats((3, 2), -2.0, 2.0),
    radii=_floats((3,), 0.05, 0.3),
    rays=st.integers(1, 20).flatmap(lambda n: _floats((n, 3), -2.0, 2.0)),
)
def test_cast_rays__matches_brute_force(
    segments: np.ndarray, centres: np.ndarray, radii: np.ndarray, rays: np.ndarray
) -> None:
    circles = np.column_stack([centres, radii])
    origins, angles = rays[:, :2], rays[:, 2] * (np.pi / 2.0)  # headings in [−π, π]
    got = cast_rays(origins, angles, segments, circles, 2.5)
    want = [brute_ray(o, a, segments, circles, 2.5) for o, a in zip(origins, angles, strict=True)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)  # same maths, different order


def test_cast_rays__no_hit_is_inf_and_beyond_range_is_inf() -> None:
    seg = np.array([[1.0, -1.0, 1.0, 1.0]])
    got = cast_rays(np.zeros((3, 2)), np.array([0.0, math.pi, 0.0]), seg, np.zeros((0, 3)), 2.0)
    assert got[0] == pytest.approx(1.0, abs=1e-12)
    assert math.isinf(got[1])  # points away from the only wall
    short = cast_rays(np.zeros((1, 2)), np.array([0.0]), seg, np.zeros((0, 3)), 0.5)
    assert math.isinf(short[0])  # the wall is beyond max_range: inf, not 0.5


def test_world_scan__noiseless_matches_brute_force_and_noisy_within_5_sigma() -> None:
    layout = load_map("two_rooms")
    cfg = WorldConfig()
    world = World(layout, cfg, 3, make_rngs(11))
    rng = np.random.default_rng(11)
    sigma = cfg.range_sensor.sigma
    n_inf = 0
    for _ in range(30):
        world.step(rng.uniform(-1, 1, size=(3, 2)))
        poses = world.poses
        true = world.true_scan()
        noisy = world.scan()
        for i, (x, y, th) in enumerate(poses):
            for b, beta in enumerate(cfg.range_sensor.angles):
                want = brute_ray(np.array([x, y]), th + beta, layout.segments, layout.pillars, 2.0)
                assert true[i, b] == pytest.approx(want, abs=1e-9) or true[i, b] == want == math.inf
        finite = np.isfinite(true)
        n_inf += int((~finite).sum())
        np.testing.assert_array_equal(np.isinf(noisy), ~finite)  # no-return beams stay inf
        # 5σ: a false failure has probability ~6e-7 per beam, ~1e-4 over these 450 beams.
        assert np.all(np.abs(noisy[finite] - true[finite]) < 5 * sigma)
        assert np.all(noisy >= 0)
    assert n_inf > 0  # the 6 m rooms leave 2 m beams without a return: that case was exercised


def test_range_sensor__hit_robots_sees_others_never_itself() -> None:
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, math.pi]])
    none = np.zeros((0, 3))
    no_seg = np.zeros((0, 4))
    sensor = RangeSensor(RangeSensorConfig(angles_deg=(0.0, 90.0), hit_robots=True))
    d = sensor.true_ranges(poses, no_seg, none, robot_radius=0.065)
    np.testing.assert_allclose(d[:, 0], [1.0 - 0.065, 1.0 - 0.065], atol=1e-12)
    assert np.isinf(d[:, 1]).all()  # sideways: nothing, and never the robot's own body
    blind = RangeSensor(RangeSensorConfig(angles_deg=(0.0,), hit_robots=False))
    assert np.isinf(blind.true_ranges(poses, no_seg, none, robot_radius=0.065)).all()


def test_range_sensor__clips_noisy_values_at_zero() -> None:
    sensor = RangeSensor(RangeSensorConfig(angles_deg=(0.0,), sigma=1.0))
    wall = np.array([[0.01, -1.0, 0.01, 1.0]])
    d = sensor.measure(np.zeros((500, 3)), wall, np.zeros((0, 3)), np.random.default_rng(0))
    assert d.min() == 0.0  # sigma 100× the range: about half the draws go negative and clip


def pair(distance: float, bearing: float, heading: float = 0.3) -> np.ndarray:
    """Observer at the origin with ``heading``; target at ``distance`` along heading + bearing."""
    a = heading + bearing
    return np.array([[0.0, 0.0, heading], [distance * math.cos(a), distance * math.sin(a), 0.0]])


NO_SEG = np.zeros((0, 4))
NO_CIRC = np.zeros((0, 3))
BOTH = np.array([True, True])


def test_camera__respects_range() -> None:
    cam = Camera(CameraConfig(range=1.5))
    near, _, _ = cam.visible(pair(1.49, 0.4), BOTH, NO_SEG, NO_CIRC)
    far, _, _ = cam.visible(pair(1.51, 0.4), BOTH, NO_SEG, NO_CIRC)
    assert near[0, 1] and near[1, 0]
    assert not far[0, 1] and not far[1, 0]


def test_camera__respects_field_of_view() -> None:
    cam = Camera(CameraConfig(fov_deg=90.0))
    inside, _, _ = cam.visible(pair(1.0, math.radians(44.0)), BOTH, NO_SEG, NO_CIRC)
    outside, _, _ = cam.visible(pair(1.0, math.radians(46.0)), BOTH, NO_SEG, NO_CIRC)
    assert inside[0, 1] and not outside[0, 1]
    behind, _, _ = cam.visible(pair(1.0, math.radians(180.0)), BOTH, NO_SEG, NO_CIRC)
    assert not behind[0, 1]
    full = Camera(CameraConfig(fov_deg=360.0))
    assert full.visible(pair(1.0, math.radians(180.0)), BOTH, NO_SEG, NO_CIRC)[0][0, 1]


def test_camera__wall_or_pillar_occludes() -> None:
    cam = Camera(CameraConfig())
    poses = pair(1.0, 0.0, heading=0.0)  # target at (1, 0)
    wall = np.array([[0.5, -0.2, 0.5, 0.2]])
    blocked, _, _ = cam.visible(poses, BOTH, wall, NO_CIRC)
    assert not blocked.any()
    beside = np.array([[0.5, 0.1, 0.5, 0.4]])  # off the line of sight
    assert cam.visible(poses, BOTH, beside, NO_CIRC)[0].all(where=~np.eye(2, dtype=bool))
    pillar = np.array([[0.5, 0.0, 0.1]])
    assert not cam.visible(poses, BOTH, NO_SEG, pillar)[0].any()
    behind = np.array([[1.5, -0.2, 1.5, 0.2]])  # beyond the target: no occlusion
    assert cam.visible(poses, BOTH, behind, NO_CIRC)[0][0, 1]


def test_camera__inactive_robots_neither_see_nor_are_seen() -> None:
    cam = Camera(CameraConfig())
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    mask, _, _ = cam.visible(poses, np.array([True, False, True]), NO_SEG, NO_CIRC)
    assert not mask[:, 1].any() and not mask[1].any()
    assert mask[0, 2] and mask[2, 0]


def test_camera__distance_and_bearing_match_geometry_within_noise() -> None:
    cfg = CameraConfig(sigma_d=0.01, sigma_bearing_deg=1.0)
    cam = Camera(cfg)
    rng = np.random.default_rng(5)
    for _ in range(200):
        d, b, h = rng.uniform(0.2, 1.4), rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi)
        det = cam.detect(pair(d, b, h), BOTH, NO_SEG, NO_CIRC, rng)
        (seen,) = det[0]
        assert seen.target == 1
        # 5σ bounds: a false failure over 400 draws has probability ~2e-4.
        assert abs(seen.distance - d) < 5 * cfg.sigma_d
        err = math.remainder(seen.bearing - b, 2 * math.pi)
        assert abs(err) < 5 * cfg.sigma_bearing
        assert -math.pi < seen.bearing <= math.pi
        # The target sees the observer back along the reverse direction.
        back = math.remainder(b + h + math.pi - 0.0, 2 * math.pi)
        assert abs(math.remainder(det[1][0].bearing - back, 2 * math.pi)) < 5 * cfg.sigma_bearing


def test_world_camera__two_rooms_door_and_wall() -> None:
    layout = load_map("two_rooms")
    cfg = WorldConfig()
    # Either side of the x = 3 wall (solid for y < 1.5), 0.8 m apart: occluded.
    poses = np.array([[2.6, 0.8, 0.0], [3.4, 0.8, math.pi]])
    world = World(layout, cfg, 2, make_rngs(0), start_poses=poses)
    assert world.camera() == [[], []]
    # Through the doorway (1.5 < y < 2.5): visible both ways.
    poses = np.array([[2.6, 2.0, 0.0], [3.4, 2.0, math.pi]])
    world = World(layout, cfg, 2, make_rngs(0), start_poses=poses)
    det = world.camera()
    assert [d.target for d in det[0]] == [1] and [d.target for d in det[1]] == [0]
    assert det[0][0].distance == pytest.approx(0.8, abs=5 * cfg.camera.sigma_d)  # 5σ noise


def test_cast_rays__empty_world_is_all_inf() -> None:
    layout = Layout("empty", (np.array([[0.0, 0.0], [0.0, 0.0]]),))
    d = cast_rays(np.zeros((4, 2)), np.arange(4.0), layout.segments, NO_CIRC, 10.0)
    assert np.isinf(d).all()

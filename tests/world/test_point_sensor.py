"""The range-bearing point sensor (seed 003, eq. 15)."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import PillarSensorConfig, WorldConfig
from polyslam_env.world.generators import make_generator
from polyslam_env.world.nearby import WallIndex
from polyslam_env.world.physics import World
from polyslam_env.world.point_sensor import PillarSensor, sense_points


def test_exact_sensing__sees_only_landmarks_in_range_with_true_range_and_bearing() -> None:
    landmarks = np.array([[10.0, 0.0], [0.0, 29.9], [0.0, -30.1], [-5.0, 5.0]])
    pose = np.array([0.0, 0.0, np.pi / 2])
    ids, z = sense_points(pose, landmarks, 30.0, (0.2, 0.035), None)
    np.testing.assert_array_equal(ids, [0, 1, 3])
    np.testing.assert_allclose(z[:, 0], [10.0, 29.9, np.hypot(5, 5)])
    np.testing.assert_allclose(z[:, 1], [-np.pi / 2, 0.0, np.pi / 4], atol=1e-15)


def test_noise__has_the_configured_standard_deviations() -> None:
    """Sample std of n = 4000 draws has relative standard error 1/√(2n) ≈ 1.1 %; 5 % is
    over four standard errors."""
    landmarks = np.array([[20.0, 0.0]])
    rng = np.random.default_rng(0)
    z = np.array(
        [sense_points(np.zeros(3), landmarks, 30.0, (0.2, 0.035), rng)[1][0] for _ in range(4000)]
    )
    np.testing.assert_allclose(z.std(axis=0), [0.2, 0.035], rtol=0.05)
    assert abs(z[:, 0].mean() - 20.0) < 4 * 0.2 / np.sqrt(4000)


# -- the pymunk world's pillar sensor ------------------------------------------------------------
def _segments_cross(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether segment p–q meets segment a–b (touching included): exact orientation tests."""

    def orient(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> float:
        return float((v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0]))

    d1, d2 = orient(a, b, p), orient(a, b, q)
    d3, d4 = orient(p, q, a), orient(p, q, b)
    return d1 * d2 <= 0 and d3 * d4 <= 0


def _circle_meets(p: np.ndarray, q: np.ndarray, circle: np.ndarray) -> bool:
    """Whether segment p–q passes strictly inside ``circle`` (x, y, r)."""
    c, r = circle[:2], circle[2]
    d = q - p
    t = np.clip(np.dot(c - p, d) / np.dot(d, d), 0.0, 1.0)
    return bool(np.hypot(*(p + t * d - c)) < r)


def _visible_oracle(
    pose: np.ndarray, pillars: np.ndarray, segments: np.ndarray, max_range: float, half_fov: float
) -> np.ndarray:
    """Brute force: every pillar whose centre is in range and view and whose surface point
    facing the robot is reached by the sight line without crossing a wall or another pillar."""
    out = []
    p = pose[:2]
    for c, (x, y, r) in enumerate(pillars):
        d = np.hypot(x - p[0], y - p[1])
        bearing = np.angle(np.exp(1j * (np.arctan2(y - p[1], x - p[0]) - pose[2])))
        if d > max_range or d <= r or abs(bearing) > half_fov:
            continue
        surface = p + (np.array([x, y]) - p) * (d - r) / d
        walls = any(_segments_cross(p, surface, s[:2], s[2:]) for s in segments)
        others = any(_circle_meets(p, surface, pillars[k]) for k in range(len(pillars)) if k != c)
        if not (walls or others):
            out.append(c)
    return np.array(out, dtype=np.int64)


def test_pillar_visibility__matches_brute_force_with_walls_and_pillars_occluding() -> None:
    rng = np.random.default_rng(5)
    for trial in range(30):
        pillars = np.column_stack([rng.uniform(-4, 4, (12, 2)), rng.uniform(0.1, 0.4, 12)])
        segments = rng.uniform(-4, 4, (6, 4))
        poses = np.column_stack([rng.uniform(-4, 4, (5, 2)), rng.uniform(-np.pi, np.pi, 5)])
        for fov in (360.0, 120.0):
            sensor = PillarSensor(
                PillarSensorConfig(enabled=True, max_range=5.0, fov_deg=fov), pillars, rng
            )
            mask, dist, _ = sensor.visible(poses, np.ones(5, bool), WallIndex.build(segments))
            for i, pose in enumerate(poses):
                want = _visible_oracle(pose, pillars, segments, 5.0, np.radians(fov) / 2)
                np.testing.assert_array_equal(np.flatnonzero(mask[i]), want, err_msg=f"{trial}")
            np.testing.assert_allclose(
                dist, np.hypot(*(pillars[None, :, :2] - poses[:, None, :2]).transpose(2, 0, 1))
            )


def test_pillar_sensor__noise_statistics_and_failed_robots() -> None:
    """Range, bearing and each descriptor number get N(0, σ²): over n = 3000 sightings the
    sample mean lies within 4 standard errors σ/√n of the truth and the sample std within 5 %
    (relative standard error 1/√(2n) ≈ 1.3 %, so about four of them)."""
    pillars = np.array([[3.0, 0.0, 0.2]])
    cfg = PillarSensorConfig(enabled=True, sigma_range=0.05, sigma_bearing_deg=2.0,
                             descriptor_dim=4, descriptor_sigma=0.3)  # fmt: skip
    rng = np.random.default_rng(1)
    sensor = PillarSensor(cfg, pillars, rng)
    walls = WallIndex.build(np.zeros((0, 4)))
    pose = np.array([[0.0, 0.0, 0.5]])
    n = 3000
    reads = [sensor.sense(pose, np.ones(1, bool), walls, rng)[0] for _ in range(n)]
    assert all(r.ids.tolist() == [0] for r in reads)
    z = np.array([r.z[0] for r in reads])
    desc = np.array([r.descriptors[0] for r in reads])
    truth = np.array([3.0, -0.5])
    sig = np.array([cfg.sigma_range, cfg.sigma_bearing])
    assert (np.abs(z.mean(axis=0) - truth) < 4 * sig / np.sqrt(n)).all()
    np.testing.assert_allclose(z.std(axis=0), sig, rtol=0.05)
    assert (np.abs(desc.mean(axis=0) - sensor.descriptors[0]) < 4 * 0.3 / np.sqrt(n)).all()
    np.testing.assert_allclose(desc.std(axis=0), 0.3, rtol=0.05)
    failed = sensor.sense(pose, np.zeros(1, bool), walls, rng)[0]
    assert len(failed.ids) == 0 and failed.z.shape == (0, 2)


def test_pillar_sensor__in_the_world_is_seeded_and_leaves_the_other_streams_alone() -> None:
    """Same seed, same readings; switching the sensor on changes no other stream's draws (the
    ranges and the camera are identical), because it has streams of its own."""
    layout = make_generator("pillar_hall")(np.random.default_rng(0))
    cfg = WorldConfig(pillar_sensor=PillarSensorConfig(enabled=True))
    runs = []
    for config in (cfg, cfg, WorldConfig()):
        world = World(layout, config, 3, make_rngs(7))
        world.step(np.tile([0.2, 0.3], (3, 1)))
        runs.append((world.scan(), world.camera(), world))
    a, b = runs[0][2].sense_pillars(), runs[1][2].sense_pillars()
    assert sum(len(r.ids) for r in a) > 0
    for ra, rb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ra.ids, rb.ids)
        np.testing.assert_array_equal(ra.z, rb.z)
        np.testing.assert_array_equal(ra.descriptors, rb.descriptors)
    np.testing.assert_array_equal(runs[0][0], runs[2][0])
    assert runs[0][1] == runs[2][1]
    with pytest.raises(RuntimeError, match="pillar_sensor.enabled"):
        runs[2][2].sense_pillars()


@pytest.mark.parametrize(
    ("field", "value"),
    [("max_range", 0.0), ("fov_deg", 400.0), ("sigma_range", -1.0), ("descriptor_dim", 0)],
)
def test_pillar_sensor_config__bad_value_names_field(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=f"pillar_sensor.{field}"):
        PillarSensorConfig(**{field: value})

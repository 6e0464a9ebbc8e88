"""SEIF map fusion between robots in the env (comms/seif_exchange.py, seed 001 §4): the wire
format, the transform's covariance against Monte Carlo, and a team that fuses maps without
relative poses and without a wrong fusion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.stats
import yaml

from policies import make_team
from polyslam_env.apps.rollout import run_episode
from polyslam_env.comms.seif_exchange import decode_map, encode_map
from polyslam_env.core.geometry import rotation, wrap_remainder
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.slam.alignment import rigid_fit
from polyslam_env.slam.backends import PointSlamRobot
from polyslam_env.slam.points.seif_fusion import (
    Fusion,
    InformationMap,
    fuse,
    fuse_jointly,
    transform_covariance,
)

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "seif_fusion.yaml"


def test_map_wire_format__round_trips_the_symmetric_information() -> None:
    rng = np.random.default_rng(0)
    means = rng.normal(size=(7, 2))
    root = rng.normal(size=(14, 14))
    information = root @ root.T + np.eye(14)
    payload = encode_map(means, information, "float64")
    assert len(payload) == 4 + (14 + 14 * 15 // 2) * 8
    got_means, got_info = decode_map(payload, "float64")
    np.testing.assert_array_equal(got_means, means)
    np.testing.assert_array_equal(got_info, information)
    half_means, half_info = decode_map(encode_map(means, information, "float32"), "float32")
    np.testing.assert_allclose(half_info, information, rtol=1e-6)
    np.testing.assert_allclose(half_means, means, rtol=1e-6)


def test_transform_covariance__matches_monte_carlo_nees() -> None:
    """Twelve landmarks seen by two maps with independent errors of σ 3 cm (A) and 5 cm (B):
    the rigid fit over the pairs has the covariance ``transform_covariance`` gives (equal
    isotropic weights, so the unweighted fit is the weighted one); its NEES over 400 trials
    averages inside the 99 % band of χ²(3·400)/400."""
    rng = np.random.default_rng(1)
    truth = np.array([1.5, -2.0, 0.6])
    points = rng.uniform(-5, 5, size=(12, 2))
    in_b = (points - truth[:2]) @ rotation(truth[2])  # p_A = R p_B + t
    sa, sb = 0.03, 0.05
    info_a = np.eye(24) / sa**2
    info_b = np.eye(24) / sb**2
    pairs = np.column_stack([np.arange(12), np.arange(12)])
    nees = []
    for _ in range(400):
        a = InformationMap(points + rng.normal(0, sa, points.shape), info_a, np.arange(12))
        b = InformationMap(in_b + rng.normal(0, sb, in_b.shape), info_b, np.arange(12))
        fit = rigid_fit(a.means, b.means)
        cov = transform_covariance(a, b, Fusion(fit, pairs, 0.0))
        e = fit - truth
        e[2] = wrap_remainder(float(e[2]))
        nees.append(float(e @ np.linalg.solve(cov, e)))
    lo, hi = scipy.stats.chi2.ppf([0.005, 0.995], 3 * len(nees)) / len(nees)
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)


def test_seif_team__fuses_maps_without_relative_poses_and_without_a_wrong_fusion() -> None:
    """``slam.backend: seif`` with ``channel.mode: alignment`` on the pillar hall, 200 steps:
    robots in radio range exchange their own maps and fuse them; fusions are accepted, none is
    more than 0.2 m or 3° off, bytes are counted, every fused map holds at least its own
    landmarks, and each robot keeps at most one map per other robot (a newer one replaces it:
    nothing is fused twice)."""
    data = yaml.safe_load(CONFIG.read_text()) | {"max_steps": 200}
    env = parallel_env(EnvConfig.from_dict(data))
    result = run_episode(env, make_team("frontier", env), seed=0)
    robots = result.robots.values()
    assert sum(m["alignments_accepted"] for m in robots) > 0
    assert sum(m["alignments_wrong"] for m in robots) == 0
    assert all(m["bytes_sent"] > 0 for m in robots)
    state = env.episode
    assert state is not None and state.seif_exchange is not None
    grew = 0
    for i, robot in enumerate(state.slams):
        assert isinstance(robot, PointSlamRobot)
        assert set(robot.fusion_sources) <= set(range(len(state.slams))) - {i}
        own = robot.information_map()
        fused = robot.landmarks()
        assert len(fused.ids) >= len(own)
        assert set(own.ids.tolist()) <= set(fused.ids.tolist())
        grew += len(fused.ids) > len(own)
    assert grew > 0


def test_fuse_jointly__consistent_where_a_fixed_transform_is_not() -> None:
    """Two maps of 11 and 10 landmarks sharing 6, with independent errors of σ 3 and 5 cm, B's
    frame unknown: the transform fitted to the 6 pairs and the landmarks fused. Estimating
    the transform jointly with the landmarks and marginalising it (``fuse_jointly``) gives a
    fused map whose NEES over 300 trials averages inside the 99 % band of χ²(30·300)/300;
    taking the fitted transform as exact (``fuse``, the seed's fusion) does not."""
    rng = np.random.default_rng(3)
    truth = np.array([1.5, -2.0, 0.6])
    world = rng.uniform(-5, 5, size=(15, 2))
    in_a, in_b = np.arange(0, 11), np.arange(5, 15)
    sa, sb = 0.03, 0.05
    pairs = np.array([(i, i - 5) for i in range(5, 11)])
    joint, exact = [], []
    for _ in range(300):
        a = InformationMap(world[in_a] + rng.normal(0, sa, (11, 2)), np.eye(22) / sa**2, in_a)
        local = (world[in_b] - truth[:2]) @ rotation(truth[2])
        b = InformationMap(local + rng.normal(0, sb, local.shape), np.eye(20) / sb**2, in_b)
        fusion = Fusion(rigid_fit(a.means[pairs[:, 0]], b.means[pairs[:, 1]]), pairs, 0.0)
        for out, values in ((fuse_jointly(a, b, fusion), joint), (fuse(a, b, fusion), exact)):
            assert len(out) == 15
            e = (out.means - world[out.ids]).ravel()
            values.append(float(e @ out.information @ e))
    lo, hi = scipy.stats.chi2.ppf([0.005, 0.995], 30 * 300) / 300
    assert lo <= np.mean(joint) <= hi, (np.mean(joint), lo, hi)
    assert np.mean(exact) > hi

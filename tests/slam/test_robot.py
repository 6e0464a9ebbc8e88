"""PolySlam, the per-robot SLAM loop, checked against the simulated world's ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env import metrics
from polyslam_env.apps.simulate import simulate, wall_follow_controller
from polyslam_env.core.seeding import make_rngs
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World


def _assert_symmetric_psd(cov: np.ndarray) -> None:
    np.testing.assert_allclose(cov, cov.T, rtol=0, atol=1e-12)
    # Round-off of the Joseph form on values ~1e-3 leaves eigenvalues ~1e-15 below zero.
    assert np.linalg.eigvalsh(cov).min() > -1e-10 * max(1.0, np.abs(cov).max())


def test_step__covariance_symmetric_psd_and_state_consistent_over_long_run() -> None:
    cfg = WorldConfig()
    layout = load_map("office")
    world = World(layout, cfg, 1, make_rngs(3))
    slam = PolySlam(SlamConfig(), cfg.range_sensor.angles, cfg.range_sensor.max_range)
    control = wall_follow_controller(cfg)
    scans = world.scan()
    created = 0
    for k in range(250):
        result = world.step(control(k, scans))
        scans = world.scan()
        info = slam.step(result.odometry[0], scans[0])
        created += info.created
        _assert_symmetric_psd(slam.cov)
        # pose, one c0 per landmark, one shape rotation per landmark (at rest: 0)
        assert slam.mean.shape == (3 + 2 * slam.n_landmarks,)
        assert not slam.mean[3 + slam.n_landmarks :].any()
        assert len(slam.shapes) == slam.n_landmarks == len(slam.landmark_ids)
    assert created >= 5  # the run did build a map: the checks above covered augmentations


def test_map__wall_following_on_curved_cave__accurate_and_complete() -> None:
    """Wall following on the curved cave map, 5 seeds, 200 steps.

    Bounds: nu_mean ≤ 0.04 m per run and ≤ 0.035 m on average (the issue's 0.03 m target is
    for the paper map; the cave bends tighter, and a cubic over a cluster of 0.35 m radius
    leaves ~1 cm more there; measured mean 0.031 m); completeness ≥ 0.55 × the boundary the
    beams actually hit in every run and ≥ 0.65 × on average (measured 0.61–0.81, mean 0.70:
    on tight bends clusters whose cubic misses ρ_k are refused and wait for more points,
    and stretches seen by fewer than ε_Z beams stay unmapped).
    """
    ratios, errors = [], []
    for seed in range(5):
        result = simulate("cave", num_robots=1, steps=200, seed=seed)
        m = result.metrics()[0]
        errors.append(m["nu_mean"])
        ratios.append(m["completeness"] / m["hit_fraction"])
        assert m["landmarks"] >= 5
    assert max(errors) <= 0.04, errors
    assert np.mean(errors) <= 0.035, errors
    assert min(ratios) >= 0.55, ratios
    assert np.mean(ratios) >= 0.65, ratios


def test_map__paper_paths__meet_the_issue_targets() -> None:
    """The issue's targets on the paper map along the paper paths, as means over 5 seeds.

    Per robot: mean nu_mean ≤ 0.03 m and mean completeness ≥ 0.8 × the fraction of the true
    boundary its beams actually hit (the issue states both as means over seeds). Measured:
    nu_mean 0.010–0.021 m, ratios 0.82–0.90. Single runs can miss (seed 4, r2: a cubic fitted
    across the north wall and the start of the bulge, nu_mean 0.045 m) — a known limitation.
    """
    runs = [simulate("paper", seed=seed).metrics() for seed in range(5)]
    for robot in range(3):
        nu_mean = np.mean([r[robot]["nu_mean"] for r in runs])
        ratio = np.mean([r[robot]["completeness"] / r[robot]["hit_fraction"] for r in runs])
        assert nu_mean <= 0.03, (robot, nu_mean)
        assert ratio >= 0.8, (robot, ratio)
    assert all(m["collisions"] == 0 for r in runs for m in r)


def test_nees__straight_walls_with_initial_error__consistent_over_seeds() -> None:
    """Standard NEES over 20 seeded runs when the start offset is drawn from P0.

    A consistent filter gives 3; the issue asks for a factor of 2 (1.5 … 6). The per-run
    NEES is a time average of correlated terms, so the band is checked on the mean over runs.
    """
    values = [
        simulate("two_rooms", num_robots=1, steps=120, seed=seed, initial_error=True).metrics()[0][
            "nees"
        ]
        for seed in range(20)
    ]
    assert 1.5 <= float(np.mean(values)) <= 6.0, values


def test_nees_paper__is_tiny_like_the_papers_table() -> None:
    """eᵀPe (P, not P⁻¹, as printed) is ~1e-6 for cm errors and P ~ (5 cm)²: Table 1's order."""
    m = simulate("two_rooms", num_robots=1, steps=100, seed=0).metrics()[0]
    assert 1e-9 < m["nees_paper"] < 1e-4


def test_divergence__covariance_beyond_k_p0_is_flagged_not_silent() -> None:
    """The paper's criterion: dead reckoning with large noise and nothing in sight."""
    cfg = SlamConfig(odom_sigma_xy=0.05, odom_sigma_theta_deg=5.0)
    slam = PolySlam(cfg, np.radians([0.0]), 2.0)
    flags = [slam.step(np.array([0.1, 0.0, 0.05]), np.array([np.inf])).diverging for _ in range(60)]
    assert flags[0] is False
    assert any(flags)
    assert slam.diverging  # stays flagged: P only grows without measurements


def test_divergence__most_screened_beams_outliers_are_flagged() -> None:
    """The innovation screen: 7 outliers among the last 10 screened beams flag; 6 do not. One
    beam ahead on a mapped wall 1 m away; a reading of 0.3 m is a gross outlier (its NIS is
    far past the gate), the true 1 m is not."""
    slam = PolySlam(SlamConfig(), np.radians([0.0]), 2.0)
    wall = Polynomial(2, np.array([1.0, 0.0, 0.0, 0.0]), -1.0, 1.0)  # x¹ = 1
    gx = np.zeros((1, 3))
    gx[0, 0] = 1.0
    slam.insert_landmark(Fit(wall, 1.0, gx, np.ones((1, 1)), np.eye(1) * 1e-4, 0.01, 1))
    readings = [1.0] * 4 + [0.3] * 6  # a run of gross outliers: not yet
    flags = [slam.step(np.zeros(3), np.array([r])).diverging for r in readings]
    assert not any(flags)
    assert slam.step(np.zeros(3), np.array([0.3])).diverging  # seven of the last ten


def test_divergence__healthy_run_is_not_flagged() -> None:
    result = simulate("two_rooms", num_robots=2, steps=150, seed=1)
    assert not any(run.diverged for run in result.runs)


def test_polynomials__map_lies_on_true_walls_in_absolute_frame() -> None:
    result = simulate("two_rooms", num_robots=1, steps=150, seed=2)
    run = result.runs[0]
    per_poly = metrics.map_distances(run.polynomials, run.start_pose, result.layout)
    distances = np.concatenate(per_poly)
    # 95 % of map points within 6 cm of a wall: 3 × the 2 cm range noise.
    assert np.quantile(distances, 0.95) < 0.06


def test_step__rejects_nothing_silently_on_no_returns() -> None:
    """All beams without return (open space): no landmarks, prediction only, finite state."""
    slam = PolySlam(SlamConfig(), np.radians([90, 0, -90]), 2.0)
    for _ in range(20):
        info = slam.step(np.array([0.05, 0.0, 0.01]), np.full(3, np.inf))
        assert info.beams_used == 0 and info.n_landmarks == 0
    assert np.all(np.isfinite(slam.mean))
    assert slam.pose[0] == pytest.approx(20 * 0.05, rel=0.1)

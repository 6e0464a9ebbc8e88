"""PolySlam, the per-robot SLAM loop, checked against the simulated world's ground truth."""

from __future__ import annotations

import functools

import numpy as np

from polyslam_env import metrics
from polyslam_env.apps.benchmark import make_inputs, make_slam, make_walls
from polyslam_env.apps.simulate import simulate, wall_follow_controller
from polyslam_env.core.seeding import make_rngs
from polyslam_env.metrics.episode import RobotRun
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World
from tests.stats import log_chi2_mean_band, log_mean, weighted_chi2_band


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
        assert (slam.cov == slam.cov.T).all()  # exactly: the update mirrors, never recomputes
        # pose, one c0 per landmark, one shape rotation per landmark (at rest: 0)
        assert slam.mean.shape == (3 + 2 * slam.n_landmarks,)
        assert not slam.mean[3 + slam.n_landmarks :].any()
        assert len(slam.shapes) == slam.n_landmarks == len(slam.landmark_ids)
    assert created >= 5  # the run did build a map: the checks above covered augmentations


def test_cov__mirrored_when_read_the_same_episode_bit_for_bit_as_read_every_step() -> None:
    """The update writes P's upper triangle (and pose block) only and ``cov`` mirrors it on
    the first read: a filter whose ``cov`` is never read during 60 steps (30 landmarks,
    turns considered, every beam updating) ends in the same bits as one read every step,
    so no kernel reads the copy that waits."""
    rng = np.random.default_rng(7)
    walls = make_walls(30, rng)
    inputs = make_inputs(walls, 60, rng)
    read, unread = make_slam(walls), make_slam(walls)
    assert read.config.rotation_states
    for odometry, ranges in inputs:
        read.step(odometry, ranges)
        assert (read.cov == read.cov.T).all()
        unread.step(odometry, ranges)
    assert unread.mean.tobytes() == read.mean.tobytes()
    assert unread.cov.tobytes() == read.cov.tobytes()


def test_map__wall_following_on_curved_cave__accurate_and_complete() -> None:
    """Wall following on the curved cave map, 5 seeds, 200 steps: the issue's targets, stated
    for the paper map as means over seeds, hold on the cave's bends too: mean nu_mean ≤ 0.03 m
    and mean completeness ≥ 0.8 × the boundary the beams actually hit."""
    ratios, errors = [], []
    for seed in range(5):
        result = simulate("cave", num_robots=1, steps=200, seed=seed)
        m = result.metrics()[0]
        errors.append(m["nu_mean"])
        ratios.append(m["completeness"] / m["hit_fraction"])
        assert m["landmarks"] >= 5
    assert np.mean(errors) <= 0.03, errors
    assert np.mean(ratios) >= 0.8, ratios


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


#: Runs of the two_rooms NEES tests, fixed from the power: the log-mean band of 30 final NEES
#: at α = 1 % rejects a filter reporting half its covariance with probability 0.93
#: (``tests.stats.log_chi2_mean_power``).
NEES_RUNS = 30


@functools.cache
def _two_rooms_runs() -> tuple[RobotRun, ...]:
    """One robot on two_rooms, 120 steps, start offset drawn from P0, seeds 0 … NEES_RUNS − 1."""
    return tuple(
        simulate("two_rooms", num_robots=1, steps=120, seed=seed, initial_error=True).runs[0]
        for seed in range(NEES_RUNS)
    )


def _final(run: RobotRun) -> tuple[float, float]:
    """The last step's NEES eᵀP⁻¹e and the paper's index eᵀPe (absolute frame)."""
    args = (run.true_poses[-1:], run.est_poses[-1:], run.est_covs[-1:], run.start_pose)
    return float(metrics.nees_series(*args)[0]), float(metrics.nees_paper_series(*args)[0])


def test_nees__straight_walls_with_initial_error__consistent_over_seeds() -> None:
    """NEES_RUNS seeded runs with the start offset drawn from P0. The final step's NEES is
    χ²(3) for a consistent filter: the mean of its log lies in the exact 99 % band
    (``tests.stats``), and the mutant reporting half the covariance (every NEES doubled) falls
    outside it. The issue's own target, the time-averaged NEES within a factor 2 of 3
    (1.5 … 6), still holds for the mean over runs; it was the whole test before, and the
    mutant (mean doubled, 5.6 here) passed it."""
    runs = _two_rooms_runs()
    final = np.array([_final(run)[0] for run in runs])
    lo, hi = log_chi2_mean_band(3, NEES_RUNS, 0.01)
    assert lo <= log_mean(final) <= hi, (log_mean(final), lo, hi, final)
    assert not lo <= log_mean(2.0 * final) <= hi  # the mutant is caught
    averaged = [metrics.nees(r.true_poses, r.est_poses, r.est_covs, r.start_pose) for r in runs]
    assert 1.5 <= float(np.mean(averaged)) <= 6.0, averaged


def test_nees_paper__is_its_generalised_chi2_over_seeds() -> None:
    """The paper's index eᵀPe (P, not P⁻¹, as printed: ~1e-6 for cm errors and P ~ (5 cm)²,
    Table 1's order). For a consistent filter e ~ N(0, P) at a step, so eᵀPe = Σ λ_i² w_i² with
    λ_i the eigenvalues of P and w_i ~ N(0, 1): summed over the NEES_RUNS runs' last steps it
    lies in the exact 99 % band of that weighted χ² (``tests.stats.weighted_chi2_band``). The
    mutant reporting half the covariance halves the sum and quarters its weights: it falls out
    here, though this test's power against it is only 0.48 (from the same weights: the sum is
    dominated by a few position eigenvalues; the NEES test above is the sharp one). Before:
    1e-9 < nees_paper < 1e-4, five decades, which the mutant passed."""
    runs = _two_rooms_runs()
    total = sum(_final(run)[1] for run in runs)
    weights = np.concatenate([np.linalg.eigvalsh(run.est_covs[-1]) ** 2 for run in runs])
    lo, hi = weighted_chi2_band(weights, 0.01)
    assert lo <= total <= hi, (total, lo, hi)
    lo_m, hi_m = weighted_chi2_band(weights / 4.0, 0.01)
    assert not lo_m <= total / 2.0 <= hi_m  # the mutant is caught


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
    # prediction only: the pose is the 20 odometry increments composed, computed here with
    # rotation matrices (rounding of 20 compositions of unit-scale values)
    pose = np.eye(3)
    for _ in range(20):
        c, s = np.cos(0.01), np.sin(0.01)
        pose = pose @ np.array([[c, -s, 0.05], [s, c, 0.0], [0.0, 0.0, 1.0]])
    want = [pose[0, 2], pose[1, 2], np.arctan2(pose[1, 0], pose[0, 0])]
    np.testing.assert_allclose(slam.pose, want, rtol=0, atol=1e-12)

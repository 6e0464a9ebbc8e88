"""The motion-model proposal (FastSLAM 1.0's), the EM passes and the ancestry count."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.points import PointFastSlam, PointMeasurements, PointSlamConfig
from polyslam_env.slam.points import particles as pt
from polyslam_env.slam.points.particles import surviving_ancestors
from polyslam_env.world.kinematic import car_step

#: Three landmarks 10–20 m ahead of a robot at the origin facing +x.
LANDMARKS = np.array([[12.0, 4.0], [18.0, -6.0], [9.0, -3.0]])
IDS = np.arange(3, dtype=np.int64)


def _range_bearing(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    dx, dy = point[0] - pose[0], point[1] - pose[1]
    bearing = math.atan2(dy, dx) - pose[2]
    return np.array([math.hypot(dx, dy), math.atan2(math.sin(bearing), math.cos(bearing))])


def _two_sweeps(
    config: PointSlamConfig, seed: int, periods: int = 40
) -> tuple[PointFastSlam, np.ndarray, np.ndarray]:
    """A filter that mapped the three landmarks from the origin (no controls: its particles
    all sit there), and the controls (K, 2) and measurements (3, 2) of its second sweep, taken
    from the true pose after driving ``periods`` × 25 ms at 4 m/s with steering 0.1 rad."""
    rng = np.random.default_rng(seed)
    noise = np.array(config.measurement_sigmas)
    slam = PointFastSlam(config, np.zeros(3), np.random.default_rng(seed + 1))
    z1 = np.array([_range_bearing(np.zeros(3), p) for p in LANDMARKS])
    slam.step(np.zeros((0, 2)), PointMeasurements(IDS, z1 + rng.normal(0, noise, z1.shape)))
    controls = np.tile([4.0, 0.1], (periods, 1))
    truth = np.zeros(3)
    for v, g in controls:
        truth = car_step(truth, v, g, config.dt, config.wheelbase)
    z2 = np.array([_range_bearing(truth, p) for p in LANDMARKS])
    return slam, controls, z2 + rng.normal(0, noise, z2.shape)


def _oracle_log_likelihood(
    pose: np.ndarray, means: np.ndarray, covs: np.ndarray, z: np.ndarray, noise: np.ndarray
) -> float:
    """Σ_j log N(z_j; h(pose, μ_j), H_j Σ_j H_jᵀ + R), written out landmark by landmark."""
    total = 0.0
    for mu, sigma, zj in zip(means, covs, z, strict=True):
        dx, dy = mu[0] - pose[0], mu[1] - pose[1]
        q = dx * dx + dy * dy
        r = math.sqrt(q)
        h = np.array([[dx / r, dy / r], [-dy / q, dx / q]])
        s = h @ sigma @ h.T + noise
        v = zj - _range_bearing(pose, mu)
        v[1] = math.atan2(math.sin(v[1]), math.cos(v[1]))
        maha = float(v @ np.linalg.solve(s, v))
        total += -0.5 * maha - 0.5 * math.log(np.linalg.det(2.0 * math.pi * s))
    return total


def test_motion_proposal__draws_from_the_prediction_and_weighs_by_the_likelihood() -> None:
    """With ``proposal: motion`` a sweep draws each pose from the motion prediction itself
    and multiplies each weight by the landmarks' predictive likelihood at the drawn pose
    (eq. 3 with q = p(x | x_{k−1}, u): the prior over the proposal cancels). Checked against
    an oracle that writes the likelihood out; resampling is off so the weights stay visible."""
    config = PointSlamConfig(particles=5, proposal="motion", resample_fraction=0.0)
    slam, controls, z = _two_sweeps(config, seed=3)
    before = copy.deepcopy(slam)
    prior = pt.PoseBlock(before.poses.poses.copy(), before.poses.covs.copy())
    pt.predict(prior, controls, config)
    expected_poses = pt.sample(before._rng, prior.poses, prior.covs)
    slam.step(controls, PointMeasurements(IDS, z))
    np.testing.assert_array_equal(slam.poses.poses, expected_poses)
    noise = np.diag(np.square(config.measurement_sigmas))
    m = len(IDS)
    increments = [
        _oracle_log_likelihood(pose, before.map.means[k, :m], before.map.covs[k, :m], z, noise)
        for k, pose in enumerate(expected_poses)
    ]
    expected = pt.normalise(before.log_weights + np.array(increments))
    np.testing.assert_allclose(slam.log_weights, expected, rtol=0, atol=1e-10)
    assert np.ptp(slam.log_weights) > 0.1  # the weights do differ: the check has teeth


def test_proposals__target_the_same_posterior_within_monte_carlo_error() -> None:
    """FastSLAM 2.0's proposal and the motion model's are two importance samplers of the same
    posterior (prediction × landmark likelihood), so their weighted pose means agree within
    Monte Carlo error: 4 standard errors of the difference (self-normalised importance
    sampling, se² ≈ Σ w_i² (x_i − x̄)²), per coordinate, with 4000 particles each. Noisy
    controls over 5 s and a precise sensor make the prediction far wider than the landmarks'
    likelihood, so the two samplers draw differently (the motion model's weights vary far
    more) and their agreement says something."""
    means, variances, sizes = [], [], []
    for proposal in ("fastslam2", "motion"):
        config = PointSlamConfig(
            particles=4000,
            proposal=proposal,
            resample_fraction=0.0,
            sigma_v=1.0,
            sigma_g_deg=8.0,
            sigma_r=0.1,
            sigma_b_deg=1.0,
        )
        slam, controls, z = _two_sweeps(config, seed=5, periods=200)
        slam.step(controls, PointMeasurements(IDS, z))
        w = np.exp(slam.log_weights)
        mean = w @ slam.poses.poses
        means.append(mean)
        variances.append((w**2) @ (slam.poses.poses - mean) ** 2)
        sizes.append(pt.effective_size(slam.log_weights))
    assert sizes[1] < 0.25 * sizes[0], f"effective sizes {sizes}"
    diff = means[0] - means[1]
    se = np.sqrt(variances[0] + variances[1])
    assert np.all(np.abs(diff) < 4.0 * se), f"difference {diff} against se {se}"


def test_config__unknown_proposal_and_zero_em_passes__are_named_errors() -> None:
    with pytest.raises(ConfigError, match="proposal"):
        PointSlamConfig(proposal="prior")
    with pytest.raises(ConfigError, match="em_passes"):
        PointSlamConfig(em_passes=0)


def test_em_passes__one_is_the_default_and_more_move_the_particles_again() -> None:
    base = PointSlamConfig(particles=6, em_move=True, em_mobility=(0.05, 0.05, 0.01))
    results = []
    for config in (base, base.replace(em_passes=1), base.replace(em_passes=3)):
        slam, controls, z = _two_sweeps(config, seed=2)
        slam.step(controls, PointMeasurements(IDS, z))
        results.append(slam.poses.poses)
    np.testing.assert_array_equal(results[0], results[1])
    assert not np.array_equal(results[0], results[2])


@pytest.mark.parametrize("seed", range(5))
def test_surviving_ancestors__match_labels_carried_forward(seed: int) -> None:
    """Brute force: label the particles after step ``start``, carry each label to its
    children step by step, count the labels left after ``stop``."""
    rng = np.random.default_rng(seed)
    n, steps = 8, 30
    parents = [
        np.sort(rng.integers(0, n, n)) if rng.random() < 0.5 else np.arange(n) for _ in range(steps)
    ]
    for start in range(0, steps - 1, 3):
        labels = np.arange(n)
        for stop in range(start + 1, steps):
            labels = labels[parents[stop]]
            assert surviving_ancestors(parents, start, stop) == len(np.unique(labels))

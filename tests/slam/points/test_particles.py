"""Particle weights, resampling and the landmark EKF pieces."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.slam.points import particles as pt


@pytest.mark.parametrize("seed", range(10))
def test_systematic_resample__gives_floor_or_ceil_of_n_w_copies(seed: int) -> None:
    """A property of low-variance resampling: particle i gets ⌊N w_i⌋ or ⌈N w_i⌉ copies."""
    rng = np.random.default_rng(seed)
    n = 10
    log_w = pt.normalise(rng.normal(size=n) * 2)
    counts = np.bincount(pt.systematic_resample(rng, log_w), minlength=n)
    expected = n * np.exp(log_w)
    assert counts.sum() == n
    assert np.all(counts >= np.floor(expected - 1e-9)) and np.all(
        counts <= np.ceil(expected + 1e-9)
    )


def test_normalise_and_effective_size() -> None:
    log_w = pt.normalise(np.array([-1000.0, -1001.0, -1000.5]))  # underflows without the shift
    # a few ulp of rounding per term (exp, log, sum of three)
    assert np.isfinite(log_w).all() and np.exp(log_w).sum() == pytest.approx(1.0, abs=1e-15)
    assert pt.effective_size(np.full(8, -np.log(8))) == pytest.approx(8.0)
    assert pt.effective_size(pt.normalise(np.array([0.0, -np.inf, -np.inf]))) == pytest.approx(1.0)


def test_inverse2_and_logpdf2__match_numpy() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(20, 2, 2))
    cov = a @ a.swapaxes(-1, -2) + 0.1 * np.eye(2)
    v = rng.normal(size=(20, 2))
    np.testing.assert_allclose(pt.inverse2(cov)[0], np.linalg.inv(cov), rtol=1e-10)
    np.testing.assert_allclose(pt.gaussian_logpdf2(v, cov), pt.gaussian_logpdf(v, cov), rtol=1e-12)


def test_landmark_update__covariance_stays_symmetric_psd_and_shrinks() -> None:
    rng = np.random.default_rng(1)
    poses = rng.normal(size=(5, 3))
    noise = np.diag([0.2**2, np.radians(2) ** 2])
    z = np.array([[12.0, 0.3], [25.0, -1.0]])
    means, covs = pt.init_landmarks(poses, z, noise)
    for _ in range(10):
        new_means, new_covs = pt.update_landmarks(means, covs, poses, z, noise)
        np.testing.assert_array_equal(new_covs, new_covs.swapaxes(-1, -2))
        assert np.all(np.linalg.eigvalsh(new_covs) > 0)
        assert np.all(np.linalg.eigvalsh(covs - new_covs) > -1e-12)  # information only grows
        means, covs = new_means, new_covs


def test_consensus_term__pulls_by_epsilon_towards_the_neighbours() -> None:
    """Eq. 12's extra term equals ε Σ_n (μ^n − μ) exactly; ε = 0 is the plain EKF."""
    rng = np.random.default_rng(2)
    poses = rng.normal(size=(4, 3))
    noise = np.diag([0.04, 0.001])
    z = np.array([[10.0, 0.5]])
    means, covs = pt.init_landmarks(poses, z, noise)
    others = np.array([[[1.0, 2.0], [3.0, -1.0]]])  # two neighbours' estimates of landmark 0
    neighbours = (others.sum(axis=1), np.array([2.0]))
    plain_m, plain_c = pt.update_landmarks(means, covs, poses, z, noise)
    zero_m, zero_c = pt.update_landmarks(means, covs, poses, z, noise, 0.0, neighbours)
    np.testing.assert_array_equal(zero_m, plain_m)
    np.testing.assert_array_equal(zero_c, plain_c)
    eps_m, eps_c = pt.update_landmarks(means, covs, poses, z, noise, 0.1, neighbours)
    expected = plain_m + 0.1 * ((others[0][None] - means[:, 0:1, None, :]).sum(axis=2))
    np.testing.assert_allclose(eps_m, expected, rtol=1e-13)
    np.testing.assert_array_equal(eps_c, plain_c)  # eq. 13: the consensus leaves Σ alone

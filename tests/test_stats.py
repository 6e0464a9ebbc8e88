"""The suite's own statistics (``tests/stats.py``) against direct computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from tests.stats import (
    log_chi2_mean_band,
    log_chi2_mean_cdf,
    log_chi2_mean_power,
    standard_normal_failures,
    weighted_chi2_band,
    weighted_chi2_cdf,
)


@pytest.mark.parametrize("n", [1, 30])
def test_log_chi2_mean_cdf__matches_sampling(n: int) -> None:
    """2·10⁵ sampled means of n log χ²(3): the inverted characteristic function gives their
    empirical CDF at five points to within 4.5 binomial standard errors (a right CDF fails one
    of the five with probability < 4e-5)."""
    rng = np.random.default_rng(0)
    draws = 200_000
    sims = np.log(rng.chisquare(3, (draws, n))).mean(axis=1)
    for q in (0.005, 0.1, 0.5, 0.9, 0.995):
        x = float(np.quantile(sims, q))
        want = float(np.mean(sims <= x))
        se = math.sqrt(want * (1 - want) / draws)
        assert abs(log_chi2_mean_cdf(x, 3, n) - want) < 4.5 * se, (n, q)


def test_log_chi2_mean_cdf__one_run_is_the_chi2_cdf() -> None:
    """n = 1: P(log X ≤ x) = P(X ≤ eˣ), exactly (quadrature to 1e-9)."""
    for x in (-2.0, 0.0, 0.8, 2.0):
        assert log_chi2_mean_cdf(x, 3, 1) == pytest.approx(
            scipy.stats.chi2.cdf(math.exp(x), 3), abs=1e-9
        )


def test_log_chi2_mean_band__holds_its_level_and_its_power_is_its_shifted_tails() -> None:
    lo, hi = log_chi2_mean_band(3, 30, 0.01)
    assert log_chi2_mean_cdf(lo, 3, 30) == pytest.approx(0.005, abs=1e-9)
    assert log_chi2_mean_cdf(hi, 3, 30) == pytest.approx(0.995, abs=1e-9)
    assert log_chi2_mean_power(3, 30, 0.01, 1.0) == pytest.approx(0.01, abs=1e-9)
    assert log_chi2_mean_power(3, 30, 0.01, 2.0) > 0.9  # the stated power of 0.93


def test_standard_normal_failures__passes_normal_draws_and_names_each_fault() -> None:
    rng = np.random.default_rng(1)
    z = rng.standard_normal((300, 3))
    assert standard_normal_failures(z) == []
    # a mean off 0 fails the mean check (and the scatter's, taken about the known mean 0)
    assert "mean" in [f.split(":")[0] for f in standard_normal_failures(z + 0.5)]
    scaled = z * np.array([1.0, 1.5, 1.0])
    assert [f.split(":")[0] for f in standard_normal_failures(scaled)] == ["axis 1"]
    mixed = z.copy()
    mixed[:, 2] = (z[:, 0] + z[:, 2]) / math.sqrt(2.0)
    assert [f.split(":")[0] for f in standard_normal_failures(mixed)] == ["correlation"]


def test_weighted_chi2_cdf__equal_weights_are_a_scaled_chi2() -> None:
    for x in (10.0, 30.0, 55.0):
        want = scipy.stats.chi2.cdf(x, 30)
        assert weighted_chi2_cdf(x * 1e-6, np.full(30, 1e-6)) == pytest.approx(want, abs=1e-9)


def test_weighted_chi2_band__holds_sampled_draws_of_unequal_weights() -> None:
    """90 weights spread over three decades (as P²'s eigenvalues over 30 runs): 10⁵ sampled
    sums fall below and above the 99 % band's ends in 0.5 % ± 4.5 binomial standard errors."""
    rng = np.random.default_rng(2)
    weights = rng.uniform(0.0, 1.0, 90) ** 3 * 1e-6
    draws = 100_000
    sums = (rng.standard_normal((draws, 90)) ** 2 * weights).sum(axis=1)
    lo, hi = weighted_chi2_band(weights, 0.01)
    se = math.sqrt(0.005 * 0.995 / draws)
    assert abs(np.mean(sums < lo) - 0.005) < 4.5 * se
    assert abs(np.mean(sums > hi) - 0.005) < 4.5 * se

"""The studies' t interval: a textbook value and its coverage over repeated samples."""

import numpy as np
import pytest

from polyslam_env.metrics.statistics import paired_interval, t_half_width


def test_t_half_width__textbook_value():
    # 1..5: mean 3, s = sqrt(2.5), t(0.975, 4) = 2.776445 (tables) -> 2.776445 * s / sqrt(5).
    assert t_half_width([1, 2, 3, 4, 5]) == pytest.approx(2.776445 * np.sqrt(2.5 / 5), rel=1e-6)
    mean, half = paired_interval(np.array([2.0, 4.0]))
    # t(0.975, 1) = 12.7062; s = sqrt(2); n = 2.
    assert (mean, half) == pytest.approx((3.0, 12.7062 * np.sqrt(2) / np.sqrt(2)), rel=1e-5)


def test_t_half_width__covers_the_true_mean_at_its_level():
    # 4,000 samples of 8 normal draws: the 95 % interval holds the mean in a binomial share
    # whose sd is sqrt(0.95 · 0.05 / 4000) = 0.0034; 4 sd either side fails by chance < 1e-4.
    rng = np.random.default_rng(7)
    draws = rng.normal(1.5, 2.0, size=(4000, 8))
    hits = [abs(x.mean() - 1.5) <= t_half_width(x) for x in draws]
    assert abs(np.mean(hits) - 0.95) < 4 * np.sqrt(0.95 * 0.05 / 4000)
    hits90 = [abs(x.mean() - 1.5) <= t_half_width(x, level=0.9) for x in draws]
    assert abs(np.mean(hits90) - 0.90) < 4 * np.sqrt(0.90 * 0.10 / 4000)


def test_t_half_width__one_value_has_no_interval():
    assert np.isnan(t_half_width([3.0]))

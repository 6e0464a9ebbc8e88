"""The divergence flag: its outlier-count threshold, and that it fires on injected faults
(kidnap, wheel slip) within 20 steps and stays quiet in healthy episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.ekf import normalised_innovations, outlier_count_threshold
from polyslam_env.slam.robot import PolySlam
from tests.slam.divergence_trials import (
    DEADLINE,
    FAULT_STEP,
    KIDNAP_05,
    SLIP_05,
    detection_delay,
    first_alarm,
)


def _binomial_tail(n: int, p: float, m: int) -> float:
    """P(Bin(n, p) ≥ m), summed term by term (the readable oracle)."""
    return sum(math.comb(n, j) * p**j * (1 - p) ** (n - j) for j in range(m, n + 1))


@pytest.mark.parametrize(("n", "p", "alpha"), [(10, 0.16, 1e-3), (10, 0.01, 1e-3), (25, 0.3, 0.01)])
def test_outlier_count_threshold__is_the_smallest_count_within_the_false_alarm(
    n: int, p: float, alpha: float
) -> None:
    m = outlier_count_threshold(n, p, alpha)
    assert _binomial_tail(n, p, m) <= alpha
    assert m == 1 or _binomial_tail(n, p, m - 1) > alpha


def test_normalised_innovations__match_the_dense_h_p_ht_plus_r() -> None:
    """ν_i² / (H P Hᵀ + R)_ii with a dense H built row by row (the oracle), two rows on one c0."""
    rng = np.random.default_rng(3)
    n = 9
    a = rng.normal(size=(n, n))
    cov = a @ a.T  # (n, n) symmetric positive definite
    c0_index = np.array([3, 7, 7, 5])
    h_pose, h_c0 = rng.normal(size=(4, 3)), rng.normal(size=4)
    r, innovation = np.full(4, 0.02**2), rng.normal(size=4)
    H = np.zeros((4, n))
    H[:, :3] = h_pose
    H[np.arange(4), c0_index] = h_c0
    expected = innovation**2 / (np.diag(H @ cov @ H.T) + r)
    got = normalised_innovations(cov, innovation, h_pose, c0_index, h_c0, r)
    np.testing.assert_allclose(got, expected, rtol=1e-12)  # rounding of a few products


def test_outlier_count_threshold__never_when_even_all_outliers_is_too_likely() -> None:
    assert outlier_count_threshold(3, 0.9, 1e-3) == 4


def test_divergence__screen_sees_a_wall_that_moved() -> None:
    """A robot that has mapped a wall 1 m ahead, then finds it at 1.5 m without having moved
    (as after a kidnap): the screen's outliers raise the flag within a window of beams. The
    five beams are 10° apart, so every one is screened only with ``update_spacing_deg`` 0."""
    angles = np.radians([-20.0, -10.0, 0.0, 10.0, 20.0])
    slam = PolySlam(SlamConfig(update_spacing_deg=0.0), angles, 2.0)
    rng = np.random.default_rng(0)
    wall = 1.0 / np.cos(angles)  # a wall x = 1 m, seen from the origin facing +x
    still = np.zeros(3)
    for _ in range(15):  # map it
        slam.step(still, wall + rng.normal(0.0, 0.02, 5))
    assert slam.n_landmarks >= 1 and not slam.diverging
    flags = [slam.step(still, wall + 0.5 + rng.normal(0.0, 0.02, 5)).diverging for _ in range(3)]
    assert flags[-1]


def test_divergence__screen_tests_only_the_beams_the_update_uses() -> None:
    """Two beams 11.25° apart facing a mapped wall that then moves 0.5 m away: every beam is an
    outlier from then on. With ``update_spacing_deg`` 22.5 only one of them is screened, so the
    alarm's count (7 of the last 10 screened beams) is reached at the 7th step; with 0 both
    are, and it is reached at the 4th (⌈7 / 2⌉)."""
    angles = np.radians([-5.625, 5.625])
    wall = 1.0 / np.cos(angles)
    for spacing, first in ((22.5, 7), (0.0, 4)):
        slam = PolySlam(SlamConfig(update_spacing_deg=spacing), angles, 2.0)
        rng = np.random.default_rng(0)
        for _ in range(20):  # map it
            slam.step(np.zeros(3), wall + rng.normal(0.0, 0.02, 2))
        assert slam.n_landmarks >= 1 and not slam.diverging
        flags = [
            slam.step(np.zeros(3), wall + 0.5 + rng.normal(0.0, 0.02, 2)).diverging
            for _ in range(first)
        ]
        assert flags == [False] * (first - 1) + [True], spacing


def _rate(delays: list[int | None]) -> float:
    return sum(d is not None and d >= 0 for d in delays) / len(delays)


RUNS = 20


@pytest.mark.slow
@pytest.mark.parametrize("fault", [KIDNAP_05, SLIP_05], ids=["kidnap_0.5m", "slip_0.5x20"])
def test_divergence__fires_within_20_steps_of_a_fault_in_90_percent_of_runs(
    fault: dict[str, object],
) -> None:
    """20 seeded runs (see ``divergence_trials``): the flag fires at most DEADLINE steps after
    the fault at FAULT_STEP in ≥ 90 % of them (≥ 18 of 20)."""
    delays = [detection_delay(seed, fault) for seed in range(RUNS)]
    assert _rate(delays) >= 0.9, f"delays after step {FAULT_STEP} (≤ {DEADLINE}): {delays}"


@pytest.mark.slow
def test_divergence__quiet_in_99_percent_of_healthy_episodes() -> None:
    """100 healthy episodes as long as a fault trial: the false-alarm rate is ≤ 1 % unless the
    count is improbably high for that rate. A detector at exactly 1 % fires in ≥ 4 of 100 with
    probability 1.8 % (binomial), so more than 3 alarms rejects "≤ 1 %" at the 5 % level;
    demanding ≤ 1 alarm would fail a 1 % detector in 26 % of samples."""
    alarms = [first_alarm(seed, None, FAULT_STEP + DEADLINE) for seed in range(100)]
    fired = [(seed, a) for seed, a in enumerate(alarms) if a is not None]
    limit = int(scipy.stats.binom.ppf(0.95, 100, 0.01))  # 3: P(X > 3 | p = 1 %) < 5 %
    assert len(fired) <= limit, f"false alarms (seed, step): {fired}"

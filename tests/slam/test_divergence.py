"""The divergence flag: its outlier-count threshold, and that it fires on injected faults
(kidnap, wheel slip) within 20 steps and stays quiet in healthy episodes."""

from __future__ import annotations

import math
from collections.abc import Iterator

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
from tests.stats import Sprt


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


#: Detection, claimed ≥ 90 % of faults flagged within DEADLINE steps: Wald's SPRT of 90 %
#: against 80 %, nominal α = β = 5 %, at most 150 seeds. Exactly (``Sprt.operating``): a
#: detector at 90 % passes with probability 0.944, one at 80 % with 0.060 (power 0.94), and
#: one at 95 % (README's kidnap 0.5 m) is accepted after 38 seeds on average. (The rule it
#: replaces, ≥ 18 of 20, passed an 80 % detector with probability 0.21 and failed a 90 % one
#: with 0.32.)
DETECTION = Sprt(p0=0.9, p1=0.8, alpha=0.05, beta=0.05, n_max=150)
#: False alarms, claimed in ≤ 1 % of healthy episodes: SPRT of 99 % quiet episodes against
#: 97 %, at most 400 seeds: a detector at 1 % passes with probability 0.943 after 261 seeds on
#: average, one at 3 % with 0.095 (power 0.905). (≤ 3 alarms in 100 passed 3 % with 0.65.)
QUIET = Sprt(p0=0.99, p1=0.97, alpha=0.05, beta=0.05, n_max=400)


@pytest.mark.slow
@pytest.mark.parametrize("fault", [KIDNAP_05, SLIP_05], ids=["kidnap_0.5m", "slip_0.5x20"])
def test_divergence__fires_within_20_steps_of_a_fault_in_90_percent_of_runs(
    fault: dict[str, object],
) -> None:
    """Seeded runs (see ``divergence_trials``), one at a time until DETECTION decides: the
    flag fires at most DEADLINE steps after the fault at FAULT_STEP."""
    delays: list[int | None] = []

    def detected() -> Iterator[bool]:
        for seed in range(DETECTION.n_max):
            delays.append(detection_delay(seed, fault))
            yield delays[-1] is not None and delays[-1] >= 0

    accepted, n, hits = DETECTION.run(detected())
    assert accepted, f"{hits} of {n} flagged within {DEADLINE} steps of step {FAULT_STEP}: {delays}"


@pytest.mark.slow
def test_divergence__quiet_in_99_percent_of_healthy_episodes() -> None:
    """Healthy episodes as long as a fault trial, one at a time until QUIET decides."""
    fired: list[tuple[int, int]] = []

    def quiet() -> Iterator[bool]:
        for seed in range(QUIET.n_max):
            alarm = first_alarm(seed, None, FAULT_STEP + DEADLINE)
            if alarm is not None:
                fired.append((seed, alarm))
            yield alarm is None

    accepted, n, _ = QUIET.run(quiet())
    assert accepted, f"false alarms (seed, step) in {n} healthy episodes: {fired}"


def test_divergence_tests__catch_an_80_percent_detector_and_a_3_percent_false_alarm_rate() -> None:
    """The two sequential tests above against the mutants: their exact operating
    characteristics, and seeded Bernoulli streams at the mutants' rates rejected. A detector
    meeting the claims with a margin (95 % / 0.3 %) is accepted with probability ≥ 0.999."""
    for test, good, boundary, mutant in ((DETECTION, 0.95, 0.9, 0.8), (QUIET, 0.997, 0.99, 0.97)):
        assert test.operating(good)[0] >= 0.999
        assert test.operating(boundary)[0] >= 0.94  # α ≈ 5 % at the claim's bound
        assert test.operating(mutant)[0] <= 0.1  # power ≥ 0.9
        rng = np.random.default_rng(0)
        accepted, _, _ = test.run(iter(rng.random(test.n_max) < mutant))
        assert not accepted
    # the rules replaced: ≥ 18 of 20 detected, ≤ 3 alarms in 100
    assert scipy.stats.binom.sf(17, 20, 0.8) > 0.2  # passed an 80 % detector one time in five
    assert scipy.stats.binom.cdf(3, 100, 0.03) > 0.6  # passed a 3 % false-alarm rate

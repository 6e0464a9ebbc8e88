"""The map precision a robot's own filter expects (``metrics.expected_precision``) and the
exact distribution of a count of independent events (``metrics.count_interval``)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import special, stats

from polyslam_env.metrics.mapping import count_interval, expected_precision

TOL, FLOOR = 0.05, 0.9


def _map(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Six straight walls of 40 points each whose normal errors are their offset plus their
    turn times the lever from their middle (c0 and α per wall, as PolySlam's map), with a
    covariance in which all walls share one pose-like error (correlated, not independent)."""
    walls, points = 6, 40
    lengths = rng.uniform(0.02, 0.05, walls * points)
    jac = np.zeros((walls * points, 2 * walls + 1))
    for w in range(walls):
        rows = slice(w * points, (w + 1) * points)
        jac[rows, w] = 1.0
        jac[rows, walls + w] = np.linspace(-1.5, 1.5, points)  # lever (m) on α
    shared = rng.normal(size=(2 * walls, 1))  # one common error moves every wall
    base = np.diag(np.r_[np.full(walls, 0.02**2), np.full(walls, np.radians(0.6) ** 2)])
    cov = np.zeros((2 * walls + 1, 2 * walls + 1))  # the last state moves no point
    cov[:-1, :-1] = base + 0.015**2 * shared @ shared.T
    cov[-1, -1] = 5.0
    return lengths, jac, cov


def _true_precisions(
    rng: np.random.Generator, lengths: np.ndarray, jac: np.ndarray, cov: np.ndarray, n: int
) -> np.ndarray:
    """Precision of ``n`` maps whose state errors are drawn from N(0, cov) independently."""
    errors = jac @ rng.multivariate_normal(np.zeros(len(cov)), cov, size=n).T  # (M, n)
    return (lengths / lengths.sum()) @ (np.abs(errors) <= TOL)


def test_expected_precision__matches_maps_drawn_from_the_same_errors() -> None:
    """Against 4,000 maps drawn independently of the function's own draws: the exact mean
    within 4 standard errors of their mean precision, and P(precision < 0.9) within 4
    standard deviations of the two estimates' binomial errors (400 draws and 4,000)."""
    rng = np.random.default_rng(5)
    lengths, jac, cov = _map(rng)
    mean, risk = expected_precision(lengths, jac, cov, TOL, FLOOR)
    truth = _true_precisions(rng, lengths, jac, cov, 4000)
    assert abs(mean - truth.mean()) <= 4 * truth.std() / np.sqrt(len(truth))
    frequency = float(np.mean(truth < FLOOR))
    assert 0.1 < frequency < 0.9  # the case tests the tail, not a certainty
    spread = np.sqrt(frequency * (1 - frequency) * (1 / 400 + 1 / len(truth)))
    assert abs(risk - frequency) <= 4 * spread


def test_expected_precision__mean_is_the_length_weighted_normal_probability() -> None:
    """Independent points: the mean is Σ ℓ_i erf(tol / (√2 σ_i)) / Σ ℓ_i exactly; a point
    with no variance is within tolerance for sure; the same inputs give the same numbers."""
    lengths = np.array([1.0, 2.0, 1.0])
    jac = np.eye(3)
    sd = np.array([0.01, 0.1, 0.0])
    cov = np.diag(sd**2)
    mean, risk = expected_precision(lengths, jac, cov, TOL, FLOOR)
    exact = (special.erf(TOL / (np.sqrt(2) * 0.01)) + 2 * special.erf(TOL / (np.sqrt(2) * 0.1))
             + 1.0) / 4  # fmt: skip
    assert mean == pytest.approx(exact, rel=1e-12)
    assert (mean, risk) == expected_precision(lengths, jac, cov, TOL, FLOOR)
    assert 0.0 < risk < 1.0


def test_expected_precision__frozen_errors_are_one_curve_per_landmark() -> None:
    """A landmark's frozen error (``PolySlam.map_frozen_variance``) counts as one more normal
    variate per landmark that moves its points by √variance each: the mean equals that of the
    map with those variates as states (to rounding), and the probability matches 4,000 maps
    drawn so, within 4 standard deviations of the two estimates' binomial errors. Without the
    frozen errors the map is more precise than it is (the mean is higher)."""
    rng = np.random.default_rng(8)
    lengths, jac, cov = _map(rng)
    walls = 6
    landmark = np.repeat(np.arange(walls), len(lengths) // walls)
    frozen = rng.uniform(0.0, 0.03, walls)[landmark] ** 2 * np.linspace(0.2, 1.0, len(lengths))
    mean, risk = expected_precision(lengths, jac, cov, TOL, FLOOR, frozen=(frozen, landmark))
    extra = np.zeros((len(lengths), walls))
    extra[np.arange(len(lengths)), landmark] = np.sqrt(frozen)
    wide = np.hstack([jac, extra])
    wide_cov = np.zeros((len(cov) + walls, len(cov) + walls))
    wide_cov[: len(cov), : len(cov)] = cov
    wide_cov[len(cov) :, len(cov) :] = np.eye(walls)
    assert mean == pytest.approx(expected_precision(lengths, wide, wide_cov, TOL)[0], rel=1e-12)
    assert mean < expected_precision(lengths, jac, cov, TOL, FLOOR)[0]
    truth = _true_precisions(rng, lengths, wide, wide_cov, 4000)
    frequency = float(np.mean(truth < FLOOR))
    assert 0.1 < frequency < 0.9  # the case tests the tail, not a certainty
    spread = np.sqrt(frequency * (1 - frequency) * (1 / 400 + 1 / len(truth)))
    assert abs(risk - frequency) <= 4 * spread


def test_expected_precision__empty_certain_and_hopeless_maps() -> None:
    assert expected_precision(np.zeros(0), np.zeros((0, 3)), np.eye(3)) == (1.0, 0.0)
    lengths, jac = np.ones(5), np.ones((5, 2))
    assert expected_precision(lengths, jac, np.zeros((2, 2))) == (1.0, 0.0)
    # five independent points with σ = 1 m against 5 cm: each within it with P = 0.04, all
    # five (the only way to reach 0.9) with P = 0.04⁵
    mean, risk = expected_precision(lengths, np.eye(5), np.eye(5))
    assert mean == pytest.approx(special.erf(0.05 / np.sqrt(2)), rel=1e-12) and risk == 1.0


@pytest.mark.parametrize("n, p", [(60, 0.112), (20, 0.5), (7, 0.03)])
def test_count_interval__equal_probabilities_give_the_binomial(n: int, p: float) -> None:
    expected, lo, hi = count_interval([p] * n)
    assert expected == pytest.approx(n * p, rel=1e-12)
    assert (lo, hi) == tuple(int(v) for v in stats.binom.interval(0.95, n, p))


def test_count_interval__unequal_probabilities_against_enumeration() -> None:
    """The exact distribution of the count by enumerating all 2⁸ outcomes."""
    probs = [0.9, 0.02, 0.5, 0.3, 0.0, 1.0, 0.15, 0.6]
    pmf = np.zeros(len(probs) + 1)
    for outcome in itertools.product([0, 1], repeat=len(probs)):
        chances = [p if o else 1 - p for p, o in zip(probs, outcome, strict=True)]
        pmf[sum(outcome)] += np.prod(chances)
    cdf = np.cumsum(pmf)
    lo = int(np.argmax(cdf >= 0.025 - 1e-12))
    hi = int(np.argmax(cdf >= 0.975 - 1e-12))
    assert count_interval(probs) == (pytest.approx(sum(probs)), lo, hi)

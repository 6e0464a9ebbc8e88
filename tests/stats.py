"""Sampling distributions the suite's statistical tests are built on, with their power.

A statistical test here fixes its sample size and its level α before it looks at a result,
and states its power against a named mutant (a filter with its covariance halved, a channel
that loses 0.7 instead of 0.5 …) computed from the same distribution.

The final NEES of a whole episode is heavy-tailed (a wall group's direction 2σ off gives a
run of 16), so the χ² band of the *mean* of n runs (:func:`polyslam_env.metrics.nees_band`)
is not its test. The mean of ``log NEES`` is: a consistent filter's NEES is χ²(d), so
``log NEES = log 2 + log G`` with ``G ~ Gamma(d/2)``, whose moments are finite and whose right
tail is exponential — one run of 16 moves the log-mean of 30 runs by 0.07, a tenth of what a
covariance off by a factor 2 moves it (log 2 = 0.69). The distribution of the mean of n such
logs has the characteristic function ``φ(t/n)ⁿ`` with ``φ(t) = 2^{it} Γ(d/2 + it) / Γ(d/2)``;
:func:`log_chi2_mean_cdf` inverts it exactly (Gil-Pelaez), and a filter whose covariance is
scaled by 1/s moves every log NEES by exactly ``log s``, so the power against it is exact too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
import scipy.integrate
import scipy.optimize
import scipy.special
import scipy.stats


def _log_chi2_moments(dof: int) -> tuple[float, float]:
    """Mean and variance of log X for X ~ χ²(dof): ψ(d/2) + log 2 and ψ′(d/2)."""
    a = dof / 2.0
    return float(scipy.special.digamma(a) + math.log(2.0)), float(scipy.special.polygamma(1, a))


def _gil_pelaez_cdf(x: float, log_cf: Callable[[float], complex]) -> float:
    """P(X ≤ x) from the log characteristic function of X (Gil-Pelaez):
    F(x) = 1/2 − (1/π) ∫₀^∞ Im(e^{−itx} φ(t)) / t dt, the integral stopped where the
    integrand's envelope |φ(t)| / t is below e⁻⁴⁰ (4e-18). The φ here must fall fast enough
    for that before t = 1e4 (a weighted χ² of a handful of terms does not; it is refused)."""

    def integrand(t: float) -> float:
        return float(np.imag(np.exp(log_cf(t) - 1j * t * x))) / t

    upper = 1.0
    while log_cf(upper).real - math.log(upper) > -40.0:
        upper *= 2.0
        if upper > 1e4:
            raise ValueError("the characteristic function falls too slowly for the quadrature")
    value, _ = scipy.integrate.quad(integrand, 0.0, upper, limit=2000, epsabs=1e-13)
    return 0.5 - value / math.pi


def _quantile(cdf: Callable[[float], float], p: float, lo: float, hi: float) -> float:
    return float(scipy.optimize.brentq(lambda x: cdf(x) - p, lo, hi, xtol=1e-12))


def log_chi2_mean_cdf(x: float, dof: int, n: int) -> float:
    """P(M ≤ x) for M the mean of log X_i over n independent X_i ~ χ²(dof):
    log φ_M(t) = n (i (t/n) log 2 + log Γ(d/2 + i t/n) − log Γ(d/2)), |φ_M| falling like
    e^{−π t / 2} and faster."""
    a = dof / 2.0

    def log_cf(t: float) -> complex:
        u = t / n
        log_phi = n * (1j * u * math.log(2.0) + scipy.special.loggamma(a + 1j * u))
        return complex(log_phi - n * scipy.special.loggamma(a))

    return _gil_pelaez_cdf(x, log_cf)


def weighted_chi2_cdf(x: float, weights: np.ndarray) -> float:
    """P(Q ≤ x) for Q = Σ_j λ_j w_j², w_j independent N(0, 1), ``weights`` λ_j > 0:
    log φ(t) = −½ Σ log(1 − 2iλ_j t). (eᵀAe for e ~ N(0, P) is such a Q with λ the
    eigenvalues of P^{1/2} A P^{1/2}.)"""
    lam = np.asarray(weights, dtype=float).ravel()
    scale = float(lam.sum())
    lam = lam / scale  # Q / scale has mean 1

    def log_cf(t: float) -> complex:
        return complex(-0.5 * np.sum(np.log(1.0 - 2j * lam * t)))

    return _gil_pelaez_cdf(x / scale, log_cf)


def weighted_chi2_band(weights: np.ndarray, alpha: float) -> tuple[float, float]:
    """Two-sided level-``alpha`` band of :func:`weighted_chi2_cdf`'s Q."""
    lam = np.asarray(weights, dtype=float).ravel()
    mean, sd = float(lam.sum()), float(np.sqrt(2.0 * np.sum(lam**2)))
    lo, hi = 0.0, mean + 40.0 * sd

    def cdf(x: float) -> float:
        return weighted_chi2_cdf(x, lam)

    return _quantile(cdf, alpha / 2.0, lo, hi), _quantile(cdf, 1.0 - alpha / 2.0, lo, hi)


def log_chi2_mean_band(dof: int, n: int, alpha: float) -> tuple[float, float]:
    """Two-sided level-``alpha`` band of the mean of log χ²(dof) over n runs: the α/2 and
    1 − α/2 quantiles of :func:`log_chi2_mean_cdf`."""
    mean, var = _log_chi2_moments(dof)
    sd = math.sqrt(var / n)

    def cdf(x: float) -> float:
        return log_chi2_mean_cdf(x, dof, n)

    lo, hi = mean - 12 * sd, mean + 12 * sd
    return _quantile(cdf, alpha / 2.0, lo, hi), _quantile(cdf, 1.0 - alpha / 2.0, lo, hi)


def log_chi2_mean_power(dof: int, n: int, alpha: float, scale: float) -> float:
    """Probability that the band of :func:`log_chi2_mean_band` rejects a filter whose every
    NEES is ``scale`` times a consistent one's (its covariance scaled by 1/``scale``): the
    log-mean is then shifted by exactly log(scale)."""
    lo, hi = log_chi2_mean_band(dof, n, alpha)
    shift = math.log(scale)
    return log_chi2_mean_cdf(lo - shift, dof, n) + 1.0 - log_chi2_mean_cdf(hi - shift, dof, n)


def log_mean(values: np.ndarray | list[float]) -> float:
    """The statistic of :func:`log_chi2_mean_band`: the mean of log NEES over runs."""
    return float(np.mean(np.log(np.asarray(values, dtype=float))))


def standard_normal_failures(z: np.ndarray, tail: float = 1e-3) -> list[str]:
    """What is wrong with ``z`` (n, d), rows claimed independent N(0, I); [] if nothing.

    Known mean 0, so the scatter W = zᵀz is Wishart(n, I), and its Bartlett decomposition
    W = Rᵀ R (R from the QR of z, upper triangular) has independent pieces: R_kk² ~ χ²(n − k)
    and R_jk ~ N(0, 1) for j < k. The checks, each at ``tail`` per side:

    * the mean: n ‖z̄‖² ~ χ²(d), upper tail;
    * each axis's variance: Σ_i z_ik² ~ χ²(n), both tails;
    * the correlations: Σ_{j<k} R_jk² ~ χ²(d(d−1)/2), upper tail — what the per-axis checks
      cannot see (x and y fully correlated leave every axis N(0, 1); here R_01² = ‖z_0‖² ≈ n).

    1 + 2d + 1 tails: a right draw fails one with probability ≤ (2d + 2) · ``tail``.
    """
    z = np.asarray(z, dtype=float)
    n, d = z.shape
    failures = []
    mean_stat = n * float(z.mean(axis=0) @ z.mean(axis=0))
    if mean_stat > scipy.stats.chi2.isf(tail, d):
        failures.append(f"mean: n‖z̄‖² = {mean_stat:.1f} above χ²({d})'s {1 - tail} quantile")
    lo, hi = scipy.stats.chi2.ppf(tail, n), scipy.stats.chi2.isf(tail, n)
    for axis, s in enumerate((z * z).sum(axis=0).tolist()):
        if not lo < s < hi:
            failures.append(f"axis {axis}: Σz² = {s:.1f} outside χ²({n}) [{lo:.1f}, {hi:.1f}]")
    r = np.linalg.qr(z, mode="r")  # (d, d)
    off = float(np.sum(np.triu(r, 1) ** 2))
    dof = d * (d - 1) // 2
    if off > scipy.stats.chi2.isf(tail, dof):
        failures.append(f"correlation: Σ R_jk² = {off:.1f} above χ²({dof})'s {1 - tail} quantile")
    return failures


@dataclass(frozen=True)
class Sprt:
    """Wald's sequential probability ratio test of a success probability: H0 p = ``p0`` against
    H1 p = ``p1``, with nominal error rates ``alpha`` (rejecting H0 when p = p0) and ``beta``
    (accepting it when p = p1). After each trial the log likelihood ratio of H0 to H1 is
    compared with log((1 − β)/α) (accept H0) and log(β/(1 − α)) (reject it); at ``n_max``
    trials the nearer bound decides. A detector far better than p0 is accepted after few
    trials; :meth:`operating` gives the exact acceptance probability and mean trial count.
    """

    p0: float
    p1: float
    alpha: float
    beta: float
    n_max: int

    def _llr(self, successes: int, failures: int) -> float:
        return successes * math.log(self.p0 / self.p1) + failures * math.log(
            (1.0 - self.p0) / (1.0 - self.p1)
        )

    def _decide(self, successes: int, failures: int) -> bool | None:
        """True: accept H0; False: reject it; None: go on."""
        llr = self._llr(successes, failures)
        upper, lower = (
            math.log((1 - self.beta) / self.alpha),
            math.log(self.beta / (1 - self.alpha)),
        )
        if llr >= upper:
            return True
        if llr <= lower:
            return False
        if successes + failures >= self.n_max:
            return llr >= 0.5 * (upper + lower)
        return None

    def run(self, trials: Iterable[bool]) -> tuple[bool, int, int]:
        """(H0 accepted, trials used, successes) over ``trials``, drawn only as needed."""
        successes = failures = 0
        for outcome in trials:
            successes += bool(outcome)
            failures += not outcome
            decision = self._decide(successes, failures)
            if decision is not None:
                return decision, successes + failures, successes
        raise ValueError(f"the trials ran out after {successes + failures} of {self.n_max}")

    def operating(self, p: float) -> tuple[float, float]:
        """(P(H0 accepted), mean number of trials) when each trial succeeds with ``p``: exact,
        by carrying the probability of every (trials, successes) still going on."""
        going = {0: 1.0}  # successes → probability, after n trials, of no decision yet
        accepted = mean_n = 0.0
        for n in range(1, self.n_max + 1):
            after: dict[int, float] = {}
            for k, prob in going.items():
                for k_new, q in ((k + 1, p), (k, 1.0 - p)):
                    decision = self._decide(k_new, n - k_new)
                    if decision is None:
                        after[k_new] = after.get(k_new, 0.0) + prob * q
                    else:
                        accepted += prob * q * decision
                        mean_n += prob * q * n
            going = after
        return accepted, mean_n

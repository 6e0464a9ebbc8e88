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

import numpy as np
import scipy.integrate
import scipy.optimize
import scipy.special
import scipy.stats


def _log_chi2_moments(dof: int) -> tuple[float, float]:
    """Mean and variance of log X for X ~ χ²(dof): ψ(d/2) + log 2 and ψ′(d/2)."""
    a = dof / 2.0
    return float(scipy.special.digamma(a) + math.log(2.0)), float(scipy.special.polygamma(1, a))


def log_chi2_mean_cdf(x: float, dof: int, n: int) -> float:
    """P(M ≤ x) for M the mean of log X_i over n independent X_i ~ χ²(dof).

    Gil-Pelaez: F(x) = 1/2 − (1/π) ∫₀^∞ Im(e^{−itx} φ_M(t)) / t dt, with
    log φ_M(t) = n (i (t/n) log 2 + log Γ(d/2 + i t/n) − log Γ(d/2)). |φ_M| falls like
    e^{−π t / 2} and faster, so the integral stops where it is below e⁻⁴⁰ (4e-18).
    """
    a = dof / 2.0

    def log_abs_phi(t: float) -> float:
        return float(n * (scipy.special.loggamma(a + 1j * t / n).real - scipy.special.loggamma(a)))

    def integrand(t: float) -> float:
        u = t / n
        log_phi = n * (1j * u * math.log(2.0) + scipy.special.loggamma(a + 1j * u))
        log_phi -= n * scipy.special.loggamma(a)
        return float(np.imag(np.exp(log_phi - 1j * t * x))) / t

    upper = 1.0
    while log_abs_phi(upper) > -40.0:
        upper *= 2.0
    value, _ = scipy.integrate.quad(integrand, 0.0, upper, limit=1000, epsabs=1e-13)
    return 0.5 - value / math.pi


def log_chi2_mean_band(dof: int, n: int, alpha: float) -> tuple[float, float]:
    """Two-sided level-``alpha`` band of the mean of log χ²(dof) over n runs: the α/2 and
    1 − α/2 quantiles of :func:`log_chi2_mean_cdf`."""
    mean, var = _log_chi2_moments(dof)
    sd = math.sqrt(var / n)

    def quantile(p: float) -> float:
        return float(
            scipy.optimize.brentq(
                lambda x: log_chi2_mean_cdf(x, dof, n) - p, mean - 12 * sd, mean + 12 * sd,
                xtol=1e-10,
            )
        )  # fmt: skip

    return quantile(alpha / 2.0), quantile(1.0 - alpha / 2.0)


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

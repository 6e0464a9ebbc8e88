"""Confidence intervals the studies report (paired differences of seeded episodes)."""

from collections.abc import Sequence

import numpy as np
from scipy import stats


def t_half_width(values: Sequence[float] | np.ndarray, level: float = 0.95) -> float:
    """Half-width of the two-sided Student-t interval of the mean of ``values`` at ``level``.

    The differences of paired episodes (same seed, same robot) are the usual input: their mean
    is then the effect and this its uncertainty. Fewer than two values have no interval: nan
    (as scipy's own statistics answer), which plots draw as no error bar.
    """
    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return float("nan")
    quantile = stats.t.ppf(0.5 + level / 2.0, x.size - 1)
    return float(quantile * x.std(ddof=1) / np.sqrt(x.size))


def paired_interval(
    diffs: Sequence[float] | np.ndarray, level: float = 0.95
) -> tuple[float, float]:
    """(mean, t half-width at ``level``) of paired differences."""
    d = np.asarray(diffs, dtype=float)
    return float(d.mean()), t_half_width(d, level)

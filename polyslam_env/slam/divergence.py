"""The divergence monitor of one robot's SLAM: two tests, either flags (paper §3.1, SPEC §3).

* **The paper's**: the pose covariance P_{k|k−1} beyond K·P0, read as "P − K P0 is not
  negative semidefinite" (:func:`beyond_k_p0`). The compiled step first checks the cheap
  sufficient condition ‖P‖_F < λ_min(K P0)/2, under which λ_max(P − K P0) ≤ ‖P‖_F −
  λ_min(K P0) < 0: the eigenvalues are asked for only when the pose is that uncertain.
* **The innovation screen**: of the last :data:`SCREEN_WINDOW` beams whose return (or lack of
  one) the map predicts, at the predicted pose and against the map as it stood before the
  step's changes (created or refit landmarks would explain the very beams they were made of),
  at least ``switches[S_SCREEN_ALARM]`` are outliers (NIS beyond the χ²(1) gate). A lost
  filter (kidnapped, wheels slipping) predicts most beams wrong at once, while a healthy one
  meets an outlier now and then; counting outliers rather than summing NIS keeps one gross
  outlier from raising the alarm alone. A beam without return whose predicted hit lies within
  range counts with the range r_max: a lower bound of its true range, so its NIS is a lower
  bound too. Only the update's beams (``update_spacing_deg``) are screened: the alarm's count
  is binomial for independent beams, and beams closer together share more of their
  landmark's error (with all seventeen default beams, 3 of 100 healthy episodes raised the
  flag). The compiled step keeps the window (``step_kernels``).
"""

from __future__ import annotations

import numpy as np

from polyslam_env.slam import ekf
from polyslam_env.slam.config import SlamConfig

#: The screen's window: the last SCREEN_WINDOW screened beams, each an outlier when its NIS
#: exceeds the χ²(1) gate quantile (probability 1 − gate_prob for a consistent filter).
#: Besides, up to SCREEN_CONTAMINATION of the beams of a healthy robot are gross outliers
#: (occlusion by walls not yet mapped, polynomials reaching past their support: 6.5 % of
#: 6,785 beams over 40 healthy wall-following episodes, up to 17 % in one episode), so an
#: alarm needs the count that Bin(SCREEN_WINDOW, 1 − gate_prob + SCREEN_CONTAMINATION)
#: reaches with probability at most SCREEN_FALSE_ALARM (7 of 10 with the defaults).
SCREEN_WINDOW = 10
SCREEN_CONTAMINATION = 0.15
SCREEN_FALSE_ALARM = 1e-3


def screen_alarm(config: SlamConfig) -> int:
    """Outliers among the screen's window that raise the alarm (module docstring)."""
    return ekf.outlier_count_threshold(
        SCREEN_WINDOW, 1.0 - config.gate_prob + SCREEN_CONTAMINATION, SCREEN_FALSE_ALARM
    )


def beyond_k_p0(cov: np.ndarray, config: SlamConfig) -> bool:
    """The paper's test on the pose block of ``cov``: P_{k|k−1} beyond K·P0
    (:func:`~polyslam_env.slam.ekf.is_diverging`)."""
    return ekf.is_diverging(cov[:3, :3], config.p0, config.k_divergence)

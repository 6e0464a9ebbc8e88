"""The state layout's index arithmetic (polyslam_env/slam/layout.py)."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.slam.layout import new_c0_before_turns


@pytest.mark.parametrize("n", [0, 1, 2, 7, 40])
def test_new_c0_before_turns__is_the_index_permutation(n: int) -> None:
    """[pose, c0s, αs, c0_new, α_new] → [pose, c0s, c0_new, αs, α_new], entry for entry as
    the fancy-index gather by the permutation, signed zeros and nan included."""
    rng = np.random.default_rng(n)
    size = 3 + 2 * n + 2
    mean, cov = rng.normal(size=size), rng.normal(size=(size, size))
    cov[0, -1], cov[-1, 0], mean[-2] = -0.0, np.nan, -0.0
    order = np.r_[0 : 3 + n, size - 2, 3 + n : size - 2, size - 1]
    got_mean, got_cov = new_c0_before_turns(mean, cov, n)
    assert got_mean.tobytes() == mean[order].tobytes()
    assert got_cov.tobytes() == cov[np.ix_(order, order)].tobytes()

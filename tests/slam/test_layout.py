"""The state layout's index arithmetic (polyslam_env/slam/layout.py)."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.slam import ekf
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.layout import StateLayout, TurnSource, new_c0_before_turns, turn_row
from polyslam_env.slam.polynomial import Polynomial


def _augmented(mean: np.ndarray, cov: np.ndarray, value: float, gx: np.ndarray, var: float):
    """The oracle of one augmentation (paper eq. 4–5) with numpy's own copies."""
    cross = cov @ gx
    size = mean.size
    new_cov = np.empty((size + 1, size + 1))
    new_cov[:size, :size] = cov
    new_cov[:size, size] = cross
    new_cov[size, :size] = cross
    new_cov[size, size] = gx @ cross + var
    return np.append(mean, value), new_cov


@pytest.mark.parametrize("n", [0, 1, 2, 7, 40])
def test_new_c0_before_turns__is_the_index_permutation(n: int) -> None:
    """[pose, c0s, αs, c0_new, α_new] → [pose, c0s, c0_new, αs, α_new]."""
    size = 3 + 2 * n + 2
    expected = np.r_[0 : 3 + n, size - 2, 3 + n : size - 2, size - 1]
    assert new_c0_before_turns(n).tolist() == expected.tolist()


@pytest.mark.parametrize("n", [0, 1, 2, 7, 40])
@pytest.mark.parametrize("source", ["clone", "rotation", "gradient"])
def test_add__is_two_augmentations_and_the_permutation(n: int, source: str) -> None:
    """A new landmark's c0 and α, bit for bit as two numpy augmentations (the second with
    α's row from turn_row) followed by the fancy-index gather of the permutation; signed
    zeros kept."""
    rng = np.random.default_rng(n)
    size = 3 + 2 * n
    a = rng.normal(size=(size, size))
    cov = a @ a.T
    mean = rng.normal(size=size)
    if size > 4:
        mean[4] = -0.0
    gx = rng.normal(size=(1, size))
    gy, v = rng.normal(size=(1, 6)), np.diag(rng.uniform(0.1, 1.0, 6))
    fit = Fit(Polynomial(1, np.array([0.2, 0.1, 0.0]), 0.0, 1.0), 0.3, gx, gy, v, 0.01, 1)
    turn = {
        "clone": TurnSource(),
        "rotation": TurnSource([(n - 1, 0.3)] if n else []),
        "gradient": TurnSource(gradient=(rng.normal(size=size), 2e-4)),
    }[source]
    got_mean, got_cov = StateLayout(True).add(mean, cov, n, fit, turn, 1e-4)

    gy_v_gy = float(gy[0] @ v @ gy[0])
    m1, c1 = _augmented(mean, cov, 0.3, gx[0], gy_v_gy)
    row, var = turn_row(size + 1, n, turn, 1e-4)
    m2, c2 = _augmented(m1, c1, 0.0, row, var)
    order = np.r_[0 : 3 + n, size, 3 + n : size, size + 1]
    assert got_mean.tobytes() == m2[order].tobytes()
    assert got_cov.tobytes() == c2[np.ix_(order, order)].tobytes()
    # and without rotation states, one augmentation as ekf.augment always made it
    plain_mean, plain_cov = StateLayout(False).add(mean, cov, n, fit, turn, 1e-4)
    assert plain_mean.tobytes() == m1.tobytes() and plain_cov.tobytes() == c1.tobytes()
    assert ekf.augment(mean, cov, 0.3, gx, gy, v)[1].tobytes() == c1.tobytes()

"""Closed-form geometry helpers against numpy's general routines."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.core.geometry import symmetric_eigvals3, wrap_angle, wrap_scalar


def _random_symmetric(rng: np.random.Generator, kind: str) -> np.ndarray:
    if kind == "indefinite":
        a = rng.normal(size=(3, 3))
        return a + a.T
    if kind == "covariance":  # pose covariances: metres² and rad², very different scales
        a = rng.normal(size=(3, 3)) * np.array([0.05, 0.05, 0.02])
        return a @ a.T + np.diag([1e-6, 1e-6, 1e-8])
    if kind == "repeated":  # two equal eigenvalues in a random basis (σx = σy in P0)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        values = rng.normal(size=2)
        return (q * np.array([values[0], values[0], values[1]])) @ q.T
    a = np.diag(rng.normal(size=3))  # exactly diagonal
    return a


@pytest.mark.parametrize("kind", ["indefinite", "covariance", "diagonal"])
def test_symmetric_eigvals3__match_eigvalsh(kind: str) -> None:
    rng = np.random.default_rng(11)
    for _ in range(200):
        a = _random_symmetric(rng, kind)
        got = np.array(symmetric_eigvals3(a))
        want = np.linalg.eigvalsh(a)
        # 1e-12 of ‖A‖: both are backward stable, so a few hundred ulps at most; the
        # distinct eigenvalues of random matrices keep acos away from its steep ends
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_symmetric_eigvals3__repeated_pair_within_documented_accuracy() -> None:
    rng = np.random.default_rng(12)
    for _ in range(200):
        a = _random_symmetric(rng, "repeated")
        got = np.array(symmetric_eigvals3(a))
        want = np.linalg.eigvalsh(a)
        spread = np.abs(want).max()
        # the pair: ~√eps of the spread (the docstring's 1e-8·p, with room for p ≤ ‖A‖)
        np.testing.assert_allclose(got, want, rtol=0, atol=5e-8 * spread)


def test_wrap_scalar__equals_wrap_angle() -> None:
    angles = np.concatenate([np.linspace(-20.0, 20.0, 4001), [np.pi, -np.pi, 0.0, 3 * np.pi]])
    want = wrap_angle(angles)
    got = np.array([wrap_scalar(float(a)) for a in angles])
    np.testing.assert_array_equal(got, want)  # the same formula on the same floats
    assert wrap_scalar(-np.pi) == np.pi  # (−π, π]

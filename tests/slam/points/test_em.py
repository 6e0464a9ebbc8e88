"""EM-FastSLAM's attraction-repulsion move (eqs. 4, 6, 7 as SPEC §8 corrects them)."""

from __future__ import annotations

import numpy as np
import pytest

from polyslam_env.slam.points.em import charges, em_move, forces
from polyslam_env.slam.points.models import pose_difference

MOBILITY = np.array([0.008, 0.005, 0.001])  # the seed's R


def test_charges__follow_eq_4() -> None:
    f = np.array([0.1, 0.5, 0.3, 0.1])
    q = charges(f, dim=3)
    assert q is not None
    gap = 0.5 - f
    np.testing.assert_allclose(q, np.exp(-3 * gap / gap.sum()), rtol=1e-15)
    assert q[1] == 1.0 and np.all((q > 0) & (q <= 1))
    assert charges(np.full(4, 0.25)) is None  # equal weights: nothing to move on


def test_forces__better_particle_attracts_worse_repels() -> None:
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    f = np.array([0.2, 0.8])
    q = charges(f)
    assert q is not None
    force = forces(x, f, q)
    assert force[0, 0] > 0  # particle 0 pulled towards the better particle 1
    assert force[1, 0] > 0  # particle 1 pushed away from the worse particle 0
    np.testing.assert_allclose(force[0], q[0] * q[1] * (x[1] - x[0]))


@pytest.mark.parametrize("seed", range(20))
def test_em_move__never_moves_a_particle_more_than_r_per_component(seed: int) -> None:
    """|Δx_d| = λ R_d |F_d| / ‖F‖ ≤ R_d since λ ≤ 1 and |F_d| ≤ ‖F‖."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 50))
    x = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-np.pi, np.pi, n)])
    f = rng.random(n)
    moved = em_move(np.random.default_rng(seed + 100), x, f, MOBILITY)
    step = np.abs(pose_difference(moved, x))
    assert np.all(step <= MOBILITY * (1 + 1e-12))
    np.testing.assert_array_equal(moved[np.argmax(f)], x[np.argmax(f)])  # the best stays
    assert np.any(step > 0)


def test_em_move__equal_weights_move_nothing() -> None:
    x = np.random.default_rng(0).normal(size=(10, 3))
    assert em_move(np.random.default_rng(1), x, np.full(10, 0.1), MOBILITY) is x

"""The seed's protocol for the aligners (seed 004, §§5–6): each aligner refined on its own
correspondences (``refinement: own``) and only RANSAC declining, by its supports
(``declines: seed``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import between
from polyslam_env.slam.alignment import ALIGNERS, AlignConfig, FeatureMap, align, rigid_fit
from polyslam_env.slam.alignment.aligners import _supports, candidate_matches

SEED = AlignConfig(refinement="own", declines="seed")
DESCRIPTOR_DIM = 8


def _local(frame: np.ndarray, points: np.ndarray) -> np.ndarray:
    return between(frame, np.column_stack([points, np.zeros(len(points))]))[:, :2]


def _decoy_scene(rng: np.random.Generator) -> tuple[FeatureMap, FeatureMap, int]:
    """40 landmarks on 20 × 12 m seen by both robots (B's positions with σ = 10 cm per
    coordinate), plus, in A's map only, a decoy 10 cm beside each of the first 20 with a
    descriptor no B landmark matches. Re-pairing by nearest neighbour takes the decoy for
    about half of those landmarks; the descriptor matches never do. Returns A, B and the
    number of real landmarks (A's decoys follow them)."""
    n = 40
    points = rng.uniform([0, 0], [20, 12], (n, 2))
    desc = rng.normal(size=(n, DESCRIPTOR_DIM))
    frame_a = np.array([1.0, -2.0, 0.3])
    frame_b = np.array([6.0, 3.0, -0.8])
    angle = rng.uniform(-np.pi, np.pi, 20)
    decoys = points[:20] + 0.1 * np.column_stack([np.cos(angle), np.sin(angle)])
    a = FeatureMap(
        _local(frame_a, np.vstack([points, decoys])),
        np.vstack([desc, 10.0 + rng.normal(size=(20, DESCRIPTOR_DIM))]),
    )
    b = FeatureMap(_local(frame_b, points) + rng.normal(0, 0.1, (n, 2)), desc)
    return a, b, n


def test_svd_refined_on_its_own_correspondences__never_pairs_a_decoy() -> None:
    """SVD's own correspondences are descriptor matches, which never include a decoy: the
    refinement over them keeps a subset and returns their least-squares fit. Re-pairing by
    nearest neighbour (``refinement: nearest``) picks up decoys: the check can fail."""
    rng = np.random.default_rng(0)
    repaired_decoys = 0
    for _ in range(5):
        a, b, n = _decoy_scene(rng)
        matches = {tuple(p) for p in candidate_matches(a, b, SEED.descriptor_threshold)}
        result = align("svd", a, b, rng, SEED)
        assert result.accepted and result.pairs is not None
        assert {tuple(p) for p in result.pairs} <= matches
        assert np.all(result.pairs[:, 0] < n)
        fit = rigid_fit(a.positions[result.pairs[:, 0]], b.positions[result.pairs[:, 1]])
        np.testing.assert_allclose(result.transform, fit, rtol=0, atol=1e-12)
        nearest = align("svd", a, b, rng, SEED.replace(refinement="nearest"))
        assert nearest.pairs is not None
        repaired_decoys += int(np.sum(nearest.pairs[:, 0] >= n))
    assert repaired_decoys > 10


@pytest.mark.parametrize("method", sorted(ALIGNERS))
def test_refinement_own__keeps_a_subset_of_the_aligners_own_correspondences(method: str) -> None:
    """RANSAC's own correspondences are the supports of its best hypothesis, ICP's (and the
    improved ICP's) the nearest neighbours at its converged transform, SVD's descriptor
    matches: the refined answer is the least-squares fit of a subset of them."""
    rng = np.random.default_rng(1)
    for _ in range(5):
        a, b, _ = _decoy_scene(rng)
        result = align(method, a, b, rng, SEED)
        assert result.accepted and result.pairs is not None and result.raw is not None
        if method == "svd":
            own = candidate_matches(a, b, SEED.descriptor_threshold)
        else:
            own = _supports(result.raw, cKDTree(a.positions), a, b, SEED)
        assert {tuple(p) for p in result.pairs} <= {tuple(p) for p in own}
        fit = rigid_fit(a.positions[result.pairs[:, 0]], b.positions[result.pairs[:, 1]])
        np.testing.assert_allclose(result.transform, fit, rtol=0, atol=1e-12)


def _sparse_maps(rng: np.random.Generator, shared: int) -> tuple[FeatureMap, FeatureMap]:
    """Maps of a 400 × 400 m field sharing ``shared`` landmarks, 30 more each of their own:
    landmarks hundreds of metres apart, so no wrong transform gathers a chance support."""
    n = shared + 60
    points = rng.uniform(0, 400, (n, 2))
    desc = rng.normal(size=(n, DESCRIPTOR_DIM))
    in_a = np.r_[np.arange(shared), shared + np.arange(30)]
    in_b = np.r_[np.arange(shared), shared + 30 + np.arange(30)]
    frame_b = np.array([30.0, -20.0, 1.1])
    a = FeatureMap(points[in_a], desc[in_a])
    b = FeatureMap(_local(frame_b, points[in_b]), desc[in_b])
    return a, b


def test_declines_seed__only_ransac_and_only_below_twenty_supports() -> None:
    """19 shared landmarks: RANSAC's best hypothesis has 19 supports and it declines, saying
    so; SVD, ICP and the improved ICP answer (the guarded rule declines them all). 20 shared
    landmarks: RANSAC answers too."""
    rng = np.random.default_rng(2)
    a, b = _sparse_maps(rng, 19)
    for method in ALIGNERS:
        guarded = align(method, a, b, np.random.default_rng(3))
        assert not guarded.accepted
        result = align(method, a, b, np.random.default_rng(3), SEED)
        if method == "ransac":
            assert not result.accepted
            assert result.reason.startswith("19 supports < 20 needed"), result.reason
        else:
            assert result.accepted, (method, result.reason)
    a, b = _sparse_maps(rng, 20)
    assert align("ransac", a, b, np.random.default_rng(3), SEED).accepted


def test_declines_seed__answers_where_only_the_chance_test_would_decline() -> None:
    """A map so dense that 20 supports are within chance (the guarded rule's chance level is
    higher): the guarded RANSAC declines, the seed's answers."""
    rng = np.random.default_rng(4)
    n = 300
    points = rng.uniform([0, 0], [12, 8], (n, 2))
    desc = rng.normal(size=(n, DESCRIPTOR_DIM))
    frame_b = np.array([2.0, 1.0, 0.4])
    keep = rng.choice(n, 25, replace=False)
    a = FeatureMap(points, desc)
    b = FeatureMap(_local(frame_b, points[keep]), desc[keep])
    guarded = align("ransac", a, b, np.random.default_rng(5))
    assert not guarded.accepted and "chance" in guarded.reason
    seed = align("ransac", a, b, np.random.default_rng(5), SEED)
    assert seed.accepted, seed.reason


def test_config__unknown_refinement_or_decline_rule__is_a_named_error() -> None:
    with pytest.raises(ConfigError, match="alignment.refinement"):
        AlignConfig(refinement="closest")
    with pytest.raises(ConfigError, match="alignment.declines"):
        AlignConfig(declines="never")

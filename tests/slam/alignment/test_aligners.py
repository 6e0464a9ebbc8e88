"""Aligners (seed 004): exact on noise-free correspondences, bounded under noise and outliers,
decline on unrelated maps; the team solver is consistent around every cycle."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import between, compose, wrap_remainder
from polyslam_env.slam.alignment import (
    ALIGNERS,
    AlignConfig,
    FeatureMap,
    PairwiseAlignment,
    align,
    rigid_fit,
    solve_team,
)

DESCRIPTOR_DIM = 8


def _world(rng: np.random.Generator, n: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks (n, 2) over a 20 × 12 m floor and their true descriptors (n, d) ~ N(0, I):
    two different landmarks' descriptors are ~4 apart, far beyond th0 = 0.7."""
    return rng.uniform([0, 0], [20, 12], size=(n, 2)), rng.normal(size=(n, DESCRIPTOR_DIM))


def _observed(
    rng: np.random.Generator,
    world: tuple[np.ndarray, np.ndarray],
    frame: np.ndarray,
    keep: np.ndarray,
    pos_sigma: float = 0.0,
    desc_sigma: float = 0.0,
) -> FeatureMap:
    """The landmarks ``keep`` as a robot whose frame is ``frame`` (in the world) maps them."""
    pos, desc = world
    local = between(frame, np.column_stack([pos[keep], np.zeros(len(keep))]))[:, :2]
    local = local + rng.normal(0.0, pos_sigma, local.shape) if pos_sigma else local
    d = desc[keep] + (rng.normal(0.0, desc_sigma, (len(keep), DESCRIPTOR_DIM)) if desc_sigma else 0)
    return FeatureMap(local, d)


def _pose_error(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    e = np.asarray(got, dtype=float) - want
    e[2] = wrap_remainder(float(e[2]))
    return e


def _random_frames(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    frame_a = np.array([rng.uniform(0, 20), rng.uniform(0, 12), rng.uniform(-np.pi, np.pi)])
    frame_b = np.array([rng.uniform(0, 20), rng.uniform(0, 12), rng.uniform(-np.pi, np.pi)])
    return frame_a, frame_b, between(frame_a, frame_b, wrap_remainder)  # B's frame in A's


@pytest.mark.parametrize("method", sorted(ALIGNERS))
def test_aligner__noise_free_correspondences__recovers_the_transform_exactly(method: str) -> None:
    """Overlapping maps (60 of 120 landmarks in common), no noise: the transform to rounding."""
    rng = np.random.default_rng(0)
    world = _world(rng)
    for _ in range(5):
        frame_a, frame_b, truth = _random_frames(rng)
        a = _observed(rng, world, frame_a, np.arange(0, 90))
        b = _observed(rng, world, frame_b, np.arange(30, 120))
        result = align(method, a, b, rng)
        assert result.accepted, result.reason
        np.testing.assert_allclose(_pose_error(result.transform, truth), 0.0, atol=1e-9)
        assert result.inliers == 60


@pytest.mark.parametrize("method", sorted(ALIGNERS))
def test_aligner__noise_and_outliers__within_its_stated_covariance(method: str) -> None:
    """Positions with σ = 5 cm, descriptors with σ = 0.1 (matches still below th0 = 0.7:
    ‖δ‖ ~ 0.1·√(2·8) = 0.4), and 20 % of B's common landmarks relabelled to a wrong A
    landmark's descriptor (outlier matches). Over 40 trials the NEES of the refined transform
    against the covariance the aligner reports averages within the 99 % band of χ²(3·40)/40,
    and every accepted error is below 5σ of that covariance — the refinement's outlier
    rejection must leave only the inliers (an outlier would add metres). RANSAC and SVD
    accept every trial; ICP, which starts from one random pair, may decline (the seed finds
    it the least reliable) but never accepts a wrong transform."""
    rng = np.random.default_rng(1)
    world = _world(rng)
    nees = []
    for _ in range(40):
        frame_a, frame_b, truth = _random_frames(rng)
        common = np.arange(30, 90)
        a = _observed(rng, world, frame_a, np.arange(0, 90), 0.05 / np.sqrt(2), 0.1 / np.sqrt(2))
        b = _observed(rng, world, frame_b, np.arange(30, 120), 0.05 / np.sqrt(2), 0.1 / np.sqrt(2))
        wrong = rng.choice(len(common), size=len(common) // 5, replace=False)
        desc = b.descriptors.copy()
        desc[wrong] = a.descriptors[rng.integers(0, 30, size=len(wrong))]  # A-only landmarks
        b = FeatureMap(b.positions, desc)
        result = align(method, a, b, rng)
        if method in ("icp", "imp_icp") and not result.accepted:
            continue
        assert result.accepted, result.reason
        e = _pose_error(result.transform, truth)
        value = float(e @ np.linalg.solve(result.covariance, e))
        assert value < 25 * 3, (method, e, np.sqrt(np.diag(result.covariance)))
        nees.append(value)
    assert len(nees) >= 20, f"{method} accepted only {len(nees)} of 40"
    lo, hi = scipy.stats.chi2.ppf([0.005, 0.995], 3 * len(nees)) / len(nees)
    assert lo <= np.mean(nees) <= hi, (method, np.mean(nees), lo, hi)


@pytest.mark.parametrize("method", sorted(ALIGNERS))
def test_aligner__unrelated_maps__declines(method: str) -> None:
    """Two maps of different places (no landmark in common, independent descriptors): no
    transform, whatever the aligner (a wrong merge is worse than none)."""
    rng = np.random.default_rng(2)
    for _ in range(10):
        a = FeatureMap(*_world(rng, 90))
        b = FeatureMap(*_world(rng, 90))
        result = align(method, a, b, rng)
        assert not result.accepted
        assert result.reason


@pytest.mark.parametrize("method", sorted(ALIGNERS))
def test_aligner__too_little_overlap__declines_rather_than_guessing(method: str) -> None:
    """Only 8 landmarks in common, fewer than min_support = 20: declined."""
    rng = np.random.default_rng(3)
    world = _world(rng)
    frame_a, frame_b, _ = _random_frames(rng)
    a = _observed(rng, world, frame_a, np.arange(0, 58))
    b = _observed(rng, world, frame_b, np.arange(50, 120))
    assert not align(method, a, b, rng).accepted


def test_rigid_fit__matches_brute_force_over_angles() -> None:
    """The closed form minimises Σ‖a − (R b + t)‖²: no angle on a fine grid does better."""
    rng = np.random.default_rng(4)
    b = rng.normal(size=(15, 2))
    a = b @ np.array([[0.6, -0.8], [0.8, 0.6]]).T + [1.0, -2.0] + rng.normal(0, 0.1, (15, 2))
    t = rigid_fit(a, b)

    def cost(theta: float) -> float:
        c, s = np.cos(theta), np.sin(theta)
        moved = b @ np.array([[c, -s], [s, c]]).T
        shift = (a - moved).mean(axis=0)
        return float(np.sum((a - moved - shift) ** 2))

    grid = np.linspace(-np.pi, np.pi, 20001)
    assert cost(float(t[2])) <= min(cost(g) for g in grid) + 1e-12


def test_align__unknown_method_and_bad_config__name_the_problem() -> None:
    rng = np.random.default_rng(5)
    m = FeatureMap(np.zeros((0, 2)), np.zeros((0, 4)))
    with pytest.raises(ConfigError, match="alignment method: unknown 'sift'"):
        align("sift", m, m, rng)
    with pytest.raises(ConfigError, match="alignment.min_support"):
        AlignConfig(min_support=2)


# -- team ------------------------------------------------------------------------------------------
def test_team__composes_consistently_around_every_cycle_and_beats_raw_pairs() -> None:
    """Four maps, all six pairs aligned with noise (σ 5 cm, 0.5°): the solved transforms compose
    to the identity around every cycle, and their error against the truth is smaller than the
    raw pairwise estimates' (averaging over redundant cycles), over 20 trials."""
    rng = np.random.default_rng(6)
    sigma = np.array([0.05, 0.05, np.radians(0.5)])
    cov = np.diag(sigma**2)
    raw_err, solved_err = [], []
    for _ in range(20):
        frames = np.column_stack(
            [rng.uniform(0, 20, 4), rng.uniform(0, 12, 4), rng.uniform(-np.pi, np.pi, 4)]
        )
        pairs = []
        for i in range(4):
            for j in range(i + 1, 4):
                truth = between(frames[i], frames[j], wrap_remainder)
                z = compose(truth, rng.normal(0.0, sigma))
                pairs.append(PairwiseAlignment(i, j, z, cov))
                raw_err.append(np.linalg.norm(_pose_error(z, truth)[:2]))
        sol = solve_team(4, pairs)
        assert sol.connected.all()
        for i in range(4):
            for j in range(4):
                for k in range(4):
                    ij_jk = compose(sol.relative(i, j), sol.relative(j, k))
                    loop = compose(ij_jk, sol.relative(k, i))
                    np.testing.assert_allclose(_pose_error(loop, np.zeros(3)), 0.0, atol=1e-9)
        for p in pairs:
            truth = between(frames[p.i], frames[p.j], wrap_remainder)
            solved_err.append(np.linalg.norm(_pose_error(sol.relative(p.i, p.j), truth)[:2]))
    assert np.mean(solved_err) < np.mean(raw_err)


def test_team__unconnected_map_gets_no_pose() -> None:
    pairs = [PairwiseAlignment(0, 1, np.array([1.0, 0.0, 0.1]), np.eye(3) * 1e-4)]
    sol = solve_team(3, pairs)
    assert sol.connected.tolist() == [True, True, False]
    np.testing.assert_allclose(sol.relative(0, 1), [1.0, 0.0, 0.1], atol=1e-12)


# -- oriented features (corners) -----------------------------------------------------------------
def _corner_world(rng: np.random.Generator, n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Corners (n, 2) over a 20 × 12 m floor with headings (n,): every one opens at 90° and is
    concave, so their descriptors tell nothing apart."""
    return rng.uniform([0, 0], [20, 12], size=(n, 2)), rng.uniform(-np.pi, np.pi, size=n)


def _corners_seen(
    world: tuple[np.ndarray, np.ndarray], frame: np.ndarray, keep: np.ndarray
) -> FeatureMap:
    pos, head = world
    local = between(frame, np.column_stack([pos[keep], head[keep]]), wrap_remainder)
    return FeatureMap(local[:, :2], np.tile([np.pi / 2, 1.0], (len(keep), 1)), local[:, 2])


def test_ransac_on_corners__one_match_is_a_hypothesis__exact_without_noise() -> None:
    """Corners carry a heading: one match fixes the transform, and RANSAC tries them all. With
    30 of 40 corners in common and no noise it returns the transform to rounding, with every
    common corner supporting it."""
    rng = np.random.default_rng(10)
    world = _corner_world(rng)
    for _ in range(5):
        frame_a, frame_b, truth = _random_frames(rng)
        a = _corners_seen(world, frame_a, np.arange(0, 35))
        b = _corners_seen(world, frame_b, np.arange(5, 40))
        result = align("ransac", a, b, rng, AlignConfig(min_support=6))
        assert result.accepted, result.reason
        np.testing.assert_allclose(_pose_error(result.transform, truth), 0.0, atol=1e-9)
        assert result.inliers == 30


def test_ransac_on_corners__a_repeating_lattice_is_ambiguous_until_evidence_decides() -> None:
    """Corners on a 1.5 m lattice (shelf ends): B sees a window well inside A, so shifting it
    by one period matches as many corners as the truth. RANSAC declines as ambiguous. A
    ``score`` that knows better (the caller's wall agreement) makes it choose the truth, and a
    ``veto`` that refuses the truth leaves only its shifted rivals: still ambiguous."""
    xs, ys = np.meshgrid(np.arange(8) * 1.5, np.arange(6) * 1.5)
    lattice = np.column_stack([xs.ravel(), ys.ravel()])
    world = (lattice, np.full(len(lattice), 0.3))
    rng = np.random.default_rng(11)
    frame_a, frame_b, truth = _random_frames(rng)
    inner = np.flatnonzero((lattice[:, 0] > 2) & (lattice[:, 0] < 9) & (lattice[:, 1] > 2))
    a = _corners_seen(world, frame_a, np.arange(len(lattice)))
    b = _corners_seen(world, frame_b, inner)
    cfg = AlignConfig(min_support=6)
    result = align("ransac", a, b, rng, cfg)
    assert not result.accepted and result.reason.startswith("ambiguous"), result.reason

    def close_to_truth(t: np.ndarray) -> float:
        return 10.0 if np.abs(_pose_error(t, truth)).max() < 1e-6 else 1.0

    chosen = align("ransac", a, b, rng, cfg, score=close_to_truth)
    assert chosen.accepted, chosen.reason
    np.testing.assert_allclose(_pose_error(chosen.transform, truth), 0.0, atol=1e-9)

    def refuse_truth(t: np.ndarray) -> str:
        return "vetoed" if np.abs(_pose_error(t, truth)).max() < 1e-6 else ""

    vetoed = align("ransac", a, b, rng, cfg, veto=refuse_truth)
    assert not vetoed.accepted and vetoed.reason.startswith("ambiguous")
    assert vetoed.transform is None
    everything = align("ransac", a, b, rng, cfg, veto=lambda t: "no radio")
    assert not everything.accepted and everything.reason == "no radio"


def test_ransac_on_corners__unrelated_buildings__decline() -> None:
    """Corners of two different random floors (nothing in common): declined every time."""
    rng = np.random.default_rng(12)
    for _ in range(10):
        frame_a, frame_b, _ = _random_frames(rng)
        a = _corners_seen(_corner_world(rng), frame_a, np.arange(40))
        b = _corners_seen(_corner_world(rng), frame_b, np.arange(40))
        assert not align("ransac", a, b, rng, AlignConfig(min_support=6)).accepted


def test_ransac_on_corners__scored_hypotheses_are_refitted_before_they_are_ranked() -> None:
    """One corner's heading is 2° off, so the hypothesis it gives misplaces corners metres
    away by tens of centimetres: a ``score`` as sharp as wall agreement (B's corners laid
    within 3 cm of where they belong) gives every single-corner hypothesis at most a few of the
    30 common corners, so none stands out (and a wrong transform laying some wall on wall, in
    a building that repeats, beat the truth). Each hypothesis is refitted on its supports
    before it is scored, so the truth wins, to the corners' position noise (headings do not
    enter the refit)."""
    rng = np.random.default_rng(13)
    world = _corner_world(rng)
    frame_a, frame_b, truth = _random_frames(rng)
    a = _corners_seen(world, frame_a, np.arange(0, 35))
    clean = _corners_seen(world, frame_b, np.arange(5, 40))
    assert a.headings is not None and clean.headings is not None
    b = FeatureMap(
        clean.positions + rng.normal(0.0, 0.005, clean.positions.shape),
        clean.descriptors,
        clean.headings + np.radians(2.0) * rng.choice([-1.0, 1.0], len(clean.positions)),
    )
    assert b.headings is not None
    want = clean.positions @ _rot(truth[2]).T + truth[:2]  # B's corners where they belong

    def sharp(t: np.ndarray) -> float:
        moved = b.positions @ _rot(t[2]).T + t[:2]
        return float((np.hypot(*(moved - want).T) < 0.03).sum())

    single = [  # the true matches: A's corner k + 5 is B's corner k
        sharp(np.array([*(a.positions[k + 5] - _rot(a.headings[k + 5] - b.headings[k])
                          @ b.positions[k]), a.headings[k + 5] - b.headings[k]]))
        for k in range(30)
    ]  # fmt: skip
    assert max(single) <= 10.0, "a single corner's hypothesis lays a third of them at most"
    result = align("ransac", a, b, rng, AlignConfig(min_support=6), score=sharp)
    assert result.accepted, result.reason
    error = _pose_error(result.transform, truth)
    # 5 mm position noise over 30 corners spread over metres: the fit's standard error is
    # about 1 mm and 0.01°; ten times that bounds it
    assert np.hypot(*error[:2]) < 0.01 and abs(error[2]) < np.radians(0.1)


def _rot(theta: float) -> np.ndarray:
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])

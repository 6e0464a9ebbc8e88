"""The map itself (issue 14): one wall one landmark, evidence-bounded extents, splits at
gaps and corners, faces kept apart — on a synthetic scan generator and seeded episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.landmarks import EXTENT_MARGIN
from polyslam_env.slam.merging import JOIN_GAP
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam

BEAMS_DEG = (90.0, 45.0, 0.0, -45.0, -90.0)
MAX_RANGE = 2.0
RANGE_SIGMA = 0.02


def cast(pose: np.ndarray, walls: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Brute-force ranges (B,) from ``pose`` (3,) to segments ``walls`` (W, 2, 2); inf if none
    within MAX_RANGE (the oracle the SLAM's own ray casting is not)."""
    out = np.full(len(angles), np.inf)
    p = pose[:2]
    for b, phi in enumerate(pose[2] + angles):
        u = np.array([math.cos(phi), math.sin(phi)])
        for a, c in walls:
            e = c - a
            den = u[0] * (-e[1]) - u[1] * (-e[0])
            if abs(den) < 1e-12:
                continue
            d = a - p
            t = (d[0] * (-e[1]) - d[1] * (-e[0])) / den
            s = (u[0] * d[1] - u[1] * d[0]) / den
            if 0 < t <= MAX_RANGE and 0 <= s <= 1:
                out[b] = min(out[b], t)
    return out


def drive(
    walls: np.ndarray, moves: list[tuple[float, float]], seed: int
) -> tuple[PolySlam, list[np.ndarray], np.ndarray]:
    """Run a PolySlam along unicycle ``moves`` (v·T, Δθ) from the origin among ``walls``.

    Odometry and ranges get the SLAM config's noise (seeded); the robot's frame is the world
    frame. Returns the SLAM, the true hit points of each step and the true poses (K+1, 3).
    """
    rng = np.random.default_rng(seed)
    cfg = SlamConfig()
    angles = np.radians(BEAMS_DEG)
    slam = PolySlam(cfg, angles, MAX_RANGE)
    pose = np.zeros(3)
    poses, hits = [pose.copy()], []
    odo_sigma = np.array([cfg.odom_sigma_xy, cfg.odom_sigma_xy, math.radians(0.01)])
    for dist, turn in moves:
        pose = pose + np.array([dist * math.cos(pose[2]), dist * math.sin(pose[2]), turn])
        poses.append(pose.copy())
        ranges = cast(pose, walls, angles)
        ok = np.isfinite(ranges)
        phi = pose[2] + angles[ok]
        hits.append(pose[:2] + ranges[ok, None] * np.stack([np.cos(phi), np.sin(phi)], axis=1))
        noisy = ranges + rng.normal(0.0, RANGE_SIGMA, len(ranges))
        odometry = np.array([dist, 0.0, turn]) + rng.normal(0.0, odo_sigma)
        slam.step(odometry, noisy)
    return slam, hits, np.array(poses)


def straight(length: float, step: float = 0.08) -> list[tuple[float, float]]:
    return [(step, 0.0)] * round(length / step)


def turn_around(steps: int = 12) -> list[tuple[float, float]]:
    return [(0.0, math.pi / steps)] * steps


@pytest.mark.xfail(
    strict=True,
    reason="known limitation (issue 14, open): over repeated passes the pose estimate drifts by"
    " several cm (shape slopes fitted on 0.35 m clusters bias the heading), a re-observed"
    " stretch lands > THIN_WALL off the old piece or > JOIN_GAP past its end and becomes a"
    " second landmark; 1 landmark in 4 of 6 seeds after two passes, 3 of 6 after three",
)
def test_reobserved_wall__creates_no_second_landmark() -> None:
    """Drive past a 6 m wall (y = 0.8), turn, drive back past it, turn, pass it again: the
    world has one wall, so the map must hold exactly one landmark after every pass."""
    walls = np.array([[[-1.0, 0.8], [6.0, 0.8]]])
    one = straight(4.0)
    two = one + turn_around() + straight(4.0)
    three = two + turn_around() + straight(4.0)
    for seed in range(6):
        counts = [drive(walls, moves, seed)[0].n_landmarks for moves in (one, two, three)]
        assert counts == [1, 1, 1], (seed, counts)


def test_doorway__wall_with_a_gap_is_two_landmarks_not_bridged() -> None:
    """A wall with a 0.6 m doorway (x ∈ [2, 2.6]): no polynomial spans the doorway."""
    walls = np.array([[[-1.0, 0.8], [2.0, 0.8]], [[2.6, 0.8], [6.0, 0.8]]])
    for seed in range(3):
        slam, _, _ = drive(walls, straight(4.5), seed)
        for p in slam.polynomials():
            xy = p.equally_spaced(50)
            inside = (xy[:, 0] > 2.0 + EXTENT_MARGIN) & (xy[:, 0] < 2.6 - EXTENT_MARGIN)
            assert not np.any(inside & (np.abs(xy[:, 1] - 0.8) < 0.1)), (seed, p.lo, p.hi)


def test_corner__is_not_one_polynomial_bending_around_it() -> None:
    """Along a wall that turns by 90° (a room's corner): every landmark stays on one wall
    (within 3σ of the range noise plus the odometry drift of the short run, < 1 cm)."""
    walls = np.array([[[-1.0, 0.8], [3.0, 0.8]], [[3.0, 0.8], [3.0, -2.0]]])
    for seed in range(3):
        slam, _, _ = drive(walls, straight(2.6), seed)
        for p in slam.polynomials():
            xy = p.equally_spaced(50)
            d_a = np.abs(xy[:, 1] - 0.8)
            d_b = np.abs(xy[:, 0] - 3.0)
            assert min(d_a.max(), d_b.max()) <= 3 * RANGE_SIGMA + 0.01, (seed, p.lo, p.hi)


def test_extents__reach_no_further_than_the_supporting_hits_plus_margin() -> None:
    """Every map point lies within EXTENT_MARGIN (+ the run's largest true position error,
    by which the whole map can be displaced, + 3σ range noise across the wall) of a true hit;
    a join bridges at most JOIN_GAP = 2 × EXTENT_MARGIN, its middle within the margin."""
    walls = np.array(
        [
            [[-1.0, 0.8], [2.0, 0.8]],
            [[2.6, 0.8], [6.0, 0.8]],
            [[-1.0, -0.9], [6.0, -0.9]],
            [[6.0, 0.8], [6.0, -0.9]],
        ]
    )
    assert JOIN_GAP <= 2 * EXTENT_MARGIN
    for seed in range(3):
        moves = straight(4.5) + turn_around() + straight(4.0)
        slam, hits, poses = drive(walls, moves, seed)
        all_hits = np.vstack(hits)
        pose_err = float(np.max(np.linalg.norm(slam.pose[:2] - poses[-1, :2])))
        tol = EXTENT_MARGIN + pose_err + 3 * RANGE_SIGMA
        for p in slam.polynomials():
            xy = p.equally_spaced(100)
            nearest = np.min(np.linalg.norm(xy[:, None, :] - all_hits[None], axis=2), axis=1)
            assert nearest.max() <= tol, (seed, p.lo, p.hi, nearest.max(), tol)


def test_evidence__extents_stay_within_the_evidence_of_their_hits_at_every_step() -> None:
    """The table's own invariant on a seeded run (walls, a doorway, a corner, back and forth):
    after every step each landmark's extent lies within its evidence interval ± EXTENT_MARGIN
    (that the evidence is where true hits are is the test above)."""
    walls = np.array(
        [[[-1.0, 0.8], [2.0, 0.8]], [[2.6, 0.8], [5.0, 0.8]], [[5.0, 0.8], [5.0, -0.9]]]
    )
    cfg = SlamConfig()
    rng = np.random.default_rng(11)
    angles = np.radians(BEAMS_DEG)
    slam = PolySlam(cfg, angles, MAX_RANGE)
    pose = np.zeros(3)
    for dist, turn in straight(4.0) + turn_around() + straight(3.0):
        pose = pose + np.array([dist * math.cos(pose[2]), dist * math.sin(pose[2]), turn])
        ranges = cast(pose, walls, angles) + rng.normal(0.0, RANGE_SIGMA, len(angles))
        slam.step(np.array([dist, 0.0, turn]), ranges)
        table = slam.table
        for i, poly in enumerate(table.polys):
            ev_lo, ev_hi = table.evidence[i]
            assert ev_lo - EXTENT_MARGIN - 1e-12 <= poly.lo <= poly.hi
            assert poly.hi <= ev_hi + EXTENT_MARGIN + 1e-12
    assert slam.n_landmarks >= 3


def test_insert_landmark__keeps_the_senders_extent_as_its_evidence() -> None:
    slam = PolySlam(SlamConfig(), np.radians(BEAMS_DEG), MAX_RANGE)
    poly = Polynomial(1, np.array([0.8, 0.0, 0.0, 0.0]), 1.0, 2.5)
    fit = Fit(poly, 0.8, np.zeros((1, 3)), np.ones((1, 1)) * 1.0, np.eye(1) * 1e-4, 0.01, 1)
    lid = slam.insert_landmark(fit)
    i = slam.table.index_of(lid)
    assert tuple(slam.table.evidence[i]) == (1.0, 2.5)
    assert (slam.table.polys[i].lo, slam.table.polys[i].hi) == (1.0, 2.5)

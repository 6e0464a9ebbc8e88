"""The map itself (issue 14): one wall one landmark, evidence-bounded extents, splits at
gaps and corners, faces kept apart — on a synthetic scan generator and seeded episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.landmarks import EXTENT_MARGIN
from polyslam_env.slam.merging import JOIN_GAP
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam, update_beam_mask

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
    walls: np.ndarray,
    moves: list[tuple[float, float]],
    seed: int,
    cfg: SlamConfig | None = None,
) -> tuple[PolySlam, list[np.ndarray], np.ndarray, np.ndarray]:
    """Run a PolySlam along unicycle ``moves`` (v·T, Δθ) from the origin among ``walls``.

    Odometry and ranges get the SLAM config's noise (seeded); the robot's frame is the world
    frame. Returns the SLAM, the true hit points of each step, the true poses (K+1, 3) and
    the estimated ones (K+1, 3).
    """
    cfg = SlamConfig() if cfg is None else cfg
    rng = np.random.default_rng(seed)
    angles = np.radians(BEAMS_DEG)
    slam = PolySlam(cfg, angles, MAX_RANGE)
    pose = np.zeros(3)
    poses, hits, estimates = [pose.copy()], [], [slam.pose]
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
        estimates.append(slam.pose)
    return slam, hits, np.array(poses), np.array(estimates)


def straight(length: float, step: float = 0.08) -> list[tuple[float, float]]:
    return [(step, 0.0)] * round(length / step)


def turn_around(steps: int = 12) -> list[tuple[float, float]]:
    return [(0.0, math.pi / steps)] * steps


ONE_WALL = np.array([[[-1.0, 0.8], [6.0, 0.8]]])  # the only wall: y = 0.8, x ∈ [−1, 6]
JOINING = SlamConfig(join_pieces=True)  # the default
PAPER_MERGING = SlamConfig(join_pieces=False)
CONFIGS, CONFIG_IDS = [PAPER_MERGING, JOINING], ["paper-merging", "join-pieces"]


def test_reobserved_wall__creates_no_second_landmark() -> None:
    """Drive 4 m past a 6 m wall, turn around, drive back past it (10 seeds): the world has
    one wall, so the map holds exactly one landmark after each pass, with ``join_pieces``.
    Without it (the paper's merging) every one of these runs holds 4 landmarks
    after the first pass and 4–6 after the second: pieces of ~1 m, each a cluster's fit.
    """
    one = straight(4.0)
    two = one + turn_around() + straight(4.0)
    for seed in range(10):
        counts = [drive(ONE_WALL, moves, seed, JOINING)[0].n_landmarks for moves in (one, two)]
        assert counts == [1, 1], (seed, counts)
    # the pieces the joins remove
    assert drive(ONE_WALL, one, 0, PAPER_MERGING)[0].n_landmarks > 1


def test_reobserved_wall__third_pass_creates_no_second_landmark() -> None:
    three = straight(4.0) + turn_around() + straight(4.0) + turn_around() + straight(4.0)
    counts = [drive(ONE_WALL, three, seed, JOINING)[0].n_landmarks for seed in range(10)]
    assert counts == [1] * 10, counts


@pytest.mark.parametrize("cfg", CONFIGS, ids=CONFIG_IDS)
def test_doorway__wall_with_a_gap_is_two_landmarks_not_bridged(cfg: SlamConfig) -> None:
    """A wall with a 0.6 m doorway (x ∈ [2, 2.6]): no polynomial spans the doorway."""
    walls = np.array([[[-1.0, 0.8], [2.0, 0.8]], [[2.6, 0.8], [6.0, 0.8]]])
    for seed in range(3):
        slam, *_ = drive(walls, straight(4.5), seed, cfg)
        for p in slam.polynomials():
            xy = p.equally_spaced(50)
            inside = (xy[:, 0] > 2.0 + EXTENT_MARGIN) & (xy[:, 0] < 2.6 - EXTENT_MARGIN)
            assert not np.any(inside & (np.abs(xy[:, 1] - 0.8) < 0.1)), (seed, p.lo, p.hi)


@pytest.mark.parametrize("cfg", CONFIGS, ids=CONFIG_IDS)
def test_corner__is_not_one_polynomial_bending_around_it(cfg: SlamConfig) -> None:
    """Along a wall that turns by 90° (a room's corner): every landmark stays on one wall
    (within 3σ of the range noise plus the odometry drift of the short run, < 1 cm)."""
    walls = np.array([[[-1.0, 0.8], [3.0, 0.8]], [[3.0, 0.8], [3.0, -2.0]]])
    for seed in range(3):
        slam, *_ = drive(walls, straight(2.6), seed, cfg)
        for p in slam.polynomials():
            xy = p.equally_spaced(50)
            d_a = np.abs(xy[:, 1] - 0.8)
            d_b = np.abs(xy[:, 0] - 3.0)
            assert min(d_a.max(), d_b.max()) <= 3 * RANGE_SIGMA + 0.01, (seed, p.lo, p.hi)


@pytest.mark.parametrize("cfg", CONFIGS, ids=CONFIG_IDS)
def test_extents__reach_no_further_than_the_supporting_hits_plus_margin(cfg: SlamConfig) -> None:
    """Each polynomial's end points lie within EXTENT_MARGIN of a true hit, and its inside
    within JOIN_GAP / 2 (a join bridges at most JOIN_GAP), plus what the estimate adds: the
    map is placed with the estimated pose, off by at most max|Δp| + MAX_RANGE · max|Δθ| over
    the run, and 3σ of range noise across the wall."""
    walls = np.array(
        [
            [[-1.0, 0.8], [2.0, 0.8]],
            [[2.6, 0.8], [6.0, 0.8]],
            [[-1.0, -0.9], [6.0, -0.9]],
            [[6.0, 0.8], [6.0, -0.9]],
        ]
    )
    for seed in range(3):
        moves = straight(4.5) + turn_around() + straight(4.0)
        slam, hits, poses, estimates = drive(walls, moves, seed, cfg)
        all_hits = np.vstack(hits)
        d_theta = np.abs(np.angle(np.exp(1j * (estimates[:, 2] - poses[:, 2]))))
        displaced = np.linalg.norm(estimates[:, :2] - poses[:, :2], axis=1).max()
        slack = displaced + MAX_RANGE * d_theta.max() + 3 * RANGE_SIGMA
        for p in slam.polynomials():
            xy = p.equally_spaced(100)
            nearest = np.min(np.linalg.norm(xy[:, None, :] - all_hits[None], axis=2), axis=1)
            assert max(nearest[0], nearest[-1]) <= EXTENT_MARGIN + slack, (seed, p.lo, p.hi)
            assert nearest.max() <= JOIN_GAP / 2 + slack, (seed, p.lo, p.hi)


@pytest.mark.parametrize("cfg", CONFIGS, ids=CONFIG_IDS)
def test_evidence__extents_stay_within_their_hits_evidence_at_every_step(cfg: SlamConfig) -> None:
    """The table's own invariant on a seeded run (walls, a doorway, a corner, back and forth):
    after every step each landmark's extent lies within its evidence interval ± EXTENT_MARGIN
    (that the evidence is where true hits are is the test above)."""
    walls = np.array(
        [[[-1.0, 0.8], [2.0, 0.8]], [[2.6, 0.8], [5.0, 0.8]], [[5.0, 0.8], [5.0, -0.9]]]
    )
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


def test_merge__a_join_that_fails_does_not_hide_an_overlap_with_the_same_wall() -> None:
    """Landmarks A: y = 0.80 on x ∈ [0, 3], and B: starting at (3.15, 0.84) level with it,
    then bending away (y = 0.84 + 0.4 (x − 3.15)²). A new piece N: y = 0.83 on [0.1, 2.95]
    overlaps A (γ 3 cm) and meets B end to end (offset 1 cm, the smaller γ), but no one
    polynomial follows N and B's bend, so that join is refused; N must then merge with A,
    its own stretch of wall. Trying only the best partner left N beside A (found on a
    warehouse: a received wall 2.4 cm beside the robot's own over 6 m, 8 % duplicates)."""
    slam = PolySlam(SlamConfig(), np.radians([90.0]), MAX_RANGE)

    def fit_of(coeffs: list[float], lo: float, hi: float) -> Fit:
        poly = Polynomial(1, np.array(coeffs), lo, hi)
        gx = np.zeros((1, slam.mean.size))
        return Fit(poly, coeffs[0], gx, np.ones((1, 1)), np.eye(1) * 1e-4, 0.01, 1)

    a = slam.insert_landmark(fit_of([0.80, 0.0, 0.0, 0.0], 0.0, 3.0), merge=False)
    curv = 0.4
    bend = [0.84 + curv * 3.15**2, -2.0 * curv * 3.15, curv, 0.0]
    b = slam.insert_landmark(fit_of(bend, 3.15, 5.0), merge=False)
    merged_id = slam.insert_landmark(fit_of([0.83, 0.0, 0.0, 0.0], 0.1, 2.95))
    assert slam.landmark_ids == [b, merged_id] and a != merged_id  # N and A are one now
    merged = slam.table.polys[slam.table.index_of(merged_id)]
    assert (merged.lo, merged.hi) == pytest.approx((0.0, 3.0), abs=0.05)


@pytest.mark.parametrize(
    ("wall", "hit", "stretched"),
    [
        ((0.2, 0.6), (0.8, 0.8), True),  # 0.2 m past the end, on the line: the same wall
        ((0.2, 0.6), (0.86, 0.86), False),  # 6 cm (3σ of the range noise) off the line
        ((0.2, 0.4), (0.8, 0.8), False),  # 0.4 m past the end: wider than GAP_SPLIT, a door
    ],
)
def test_hit_past_an_end__on_the_continued_wall_stretches_it_with_stretch_ends_only(
    wall: tuple[float, float], hit: tuple[float, float], stretched: bool
) -> None:
    """A landmark y = 0.8 on ``wall`` (ξ-interval) and one beam hit at ``hit``, beyond ρ_k and
    σ_k of its end (0.08 and 0.1 m at zero uncertainty): the paper files it in a cluster; with
    ``stretch_ends`` a hit within GAP_SPLIT past the end and within 2σ of the continued curve
    (whose turn is known to within the range noise there: lever 0.4 m × σ_α 0.041 rad = 1.6 cm
    for a 0.4 m shape fitted on ε_Z + 1 points) stretches the extent and its evidence to the
    hit, anything else is filed as in the paper. Either way no beam updates c0 (the hit is
    past the extent it had)."""
    assert math.hypot(hit[0] - wall[1], hit[1] - 0.8) > SlamConfig().sigma_min
    angles = np.radians([45.0])
    ranges = np.array([math.hypot(*hit)])  # the 45° beam from the origin ends at the hit
    for cfg, join in ((SlamConfig(), True), (SlamConfig(stretch_ends=False), False)):
        slam = PolySlam(cfg, angles, MAX_RANGE)
        poly = Polynomial(1, np.array([0.8, 0.0, 0.0, 0.0]), *wall)
        fit = Fit(poly, 0.8, np.zeros((1, 3)), np.ones((1, 1)), np.eye(1) * 1e-4, 0.01, 1)
        slam.insert_landmark(fit)
        info = slam.step(np.zeros(3), ranges)
        expect = stretched and join
        assert slam.table.polys[0].hi == (hit[0] if expect else wall[1]), (cfg.stretch_ends, hit)
        assert slam.table.evidence[0][1] == (hit[0] if expect else wall[1])
        assert info.beams_used == 0
        assert len(slam.points.clusters()) == int(not expect)


def test_hit_past_an_end__off_the_curve_does_not_update_through_the_extent() -> None:
    """A landmark y = 0.8, x ∈ [0.2, 0.6]; the robot at (1, 0.2) with a few cm of pose
    uncertainty looks at (0.58, 0.8), on the extent, and its beam stops at (0.62, 0.743), 6 cm
    from the end point (good: ε ≤ ρ_k) but 5.7 cm off the line and past the extent, as on a
    shelf's side face near the corner of the face the landmark is. The ray crosses the line
    inside the extent, so the paper's filter updates with a 7 cm innovation the gate lets
    through and moves the pose by several cm; with ``stretch_ends`` the beam is not used."""
    moved = {}
    for stretch in (True, False):
        # the beam's hit is 2 cm from the end: end_sigma would leave it out as well
        slam = _looking_at_a_wall_end(0.58, stretch_ends=stretch, end_sigma=0.0)
        before = slam.pose
        direction = np.array([0.58 - 1.0, 0.8 - 0.2]) / math.hypot(0.42, 0.6)
        hit = before[:2] + (0.62 - 1.0) / direction[0] * direction
        assert abs(hit[1] - 0.8) > 2 * RANGE_SIGMA and math.hypot(*(hit - [0.6, 0.8])) < 0.08
        info = slam.step(np.zeros(3), np.array([math.hypot(*(hit - before[:2]))]))
        moved[stretch] = (info.beams_used, float(np.linalg.norm(slam.pose[:2] - before[:2])))
    assert moved[True] == (0, 0.0)
    assert moved[False][0] == 1 and moved[False][1] > 0.02  # the paper's filter is pulled


def test_beam_whose_hit_may_pass_the_end__is_left_out_with_end_sigma() -> None:
    """A landmark y = 0.8, x ∈ [0.2, 0.6]; the robot at (1, 0.2) with several cm of pose
    uncertainty. A beam aimed 2 cm inside the end, at (0.58, 0.8), may just as well pass the
    end (σ of its hit along the wall is several cm): with ``end_sigma`` = 2 it is not used,
    with 0 (the paper) it is. A beam aimed at the middle, (0.4, 0.8), is used by both. The
    readings are the true ranges to the wall, so nothing else tells the two apart."""
    used = {}
    for end_sigma in (2.0, 0.0):
        for target in (0.58, 0.4):
            slam = _looking_at_a_wall_end(target, end_sigma=end_sigma)
            sd_along = math.sqrt(slam.pose_cov_relative[0, 0])
            assert 0.02 < 2.0 * sd_along  # the pose's own share of σ_ξ already puts 2 cm in doubt
            info = slam.step(np.zeros(3), np.array([math.hypot(target - 1.0, 0.6)]))
            used[end_sigma, target] = info.beams_used
    assert used == {(2.0, 0.58): 0, (2.0, 0.4): 1, (0.0, 0.58): 1, (0.0, 0.4): 1}


def test_beam_cast_onto_another_landmark_than_its_own__is_left_out() -> None:
    """A received wall y = 0.45 known to 10 cm (its c0), whose extent runs 24 cm past the
    corner it makes with the wall x = x_c (a received wall's end is only as good as the frame
    transform), and a beam from the origin, 15° left of straight up, that truly hits the
    second wall 0.24 m beyond the first wall's line. Its point belongs to the second wall (the
    association's), but at the mean the beam is cast onto the first wall's overhang, 24 cm
    short: within the χ² gate (2.3σ), cast from the first wall's sigma points at ±2σ still
    onto it, and far enough from its end for ``end_sigma``. The update would move that wall
    by ~20 cm off the line it is on; the beam is left out and the wall stays. With the first
    wall ending at the corner the same beam is cast onto the second wall and used."""
    angle = math.radians(105.0)
    t_hit = 0.45 / math.sin(angle) + 0.24  # the range to the second wall
    x_c = t_hit * math.cos(angle)
    results = {}
    for end in (x_c + 0.24, x_c - EXTENT_MARGIN - 0.01):
        slam = PolySlam(SlamConfig(), np.array([angle]), MAX_RANGE)
        for poly, var in (
            (Polynomial(1, np.array([0.45, 0.0, 0.0, 0.0]), -3.0, end), 0.1**2),
            (Polynomial(2, np.array([x_c, 0.0, 0.0, 0.0]), 0.45, 3.0), 1e-4),
        ):
            gx = np.zeros((1, slam.mean.size))
            slam.insert_landmark(
                Fit(poly, poly.c0, gx, np.ones((1, 1)), np.eye(1) * var, 0.01, 1), merge=False
            )
        first = slam.c0s[0]
        info = slam.step(np.zeros(3), np.array([t_hit]))
        results[end > x_c] = (info.beams_used, float(slam.c0s[0] - first))
    assert results[True] == (0, 0.0)
    assert results[False] == (1, 0.0)  # cast onto the second wall: the first has no row


def test_short_landmark__does_not_update_with_min_update_extent() -> None:
    """The landmark y = 0.8, x ∈ [0.2, 0.6] is 0.4 m long; a beam on its middle updates the
    pose by default and with ``min_update_extent`` 0.3 m, and not with 0.5 m (its extent is
    shorter); a negative floor is a one-line error naming the field."""
    used = {}
    for floor in (0.0, 0.3, 0.5):
        slam = _looking_at_a_wall_end(0.4, min_update_extent=floor)
        before = slam.pose
        info = slam.step(np.zeros(3), np.array([math.hypot(0.4 - 1.0, 0.6)]))
        used[floor] = info.beams_used
        if not info.beams_used:
            assert np.array_equal(slam.pose, before)
    assert used == {0.0: 1, 0.3: 1, 0.5: 0}
    with pytest.raises(ConfigError, match="slam.min_update_extent"):
        SlamConfig(min_update_extent=-0.1)


def _looking_at_a_wall_end(target: float, **config: object) -> PolySlam:
    """A PolySlam (one beam, straight ahead; odometry noise 3 cm and 0.3° per step) with one
    landmark y = 0.8, x ∈ [0.2, 0.6], driven without returns to (1, 0.2) and turned to look at
    (``target``, 0.8): its pose is exact there, and uncertain by several centimetres."""
    cfg = SlamConfig(odom_sigma_xy=0.03, odom_sigma_theta_deg=0.3, **config)  # type: ignore[arg-type]
    slam = PolySlam(cfg, np.array([0.0]), MAX_RANGE)
    poly = Polynomial(1, np.array([0.8, 0.0, 0.0, 0.0]), 0.2, 0.6)
    slam.insert_landmark(
        Fit(poly, 0.8, np.zeros((1, 3)), np.ones((1, 1)), np.eye(1) * 1e-4, 0.01, 1)
    )
    none = np.array([np.inf])
    slam.step(np.array([0.0, 0.0, math.atan2(0.2, 1.0)]), none)
    slam.step(np.array([math.hypot(1.0, 0.2), 0.0, 0.0]), none)  # now at (1, 0.2)
    heading = math.atan2(0.8 - 0.2, target - 1.0)
    slam.step(np.array([0.0, 0.0, heading - slam.pose[2]]), none)
    assert np.allclose(slam.pose, [1.0, 0.2, heading])
    return slam


def test_update_beam_mask__keeps_beams_at_least_the_spacing_apart() -> None:
    deg = np.radians
    seventeen = deg([90.0 - 11.25 * i for i in range(17)])
    assert update_beam_mask(seventeen, 22.5).tolist() == [i % 2 == 0 for i in range(17)]
    assert update_beam_mask(seventeen, 0.0).all()
    assert update_beam_mask(deg(BEAMS_DEG), 22.5).all()  # the paper's five are 45° apart
    assert update_beam_mask(deg(BEAMS_DEG), 90.0).tolist() == [True, False, True, False, True]
    shuffled = deg([0.0, 90.0, -45.0, 45.0, -90.0, 22.5])  # in order of angle, not of index
    assert update_beam_mask(shuffled, 45.0).tolist() == [True, True, True, True, True, False]
    assert update_beam_mask(deg([10.0]), 360.0).tolist() == [True]


def test_update_spacing__beams_between_map_the_wall_but_do_not_update() -> None:
    """Three beams 11.25° apart along a wall on the left: with ``update_spacing_deg`` 22.5 the
    middle one never enters the update (the update kernel is never handed it), with 0 it
    does; its hits still build the map either way: the wall's landmark is born at the same
    step, and earlier than with the two outer beams alone."""
    chosen: list[set[int]] = []

    def run(beams: tuple[float, ...], spacing: float) -> tuple[int, set[int]]:
        chosen.clear()
        cfg = SlamConfig(update_spacing_deg=spacing)
        rng = np.random.default_rng(3)
        angles = np.radians(beams)
        slam = PolySlam(cfg, angles, MAX_RANGE)
        pose, born = np.zeros(3), -1
        for k, (dist, turn) in enumerate(straight(3.0)):
            pose = pose + np.array([dist * math.cos(pose[2]), dist * math.sin(pose[2]), turn])
            ranges = cast(pose, ONE_WALL, angles) + rng.normal(0.0, RANGE_SIGMA, len(angles))
            slam.step(np.array([dist, 0.0, turn]), ranges)
            chosen.append(set(slam.last_update_beams.tolist()))
            if born < 0 and slam.n_landmarks:
                born = k
        return born, set().union(*chosen)

    born_spaced, used_spaced = run((90.0, 78.75, 67.5), 22.5)
    born_all, used_all = run((90.0, 78.75, 67.5), 0.0)
    born_outer, _ = run((90.0, 67.5), 0.0)
    assert used_spaced == {0, 2} and used_all == {0, 1, 2}
    assert 0 <= born_spaced == born_all < born_outer

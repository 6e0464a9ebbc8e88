"""Refining the rendezvous transform on shared walls: Jacobian, recovery, refusal."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from polyslam_env.comms import alignment
from polyslam_env.comms.alignment import CHI2_3DOF_99, WallArrays, align_transform, frame_points
from polyslam_env.comms.kernels import match_walls, near_chains, unit_tangents
from polyslam_env.core.geometry import inverse, rotation, transform_points
from polyslam_env.slam.polynomial import Polynomial

# Walls in the receiver's frame: a corner and a curved wall, so that all of T is observable.
WALLS = [
    Polynomial(1, [1.0, 0.0, 0.0, 0.0], -1.0, 2.0),  # y = 1
    Polynomial(2, [2.0, 0.0, 0.0, 0.0], -1.0, 1.0),  # x = 2
    Polynomial(1, [-1.0, 0.1, 0.2, 0.0], -1.0, 1.5),  # y = −1 + 0.1x + 0.2x²
]
T_TRUE = np.array([0.3, -0.2, 0.4])  # sender's frame in the receiver's
COV_T = np.diag([0.03**2, 0.03**2, 0.025**2])  # camera: ~3 cm, ~1.4°


def _chains(walls: list[Polynomial]) -> list[np.ndarray]:
    """The walls as the sender holds them: points every ~5 cm in the sender's frame."""
    return [transform_points(w.sample_arclength(0.05), inverse(T_TRUE)) for w in walls]


def test_frame_points__jacobian_matches_finite_differences() -> None:
    q = np.random.default_rng(0).normal(size=(7, 2))
    _, jac = frame_points(q, T_TRUE)
    eps = 1e-6
    for col in range(3):
        e = np.zeros(3)
        e[col] = eps
        num = (frame_points(q, T_TRUE + e)[0] - frame_points(q, T_TRUE - e)[0]) / (2 * eps)
        np.testing.assert_allclose(num, jac[:, :, col], atol=1e-8)  # central FD error ~eps²


def test_align_transform__recovers_the_transform_from_noise_free_walls() -> None:
    # camera error of about 1σ on each component; Mahalanobis 2.1 < χ²₃ 99 %
    t0 = T_TRUE + np.array([0.03, -0.02, 0.02])
    # a pair's σ of 0.1 mm makes the prior's pull ~ (σ/σ_T)² ≈ 1e-5 of the 3 cm offset
    t = align_transform(t0, COV_T, _chains(WALLS), WALLS, sigma=1e-4)
    np.testing.assert_allclose(t, T_TRUE, atol=1e-5)


def test_align_transform__with_realistic_weight_moves_towards_the_truth() -> None:
    t0 = T_TRUE + np.array([0.03, -0.02, 0.02])
    t = align_transform(t0, COV_T, _chains(WALLS), WALLS, sigma=0.02)
    # MAP of a linear-Gaussian problem shrinks the error, never grows it (in Σ_T's metric)
    info = np.linalg.inv(COV_T)
    before, after = t0 - T_TRUE, t - T_TRUE
    assert after @ info @ after < before @ info @ before


def test_align_transform__refuses_a_correction_the_camera_makes_unlikely(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # 2.5σ on every component: Mahalanobis 18.75 > χ²₃ 99 % = 11.34; the walls still pair
    offset = 2.5 * np.sqrt(np.diag(COV_T)) * np.array([1.0, -1.0, 1.0])
    assert offset @ np.linalg.inv(COV_T) @ offset > CHI2_3DOF_99
    t0 = T_TRUE + offset
    t = align_transform(t0, COV_T, _chains(WALLS), WALLS, sigma=1e-4)
    np.testing.assert_array_equal(t, t0)
    monkeypatch.setattr(alignment, "CHI2_3DOF_99", np.inf)  # without the test: it converges
    t = align_transform(t0, COV_T, _chains(WALLS), WALLS, sigma=1e-4)
    np.testing.assert_allclose(t, T_TRUE, atol=1e-5)


def test_refine_transform__a_second_basin_in_repeating_walls_keeps_the_camera_transform() -> None:
    """``restarts``: shelf faces every 1 m (y = 0, 1, 2, 3 on x ∈ [0, 6]) and a camera 0.45 m
    off along them with σ 0.4 m: a shift by one period is 2.5σ, well inside the camera's
    region, so the walls pair with either copy. One Gauss–Newton run lands in a basin with a
    posterior σ of millimetres; started again 2σ away along the prior's axes it lands in the
    other one, so the refinement is refused and the camera transform kept. With a unique
    basin the restarts agree (below)."""
    faces = [Polynomial(1, [float(y), 0.0, 0.0, 0.0], 0.0, 6.0) for y in range(4)]
    chains = [w.sample_arclength(0.05) for w in faces]  # true transform: identity
    cov_t = np.diag([0.05**2, 0.4**2, 0.01**2])
    t0 = np.array([0.0, 0.45, 0.0])
    t, cov = alignment.refine_transform(t0, cov_t, chains, faces, sigma=0.005)
    assert np.sqrt(cov[1, 1]) < 0.01  # without restarts: confident, in one of the basins
    t, cov = alignment.refine_transform(t0, cov_t, chains, faces, sigma=0.005, restarts=True)
    np.testing.assert_array_equal(t, t0)
    np.testing.assert_array_equal(cov, cov_t)


def test_refine_transform__restarts_agree_where_the_walls_fix_the_transform() -> None:
    """The corner and curved wall above fix all of T: with restarts the refinement is the
    same as without (every restart ends in the one basin)."""
    t0 = T_TRUE + np.array([0.03, -0.02, 0.02])
    plain = alignment.refine_transform(t0, COV_T, _chains(WALLS), WALLS, sigma=0.02)
    again = alignment.refine_transform(t0, COV_T, _chains(WALLS), WALLS, 0.02, restarts=True)
    np.testing.assert_array_equal(again[0], plain[0])
    np.testing.assert_array_equal(again[1], plain[1])


def test_align_transform__without_shared_walls_keeps_the_camera_transform() -> None:
    t0 = T_TRUE + np.array([0.03, -0.02, 0.02])
    far = [Polynomial(1, [10.0, 0.0, 0.0, 0.0], 9.0, 12.0)]  # nothing near the chains
    np.testing.assert_array_equal(align_transform(t0, COV_T, _chains(WALLS), far, 0.02), t0)
    np.testing.assert_array_equal(align_transform(t0, COV_T, [], WALLS, 0.02), t0)
    singular = np.zeros((3, 3))  # an exact camera: nothing to refine
    np.testing.assert_array_equal(align_transform(t0, singular, _chains(WALLS), WALLS, 0.02), t0)


def _shifted(wall: Polynomial, offset: float) -> Polynomial:
    """The wall moved by ``offset`` along η (its normal, for these nearly flat walls)."""
    return wall.with_c0(wall.c0 + offset)


def _refined_nees(rng: np.random.Generator, map_sd: float, trials: int, tell: bool) -> float:
    """Mean NEES of ``refine_transform``'s (transform, covariance) over seeded trials in which
    each map holds every wall off by an independent N(0, map_sd²) along its normal and the
    camera's t0 is drawn from its covariance; ``tell``: the maps' variances are passed."""
    nees = []
    var = map_sd * map_sd
    for _ in range(trials):
        t0 = T_TRUE + rng.multivariate_normal(np.zeros(3), COV_T)
        sent = [_shifted(w, rng.normal(0.0, map_sd)) for w in WALLS]
        held = [_shifted(w, rng.normal(0.0, map_sd)) for w in WALLS]
        extra = {"chain_var": [var] * 3, "wall_var": [var] * 3} if tell else {}
        t, cov = alignment.refine_transform(t0, COV_T, _chains(sent), held, 0.002, **extra)
        e = t - T_TRUE
        nees.append(float(e @ np.linalg.solve(cov, e)))
    return float(np.mean(nees))


def test_refine_transform__covariance_holds_the_maps_own_errors() -> None:
    """With both maps 2 cm off at every wall (their drift from their robots' true starts)
    and a 2 mm range noise, the posterior that weighs each pair by the range noise alone is
    overconfident; with each map's variance of each wall in the pair's variance, the mean
    NEES of 300 trials is at most the upper end of the 99 % band of a mean of 300 χ²(3)
    values, 3 + 2.576·√(6/300) = 3.36. (Below it is allowed: the a-posteriori variance
    factor only ever inflates the covariance.)"""
    rng = np.random.default_rng(11)
    upper = 3.0 + 2.576 * np.sqrt(6.0 / 300)
    assert _refined_nees(rng, 0.02, 300, tell=True) <= upper
    assert _refined_nees(rng, 0.02, 300, tell=False) > 3 * upper


def test_refine_transform__variance_factor_inflates_for_residuals_beyond_the_model() -> None:
    """Pairs whose residuals at the solution exceed their stated variances (maps 2 cm off,
    stated as exact) get the posterior scaled by their mean normalised square, never by less
    than 1: the same inputs with the variances stated give a posterior no larger."""
    rng = np.random.default_rng(12)
    sent = [_shifted(w, rng.normal(0.0, 0.02)) for w in WALLS]
    held = [_shifted(w, rng.normal(0.0, 0.02)) for w in WALLS]
    t0 = T_TRUE + np.array([0.01, -0.01, 0.005])
    _, blind = alignment.refine_transform(t0, COV_T, _chains(sent), held, 0.002)
    var = [0.02**2] * 3
    _, told = alignment.refine_transform(
        t0, COV_T, _chains(sent), held, 0.002, chain_var=var, wall_var=var
    )
    assert np.trace(blind) > 0
    _, exact = alignment.refine_transform(t0, COV_T, _chains(WALLS), WALLS, 0.002)
    # exact walls: residuals within the range noise, factor 1; the posterior is the plain one
    assert np.trace(blind) > 10 * np.trace(exact)
    assert np.all(np.linalg.eigvalsh(told - exact) > -1e-15)
    with pytest.raises(ValueError, match="one variance per chain"):
        alignment.refine_transform(t0, COV_T, _chains(sent), held, 0.002, chain_var=[1.0])


#: Walls in all directions, several of each, so that many (chain, wall) pairs measure each
#: component of T: where errors shared by the pairs cannot average out.
MANY_WALLS = [
    *(Polynomial(1, [y, 0.0, 0.0, 0.0], -1.0, 2.0) for y in (1.0, 2.5, 4.0, -2.0)),
    *(Polynomial(2, [x, 0.0, 0.0, 0.0], -1.0, 1.0) for x in (2.0, 3.5, -1.5, 5.0)),
    Polynomial(1, [-1.0, 0.1, 0.2, 0.0], -1.0, 1.5),
]


def _mean_nees_of_shared_offsets(rng: np.random.Generator, map_sd: float, trials: int) -> float:
    """As :func:`_refined_nees` on MANY_WALLS, but each map is off by **one** translation
    N(0, map_sd² I) shared by all its walls (each robot's pose error when it mapped them),
    and the refinement is told each wall's variance map_sd² along its normal."""
    nees = []
    var = [map_sd * map_sd] * len(MANY_WALLS)
    for _ in range(trials):
        t0 = T_TRUE + rng.multivariate_normal(np.zeros(3), COV_T)
        maps = []
        for _side in range(2):
            offset = rng.normal(0.0, map_sd, 2)
            maps.append(
                [_shifted(w, offset[1] if w.variate == 1 else offset[0]) for w in MANY_WALLS]
            )
        sent, held = maps
        t, cov = alignment.refine_transform(
            t0, COV_T, _chains(sent), held, 0.002, chain_var=var, wall_var=var
        )
        e = t - T_TRUE
        nees.append(float(e @ np.linalg.solve(cov, e)))
    return float(np.mean(nees))


@pytest.mark.xfail(
    strict=True, reason="the refined covariance treats shared map errors as independent"
)
def test_refine_transform__covariance_holds_errors_the_walls_share() -> None:
    """Known defect (issue 14's closing note): the refinement weighs each (chain, wall) pair as
    an independent observation, so an error shared by all the walls of a map (the offset of
    the map near the meeting, from its robot's pose error) is averaged down as if it were
    noise. With 9 walls, each map off by one shared 2 cm translation, the mean NEES of 300
    trials is 7.7, against the upper end of the
    99 % band of a mean of 300 χ²(3) values, 3.36. On the office floor a transform 3.7 cm off
    had a posterior σ of 1 cm. Strict: the test says when the covariance holds it."""
    rng = np.random.default_rng(13)
    upper = 3.0 + 2.576 * np.sqrt(6.0 / 300)
    assert _mean_nees_of_shared_offsets(rng, 0.02, 300) <= upper


# -- the refined turn against square walls ---------------------------------------------------
def _straight(direction_deg: float, length: float, c0: float = 0.5) -> Polynomial:
    """A straight wall of the given direction (|direction| < 45° from its variate's axis)."""
    variate = 1 if abs(math.remainder(direction_deg, 180.0)) < 45.0 else 2
    angle = math.radians(direction_deg if variate == 1 else 90.0 - direction_deg)
    return Polynomial(variate, [c0, math.tan(angle), 0.0, 0.0], 0.0, length)


def test_straight_walls__keeps_long_straight_walls_with_their_directions() -> None:
    walls = [
        _straight(0.4, 2.0),
        _straight(90.3, 1.5),
        _straight(10.0, 0.6),  # too short to give a direction
        Polynomial(1, [0.0, 0.1, 0.3, 0.0], 0.0, 3.0),  # curved
    ]
    got = alignment.straight_walls(walls)
    assert len(got) == 2
    assert math.isclose(got[0][0], math.radians(0.4)) and got[0][1] == 2.0
    assert math.isclose(got[1][0], math.radians(90.3)) and got[1][1] == 1.5


def test_square_turn__is_the_turn_that_squares_the_sent_walls_nearest_the_camera() -> None:
    """The receiver's walls run at 0.3° (+ k·90°) in its frame, the sender's at 0.3° − θ in
    its own, θ = 23°: every turn θ + k·90° squares them, and the one nearest the camera's turn
    is θ; a sent wall off square by 7° (shorter than the rest together) does not move the
    length-weighted median."""
    theta = 23.0
    held = alignment.straight_walls([_straight(0.3, 4.0), _straight(90.3, 2.0)])
    sent_walls = [_straight(0.3 - theta + k * 90.0, 2.0) for k in (0, 1, 2)]
    sent = alignment.straight_walls([*sent_walls, _straight(7.3 - theta, 1.5)])
    for camera in (theta + 1.4, theta - 2.0, theta + 44.0):
        got = alignment.square_turn(sent, held, math.radians(camera))
        assert got is not None
        assert math.isclose(math.degrees(got), theta, abs_tol=1e-9), camera
    assert alignment.square_turn([], held, 0.0) is None
    assert alignment.square_turn(sent, [], 0.0) is None


def test_square_turn__is_the_numpy_oracle_bit_for_bit() -> None:
    """``square_turn`` (numpy's argsort, then the running sums and the search in Python)
    against its numpy form (``tests/comms/reference_geometry.py``), every bit: random walls,
    walls of equal directions (ties in the turns, of unequal lengths) and of equal lengths
    (a running sum landing on half the total)."""
    from tests.comms import reference_geometry as ref

    rng = np.random.default_rng(3)
    for case in range(3000):
        n = int(rng.integers(1, 25))
        directions = rng.uniform(-np.pi, np.pi, n)
        lengths = rng.uniform(0.5, 6.0, n)
        if case % 3 == 0:  # ties: a few directions, repeated (and a quarter turn apart)
            few = rng.uniform(-np.pi, np.pi, 3)
            directions = few[rng.integers(0, 3, n)] + 0.5 * np.pi * rng.integers(-1, 2, n)
        if case % 4 == 0:
            lengths = np.full(n, float(rng.choice([1.0, 2.5])))
        sent = list(zip(directions.tolist(), lengths.tolist(), strict=True))
        held = [(float(rng.uniform(-np.pi, np.pi)), 3.0), (float(rng.uniform(-1, 1)), 1.0)]
        turn = float(rng.uniform(-np.pi, np.pi))
        got = alignment.square_turn(sent, held, turn)
        want = ref.square_turn(sent, held, turn)
        assert got is not None and want is not None
        assert np.float64(got).tobytes() == np.float64(want).tobytes()


def _square_check(walls: np.ndarray) -> tuple[Any, tuple[Any, ...], np.ndarray, float, float]:
    """A receiver that drove the corner drive among ``walls`` (its longest straight wall runs
    along x) and a message's records whose straight wall runs at −20° in the sender's frame:
    the receiver, the records, the refined transform's covariance, the square turn (20° + the
    receiver's wall's own direction) and σ, the refined turn's σ plus twice the receiver's
    wall's turn variance."""
    from polyslam_env.comms.messages import PolynomialRecord
    from tests.slam.test_links import CORNER_DRIVE
    from tests.slam.test_map_building import drive

    slam, *_ = drive(walls, CORNER_DRIVE, 0)
    lengths = [p.hi - p.lo for p in slam.polynomials()]
    k = int(np.argmax(lengths))
    wall = slam.polynomials()[k]
    assert not np.any(wall.coeffs[2:]) and wall.variate == 1  # the wall along x
    square = math.radians(20.0) + math.atan(float(wall.coeffs[1]))
    turn = len(slam.table) + 3 + k
    cov = np.diag([1e-4, 1e-4, math.radians(0.15) ** 2])
    sigma = math.sqrt(cov[2, 2] + 2.0 * slam.cov[turn, turn])
    records = (PolynomialRecord(1, _straight(-20.0, 3.0), 1e-4),)
    return slam, records, cov, square, sigma


def test_off_square__refuses_a_refined_turn_beyond_3_sigma_of_the_square_one() -> None:
    """A receiver that mapped a room's corner and a message whose straight wall runs at −20°
    (:func:`_square_check`): the square turns are 20° + k·90° (+ the receiver's wall's own
    direction). A refined turn 2.9 σ from it is kept, 3.1 σ is refused; with
    ``square_walls`` off nothing is refused."""
    from polyslam_env.comms.exchange import RendezvousExchange
    from polyslam_env.slam.config import SlamConfig
    from tests.slam.test_links import CORNER

    slam, records, cov, square, sigma = _square_check(CORNER)
    camera = np.array([1.0, 2.0, math.radians(21.0)])
    for factor, refused in ((0.0, False), (2.9, False), (3.1, True), (-3.1, True)):
        refined = np.array([1.0, 2.0, square + factor * sigma])
        got = RendezvousExchange._off_square(slam, records, camera, refined, cov)
        assert got is refused, factor
    slam.config = SlamConfig(square_walls=False)
    refined = np.array([1.0, 2.0, square + 5.0 * sigma])
    assert not RendezvousExchange._off_square(slam, records, camera, refined, cov)


@pytest.mark.parametrize(
    "square_evidence",
    [True, pytest.param(False, marks=pytest.mark.xfail(strict=True, reason="rule forced on"))],
)
def test_off_square__on_an_angled_floor_keeps_a_refined_turn_that_is_not_square(
    square_evidence: bool,
) -> None:
    """A receiver whose map holds a wall clearly at 30° (the angled room of
    tests/slam/test_links.py) is not on a rectilinear floor, so the refined turn is not
    judged by the square one: one 5 σ from it is kept. With the rule forced on
    (``square_evidence`` off) it is refused, although nothing says the sender's walls are
    square to the receiver's."""
    from polyslam_env.comms.exchange import RendezvousExchange
    from polyslam_env.slam.config import SlamConfig
    from tests.slam.test_links import ANGLED_ROOM

    slam, records, cov, square, sigma = _square_check(ANGLED_ROOM)
    assert not slam.walls.rectilinear()
    slam.config = SlamConfig(square_evidence=square_evidence)
    camera = np.array([1.0, 2.0, math.radians(21.0)])
    refined = np.array([1.0, 2.0, square + 5.0 * sigma])
    assert not RendezvousExchange._off_square(slam, records, camera, refined, cov)


def _match_oracle(
    p: np.ndarray,
    dp_dt: np.ndarray,
    tangents: np.ndarray,
    walls: list[Polynomial],
    cov_t: np.ndarray,
    point_var: np.ndarray,
    wall_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The pairing (``_match`` below) in numpy, wall by wall over every point (what the compiled
    ``comms.kernels.match_walls`` replaced)."""
    n_pts = len(p)
    best = np.full(n_pts, np.inf)
    residual, grad, wall_of = np.zeros(n_pts), np.zeros((n_pts, 3)), np.full(n_pts, -1)
    cos_max = np.cos(np.radians(alignment.MAX_ANGLE_DEG))
    for w, poly in enumerate(walls):
        xi, eta = poly.from_xy(p)
        (at,) = np.nonzero((xi >= poly.lo) & (xi <= poly.hi))
        if not len(at):
            continue
        xi, eta = xi[at], eta[at]
        slope = poly.slope(xi)
        normal = poly.normals(xi)
        r = (eta - poly.value(xi)) / np.sqrt(1.0 + slope * slope)
        g = np.einsum("ni,nij->nj", normal, dp_dt[at])
        pred = np.sqrt(np.einsum("ni,ij,nj->n", g, cov_t, g) + point_var[at] + wall_var[w])
        parallel = np.abs(np.einsum("ni,ni->n", normal, tangents[at])) <= np.sqrt(1 - cos_max**2)
        score = np.abs(r) / pred
        ok = parallel & (score <= alignment.GATE_SIGMAS) & (score < best[at])
        rows = at[ok]
        best[rows], residual[rows], grad[rows], wall_of[rows] = score[ok], r[ok], g[ok], w
    keep = wall_of >= 0
    if not keep.any():
        return None
    return residual[keep], grad[keep], wall_of[keep], keep


def test_match__compiled_with_reach_boxes_is_the_numpy_pairing_bit_for_bit() -> None:
    """The compiled pairing (``_match``), on every chain and on the chains within each wall's
    reach (``wall_reach``, ``_near_chains``), against the numpy oracle over every point, bit
    for bit, on random walls and short chains (tight boxes) with a prior wide enough that the
    gate reaches far: the reach bound at a tenth of its size drops pairing points here."""
    rng = np.random.default_rng(7)
    left_out = paired = 0
    for _ in range(40):
        walls = []
        for _ in range(6):
            coeffs = [*rng.normal(0, 2, 2), *rng.normal(0, 0.1, int(rng.integers(0, 3)))]
            lo, hi = sorted(rng.uniform(-3, 3, 2))
            walls.append(Polynomial(int(rng.integers(1, 3)), coeffs, lo, hi))
        chains = [transform_points(w.sample_arclength(0.05), inverse(T_TRUE)) for w in walls]
        chains = [c + rng.normal(0, 0.05, c.shape) + rng.normal(0, 0.2, 2) for c in chains[:4]]
        chains = [c[k : k + 3] for c in chains for k in range(0, len(c), 3)]  # tight boxes
        cov_t = COV_T * rng.uniform(0.5, 20.0)
        q = np.vstack(chains)
        starts = np.cumsum([0] + [len(c) for c in chains])
        point_var = np.full(len(q), 0.02**2)
        wall_var = rng.uniform(0, 0.05**2, len(walls))
        p, dp_dt = frame_points(q, T_TRUE + rng.normal(0, 0.05, 3))
        tangents = np.vstack([_tangents(c) for c in chains])
        args = (p, dp_dt, tangents, walls, cov_t, point_var, wall_var)
        reach = alignment.wall_reach(walls, wall_var, cov_t, point_var, q)
        meets = _near_chains(reach, p, starts)
        left_out += int(meets.size - meets.sum())
        oracle = _match_oracle(*args)
        for out in (_match(*args), _match(*args, meets, starts)):
            assert (oracle is None) == (out is None)
            if oracle is not None and out is not None:
                paired += len(oracle[0])
                for a, b in zip(oracle, out, strict=True):
                    np.testing.assert_array_equal(a, b)
    assert left_out > 0 and paired > 0  # the boxes did leave chains out; points did pair


def _wall_reach_oracle(
    walls: list[Polynomial], wall_var: np.ndarray, cov_t: np.ndarray, point_var: np.ndarray,
    q: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """``alignment.wall_reach`` wall by wall over ``Polynomial`` objects (what the compiled
    ``comms.kernels.reach_boxes`` replaced)."""
    from polyslam_env.slam.map_kernels import eta_range

    worst = float(np.trace(cov_t)) * (1.0 + float(np.max(np.sum(q * q, axis=1), initial=0.0)))
    worst += float(np.max(point_var, initial=0.0))
    out = np.empty((len(walls), 4))
    for w, poly in enumerate(walls):
        shape = poly.coeffs.copy()
        shape[0] = 0.0
        b_lo, b_hi = eta_range(shape, poly.lo, poly.hi)
        slope = poly.max_slope()
        reach = alignment.GATE_SIGMAS * np.sqrt((worst + wall_var[w]) * (1.0 + slope * slope))
        reach += 1e-9
        eta = (poly.c0 + b_lo - reach, poly.c0 + b_hi + reach)
        out[w] = (poly.lo, poly.hi, *eta) if poly.variate == 1 else (*eta, poly.lo, poly.hi)
    return out


def _random_walls(rng: np.random.Generator, n: int) -> list[Polynomial]:
    """Lines to quintics of either variate, many cubics with their slope's turn inside."""
    walls = []
    for _ in range(n):
        order = int(rng.choice([1, 2, 3, 3, 3, 4, 5]))
        coeffs = [*rng.normal(0, 2, 2), *rng.normal(0, 0.3, order - 1)]
        lo, hi = sorted(rng.uniform(-3, 3, 2))
        walls.append(Polynomial(int(rng.integers(1, 3)), coeffs, lo, hi))
    return walls


def test_wall_reach__compiled_is_the_per_polynomial_bound_bit_for_bit() -> None:
    """``wall_reach`` (``comms.kernels.reach_boxes``, slopes of orders ≥ 4 from
    ``Polynomial.max_slope``) equals the per-polynomial version bit for bit, on walls of
    mixed orders packed into one zero-padded array; and the packed walls' normal variances
    (``comms.kernels.normal_variances``) equal ``exchange.normal_variance`` bit for bit. A
    mutation (the turn of a cubic's slope ignored) fails the first: cubics' turns land inside
    their extents here."""
    from polyslam_env.comms.exchange import normal_variance
    from polyslam_env.comms.kernels import normal_variances

    rng = np.random.default_rng(11)
    turns_inside = 0
    for _ in range(60):
        walls = _random_walls(rng, 8)
        for poly in walls:
            if poly.order == 3:
                turn = -poly.coeffs[2] / (3 * poly.coeffs[3])
                turns_inside += int(poly.lo < turn < poly.hi)
        wall_var = rng.uniform(0, 0.05**2, len(walls))
        cov_t = COV_T * rng.uniform(0.5, 20.0)
        q = rng.normal(0, 2, (int(rng.integers(0, 30)), 2))
        point_var = np.full(len(q), 0.02**2)
        expected = _wall_reach_oracle(walls, wall_var, cov_t, point_var, q)
        got = alignment.wall_reach(walls, wall_var, cov_t, point_var, q)
        assert got.tobytes() == expected.tobytes()
        packed = alignment.pack_walls(walls)
        c0_var = rng.uniform(0, 0.01, len(walls))
        variances = normal_variances(packed.order, packed.coeffs, packed.extent, c0_var)
        pairs = zip(walls, c0_var.tolist(), strict=True)
        oracle = np.array([normal_variance(poly, var) for poly, var in pairs])
        assert variances.tobytes() == oracle.tobytes()
    assert turns_inside > 20


def _near_chains_oracle(reach: np.ndarray, p: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``alignment._near_chains`` in numpy (what the compiled ``comms.kernels.near_chains``
    replaced): each chain's box by ``reduceat``, met against every reach box."""
    first = starts[:-1]
    lo, hi = np.minimum.reduceat(p, first, axis=0), np.maximum.reduceat(p, first, axis=0)
    return np.asarray(
        (lo[None, :, 0] <= reach[:, 1, None]) & (hi[None, :, 0] >= reach[:, 0, None])
        & (lo[None, :, 1] <= reach[:, 3, None]) & (hi[None, :, 1] >= reach[:, 2, None])
    )  # fmt: skip


def test_near_chains__compiled_answers_as_the_numpy_boxes() -> None:
    """Chains of 1 to 9 points (single points, ties on the box edges, NaN points) against
    reach boxes that touch, hold or miss them: the compiled test answers as numpy's."""
    rng = np.random.default_rng(5)
    met = 0
    for trial in range(300):
        lengths = rng.integers(1, 10, int(rng.integers(1, 8)))
        starts = np.cumsum([0, *lengths.tolist()])
        p = np.round(rng.uniform(-3, 3, (int(starts[-1]), 2)), 1)  # ties on the box edges
        if trial % 5 == 0:
            p[rng.integers(0, len(p)), int(rng.integers(0, 2))] = np.nan  # numpy's box: NaN
        centre = np.round(rng.uniform(-3, 3, (int(rng.integers(1, 6)), 2)), 1)
        half = np.round(rng.uniform(0, 1.5, centre.shape), 1)
        reach = np.column_stack(
            [centre[:, 0] - half[:, 0], centre[:, 0] + half[:, 0],
             centre[:, 1] - half[:, 1], centre[:, 1] + half[:, 1]]
        )  # fmt: skip
        got = _near_chains(reach, p, starts)
        want = _near_chains_oracle(reach, p, starts)
        assert got.dtype == want.dtype and got.tolist() == want.tolist()
        met += int(want.sum())
    assert met > 100


def _gauss_newton_terms_oracle(
    chains: list[np.ndarray], t: np.ndarray, walls: list[Polynomial], cov_t: np.ndarray,
    point_var: np.ndarray, wall_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int] | None:  # fmt: skip
    """One iteration of ``alignment._refine_from`` before its products, in the numpy it ran
    (what the compiled ``comms.kernels.gauss_newton_terms`` replaced): points and tangents
    under T, the pairing over every point, each (chain, wall) pair's points weighed to one."""
    from tests.comms import reference_geometry as ref

    q = np.vstack(chains)
    chain_of = np.concatenate([np.full(len(c), k) for k, c in enumerate(chains)])
    p, dp_dt = ref.frame_points(q, t)
    tangents = np.vstack([ref.tangents(c) for c in chains]) @ rotation(t[2]).T
    match = _match_oracle(p, dp_dt, tangents, walls, cov_t, point_var, wall_var)
    if match is None:
        return None
    residual, grad, wall, keep = match
    pair = chain_of[keep] * len(walls) + wall
    counts = np.bincount(pair)
    weight = 1.0 / ((point_var[keep] + wall_var[wall]) * counts[pair])
    return residual, grad, grad * weight[:, None], weight, np.count_nonzero(counts)


def test_gauss_newton_terms__compiled_is_the_numpy_iteration_bit_for_bit() -> None:
    """The refinement's compiled iteration (points, tangents, the chains near each wall, the
    pairing, the pair weights) equals its numpy form bit for bit on random walls and chains
    (several pairs with many points, single-point chains, and transforms that pair nothing),
    and so does the refinement built on it (``refine_transform``: the same products, solves
    and result on the compiled iteration's arrays as on numpy's)."""
    from polyslam_env.comms.kernels import gauss_newton_terms

    rng = np.random.default_rng(3)
    paired = unpaired = shared = refined = 0
    for _ in range(40):
        walls = _random_walls(rng, 6)
        chains = [transform_points(w.sample_arclength(0.05), inverse(T_TRUE)) for w in walls]
        chains = [c + rng.normal(0, 0.02, c.shape) for c in chains[:4]]
        chains = [c[k : k + int(rng.integers(1, 12))] for c in chains for k in (0, 5, 20)]
        chains = [c for c in chains if len(c)]
        cov_t = COV_T * rng.uniform(0.5, 20.0)
        q = np.vstack(chains)
        lengths = [len(c) for c in chains]
        starts = np.cumsum([0, *lengths])
        chain_of = np.repeat(np.arange(len(chains)), lengths)
        point_var = 0.02**2 + rng.uniform(0, 0.03**2, len(chains))[chain_of]
        wall_var = rng.uniform(0, 0.05**2, len(walls))
        packed = alignment.pack_walls(walls)
        reach = alignment.wall_reach(packed, wall_var, cov_t, point_var, q)
        tangents_q = np.vstack([_tangents(c) for c in chains])
        for t in (T_TRUE + rng.normal(0, 0.03, 3), T_TRUE + np.array([3.0, 0.0, 0.0])):
            got = gauss_newton_terms(
                q, tangents_q, starts, chain_of, t, rotation(float(t[2])), reach,
                packed.variate, packed.coeffs, packed.extent, cov_t, point_var, wall_var,
                alignment.GATE_SIGMAS, alignment._SIN_MAX,
            )  # fmt: skip
            want = _gauss_newton_terms_oracle(chains, t, walls, cov_t, point_var, wall_var)
            if want is None:
                assert len(got[0]) == 0 and got[4] == 0
                unpaired += 1
                continue
            for a, b in zip(got[:4], want[:4], strict=True):
                assert a.shape == b.shape and a.tobytes() == b.tobytes()
            assert got[4] == want[4]
            paired += len(want[0])
            shared += int(len(want[0]) > want[4])
        start = T_TRUE + rng.normal(0, 0.03, 3)
        chain_var = rng.uniform(0, 0.03**2, len(chains))
        want_t = _refine_oracle(start, cov_t, chains, walls, 0.02, chain_var, wall_var)
        got_t = alignment.refine_transform(
            start, cov_t, chains, walls, 0.02, chain_var=chain_var, wall_var=wall_var
        )
        refined += want_t is not None
        want_t = want_t or (start, cov_t)
        assert all(a.tobytes() == b.tobytes() for a, b in zip(got_t, want_t, strict=True))
    assert paired > 500 and unpaired > 0 and shared > 10 and refined > 20


def _refine_oracle(
    t0: np.ndarray, cov_t: np.ndarray, chains: list[np.ndarray], walls: list[Polynomial],
    sigma: float, chain_var: np.ndarray, wall_var: np.ndarray, iterations: int = 5,
) -> tuple[np.ndarray, np.ndarray] | None:  # fmt: skip
    """``alignment._refine_from`` from t0 in the numpy it ran, on
    :func:`_gauss_newton_terms_oracle` (the products and the solve on numpy's own arrays)."""
    lower_inv = np.linalg.inv(np.linalg.cholesky(cov_t))
    info_prior = lower_inv.T @ lower_inv
    chain_of = np.concatenate([np.full(len(c), k) for k, c in enumerate(chains)])
    point_var = sigma * sigma + chain_var[chain_of]
    t, info = t0.copy(), info_prior
    for _ in range(iterations):
        terms = _gauss_newton_terms_oracle(chains, t, walls, cov_t, point_var, wall_var)
        if terms is None:
            return None
        residual, grad, _, weight, n_pairs = terms
        info = info_prior + (grad * weight[:, None]).T @ grad
        rhs = -(grad * weight[:, None]).T @ residual - info_prior @ (t - t0)
        step = np.linalg.solve(info, rhs)
        t = t + step
        if np.max(np.abs(step)) < 1e-9:
            break
    d = t - t0
    if float(d @ info_prior @ d) > CHI2_3DOF_99:
        return None
    posterior = np.linalg.inv(info)
    factor = max(1.0, float(weight @ (residual * residual)) / n_pairs)
    return t, factor * 0.5 * (posterior + posterior.T)


# the compiled pieces of the refinement, called as it called them before its iteration became
# one kernel (``comms.kernels.gauss_newton_terms``): the oracles below are checked through them
def _tangents(chain: np.ndarray) -> np.ndarray:
    """(N, 2) unit tangents along a chain of points (N, 2) (``kernels.unit_tangents``)."""
    return unit_tangents(np.asarray(chain, dtype=float))


def _match(
    p: np.ndarray,
    dp_dt: np.ndarray,
    tangents: np.ndarray,
    walls: list[Polynomial] | WallArrays,
    cov_t: np.ndarray,
    point_var: np.ndarray,
    wall_var: np.ndarray,
    meets: np.ndarray | None = None,
    starts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Per point (N, 2) the wall it pairs with (smallest normalised normal distance within
    the gate, same direction, inside the extent; a pair's offset variance is the point's
    ``point_var`` (N,) plus the wall's ``wall_var``): for the M points that pair, residuals
    (M,), their gradients w.r.t. T (M, 3) and wall indices (M,), and which points pair (N,)
    bool; None if none does. ``meets`` (W, K) (:func:`_near_chains`): which chains (rows
    ``starts[k]:starts[k+1]`` of ``p``) can pair with each wall (default: one chain, every
    wall); the others cannot, so leaving them out changes nothing. Compiled:
    :func:`~polyslam_env.comms.kernels.match_walls`."""
    walls = alignment.pack_walls(walls)
    if meets is None or starts is None:
        meets, starts = np.ones((len(walls.order), 1), dtype=bool), np.array([0, len(p)])
    _, residual, grad, wall_of = match_walls(
        p, dp_dt, tangents, walls.variate, walls.coeffs, walls.extent, cov_t, point_var,
        np.asarray(wall_var, dtype=float), meets, np.asarray(starts, dtype=np.int64),
        alignment.GATE_SIGMAS, alignment._SIN_MAX,
    )  # fmt: skip
    keep = wall_of >= 0
    if not keep.any():
        return None
    return residual[keep], grad[keep], wall_of[keep], keep


def _near_chains(reach: np.ndarray, p: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(W, K) whether chain k of ``p`` (rows starts[k]:starts[k+1]) has a bounding box that
    meets wall w's ``reach`` box (:func:`wall_reach`): only those chains can pair with it.
    Compiled: :func:`~polyslam_env.comms.kernels.near_chains`."""
    return near_chains(
        np.ascontiguousarray(reach, dtype=float), np.ascontiguousarray(p, dtype=float),
        np.ascontiguousarray(starts, dtype=np.int64),
    )  # fmt: skip


def test_refinement_products__compiled_are_numpy_bit_for_bit() -> None:
    """The refinement's products, solve and inverses, compiled (``comms.kernels.gauss_newton``,
    ``prior_information``, ``inverse3``) in the operations of OpenBLAS's AVX2 ("Haswell")
    kernels, equal numpy's (``a.T @ b`` across the gemm driver's splits of M at 256 and 512,
    ``a.T @ v``, a 3 × 3 times a vector, ``np.linalg.solve``, ``np.linalg.inv``, L⁻ᵀ L⁻¹ of
    ``np.linalg.cholesky``) bit for bit on random operands of many scales; a singular or
    indefinite matrix is flagged, as numpy raises. Where this process's OpenBLAS runs other
    kernels (an AVX-512 machine), the check runs in a child process pinned to the AVX2 ones,
    as the golden episodes are (``tests.golden.episodes.PINNED_ENV``)."""
    import os
    import subprocess
    import sys

    from threadpoolctl import threadpool_info

    from tests.golden.episodes import PINNED_ENV, ROOT

    kernels = {
        i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"
    }
    if kernels == {"Haswell"}:
        check_refinement_products()
        return
    code = "from tests.comms.test_alignment import check_refinement_products as c; c()"
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env={**os.environ, **PINNED_ENV},
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]


def check_refinement_products() -> None:
    """The body of :func:`test_refinement_products__compiled_are_numpy_bit_for_bit`."""
    from polyslam_env.comms.kernels import (
        inverse3,
        prior_information,
        solve3,
        times3,
        transposed_product,
        transposed_times,
    )

    rng = np.random.default_rng(5)
    sizes = [*range(1, 40), 100, 255, 256, 257, 258, 263, 300, 511, 512, 513, 514, 600, 1025]
    for m in sizes:
        for _ in range(20):
            a = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-3, 3, size=(m, 1))
            b, v = rng.normal(size=(m, 3)), rng.normal(size=m)
            assert transposed_product(a, b).tobytes() == (a.T @ b).tobytes()
            assert transposed_times(-a, v).tobytes() == (-a.T @ v).tobytes()
    for _ in range(3000):
        m = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 3, size=(3, 3))
        if rng.uniform() < 0.5:  # an information matrix: symmetric, positive definite
            m = m @ m.T + np.diag(rng.uniform(0.0, 1e4, 3))
        v = rng.normal(size=3) * 10.0 ** rng.uniform(-3, 3)
        assert times3(m, v).tobytes() == (m @ v).tobytes()
        x, regular = solve3(m, v)
        assert regular and x.tobytes() == np.linalg.solve(m, v).tobytes()
        inv, regular = inverse3(m)
        assert regular and inv.tobytes() == np.linalg.inv(m).tobytes()
        root = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 1, size=(3, 1))
        cov = root @ root.T + np.diag(rng.uniform(0.0, 1e-2, 3))  # a covariance
        lower_inv = np.linalg.inv(np.linalg.cholesky(cov))
        info, definite = prior_information(cov)
        assert definite and info.tobytes() == (lower_inv.T @ lower_inv).tobytes()
    assert not solve3(np.ones((3, 3)), np.ones(3))[1] and not inverse3(np.ones((3, 3)))[1]
    assert not prior_information(np.diag([1.0, -1.0, 1.0]))[1]
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(np.ones((3, 3)), np.ones(3))


def test_longest_straight__is_the_numpy_choice_of_the_reference_wall() -> None:
    """``kernels.longest_straight`` (``RendezvousExchange._off_square``'s reference wall)
    picks what the numpy form it replaced picks: the first of the longest rows with no
    coefficient past the slope (NaN counts, −0.0 does not) at least ``SQUARE_MIN_LENGTH``
    long, −1 for none; over random tables with ties, curved and short rows, and lines only."""
    from polyslam_env.comms.kernels import longest_straight
    from polyslam_env.slam.links import SQUARE_MIN_LENGTH

    rng = np.random.default_rng(9)
    found = 0
    for _ in range(2000):
        n, width = int(rng.integers(0, 12)), int(rng.integers(2, 6))
        shape = np.zeros((n, width))
        curved = rng.uniform(size=(n, width - 2)) < 0.3
        shape[:, 2:] = np.where(curved, rng.choice([0.1, np.nan, -0.0], size=curved.shape), 0.0)
        lo = rng.uniform(-3, 0, n)
        hi = lo + rng.choice([0.2, 1.0, 1.5, 2.5, SQUARE_MIN_LENGTH], n)
        length = hi - lo
        held = ~np.any(shape[:, 2:], axis=1) & (length >= SQUARE_MIN_LENGTH)
        want = int(np.argmax(np.where(held, length, -np.inf))) if held.any() else -1
        assert longest_straight(shape, lo, hi, SQUARE_MIN_LENGTH) == want
        found += want >= 0
    assert 500 < found < 1900

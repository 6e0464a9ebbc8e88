"""Pieces of one straight wall across a gap (a doorway): the collinearity constraint.

A doorway, a partition meeting a wall, or a shelf row's cross aisle cuts one straight wall
into pieces, and the map keeps each piece as its own landmark (an extent never bridges a gap
the beams saw through: ``landmarks.EXTENT_MARGIN``). A robot that maps the next piece after a
long drive maps it where its drifted pose puts it, a few cm off and turned by its heading
error; the pieces it mapped early say where the wall is, but only if the map knows they are
one wall.

:class:`~polyslam_env.slam.robot.PolySlam` links two straight pieces (order 1, same
variate) whose supporting hits are at most ``SlamConfig.link_gap`` apart along the wall by a
pseudo-measurement that they lie on one line: at the middle ξ of each piece's evidence, the
difference of the two curves' η,

    z = η_i(ξ) − η_j(ξ) = 0,

two rows that fix both the offset and the direction. Each η moves with its c0 and, with
rotation states, with its turn α about its pivot (:func:`link_rows`, from the same point
Jacobians as the merges' fits: :func:`~polyslam_env.slam.fitting.polynomial_points`). The
noise is each fit's variance beyond the range noise plus ``SlamConfig.wall_straightness``²;
a pair whose innovation is beyond the χ²(2) gate is not one wall (two parallel faces, a wall
and a shelf) and stays unlinked. The update corrects the pose and every correlated
landmark, and it *estimates* the two lines' turns (every other turn stays considered): a
line is turned exactly by its estimate α̂ (:func:`turned_line`) and α̂ reset to zero. So the
late piece moves onto the early one's line, turned as well as shifted, and the pose with it.

Links wait until both pieces are ``SlamConfig.link_age`` steps old: a fresh fit hangs the
hits of several steps on one pose, so its offset relative to that pose is stated too
precisely, and two fresh pieces' offsets fixed the wall's direction better than they knew it
(linked at once, the lone office robot's final NEES was 4.9 over 20 runs, above its band);
by then the beams have updated the offsets.

Received landmarks (and landmarks merged from them) are never linked: their covariance
leaves out the errors that the walls of one message share through the frame transform (the
strict xfail ``test_refine_transform__covariance_holds_errors_the_walls_share``), and a link
would trust them as if they had none.

**Curved pieces** (``SlamConfig.curve_links``, opt-in): a curve and a curve or a line of one
variate whose evidence meets (``walls.CURVE_LINK_GAP``) meet at the junction ξ of their evidence
(:func:`junction`) with one value and one tangent (:func:`junction_rows`); the noise is each
piece's frozen error at ξ, extrapolated (:func:`frozen_slope_var` for the slope), and the
curves' turns stay considered (a curve cannot be turned exactly as :func:`turned_line` turns
a line).

A fact may be used once: pieces already joined by links (directly or through others, or
merged from linked pieces) form one *wall group* and are never linked again among
themselves, so no collinearity enters the filter twice.

**Walls tied square** (``SlamConfig.square_walls``). Most floor plans are drawn at right
angles, and the generators' walls are all parallel to the axes. A shape is frozen when it is
fitted, so its direction is only as good as that fit (0.2–1° for a piece of 1–3 m seen with
2 cm range noise), and the beams never improve it (its turn α is considered, not estimated).
A straight landmark ``link_age`` steps old (at least ``min_update_extent`` long) is therefore
tied to the straight landmark of another *direction group* whose angle to it the state knows
best (smallest var(α_i − α_j)) by the pseudo-measurement

    z = (φ_i + α_i) − (φ_j + α_j) − k·90° = 0,

φ the stored line's direction (:func:`line_angle`), k the nearest multiple
(:func:`off_square`); one row, H = +1 on α_i and −1 on α_j, noise
``wall_squareness_deg``² plus each fit's direction variance beyond the range noise, gated by
χ²(1): a wall clearly off square (20°, say) stays untied, but one a degree or two off, within
the two walls' relative uncertainty, would be tied, so switch it off for such buildings. The
update estimates the two turns as a link does. Tied walls (and linked or merged ones: one
wall is parallel to itself) form a direction group, and each tie joins two groups, so no
angle is used twice; a link between pieces already in one direction group then uses one row
(their offsets at the middle between them), not two.

**Only on a rectilinear floor** (``SlamConfig.square_evidence``). The gate alone cannot tell a
wall 1° off square from a square one whose direction is known to 1°: where walls run at
any angle (an angled wing, a cave's straight stretches, turned furniture), a wall near square
is not likely to be *exactly* square, and a tie would turn it onto the wrong direction with
a variance that claims otherwise. So a tie is made only while the robot's own map says its
floor is rectilinear (:func:`rectilinear`): its confident straight walls (own, at least
``SQUARE_MIN_LENGTH`` long, ``link_age`` steps old: a pillar's arc fitted as a line has no
direction to count) are square to one of them, within the χ² gate of a tie between them, in
all but ``SQUARE_CLUTTER`` of their length. Every such wall is evidence for or against: on
the generators' axis-parallel floors each is square to the others and the rule works as
before, while clearly angled walls beyond the clutter share turn it off for as long as they
are in the map. A robot with fewer than three confident walls has no evidence either way
(two are one pair, which the tie's gate judges), and the tie's own gate decides, as before
(the first walls of an angled floor may still be tied when they pass it; from the first
clearly angled confident walls on, none is).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.slam import map_kernels
from polyslam_env.slam.ekf import chi2_1dof_quantile
from polyslam_env.slam.polynomial import Polynomial, polyval


def evidence_gap(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance (m) along ξ between two evidence intervals; negative when they overlap."""
    return max(b[0] - a[1], a[0] - b[1])


def link_rows(
    poly_i: Polynomial,
    c0_index_i: int,
    turn_i: tuple[int, float] | None,
    poly_j: Polynomial,
    c0_index_j: int,
    turn_j: tuple[int, float] | None,
    xis: np.ndarray,
    n_state: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The collinearity rows of two pieces (same variate, current c0s) at ``xis`` (m,):
    the residuals η_i(ξ) − η_j(ξ) (m,) and their Jacobian H (m, ``n_state``).

    A state change δX moves the point of a curve at ξ by δπ = D δX (``polynomial_points``'
    ``d_state``: 1 on c0 along η, J(π − π_c) on the turn α); the curve's η at the fixed ξ
    then changes by δπ_η − B'(ξ)·δπ_ξ: 1 on c0 and, on α, (ξ − ξ_c) + B'(ξ)(η − η_c) for
    variate 1 and −(ξ − ξ_c) − B'(ξ)(η − η_c) for variate 2 (J turns (x¹, x²)). Each entry
    in floats, with the operations of that product of ``polynomial_points``' Jacobian (the
    same bits: ``tests/slam/reference_links.py``); a link is a map change's most frequent
    call, and its point sets cost ~40 interpreter calls a row."""
    if poly_i.variate != poly_j.variate:
        raise ValueError("link_rows: the two pieces must share their variate")
    xis = np.asarray(xis, dtype=float).reshape(-1)
    residual = np.zeros(xis.size)
    H = np.zeros((xis.size, n_state))
    for sign, poly, c0_index, turn in (
        (1.0, poly_i, c0_index_i, turn_i),
        (-1.0, poly_j, c0_index_j, turn_j),
    ):
        if not 3 <= c0_index < n_state:
            raise ValueError(
                f"c0_index must be a landmark state index in [3, {n_state}), got {c0_index}"
            )
        coeffs = poly.coeffs
        centre = 0.0
        if turn is not None:
            turn_index, pivot = turn
            if not 3 <= turn_index < n_state or turn_index == c0_index:
                raise ValueError(f"turn index must be another state index, got {turn_index}")
            centre = float(polyval(pivot, coeffs))  # η_c
        for row, xi in enumerate(xis.tolist()):
            eta = float(polyval(xi, coeffs))
            slope = float(polyval(xi, coeffs, derivative=1))
            H[row, c0_index] += sign * (1.0 - slope * 0.0)
            if turn is not None:
                along, across = xi - pivot, eta - centre
                if poly.variate == 1:  # J(π − π_c) = (−(η − η_c), ξ − ξ_c) in (x¹, x²)
                    moved = along - slope * -across
                else:  # = (−(ξ − ξ_c), η − η_c)
                    moved = -along - slope * across
                H[row, turn_index] += sign * moved
            residual[row] += sign * eta
    return residual, H


def junction(a: tuple[float, float], b: tuple[float, float]) -> float:
    """ξ where two pieces' evidence intervals meet: the middle of the gap between them, or of
    their overlap when they overlap."""
    first, second = sorted((a, b), key=sum)
    return 0.5 * (first[1] + second[0])


def junction_rows(
    poly_i: Polynomial,
    c0_index_i: int,
    turn_i: tuple[int, float] | None,
    poly_j: Polynomial,
    c0_index_j: int,
    turn_j: tuple[int, float] | None,
    xi: float,
    n_state: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The rows that two pieces of one wall, a curve among them, meet at ``xi`` with one
    tangent (same variate, current c0s): residuals (η_i − η_j, B'_i − B'_j) at ξ (2,) and
    their Jacobian H (2, ``n_state``). The first row is :func:`link_rows`' at ξ. On the
    second, c0 does not move a slope; a turn α about the pivot (ξ_c, η_c) moves the curve's
    η at ξ by (ξ − ξ_c) + B'(ξ)(η − η_c) (variate 1; variate 2 the negative), whose
    derivative along ξ is the slope's: 1 + B'(ξ)² + B''(ξ)(η − η_c)."""
    residual = np.zeros(2)
    H = np.zeros((2, n_state))
    residual[:1], H[:1] = link_rows(
        poly_i, c0_index_i, turn_i, poly_j, c0_index_j, turn_j, np.array([xi]), n_state
    )
    for sign, poly, turn in ((1.0, poly_i, turn_i), (-1.0, poly_j, turn_j)):
        slope = float(polyval(xi, poly.coeffs, derivative=1))
        residual[1] += sign * slope
        if turn is not None:
            turn_index, pivot = turn
            across = float(polyval(xi, poly.coeffs)) - float(polyval(pivot, poly.coeffs))
            bend = 1.0 + slope * slope + float(polyval(xi, poly.coeffs, derivative=2)) * across
            H[1, turn_index] += sign * (bend if poly.variate == 1 else -bend)
    return residual, H


def chord_bias(bend: float, offset: float, half: float) -> tuple[float, float]:
    """How far a straight piece fitted to a wall of curvature ``bend`` (B'', the wall's
    η = B''·u²/2 about the piece's middle) lies from the wall at ``offset`` from its middle
    (m along ξ), its evidence ``half`` long each side: (η, slope). The least-squares line
    over hits spread evenly on [−h, h] takes the mean B''·h²/6 and no slope, so at u the
    wall is B''(u² − h²/3)/2 above it and B''·u steeper: a frozen bias no state and no
    misfit variance holds (a sagitta below the range noise, docs/notes/floors.md R6.1)."""
    return 0.5 * bend * (offset * offset - half * half / 3.0), bend * offset


def frozen_slope_var(
    shape: np.ndarray,
    order: int,
    t: float,
    fit_half: float,
    fit_inverse: np.ndarray,
    noise_var: float,
    turn_in_state: bool,
) -> float:
    """Variance of a frozen shape's slope B'(ξ) from its fit at scaled position t = (ξ −
    pivot)/``fit_half``: the slope's counterpart of the value's (``kernels._shape_fit_var``),
    σ²·a'(t)ᵀ M⁻¹ a'(t)/``fit_half``² with a' = ∂a/∂t = [0, 1, 2t, 3t², …] and M⁻¹ =
    ``fit_inverse[order]``; with ``turn_in_state`` less the slope coefficient's own part
    (the shape's turn α, a state, carries it)."""
    if order < 1 or shape[order] == 0.0:
        return 0.0
    a = np.array([float(k) * t ** (k - 1) if k else 0.0 for k in range(order + 1)])
    quad = float(a @ fit_inverse[order, : order + 1, : order + 1] @ a)
    if turn_in_state:
        quad -= float(fit_inverse[order, 1, 1])
    return noise_var * max(quad, 0.0) / fit_half**2


def line_angle(poly: Polynomial) -> float:
    """Direction (rad, in (−π, π]) of straight ``poly`` in its frame (x¹, x²): atan B' for
    η = x² (variate 1), π/2 − atan B' for η = x¹ (variate 2)."""
    slope = float(poly.coeffs[1])
    return math.atan2(slope, 1.0) if poly.variate == 1 else math.atan2(1.0, slope)


def off_square(angle: float) -> float:
    """``angle`` (rad) minus its nearest multiple of 90°: in [−π/4, π/4]."""
    quarter = 0.5 * math.pi
    return angle - quarter * round(angle / quarter)


def turned_line(poly: Polynomial, pivot: float, angle: float) -> Polynomial:
    """Straight ``poly`` (order 1 in effect; its current c0) turned by ``angle`` (rad,
    counter-clockwise in (x¹, x²), the sense of a landmark's turn α) about its point at
    ξ = ``pivot``; same variate and extent. The turned line's offset at the pivot is the
    same, so a c0 error means what it meant before (a turn state reset to zero after its
    estimate was applied keeps its covariance). The arithmetic is one compiled call
    (:func:`~polyslam_env.slam.map_kernels.turned_line`)."""
    if np.any(poly.coeffs[2:] != 0.0):
        raise ValueError("turned_line: the polynomial must be a straight line")
    c0, slope = map_kernels.turned_line(
        float(poly.coeffs[0]), float(poly.coeffs[1]), poly.variate, float(pivot), float(angle)
    )
    coeffs = np.zeros_like(poly.coeffs)
    coeffs[0], coeffs[1] = c0, slope
    return Polynomial(poly.variate, coeffs, poly.lo, poly.hi)


#: m: straight walls at least this long give a direction to the exchange's square check
#: (comms/alignment.py ``square_turn``): a short
#: piece's fitted direction is loose (a degree or more), and a round column's arc fitted as a
#: line (0.24–0.4 m) has none.
SQUARE_MIN_LENGTH = 1.0
#: Share of the confident straight walls' length that may be off square on a floor still
#: taken as rectilinear: turned furniture or a traced building's clutter among square walls
#: (a design choice, stated: one wall in ten of an otherwise square floor). An angled wing or
#: a cave's straight stretches hold more, and then no wall is tied.
SQUARE_CLUTTER = 0.1


def pair_supported(
    first: int, second: int, directions: np.ndarray, relative_var: np.ndarray, gate_prob: float
) -> bool:
    """Whether walls ``first`` and ``second`` (indices into ``directions`` (n,) rad, with
    ``relative_var`` (n, n) as :func:`rectilinear`'s) have a third wall square to both, each
    within the χ²(1) gate at ``gate_prob``: the robot's own evidence that *these* two
    directions belong to one rectilinear set (``SlamConfig.square_pair_evidence``). A pair
    alone is no evidence (its own gate judges only that it could be square); a floor-wide
    share (:func:`rectilinear`) is the wrong grain where square rooms meet angled wings or
    clutter. The caller leaves out walls that are pieces of either of the two."""
    gate = chi2_1dof_quantile(gate_prob)
    difference = directions[:, None] - directions[None, [first, second]]
    quarter = 0.5 * math.pi
    off = difference - quarter * np.round(difference / quarter)  # (n, 2)
    square = off**2 <= gate * relative_var[:, [first, second]]
    both = square[:, 0] & square[:, 1]
    both[[first, second]] = False
    return bool(both.any())


def rectilinear(
    directions: np.ndarray, relative_var: np.ndarray, lengths: np.ndarray, gate_prob: float
) -> bool:
    """Whether straight walls of ``directions`` (n,) (rad), variances of their pairwise
    differences ``relative_var`` (n, n) (rad², the state's var(α_i − α_j) plus each fit's
    direction variance and the squareness noise, as a tie's innovation) and ``lengths`` (n,)
    (m) are the walls of a rectilinear floor: the walls square to one of them (itself
    included) hold all but :data:`SQUARE_CLUTTER` of the total length. A wall is square to
    the reference when its angle to it is within the χ²(1) gate from a multiple of 90°, at
    ``gate_prob`` for the n − 1 walls judged together (Bonferroni: each at 1 − (1 −
    ``gate_prob``)/(n − 1)), so that a square floor's walls are all judged square with that
    probability. Fewer than three walls are no evidence (True): two are one pair, which the
    tie's own gate judges."""
    n = directions.size
    if n < 3:
        return True
    difference = directions[:, None] - directions[None, :]
    quarter = 0.5 * math.pi
    off = difference - quarter * np.round(difference / quarter)  # off_square, elementwise
    gate = chi2_1dof_quantile(1.0 - (1.0 - gate_prob) / (n - 1))
    square = off**2 <= gate * relative_var
    support = square.astype(float) @ lengths  # per reference wall: the length square to it
    return bool(support.max() >= (1.0 - SQUARE_CLUTTER) * lengths.sum())

"""Refining a rendezvous transform on the walls both maps hold (received walls → own walls).

The camera fixes the transform T_{l0,j0} between the sender's and the receiver's frames to
about 1.4° in heading (1° bearing noise on each side) and 2–3 cm in position; a received wall
3 m from the meeting point is then several centimetres off. Where the received walls overlap
walls the receiver already holds, those overlaps measure T much better.

:func:`align_transform` is a maximum a posteriori estimate of T: the camera's estimate t0 with
its covariance Σ_T is the prior; every point of a received chain that lies, once mapped, within
the extent of a receiver's landmark of the same direction and within a 3σ gate of it gives a
residual (its normal distance to that landmark), weighted so that each (chain, landmark) pair
counts as **one** observation (the points of one wall share its errors: they are not
independent) whose variance is the range noise's plus each map's own error of that wall along
its normal (both maps drift from their robots' true starts, so two walls that are one wall in
the world disagree by both errors). Gauss–Newton, correspondences found again at every
iteration. A result that the camera noise makes unlikely (Mahalanobis distance from t0 above
the χ²₃ 99 % quantile) is refused: the walls were matched to the wrong ones.

The posterior covariance (Σ_T⁻¹ + Jᵀ W J)⁻¹ is scaled by the a-posteriori variance factor
when the pairs' residuals exceed their variances (never shrunk): the exchange keeps a
received point only where this covariance moves it little, so an overconfident transform
would let whole walls in far from where the maps overlap.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from polyslam_env.comms.kernels import (
    chain_tangents,
    frame_chain,
    gauss_newton,
    inverse3,
    prior_information,
    reach_boxes,
)
from polyslam_env.core.geometry import rotation
from polyslam_env.slam.links import SQUARE_MIN_LENGTH, line_angle, off_square
from polyslam_env.slam.polynomial import Polynomial

#: χ²₃ 99 % quantile: a correction of T further than this (in Σ_T's metric) is refused, and
#: so is a refinement whose restarts (below) end further than this from it in its own
#: posterior's metric.
CHI2_3DOF_99 = 11.345
#: With restarts, the refinement is run again from t0 ± this many σ along each principal
#: axis of Σ_T, the region where the camera puts the truth (each axis 95 %); repeating walls
#: (shelf rows, a corridor's doors) can hold a second basin there, and a solution that
#: depends on where the search starts is not an estimate.
RESTART_SIGMAS = 2.0
GATE_SIGMAS = 3.0  # a point pairs with a wall within 3σ of its predicted normal distance
MAX_ANGLE_DEG = 30.0  # same direction: tangents within 30° (the merge test's angle)
_SIN_MAX = float(np.sqrt(1 - np.cos(np.radians(MAX_ANGLE_DEG)) ** 2))  # |n·tangent| at most


class WallArrays(NamedTuple):
    """The receiver's walls as the refinement's kernels read them (:func:`pack_walls`, or a
    landmark table's columns: a row's zero tail changes no value the kernels compute)."""

    order: np.ndarray  # (W,) int64: wall w's coefficients are coeffs[w, : order[w] + 1]
    variate: np.ndarray  # (W,) int64, 1 or 2
    coeffs: np.ndarray  # (W, M+1) float, current c0 first, zero-padded
    extent: np.ndarray  # (W, 2) lo, hi


def pack_walls(walls: Sequence[Polynomial] | WallArrays) -> WallArrays:
    """``walls`` as :class:`WallArrays` (unchanged if they are already)."""
    if isinstance(walls, WallArrays):
        return walls
    width = max((poly.order + 1 for poly in walls), default=2)
    coeffs = np.zeros((len(walls), width))
    for w, poly in enumerate(walls):
        coeffs[w, : poly.order + 1] = poly.coeffs
    return WallArrays(
        np.array([poly.order for poly in walls], dtype=np.int64),
        np.array([poly.variate for poly in walls], dtype=np.int64),
        coeffs,
        np.array([(poly.lo, poly.hi) for poly in walls], dtype=float).reshape(-1, 2),
    )


def frame_points(q: np.ndarray, transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``q`` (N, 2) of the sender's frame in the receiver's, p = R(θ) q + t, and the
    Jacobian ∂p/∂T (N, 2, 3) w.r.t. T = (t_x, t_y, θ). Compiled:
    :func:`~polyslam_env.comms.kernels.frame_chain` (R from numpy's cos and sin)."""
    t = np.asarray(transform, dtype=float)
    return frame_chain(np.asarray(q, dtype=float), t, rotation(float(t[2])))


def align_transform(
    t0: np.ndarray,
    cov_t: np.ndarray,
    chains: Sequence[np.ndarray],
    walls: Sequence[Polynomial],
    sigma: float,
    iterations: int = 5,
) -> np.ndarray:
    """:func:`refine_transform`'s transform only."""
    return refine_transform(t0, cov_t, chains, walls, sigma, iterations)[0]


def refine_transform(
    t0: np.ndarray,
    cov_t: np.ndarray,
    chains: Sequence[np.ndarray],
    walls: Sequence[Polynomial] | WallArrays,
    sigma: float,
    iterations: int = 5,
    chain_var: Sequence[float] | np.ndarray | None = None,
    wall_var: Sequence[float] | np.ndarray | None = None,
    restarts: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """MAP refinement (3,) of the transform ``t0`` (3,) with prior covariance ``cov_t``
    (3, 3), from received ``chains`` (each (N_k, 2), sender frame, points along a curve) and
    the receiver's ``walls`` (with their current c0; polynomials or :class:`WallArrays`). One
    (chain k, wall w) pair's offset has variance σ² + ``chain_var[k]`` + ``wall_var[w]``
    (m²): ``sigma`` of the range noise, and each map's own error of that wall along its
    normal (both maps drift from their robots' true starts; weighed by the range noise
    alone, the posterior is overconfident: ``tests/comms/test_alignment.py``); the variances
    default to zero.
    Returns the transform and its posterior covariance (Σ_T⁻¹ + Jᵀ W J)⁻¹ at the
    solution; ``(t0, cov_t)`` when nothing matches, Σ_T is singular, or the correction fails
    the χ²₃ 99 % test. With ``restarts`` (``channel.align_restarts``, an option) also when the
    solution is not unique: the same refinement started from t0 ± :data:`RESTART_SIGMAS` σ
    along each principal axis of Σ_T ends further from it than the χ²₃ 99 % quantile in its
    posterior's metric (a second basin, as in repeating shelf rows, where a transform refined
    1.6 m and 5° off the truth with a posterior σ of 3 cm was accepted; docs/design/exchange.md
    says why this is an option)."""
    t0 = np.asarray(t0, dtype=float)
    cov_t = np.asarray(cov_t, dtype=float)
    args = (chains, pack_walls(walls), sigma, iterations, chain_var, wall_var)
    found = _refine_from(t0, t0, cov_t, *args)
    if found is None:
        return t0, cov_t
    t, posterior = found
    if not restarts:
        return t, posterior
    info = np.linalg.inv(posterior)
    values, vectors = np.linalg.eigh(cov_t)
    for k in range(3):
        for sign in (-1.0, 1.0):
            start = t0 + sign * RESTART_SIGMAS * np.sqrt(max(values[k], 0.0)) * vectors[:, k]
            other = _refine_from(start, t0, cov_t, *args)
            if other is not None:
                d = other[0] - t
                if float(d @ info @ d) > CHI2_3DOF_99:
                    return t0, cov_t
    return t, posterior


def _refine_from(
    start: np.ndarray,
    t0: np.ndarray,
    cov_t: np.ndarray,
    chains: Sequence[np.ndarray],
    walls: WallArrays,
    sigma: float,
    iterations: int,
    chain_var: Sequence[float] | np.ndarray | None,
    wall_var: Sequence[float] | np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`refine_transform`'s Gauss–Newton from ``start`` with the prior N(t0, cov_t):
    the solution and its posterior covariance, or None when nothing matches, Σ_T is
    singular, or the correction fails the χ²₃ 99 % test."""
    info_prior, definite = prior_information(cov_t)  # (3, 3) Σ⁻¹ = L⁻ᵀ L⁻¹
    if not definite:
        return None
    n_walls = len(walls.order)
    if not n_walls or not chains:
        return None
    lengths = np.array([len(c) for c in chains], dtype=np.int64)
    q = np.concatenate(chains).astype(float, copy=False)  # (N, 2)
    starts = np.zeros(len(chains) + 1, dtype=np.int64)  # chain k is rows starts[k]:starts[k+1]
    np.cumsum(lengths, out=starts[1:])
    chain_of = np.repeat(np.arange(len(chains)), lengths)  # (N,) each point's chain
    var_c = np.zeros(len(chains)) if chain_var is None else np.asarray(chain_var, dtype=float)
    var_w = np.zeros(n_walls) if wall_var is None else np.asarray(wall_var, dtype=float)
    if var_c.shape != (len(chains),) or var_w.shape != (n_walls,):
        raise ValueError("chain_var and wall_var need one variance per chain and per wall")
    point_var = sigma * sigma + var_c[chain_of]  # (N,) before the wall's share
    tangents_q = chain_tangents(q, starts)  # (N, 2) sender frame
    reach = wall_reach(walls, var_w, cov_t, point_var, q)
    # the iterations, each pairing (``match_walls`` on the chains ``near_chains`` gives) and
    # weighing the points so that each (chain, wall) pair counts once: one compiled call
    t, info, residual, weight, n_pairs, regular = gauss_newton(
        q, tangents_q, starts, chain_of, np.asarray(start, dtype=float), t0, info_prior, reach,
        walls.variate, walls.coeffs, walls.extent, cov_t, point_var, var_w, GATE_SIGMAS,
        _SIN_MAX, iterations,
    )  # fmt: skip
    if not regular:
        raise np.linalg.LinAlgError("Singular matrix")  # as np.linalg.solve
    if not len(residual):
        return None
    d = t - t0
    if float(d @ info_prior @ d) > CHI2_3DOF_99:
        return None
    posterior, regular = inverse3(info)
    if not regular:
        raise np.linalg.LinAlgError("Singular matrix")  # as np.linalg.inv
    # a-posteriori variance factor: the pairs' normalised residuals at the solution (each
    # pair one observation) against their count; residuals larger than their variances
    # say (map errors the variances miss, errors shared by many walls) scale it up, never
    # down (Förstner & Wrobel's σ̂₀², capped below at 1)
    factor = max(1.0, float(weight @ (residual * residual)) / n_pairs)
    return t, factor * 0.5 * (posterior + posterior.T)


def is_straight_wall(poly: Polynomial, min_length: float = SQUARE_MIN_LENGTH) -> bool:
    """Whether ``poly`` is straight (no coefficient past the slope) and at least
    ``min_length`` long along ξ."""
    return bool(poly.hi - poly.lo >= min_length) and not any(poly.coeffs[2:].tolist())


def straight_walls(
    polys: Sequence[Polynomial], min_length: float = SQUARE_MIN_LENGTH
) -> list[tuple[float, float]]:
    """(direction, length) of each of ``polys`` that :func:`is_straight_wall`:
    :func:`~polyslam_env.slam.links.line_angle`."""
    return [(line_angle(p), float(p.hi - p.lo)) for p in polys if is_straight_wall(p, min_length)]


def square_turn(
    sent: Sequence[tuple[float, float]], held: Sequence[tuple[float, float]], turn: float
) -> float | None:
    """The transform's turn (rad) nearest ``turn`` that lays the sender's straight walls
    ``sent`` square to the receiver's ``held`` (each (direction in its own frame, length), as
    :func:`straight_walls` gives them): both maps' walls are tied square among themselves
    (``SlamConfig.square_walls``), so T's turn is the difference of their directions modulo
    90°. Each sent wall gives one such turn against the longest held wall; the answer is their
    length-weighted median (a wall the sender mapped off square does not move it). None when
    either side has no straight wall."""
    if not sent or not held:
        return None
    reference = max(held, key=lambda w: w[1])[0]
    turns = [turn - off_square(d + turn - reference) for d, _ in sent]
    # numpy's argsort (its order of ties), then the weights' running sums (np.cumsum's, one
    # by one) and the first reaching half the total (np.searchsorted's on sums that only grow)
    order = np.argsort(turns).tolist()
    cumulative = list(itertools.accumulate(sent[k][1] for k in order))
    return float(turns[order[bisect.bisect_left(cumulative, 0.5 * cumulative[-1])]])


def wall_reach(
    walls: Sequence[Polynomial] | WallArrays,
    wall_var: np.ndarray,
    cov_t: np.ndarray,
    point_var: np.ndarray,
    q: np.ndarray,
) -> np.ndarray:
    """(W, 4) boxes [x_lo, x_hi, y_lo, y_hi], each holding every place where a point can pair with
    that wall in :func:`~polyslam_env.comms.kernels.match_walls`: inside its extent (ξ ∈ [lo, hi])
    and within the gate, |r| ≤ GATE_SIGMAS·pred with r the η offset over √(1 + B'²). Bounds: pred² =
    gᵀΣ_T g + point_var + wall_var with g = nᵀ ∂p/∂T = (n_x, n_y, nᵀJR q), so |g|² ≤ 1 + |q|² and
    gᵀΣ_T g ≤ tr(Σ_T)(1 + max |q|²); the η offset is at most |r| √(1 + max B'²) (the slope's exact
    maximum over the extent, ``Polynomial.max_slope``); B over the extent lies in
    :func:`~polyslam_env.slam.map_kernels.eta_range` (interval arithmetic, padded), and 1e-9 m more
    covers the rounding of c0 + B. Compiled wall by wall
    (:func:`~polyslam_env.comms.kernels.reach_boxes`); slopes of orders ≥ 4 (a root finder) from
    ``Polynomial.max_slope``."""
    walls = pack_walls(walls)
    slopes = np.full(len(walls.order), -1.0)
    for w in np.flatnonzero(walls.order > 3).tolist():
        c = walls.coeffs[w, : walls.order[w] + 1]
        slopes[w] = Polynomial.unchecked(1, c, *walls.extent[w].tolist()).max_slope()
    return reach_boxes(
        walls.order, walls.variate, walls.coeffs, walls.extent, slopes,
        np.asarray(wall_var, dtype=float), np.asarray(cov_t, dtype=float),
        np.asarray(q, dtype=float), np.asarray(point_var, dtype=float), GATE_SIGMAS,
    )  # fmt: skip

"""Map merging (paper §3.3, SPEC §3 "Map merging").

When a new (or received) polynomial p overlaps a map polynomial p2 — one's extent includes
the other's, or they overlap for at least ``min_overlap`` metres — take m+1 equally spaced
points on p in the overlap; if the RMS approximation error γ of p2 on them is below γ_M the
two are replaced by one weighted LMS polynomial through ε_M equally spaced points on each
(:func:`merge_fit`: the points and :func:`~polyslam_env.slam.fitting.fit_polynomial`'s fit
of them).

Choices where the paper is silent:

* overlap is measured on the new polynomial's independent axis ξ: p2 is sampled and projected
  on it, so polynomials of different variates compare geometrically;
* ``min_overlap`` defaults to 0.1 m (about two beam spacings at 1 m range: shorter overlaps are
  end-to-end contacts of successive walls, not the same stretch of wall);
* γ is checked both ways (p2 on points of p, and p on points of p2 in the overlap) and the
  tangents of the two curves in the overlap must be within ``max_angle_deg`` (30°): with the
  paper's γ_M = 0.35 m the one-sided test alone would merge perpendicular walls at a corner,
  whose projection on p's axis is a short interval "included" in p.

One wall, one landmark (issue 14). The paper merges only overlapping polynomials, so a wall
seen piece by piece stays a chain of short landmarks whose ends touch or overlap by a few
centimetres (on a 20 × 12 m rooms map about 10 % of the map's length lay within 10 cm of, and
parallel to, another polynomial). With ``join_gap`` set, :func:`find_merge` also proposes
**joins**: two polynomials whose nearer end points are within ``join_gap`` (default
:data:`JOIN_GAP`), whose tangents there agree within :data:`JOIN_ANGLE_DEG` and whose end
points each lie within :data:`THIN_WALL` of the other's tangent line at its end. The caller
fits one polynomial through both (the merged fit) and keeps it only if that fit explains
both within its acceptance RMS, as for any new landmark.

Faces: a wall's face is seen from one side only. ``sides`` gives each landmark's observed
side (+1: the beams came from its +η side, −1: from −η, 0: unknown, e.g. received). Two
landmarks seen from opposite sides are the two faces of a wall (or two walls of a corridor)
and merge only when their distance γ is at most :data:`THIN_WALL` — a wall thinner than that is
one curve at this sensor's resolution (2.5 σ of the 2 cm range noise), while the faces of a
10 cm wall stay apart.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from polyslam_env.slam import fit_kernels, map_kernels
from polyslam_env.slam.association import GAP_SPLIT
from polyslam_env.slam.fitting import (
    Fit,
    PointSet,
    check_fit_size,
    fit_limits,
    fit_of,
    sample_args,
)
from polyslam_env.slam.polynomial import Polynomial

if TYPE_CHECKING:
    from polyslam_env.slam.landmarks import LandmarkTable

#: m, largest gap between the nearer end points of two pieces that may be joined into one
#: landmark: the gap below which points along a wall are sampling, not a doorway — the same
#: threshold a cluster fit is cut at (``association.GAP_SPLIT``), so a join never bridges
#: what a fit would have split. Pieces of one wall re-observed after a few cm of drift start
#: a little past the old end (the points between went to a cluster), ~0.15 m in the tests.
JOIN_GAP = GAP_SPLIT
#: degrees: tangents of two overlapping pieces of one wall agree within this (the merge test).
MERGE_ANGLE_DEG = 30.0
#: degrees: tangents of two pieces joined end to end must agree within this (the
#: ``duplicates`` metric's notion of parallel, SPEC §5).
JOIN_ANGLE_DEG = 10.0
#: m, 2.5 × the 2 cm range noise: the largest lateral offset between two pieces of one
#: face that noise explains; also the thickness below which two opposite faces are one curve.
THIN_WALL = 0.05


def merge_angle(poly: Polynomial, other: Polynomial, a: float, b: float, xi_other: float) -> float:
    """Angle (rad) between the tangents of ``poly`` at the middle of the overlap [a, b] and of
    ``other`` at ``xi_other`` (the middle of its samples there: ``map_kernels.merge_test``)."""
    cosine = map_kernels.merge_cosine(
        poly.variate, poly.coeffs, 0.5 * (a + b), other.variate, other.coeffs, xi_other
    )
    return float(np.arccos(cosine))


def unit_tangent(poly: Polynomial, xi: float) -> np.ndarray:
    """(2,) unit tangent of the curve at ξ, in (x¹, x²)."""
    slope = poly.slope_at(xi)
    t = np.array([1.0, slope]) if poly.variate == 1 else np.array([slope, 1.0])
    return t / math.sqrt(t.dot(t))  # np.linalg.norm's own arithmetic, without its checks


class MergeChoice(NamedTuple):
    """The partner chosen by :func:`choose_merge` and whether it is an end-to-end join."""

    partner: int  # index into the candidates given
    gamma: float
    joined: bool


def find_merge(
    new_poly: Polynomial,
    new_c0: float,
    polys: Sequence[Polynomial],
    c0s: Sequence[float] | np.ndarray,
    gamma_max: float,
    min_overlap: float = 0.1,
    max_angle_deg: float = MERGE_ANGLE_DEG,
    exclude: int | None = None,
    *,
    new_side: int = 0,
    sides: Sequence[int] | None = None,
    join_gap: float | None = None,
) -> int | None:
    """Index of the map polynomial to merge ``new_poly`` with (see :func:`choose_merge`)."""
    choice = choose_merge(
        new_poly,
        new_c0,
        polys,
        c0s,
        gamma_max,
        min_overlap,
        max_angle_deg,
        exclude,
        new_side=new_side,
        sides=sides,
        join_gap=join_gap,
    )
    return None if choice is None else choice.partner


def choose_merge(
    new_poly: Polynomial,
    new_c0: float,
    polys: Sequence[Polynomial],
    c0s: Sequence[float] | np.ndarray,
    gamma_max: float,
    min_overlap: float = 0.1,
    max_angle_deg: float = MERGE_ANGLE_DEG,
    exclude: int | None = None,
    *,
    new_side: int = 0,
    sides: Sequence[int] | None = None,
    join_gap: float | None = None,
) -> MergeChoice | None:
    """The map polynomial to merge ``new_poly`` with (smallest γ < γ_M), or None.

    ``exclude`` skips one index (the new polynomial itself when it is already in the map).
    ``new_side`` / ``sides`` are the observed faces (see the module docstring; 0 or None:
    unknown, any pairing allowed); a pair seen from opposite sides needs γ ≤ :data:`THIN_WALL`.
    With ``join_gap`` (m) pieces that do not overlap enough are joined end to end when
    :func:`join_gamma` accepts them (their γ is that function's offset).
    """
    p = new_poly.with_c0(new_c0)
    others = [p2.with_c0(float(c02)) for p2, c02 in zip(polys, c0s, strict=True)]
    gammas, joined = merge_gammas(p, candidates_of(others), min_overlap, max_angle_deg, join_gap)
    return pick_merge(p, gammas, joined, gamma_max, others.__getitem__, exclude, new_side, sides)


class Candidates(NamedTuple):
    """Polynomials to test a merge against, as arrays (:func:`merge_gammas`): the candidates'
    rows of columns holding each one's variate, coefficient row (its first entry is replaced
    by its c0), number of coefficients, c0 and extent. :func:`table_candidates` gives a map's
    columns themselves (no copies); :func:`candidates_of` packs polynomials."""

    rows: np.ndarray  # (k,) int64: the candidates, in order
    variate: np.ndarray  # (n,) int64
    shape: np.ndarray  # (n, W)
    size: np.ndarray  # (n,) int64
    c0: np.ndarray  # (n,)
    lo: np.ndarray  # (n,)
    hi: np.ndarray  # (n,)


def candidates_of(polys: Sequence[Polynomial]) -> Candidates:
    """:class:`Candidates` of polynomials that carry their c0."""
    k = len(polys)
    width = max((p.coeffs.size for p in polys), default=2)
    shape = np.zeros((k, width))
    for i, p in enumerate(polys):
        shape[i, : p.coeffs.size] = p.coeffs
    return Candidates(
        np.arange(k, dtype=np.int64),
        np.array([p.variate for p in polys], dtype=np.int64),
        shape,
        np.array([p.coeffs.size for p in polys], dtype=np.int64),
        shape[:, 0].copy(),
        np.array([p.lo for p in polys], dtype=float),
        np.array([p.hi for p in polys], dtype=float),
    )


def table_candidates(table: LandmarkTable, rows: np.ndarray, c0s: np.ndarray) -> Candidates:
    """:class:`Candidates` of a map's landmarks ``rows`` (int64) at the c0s ``c0s`` (n,): its
    columns as they are, each row at its polynomial's number of coefficients
    (:meth:`~polyslam_env.slam.landmarks.LandmarkTable.sizes`)."""
    return Candidates(rows, table.variate, table.shape, table.sizes, c0s, table.lo, table.hi)


def merge_gammas(
    p: Polynomial,
    candidates: Candidates,
    min_overlap: float,
    max_angle_deg: float = MERGE_ANGLE_DEG,
    join_gap: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(γ (k,), joined (k,)) of ``p`` (with its c0) against each candidate: its γ where they
    overlap by at least ``min_overlap`` (``map_kernels.merge_test``) and their tangents there
    agree within ``max_angle_deg``; else, with ``join_gap``, the offset of an end-to-end join
    (:func:`join_gamma`, ``joined`` True); nan where neither counts. One compiled call
    (:func:`~polyslam_env.slam.map_kernels.merge_candidates`)."""
    k = candidates.rows.size
    gammas, joined = np.empty(k), np.empty(k, dtype=np.bool_)
    map_kernels.merge_candidates(
        p.variate, p.coeffs, p.lo, p.hi, *candidates, min_overlap, max_angle_deg,
        math.nan if join_gap is None else join_gap, JOIN_ANGLE_DEG, THIN_WALL, gammas, joined,
    )  # fmt: skip
    return gammas, joined


def near_merge_gammas(
    p: Polynomial,
    table: LandmarkTable,
    c0s: np.ndarray,
    boxes: np.ndarray,
    box: np.ndarray,
    distance: float,
    min_overlap: float,
    exclude: int = -1,
    join_gap: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of a map's ``table`` (at the c0s ``c0s``) whose ``boxes`` (n, 4) lie within
    ``distance`` of ``box`` (4,) (ascending, without row ``exclude``: −1 none) and
    :func:`merge_gammas`' (γ, joined) of ``p`` against them (:func:`table_candidates`), in
    one compiled call (:func:`~polyslam_env.slam.map_kernels.near_merge_candidates`): the
    map's merge check and the exchange's same-wall test ask for it on every change."""
    columns = table_candidates(table, _NO_ROWS, c0s)[1:]  # the rows are the kernel's to find
    return map_kernels.near_merge_candidates(
        p.variate, p.coeffs, p.lo, p.hi, boxes, box, distance, exclude, *columns, min_overlap,
        MERGE_ANGLE_DEG, math.nan if join_gap is None else join_gap, JOIN_ANGLE_DEG, THIN_WALL,
    )  # fmt: skip


_NO_ROWS = np.zeros(0, dtype=np.int64)


def pick_merge(
    p: Polynomial,
    gammas: np.ndarray,
    joined: np.ndarray,
    gamma_max: float,
    other: Callable[[int], Polynomial],
    exclude: int | None = None,
    new_side: int = 0,
    sides: Sequence[int] | None = None,
) -> MergeChoice | None:
    """:func:`choose_merge`'s choice from :func:`merge_gammas`' answers: the smallest γ below
    γ_M (the first of ties), a pair of opposite faces only below :data:`THIN_WALL`;
    ``other(j)`` gives candidate j's polynomial with its c0 (read only for such a pair)."""
    best: MergeChoice | None = None
    best_gamma = gamma_max
    for j, (gamma, join) in enumerate(zip(gammas.tolist(), joined.tolist(), strict=True)):
        if j == exclude:
            continue
        side = 0 if sides is None else int(sides[j])
        opposite = new_side * side < 0 and _faces_opposite(p, new_side, other(j), side)
        limit = min(best_gamma, THIN_WALL) if opposite else best_gamma
        if gamma < limit:  # nan: neither an overlap nor a join counts
            best, best_gamma = MergeChoice(j, gamma, join), gamma
    return best


def join_gamma(poly: Polynomial, other: Polynomial, max_gap: float) -> float | None:
    """Lateral offset (m) of two pieces meeting end to end, or None if they cannot be joined.

    The nearer pair of end points must be within ``max_gap``; the tangents there within
    :data:`JOIN_ANGLE_DEG`; the offset is the larger distance of each end point from the other
    curve's tangent line at its end, and must be at most :data:`THIN_WALL`. One compiled call
    (:func:`~polyslam_env.slam.map_kernels.join_offset`; its readable numpy version is the
    oracle in ``tests/slam/reference_merging.py``): every map change and every received piece
    tries it against its neighbours.
    """
    offset = map_kernels.join_offset(
        poly.variate, poly.coeffs, poly.lo, poly.hi, other.variate, other.coeffs, other.lo,
        other.hi, max_gap, JOIN_ANGLE_DEG, THIN_WALL,
    )  # fmt: skip
    return None if math.isnan(offset) else float(offset)


def face_normal(poly: Polynomial, xi: float, side: int) -> np.ndarray:
    """(2,) unit normal at ξ pointing to the side the face was seen from (side ±1)."""
    t = unit_tangent(poly, xi)
    # +90° turns the tangent (1, B') to +η for variate 1; −90° turns (B', 1) to +η (= +x¹)
    plus_eta = np.array([-t[1], t[0]]) if poly.variate == 1 else np.array([t[1], -t[0]])
    return np.asarray(side * plus_eta)


def _faces_opposite(poly: Polynomial, side: int, other: Polynomial, other_side: int) -> bool:
    """Whether the two faces look in opposite directions (normals at their middles)."""
    n_p = face_normal(poly, 0.5 * (poly.lo + poly.hi), side)
    n_o = face_normal(other, 0.5 * (other.lo + other.hi), other_side)
    return float(n_p @ n_o) < 0.0


def merge_fit(
    poly_a: Polynomial,
    c0_index_a: int,
    c0_var_a: float,
    poly_b: Polynomial,
    c0_index_b: int,
    c0_var_b: float,
    eps_m: int,
    n_state: int,
    turn_a: tuple[int, float] | None,
    turn_b: tuple[int, float] | None,
    fit_settings: tuple[int, bool, float, bool],
) -> tuple[PointSet, Fit]:
    """ε_M equally spaced points on each polynomial (whole extents) and their merged LMS fit,
    in one compiled call (:func:`~polyslam_env.slam.fit_kernels.merge_fit`).

    Both polynomials must carry their current c0; each set weighs 1/var(c0) of its own
    landmark, so the fit's G_x has entries on both c0s, and on their turns α with ``turn_a``,
    ``turn_b`` = (α's state index, pivot ξ) (:func:`~polyslam_env.slam.fitting.
    polynomial_points`). The fit is :func:`~polyslam_env.slam.fitting.fit_polynomial`'s,
    shape fixed, with ``fit_settings`` = (order, auto_order, min_noise_var, curvature_test);
    the points-then-fit form is the oracle in ``tests/slam/reference_merging.py``.
    """
    n = 2 * eps_m
    order, auto_order, min_noise_var, curvature_test = fit_settings
    check_fit_size(n, order)
    a_c0, a_turn = sample_args(c0_index_a, c0_var_a, turn_a, n_state)
    b_c0, b_turn = sample_args(c0_index_b, c0_var_b, turn_b, n_state)
    noise_cov = np.zeros((0, 0))  # points sampled on polynomials: no noise of their own
    limits = fit_limits(n, 0.0, order, auto_order, min_noise_var, curvature_test)
    xy, d_state, weights, var, m, coeffs, lo, hi, rms, gx, gy, r, scale = fit_kernels.merge_fit(
        poly_a.coeffs, poly_a.variate, (float(poly_a.lo), float(poly_a.hi)), a_c0, a_turn,
        poly_b.coeffs, poly_b.variate, (float(poly_b.lo), float(poly_b.hi)), b_c0, b_turn,
        eps_m, n_state, order, auto_order, limits,
    )  # fmt: skip
    # sample_args checked what the points are made of (weights 1/var(c0) > 0)
    points = PointSet.unchecked(xy, d_state, np.zeros((n, 2, 0)), noise_cov, weights)
    return points, fit_of((var, m, coeffs, lo, hi, rms, gx, gy, r, scale), noise_cov)

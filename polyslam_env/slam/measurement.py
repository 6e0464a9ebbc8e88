"""Range measurement model h of the polynomial SLAM and its Jacobian (SPEC §3), per beam.

A beam leaves the robot at heading φ = θ + β and travels ``t`` metres. It meets a map
polynomial where F(t) = η0 + t·dη − c0 − B(ξ0 + t·dξ) = 0, with (ξ0, η0) the robot position
in the polynomial's (independent, dependent) coordinates and (dξ, dη) the beam direction in
the same order: x¹-variate gives ξ0 = x, η0 = y, dξ = cos φ, dη = sin φ; x²-variate swaps
them. ``B`` is the shape polynomial without constant term; ``c0`` comes from the EKF state.

h is the smallest real root 0 < t ≤ r_max whose ξ lies in the extent, minimised over all
polynomials: Taylor coefficients of B at the robot, F(s) in s = t/r_max, closed-form roots
(degree ≤ 3, companion matrices above) with a stiff-row fallback and its Newton refinement,
the nearest admissible root (first minimum in (landmark, root) order), one guarded Newton
polish, then ξ*, B'(ξ*) and D. The row of H follows by implicit differentiation of
F(t*) = 0: ∂h/∂v = −(∂F/∂v)/(∂F/∂t) with ∂F/∂t = D = dη − B'·dξ, i.e. ∂h/∂ξ0 = B'/D,
∂h/∂η0 = −1/D, ∂h/∂c0 = 1/D and ∂h/∂θ = −t*(dη' − B'·dξ')/D (' is d/dφ): for the x¹-variate
case the SPEC's (B'/D, −1/D, −t*(cos φ + B' sin φ)/D, 1/D), for the x²-variate case
(−1/D, B'/D, t*(sin φ + B' cos φ)/D, 1/D).

Both run compiled, a whole scan per call (:func:`~polyslam_env.slam.kernels.cast_scan`,
:func:`~polyslam_env.slam.kernels.beam_rows`); this module is their typed front. The readable
per-beam float version they replaced and the vectorised version over beams × polynomials are
the test oracles in ``tests/slam/reference.py`` (bit-identical up to order 3; the companion
roots of orders 4–5 agree to rounding).

Shapes are passed per landmark as :class:`~polyslam_env.slam.landmarks.ShapeArrays` (e.g.
``LandmarkTable.arrays()``) or as rows (:class:`~polyslam_env.slam.landmarks.ShapeRow`), each
trimmed to the landmark's own order: trailing zero coefficients change no root.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from polyslam_env.slam import kernels
from polyslam_env.slam.kernels import (
    BOX_MARGIN,
    DEGREE_DROP_TOL,
    IMAG_TOL,
    MAX_ORDER,
    POLISH_MAX,
    REAL_TOL,
    STIFF_TOL,
)
from polyslam_env.slam.landmarks import ShapeArrays, ShapeRow, shape_arrays

__all__ = [
    "BOX_MARGIN",
    "DEGREE_DROP_TOL",
    "IMAG_TOL",
    "POLISH_MAX",
    "REAL_TOL",
    "STIFF_TOL",
    "BeamHit",
    "Rows",
    "cast",
    "range_rows",
]


class BeamHit(NamedTuple):
    """The nearest admissible hit of one beam."""

    t: float  # range t* (m)
    landmark: int  # index into the candidates' landmark numbering (state index − 3)
    slope: float  # B'(ξ*)
    denom: float  # D = dη − B'·dξ
    phi: float  # beam heading θ + β
    variate: int  # variate of the landmark hit
    xi: float  # ξ* of the hit


class Rows(NamedTuple):
    """EKF rows of range measurements that touch the pose and one c0 each."""

    innovation: np.ndarray  # (k,) z − h
    h_pose: np.ndarray  # (k, 3) ∂h/∂(x¹, x², θ)
    c0_index: np.ndarray  # (k,) int64 state index of the c0 hit
    h_c0: np.ndarray  # (k,) ∂h/∂c0 = 1/D
    variance: np.ndarray  # (k,) R diagonal


def _checked(
    shapes: ShapeArrays | Sequence[ShapeRow],
    candidates: Sequence[int] | np.ndarray,
    c0s: Sequence[float] | np.ndarray,
    boxes: Sequence[Sequence[float]] | np.ndarray | None,
) -> tuple[ShapeArrays, np.ndarray, np.ndarray, np.ndarray]:
    """The kernels' arrays: shapes, candidates (int64), c0s, boxes (n, 4) (inf: no pruning).

    ``boxes`` has one row per landmark (n, 4) or one per candidate (K, 4)."""
    arrays = shape_arrays(shapes)
    n = len(arrays.variate)
    cand = np.asarray(candidates, dtype=np.int64).reshape(-1)
    c0 = np.ascontiguousarray(c0s, dtype=float)
    if c0.shape != (n,):
        raise ValueError(f"c0s must have shape ({n},), got {c0.shape}")
    if cand.size and (cand.min() < 0 or cand.max() >= n):
        raise ValueError(f"candidates must index the {n} landmarks, got {cand.tolist()}")
    if arrays.shape.shape[1] > MAX_ORDER + 1:
        raise ValueError(f"shape order {arrays.shape.shape[1] - 1} above {MAX_ORDER}")
    if boxes is None:
        box = np.tile(np.array([-math.inf, math.inf, -math.inf, math.inf]), (n, 1))
    else:
        box = np.asarray(boxes, dtype=float).reshape(-1, 4)
        if box.shape[0] != n:
            if box.shape[0] != cand.size:
                raise ValueError(f"boxes must have {n} or {cand.size} rows, got {box.shape[0]}")
            per_landmark = np.tile(np.array([-math.inf, math.inf, -math.inf, math.inf]), (n, 1))
            per_landmark[cand] = box
            box = per_landmark
    return arrays, cand, c0, np.ascontiguousarray(box)


def cast(
    x: float,
    y: float,
    theta: float,
    beam_angles: Sequence[float] | np.ndarray,
    candidates: Sequence[int] | np.ndarray,
    shapes: ShapeArrays | Sequence[ShapeRow],
    c0s: Sequence[float] | np.ndarray,
    max_range: float,
    boxes: Sequence[Sequence[float]] | np.ndarray | None = None,
) -> list[BeamHit | None]:
    """Per beam, the nearest admissible hit on the ``candidates`` (ascending landmark indices,
    into ``shapes`` and ``c0s``), or None. A root counts when it is real,
    0 < t ≤ max_range and its ξ lies in [lo, hi]; the smallest over all candidates wins.

    ``boxes`` (one (x_min, x_max, y_min, y_max) per landmark or per candidate), when given,
    must hold each candidate's curve over its extent (e.g. :meth:`LandmarkTable.boxes`): a
    beam whose segment passes farther than :data:`BOX_MARGIN` from a box cannot hit that
    landmark, and is not solved against it. The answer is the same; most pairs are skipped.
    """
    arrays, cand, c0, box = _checked(shapes, candidates, c0s, boxes)
    angles = np.ascontiguousarray(beam_angles, dtype=float).reshape(-1)
    t, landmark, slope, denom, xi = kernels.cast_scan(
        float(x), float(y), float(theta), angles, cand, *arrays, c0, box, float(max_range)
    )
    out: list[BeamHit | None] = []
    for b, j in enumerate(landmark.tolist()):
        if j < 0:
            out.append(None)
            continue
        phi = float(theta) + float(angles[b])
        variate = int(arrays.variate[j])
        out.append(
            BeamHit(float(t[b]), j, float(slope[b]), float(denom[b]), phi, variate, float(xi[b]))
        )
    return out


def range_rows(
    x: float,
    y: float,
    theta: float,
    beam_angles: Sequence[float] | np.ndarray,
    ranges: Sequence[float] | np.ndarray,
    shapes: ShapeArrays | Sequence[ShapeRow],
    c0s: Sequence[float] | np.ndarray,
    max_range: float,
    min_sine: float,
    range_var: float,
    boxes: Sequence[Sequence[float]] | np.ndarray | None = None,
) -> Rows:
    """The EKF rows of the measurement model alone (R = ``range_var``), against every
    landmark: per beam with a hit whose incidence sine |D|/√(1 + B'²) is at least
    ``min_sine`` (SPEC §3 skips hits closer to tangent than 10°), the innovation
    ``ranges[b]`` − t*, the pose part of H and 1/D on the c0 hit. ``PolySlam`` adds its
    landmarks' model terms in the same kernel."""
    arrays = shape_arrays(shapes)
    n, width = len(arrays.variate), arrays.shape.shape[1]
    _, _, c0, box = _checked(arrays, np.arange(n), c0s, boxes)
    angles = np.ascontiguousarray(beam_angles, dtype=float).reshape(-1)
    z = np.ascontiguousarray(ranges, dtype=float).reshape(-1)
    if z.shape != angles.shape:
        raise ValueError(f"{z.size} ranges for {angles.size} beams")
    k = angles.size
    rows = Rows(
        np.empty(k), np.empty((k, 3)), np.empty(k, dtype=np.int64), np.empty(k), np.empty(k)
    )
    used = kernels.beam_rows(
        float(x),
        float(y),
        float(theta),
        angles,
        z,
        np.arange(k),
        math.inf,
        *arrays,
        c0,
        box,
        float(max_range),
        float(min_sine),
        float(range_var),
        np.zeros(n),  # model_var
        False,  # shape_follows_pose
        False,  # shift_with_pose
        np.zeros(n),  # pivot
        np.zeros(n),  # xi_var
        np.zeros(2),  # pose_var
        np.full(n, np.nan),  # shift_slope
        np.zeros(n),  # turn_var
        np.ones(n),  # fit_half
        np.zeros((width, width, width)),
        1,
        -1,  # alpha_base: no shape rotation in the state
        rows.innovation,
        rows.h_pose,
        rows.c0_index,
        rows.h_c0,
        np.empty(k, dtype=np.int64),  # alpha_index (all −1)
        np.empty(k),  # h_alpha (all 0)
        rows.variance,
        np.empty(k),  # end_room (unused)
        np.empty((k, 4)),  # xi_grad (unused)
    )
    return Rows(*(column[:used] for column in rows))

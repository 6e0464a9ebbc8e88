"""Piecewise-linear chains for received polynomials (SPEC §4, paper §3.2).

A polynomial rotated into another frame is no longer a polynomial, so the receiver turns each
received polynomial into a chain of chords whose distance from the curve is at most
``chord_tol``, maps the vertices through ``T_{l0,j0}`` and refits in its own frame.

Vertex placement: chord lengths follow the curvature (a chord of length L on a curve of
curvature κ deviates by about κL²/8), aiming at 80 % of the tolerance, which gives close to the
fewest vertices. Every chord is then checked — the largest perpendicular distance exactly from
the critical points of the vertical error, end effects by sampling — and any chord that fails
is halved in ξ until all pass.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.polynomial import polynomial as npoly

from polyslam_env.comms import kernels
from polyslam_env.slam.polynomial import Polynomial, polyval

_AIM = 0.8  # fraction of the tolerance the curvature-based placement aims at
_DENSE = 512  # grid for the curvature integral
_CHECK_SAMPLES = 17  # samples per chord for the distance-to-segment check
_MAX_VERTICES = 100_000  # guard against runaway subdivision


def chain_points(poly: Polynomial, chord_tol: float, spacing: float) -> np.ndarray:
    """``polyline_points(piecewise_linear(poly, chord_tol), spacing)``: points (N, 2) every
    ``spacing`` (m) or less along the chain of ``poly``. Orders up to 3 in one compiled call
    (:func:`~polyslam_env.comms.kernels.chain`, bit for bit the same points), higher orders
    by the numpy functions below."""
    if poly.order > 3:
        return polyline_points(piecewise_linear(poly, chord_tol), spacing)
    _check_positive("chord_tol", chord_tol)
    _check_positive("spacing", spacing)
    out: np.ndarray = kernels.chain(
        poly.variate, poly.coeffs, float(poly.lo), float(poly.hi), float(chord_tol),
        _AIM * chord_tol, _DENSE, _CHECK_SAMPLES, float(spacing), _MAX_VERTICES,
    )  # fmt: skip
    return out


def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):  # math's: no numpy scalar per record
        raise ValueError(f"{name} must be > 0, got {value!r}")


def piecewise_linear(poly: Polynomial, chord_tol: float = 0.005) -> np.ndarray:
    """Vertices (V, 2), V >= 2, on ``poly`` with every chord within ``chord_tol`` of the curve."""
    _check_positive("chord_tol", chord_tol)
    if poly.hi == poly.lo:
        return poly.points_at(np.array([poly.lo, poly.hi]))
    xi = _initial_knots(poly, _AIM * chord_tol)
    while True:
        bad = _chord_errors(poly, xi) > chord_tol  # (V-1,)
        if not bad.any():
            return poly.points_at(xi)
        mids = 0.5 * (xi[:-1][bad] + xi[1:][bad])
        xi = np.sort(np.concatenate([xi, mids]))
        if len(xi) > _MAX_VERTICES:
            raise RuntimeError(f"piecewise_linear: more than {_MAX_VERTICES} vertices needed")


def _initial_knots(poly: Polynomial, sagitta: float) -> np.ndarray:
    """ξ knots (n+1,) spaced so each chord's sagitta κL²/8 is about ``sagitta``."""
    xi = np.linspace(poly.lo, poly.hi, _DENSE)
    d1 = poly.slope(xi)
    d2 = polyval(xi, poly.coeffs, derivative=2)
    speed = np.sqrt(1.0 + d1**2)  # ds/dξ
    kappa = np.abs(d2) / speed**3
    density = np.sqrt(kappa / (8.0 * sagitta)) * speed  # chords per unit ξ
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(xi))])
    n = max(int(np.ceil(cum[-1])), 1)
    if cum[-1] <= 0:
        return np.array([poly.lo, poly.hi])
    knots = np.interp(np.linspace(0.0, cum[-1], n + 1), cum, xi)
    knots[0], knots[-1] = poly.lo, poly.hi
    return knots


def _chord_errors(poly: Polynomial, xi: np.ndarray) -> np.ndarray:
    """Largest distance (V-1,) from the curve between consecutive knots to their chord."""
    if poly.order <= 3:
        perp = _max_perpendicular_cubic(poly, xi)
    else:
        perp = np.array([_max_perpendicular(poly, a, b) for a, b in itertools.pairwise(xi)])
    return np.maximum(perp, _sampled_segment_distance(poly, xi))


def _max_perpendicular_cubic(poly: Polynomial, xi: np.ndarray) -> np.ndarray:
    """:func:`_max_perpendicular` of every chord (V-1,) at once, for orders up to 3: e'(ξ) =
    p'(ξ) − s is at most quadratic, so its roots are the quadratic formula's (the stable form,
    q = −(b + sign(b)√D)/2, roots q/a and c/q) instead of a companion matrix per chord; the
    leading coefficients are trimmed as there (negligible next to the largest: dropped)."""
    c = np.zeros(4)
    c[: poly.order + 1] = poly.coeffs
    a, b = xi[:-1], xi[1:]
    ya, yb = poly.value(a), poly.value(b)
    s = (yb - ya) / (b - a)
    d0, d1, d2 = c[1] - s, 2.0 * c[2], 3.0 * c[3]  # e' = d0 + d1 ξ + d2 ξ², per chord
    big = 1e-12 * np.maximum(np.maximum(np.abs(d0), abs(d1)), abs(d2))
    quad = abs(d2) > big
    line = ~quad & (abs(d1) > big)
    roots = np.full((len(a), 2), np.nan)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        disc = d1 * d1 - 4.0 * d2 * d0
        real = quad & (disc >= 0.0)
        q = -0.5 * (d1 + np.copysign(np.sqrt(np.where(real, disc, 0.0)), d1))
        roots[:, 0] = np.where(real, q / d2, np.nan)
        roots[:, 1] = np.where(real & (q != 0.0), d0 / q, roots[:, 0])
        roots[line, 0] = -d0[line] / d1
    inside = (roots > a[:, None]) & (roots < b[:, None])
    crit = np.where(inside, roots, a[:, None])  # a: zero error, as no critical point
    err = poly.value(crit) - (ya[:, None] + s[:, None] * (crit - a[:, None]))
    return np.asarray(np.max(np.abs(err), axis=1) / np.hypot(1.0, s))


def _max_perpendicular(poly: Polynomial, a: float, b: float) -> float:
    """Exact max distance from the curve on [a, b] to the line through its end points."""
    ya, yb = poly.value(a), poly.value(b)
    s = (yb - ya) / (b - a)
    deriv = npoly.polyder(poly.coeffs).copy()
    deriv[0] -= s  # e'(ξ) = p'(ξ) − s
    # Leading coefficients negligible next to the largest (even subnormal ones) would blow
    # the companion matrix up to inf: drop them; they cannot move a root inside [a, b].
    deriv = npoly.polytrim(deriv, 1e-12 * float(np.max(np.abs(deriv), initial=0.0)))
    roots = npoly.polyroots(deriv) if len(deriv) > 1 and np.any(deriv[1:] != 0) else np.array([])
    crit = roots.real[(np.abs(roots.imag) < 1e-12) & (roots.real > a) & (roots.real < b)]
    if crit.size == 0:
        return 0.0
    err = poly.value(crit) - (ya + s * (crit - a))
    return float(np.max(np.abs(err)) / np.hypot(1.0, s))


def _sampled_segment_distance(poly: Polynomial, xi: np.ndarray) -> np.ndarray:
    """Max distance (V-1,) of sampled curve points to their chord segment (end effects)."""
    t = np.linspace(0.0, 1.0, _CHECK_SAMPLES)[1:-1]
    a, b = xi[:-1, None], xi[1:, None]
    pts = poly.points_at(a + (b - a) * t)  # (V-1, K, 2)
    start, end = poly.points_at(xi[:-1]), poly.points_at(xi[1:])  # (V-1, 2)
    return np.max(_segment_distance(pts, start[:, None], end[:, None]), axis=1)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` (…, 2) to segments a→b (broadcast (…, 2))."""
    ab = b - a
    denom = np.maximum(np.sum(ab * ab, axis=-1), 1e-300)
    u = np.clip(np.sum((p - a) * ab, axis=-1) / denom, 0.0, 1.0)
    return np.asarray(np.linalg.norm(p - (a + u[..., None] * ab), axis=-1))


def polyline_points(vertices: np.ndarray, spacing: float) -> np.ndarray:
    """Points (n, 2) equally spaced along the chain, both ends included, gaps <= ``spacing``."""
    _check_positive("spacing", spacing)
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    if len(v) == 0:
        raise ValueError("a polyline needs at least one vertex")
    seg = np.linalg.norm(np.diff(v, axis=0), axis=1)  # (V-1,)
    keep = np.concatenate([[True], seg > 0])
    v, s = v[keep], np.concatenate([[0.0], np.cumsum(seg[seg > 0])])
    if s[-1] == 0:
        return v[:1].copy()
    n = int(np.ceil(s[-1] / spacing)) + 1
    targets = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(targets, s, v[:, 0]), np.interp(targets, s, v[:, 1])], axis=-1)

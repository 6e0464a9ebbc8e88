"""Test oracle of the compiled association (:func:`polyslam_env.slam.map_kernels.associate_scan`):
the readable version it replaced, stored points as Python tuples in lists.

Production runs the kernel over the map's buffers; :func:`associate_step` here does the same
stage the way ``PolySlam`` did before (``store_beams`` → box candidates → ``MapBook.associate``
with the ``stretch_ends`` test → extents stretched point by point), on plain Python state
(:class:`OracleMap`), and ``test_association.py`` checks the kernel against it bit for bit:
the same good beams, clusters, Q_bad sets, requests and extents.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from polyslam_env.slam import kernels
from polyslam_env.slam.map_kernels import GAP_SPLIT, POSE_VAR_FLOOR
from polyslam_env.slam.polynomial import Polynomial
from tests.slam.reference_floats import boxes_near, nearest_by_error


class StoredPoint(NamedTuple):
    """A range return kept for later (cluster or Q_bad member)."""

    xy: np.ndarray  # (2,) frame-0 coordinates
    direction: np.ndarray  # (2,) unit beam direction in frame 0
    sigma: float
    weight: float  # 1/‖P_{k|k−1}‖
    pose: np.ndarray  # (3,) pose estimate when it was measured
    beam: int = -1
    step: int = -1


def spectral_norm3(a: np.ndarray) -> float:
    """The largest |eigenvalue| of a symmetric 3×3 block (closed form, Python floats)."""
    e0, _, e2 = symmetric_eigvals3(a)
    return max(-e0, e2)


def symmetric_eigvals3(a: np.ndarray) -> tuple[float, float, float]:
    """The closed-form eigenvalues the compiled ``geometry.symmetric_eigvals3`` replaced."""
    (a00, _, _), (a10, a11, _), (a20, a21, a22) = np.asarray(a)[:3, :3].tolist()
    off = a10 * a10 + a20 * a20 + a21 * a21
    if off == 0.0:
        d0, d1, d2 = sorted((a00, a11, a22))
        return d0, d1, d2
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0)
    det = (
        b00 * (b11 * b22 - a21 * a21)
        - a10 * (a10 * b22 - a21 * a20)
        + a20 * (a10 * a21 - b11 * a20)
    )
    half_det = det / (2.0 * p * p * p)
    phi = math.acos(min(max(half_det, -1.0), 1.0)) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return smallest, 3.0 * q - largest - smallest, largest


def store_beams(
    pose_pred: np.ndarray,
    pose_cov: np.ndarray,
    ranges: np.ndarray,
    beam_angles: np.ndarray,
    range_sigma: float,
    step: int = -1,
) -> list[StoredPoint]:
    """Beam returns of one step as stored points; beams without return are skipped."""
    pose = np.array(pose_pred, dtype=float)[:3]
    x, y, theta = pose.tolist()
    weight = 1.0 / max(spectral_norm3(np.asarray(pose_cov)), POSE_VAR_FLOOR)
    angles = np.asarray(beam_angles, dtype=float).tolist()
    out = []
    for i, r in enumerate(np.asarray(ranges, dtype=float).tolist()):
        if not math.isfinite(r):
            continue
        phi = theta + angles[i]
        c, s = math.cos(phi), math.sin(phi)
        out.append(
            StoredPoint(
                np.array([x + r * c, y + r * s]), np.array([c, s]), range_sigma, weight, pose, i,
                step,
            )
        )  # fmt: skip
    return out


# -- the shapes as Python state -------------------------------------------------------------------
def shape_range(shape: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Bounds (n, 2) on B over each extent: the numpy version ``map_kernels.eta_range``
    replaced (Taylor coefficients about the middle, |T_k| h^k summed)."""
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)  # (n,)
    shape = np.ascontiguousarray(shape, dtype=float)
    taylor = np.empty_like(shape)  # (n, M+1)
    for i in range(len(shape)):
        kernels.taylor_shift(shape[i], shape.shape[1] - 1, float(mid[i]), taylor[i])
    powers = half[:, None] ** np.arange(shape.shape[1])  # (n, M+1)
    spread = (np.abs(taylor[:, 1:]) * powers[:, 1:]).sum(axis=1)
    pad = spread * 1e-9 + 1e-9 * (1.0 + np.abs(taylor[:, 0]))
    return np.stack([taylor[:, 0] - spread - pad, taylor[:, 0] + spread + pad], axis=-1)


@dataclass
class OracleMap:
    """What the association reads and changes of the map, as plain Python: landmark ids,
    polynomials (their fit's c0), pivots, evidence and η ranges (row i = state 3 + i), the
    shape rows zero-padded to ``width``, and the book of clusters and Q_bad sets."""

    ids: list[int]
    polys: list[Polynomial]
    pivot: list[float]
    changed_at: list[int]
    evidence: list[tuple[float, float]]
    width: int
    eta: list[tuple[float, float]] = field(default_factory=list)
    clusters: list[list[StoredPoint]] = field(default_factory=list)
    qbad: dict[int, list[StoredPoint]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.eta = [self._eta_of(i) for i in range(len(self.ids))]
        self.qbad = {lid: [] for lid in self.ids}

    def shape_row(self, i: int) -> np.ndarray:
        row = np.zeros(self.width)
        row[1 : self.polys[i].order + 1] = self.polys[i].shape
        return row

    def _eta_of(self, i: int) -> tuple[float, float]:
        p = self.polys[i]
        low, high = shape_range(self.shape_row(i)[None], np.array([p.lo]), np.array([p.hi]))[0]
        return float(low), float(high)

    def boxes(self, c0s: Sequence[float]) -> np.ndarray:
        out = np.empty((len(self.ids), 4))
        for i, (p, c0) in enumerate(zip(self.polys, c0s, strict=True)):
            low, high = c0 + self.eta[i][0], c0 + self.eta[i][1]
            out[i] = (p.lo, p.hi, low, high) if p.variate == 1 else (low, high, p.lo, p.hi)
        return out

    def extend_to_hit(self, i: int, xi: float) -> None:
        ev_lo, ev_hi = self.evidence[i]
        self.evidence[i] = (min(ev_lo, xi), max(ev_hi, xi))
        p = self.polys[i]
        self.polys[i] = Polynomial(p.variate, p.coeffs, min(p.lo, xi), max(p.hi, xi))
        self.eta[i] = self._eta_of(i)


def rotation_fit_var(poly: Polynomial, fit_inverse: np.ndarray, range_var: float) -> float:
    """``PolySlam._rotation_fit_var`` as it was: the slope's fit variance σ²·M⁻¹[1, 1]/h² over
    (1 + b'²)² at the middle of the extent (numpy's polynomial slope, Python's ``** 2``)."""
    order = max(len(np.trim_zeros(np.asarray(poly.coeffs[1:], dtype=float), "b")), 1)
    inverse = fit_inverse[order]
    half = max(0.5 * (poly.hi - poly.lo), 0.05)
    slope = float(poly.slope(0.5 * (poly.lo + poly.hi)))
    return float(range_var * inverse[1, 1] / (half * half) / (1.0 + slope * slope) ** 2)


# -- the book -------------------------------------------------------------------------------------
@dataclass
class Requests:
    good: dict[int, int] = field(default_factory=dict)  # beam → row
    good_ids: dict[int, int] = field(default_factory=dict)  # beam → landmark id
    extended: dict[int, int] = field(default_factory=dict)  # beam → row
    refits: list[tuple[int, list[StoredPoint]]] = field(default_factory=list)
    new_landmarks: list[list[StoredPoint]] = field(default_factory=list)


def add_to_cluster(
    clusters: list[list[StoredPoint]], point: StoredPoint, radius: float, link: bool, eps_z: int
) -> list[StoredPoint] | None:
    """The point into the cluster with most neighbours within R; joined clusters with
    ``link``; the cluster's points (removed) once it holds more than ε_Z."""
    x, y = float(point.xy[0]), float(point.xy[1])
    counts = [sum(1 for p in c if math.hypot(p.xy[0] - x, p.xy[1] - y) <= radius) for c in clusters]
    if counts and max(counts) > 0:
        best = int(np.argmax(counts))  # ties: the oldest cluster
        clusters[best].append(point)
        joined = [i for i, n in enumerate(counts) if n > 0 and i != best] if link else []
        for i in joined:
            clusters[best].extend(clusters[i])
        for i in reversed(joined):
            del clusters[i]
            if i < best:
                best -= 1
    else:
        best = len(clusters)
        clusters.append([point])
    if len(clusters[best]) > eps_z:
        return clusters.pop(best)
    return None


def add_bad(
    qbad: dict[int, list[StoredPoint]],
    landmark_id: int,
    point: StoredPoint,
    eps_m: int,
    out: Requests,
) -> None:
    """Add to Q_bad; past ε_M points, request (or extend this step's) refit and empty it."""
    bad = qbad[landmark_id]
    bad.append(point)
    if len(bad) <= eps_m:
        return
    qbad[landmark_id] = []
    for lid, points in out.refits:
        if lid == landmark_id:
            points.extend(bad)
            return
    out.refits.append((landmark_id, bad))


class Model(NamedTuple):
    """The association's settings (``SlamConfig`` fields) and state."""

    range_sigma: float
    squared: bool
    stretch_ends: bool
    eps_m: int
    eps_z: int
    radius: float
    link: bool
    turn_var: Callable[[int], float]  # var(α − θ) of landmark row i
    #: ``SlamConfig.seen_faces``: a point is associated only with landmarks whose seen face
    #: (``sides``, row i: +1 from +η, −1 from −η, 0 both or unknown) its beam can hit
    seen_faces: bool = False
    sides: tuple[int, ...] = ()


def associate_step(
    book: OracleMap,
    mean: np.ndarray,
    cov: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    step: int,
    rho: float,
    sigma: float,
    model: Model,
) -> Requests:
    """The association stage as ``PolySlam._step`` ran it before the kernel."""
    n = len(book.ids)
    c0s = np.asarray(mean[3 : 3 + n], dtype=float)
    points = store_beams(mean[:3], cov, ranges, angles, model.range_sigma, step)
    out = Requests()
    if not points:
        return out
    xs, ys = zip(*(p.xy.tolist() for p in points), strict=True)
    box = np.array([min(xs), max(xs), min(ys), max(ys)])
    reach = math.sqrt(sigma) if model.squared else sigma
    if model.stretch_ends:
        reach = max(reach, GAP_SPLIT)
    reach = reach * (1.0 + 1e-9) + 1e-12
    candidates = boxes_near(book.boxes(c0s.tolist()), box, reach).tolist()
    rows = [book_row(book, i) for i in range(n)]
    if model.seen_faces:  # per point, the candidates whose seen face its beam can hit

        def can_hit(point: StoredPoint, i: int) -> bool:
            towards = point.direction[1] if book.polys[i].variate == 1 else point.direction[0]
            beam_side = -1 if towards > 0 else (1 if towards < 0 else 0)  # where it came from
            return model.sides[i] == 0 or beam_side == 0 or model.sides[i] == beam_side

        nearest = [
            nearest_by_error(
                [p.xy.tolist()], [i for i in candidates if can_hit(p, i)], rows,
                c0s.tolist(), model.squared,
            )[0]
            for p in points
        ]  # fmt: skip
    else:
        nearest = nearest_by_error(
            [p.xy.tolist() for p in points], candidates, rows, c0s.tolist(), model.squared
        )

    def within(point: StoredPoint, i: int) -> bool:
        p = book.polys[i]
        xi = point.xy[0] if p.variate == 1 else point.xy[1]
        return bool(p.lo <= xi <= p.hi)

    def continued_xi(point: StoredPoint, i: int) -> float | None:
        p = book.polys[i]
        xi, eta = (point.xy[0], point.xy[1]) if p.variate == 1 else (point.xy[1], point.xy[0])
        curve = float(p.with_c0(0.0).value(xi)) + mean[3 + i]
        return float(xi) if abs(eta - curve) <= 2.0 * model.range_sigma else None

    def extends(point: StoredPoint, i: int) -> bool:
        if within(point, i):
            return False
        xi = continued_xi(point, i)
        if xi is None:
            return False
        p = book.polys[i]
        if min(abs(xi - p.lo), abs(xi - p.hi)) > GAP_SPLIT:
            return False
        lever = xi - book.pivot[i]
        return lever * lever * model.turn_var(i) <= model.range_sigma**2

    for point, (best, eps) in zip(points, nearest, strict=True):
        if eps <= rho:
            out.good[point.beam] = best
            out.good_ids[point.beam] = book.ids[best]
        elif model.stretch_ends and best >= 0 and extends(point, best):
            out.extended[point.beam] = best
        elif eps <= sigma:
            add_bad(book.qbad, book.ids[best], point, model.eps_m, out)
        else:
            full = add_to_cluster(book.clusters, point, model.radius, model.link, model.eps_z)
            if full is not None:
                out.new_landmarks.append(full)
    for point in points:  # PolySlam._extend_extents
        i = out.good.get(point.beam, out.extended.get(point.beam))
        if i is None or within(point, i):
            continue
        xi = continued_xi(point, i)
        if xi is not None:
            book.extend_to_hit(i, xi)
        elif model.stretch_ends:
            out.good_ids.pop(point.beam, None)
    return out


class _Row(NamedTuple):
    variate: int
    shape: tuple[float, ...]
    lo: float
    hi: float


def book_row(book: OracleMap, i: int) -> _Row:
    """Landmark i as ``reference_floats.nearest_by_error`` takes it (own order, no zero tail)."""
    p = book.polys[i]
    shape = [0.0, *p.shape.tolist()]
    while len(shape) > 2 and shape[-1] == 0.0:
        shape.pop()
    return _Row(p.variate, tuple(shape), p.lo, p.hi)

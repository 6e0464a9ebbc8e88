"""The landmark table of one robot's map (:class:`LandmarkTable`), kept in state order.

:class:`~polyslam_env.slam.robot.PolySlam` keeps its whole map here (the EKF state holds only
the c0s): stable ids, each landmark's shape and extent as a
:class:`~polyslam_env.slam.polynomial.Polynomial`, and the same as arrays for the hot path
(association, ray casting, the shape coupling of the update, the merge check). Rebuilding the
arrays from the polynomials every step would cost O(n) Python work; the table changes one row
when the map changes (append, remove, new extent).

It also keeps a conservative η range of each shape over its extent, so that a landmark's
axis-aligned bounding box follows from its current c0 in O(1). A beam can only hit, and a
merge partner can only lie near, landmarks whose box is near: :meth:`LandmarkTable.near`
selects them without changing what the exact tests downstream decide.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np

from polyslam_env.slam import kernels
from polyslam_env.slam.polynomial import Polynomial

if TYPE_CHECKING:
    from polyslam_env.slam.fitting import StoredPoint

#: m, how far a landmark's curve may reach past the outermost beam hits that support it: 2.5 ×
#: the 2 cm range noise (a hit's own position along the wall is uncertain by about that).
#: Each landmark keeps the ξ-interval of its supporting hits (``LandmarkTable.evidence``: a
#: cluster's hits; a hit an extension reached; a refit's bad hits with the old evidence; both
#: evidences of a merge or join; a received landmark's extent, the sender's evidence) and its
#: extent is cut to that interval ± this margin. Inside, a join may bridge a gap of up to
#: ``association.GAP_SPLIT`` (narrower gaps are sampling, wider ones doorways).
EXTENT_MARGIN = 0.05


@dataclass(frozen=True, eq=False)
class PackedPolynomials:
    """Shapes, variates and extents of n polynomials as arrays, for vectorised evaluation.

    Build it once per map change with :meth:`from_polynomials` and pass it instead of the
    polynomial list on the hot path; ``c0`` is not stored (it lives in the EKF state).
    """

    variate: np.ndarray  # (n,) int, 1 or 2
    shape: np.ndarray  # (n, M+1): [0, b_1, …, b_M], zero-padded to the largest order M
    lo: np.ndarray  # (n,) extent on ξ
    hi: np.ndarray  # (n,)

    @classmethod
    def from_polynomials(cls, polys: Sequence[Polynomial]) -> PackedPolynomials:
        order = max((p.order for p in polys), default=1)
        shape = np.zeros((len(polys), order + 1))  # (n, M+1)
        for i, p in enumerate(polys):
            shape[i, 1 : p.order + 1] = p.shape
        return cls(
            variate=np.array([p.variate for p in polys], dtype=int),
            shape=shape,
            lo=np.array([p.lo for p in polys], dtype=float),
            hi=np.array([p.hi for p in polys], dtype=float),
        )

    def __len__(self) -> int:
        return len(self.variate)

    @property
    def order(self) -> int:
        return self.shape.shape[1] - 1

    def subset(self, indices: np.ndarray) -> PackedPolynomials:
        """The polynomials at ``indices`` (an index array), in that order."""
        return PackedPolynomials(
            self.variate[indices], self.shape[indices], self.lo[indices], self.hi[indices]
        )

    def arrays(self) -> ShapeArrays:
        """The shapes as the kernels take them (each row's own order computed)."""
        return ShapeArrays(self.variate, own_orders(self.shape), self.shape, self.lo, self.hi)

    def rows(self) -> list[PlainRow]:
        """Each polynomial's shape as plain floats (a :class:`ShapeRow`)."""
        columns = zip(
            self.variate.tolist(), self.shape, self.lo.tolist(), self.hi.tolist(), strict=True
        )
        return [PlainRow(v, _own_order(shape), lo, hi) for v, shape, lo, hi in columns]


class PlainRow(NamedTuple):
    """A polynomial's shape and extent as Python numbers (see :meth:`PackedPolynomials.rows`)."""

    variate: int
    shape: tuple[float, ...]  # (0, b_1, …, b_m), no zero tail
    lo: float
    hi: float


PolynomialsLike = Sequence[Polynomial] | PackedPolynomials


class ShapeRow(Protocol):
    """A landmark's shape as plain floats (e.g. a :class:`LandmarkRow`)."""

    @property
    def variate(self) -> int: ...
    @property
    def shape(self) -> tuple[float, ...]: ...  # (0, b_1, …, b_m), no zero tail
    @property
    def lo(self) -> float: ...
    @property
    def hi(self) -> float: ...


class ShapeArrays(NamedTuple):
    """Shapes as the compiled kernels read them (:mod:`polyslam_env.slam.kernels`)."""

    variate: np.ndarray  # (n,) int64, 1 or 2
    order: np.ndarray  # (n,) int64, each shape's own order (no zero tail, ≥ 1)
    shape: np.ndarray  # (n, M+1) float: [0, b_1, …, b_M], zero-padded
    lo: np.ndarray  # (n,) extent on ξ
    hi: np.ndarray  # (n,)


def own_orders(shape: np.ndarray) -> np.ndarray:
    """(n,) int64: each zero-padded shape row's own order (its last non-zero power, ≥ 1), the
    length of :func:`_own_order`'s row minus one."""
    nonzero = shape != 0.0  # (n, M+1)
    last = shape.shape[1] - 1 - np.argmax(nonzero[:, ::-1], axis=1)
    return np.maximum(np.where(nonzero.any(axis=1), last, 0), 1).astype(np.int64)


def shape_arrays(shapes: ShapeArrays | Sequence[ShapeRow]) -> ShapeArrays:
    """``shapes`` as :class:`ShapeArrays` (no copy when already packed)."""
    if isinstance(shapes, ShapeArrays):
        return shapes
    width = max((len(row.shape) for row in shapes), default=2)
    shape = np.zeros((len(shapes), width))
    for i, row in enumerate(shapes):
        shape[i, : len(row.shape)] = row.shape
    return ShapeArrays(
        np.array([row.variate for row in shapes], dtype=np.int64),
        np.array([len(row.shape) - 1 for row in shapes], dtype=np.int64),
        shape,
        np.array([row.lo for row in shapes], dtype=float),
        np.array([row.hi for row in shapes], dtype=float),
    )


def pack(polys: PolynomialsLike) -> PackedPolynomials:
    """``polys`` as :class:`PackedPolynomials` (no copy when already packed)."""
    if isinstance(polys, PackedPolynomials):
        return polys
    return PackedPolynomials.from_polynomials(polys)


def shape_range(shape: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Bounds (n, 2) on B(ξ) over ξ ∈ [lo, hi] for shapes (n, M+1) = [0, b_1, …, b_M].

    Interval arithmetic on the Taylor expansion about the middle m of the extent, with half
    width h: B(m + u) = Σ_k T_k u^k, so |B − T_0| ≤ Σ_{k≥1} |T_k| h^k. Never too narrow (the
    box tests rely on that); loose only by the curvature terms of short segments.
    """
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)  # (n,)
    shape = np.ascontiguousarray(shape, dtype=float)
    if shape.shape[1] > kernels.MAX_ORDER + 1:
        raise ValueError(f"shape order {shape.shape[1] - 1} above {kernels.MAX_ORDER}")
    taylor = np.empty_like(shape)  # (n, M+1)
    for i in range(len(shape)):
        kernels.taylor_shift(shape[i], shape.shape[1] - 1, float(mid[i]), taylor[i])
    powers = half[:, None] ** np.arange(shape.shape[1])  # (n, M+1)
    spread = (np.abs(taylor[:, 1:]) * powers[:, 1:]).sum(axis=1)
    # a relative pad absorbs the rounding of T_0 and of the exact values this bounds
    pad = spread * 1e-9 + 1e-9 * (1.0 + np.abs(taylor[:, 0]))
    return np.stack([taylor[:, 0] - spread - pad, taylor[:, 0] + spread + pad], axis=-1)


class LandmarkRow(NamedTuple):
    """One landmark's shape and scalars as Python numbers (see :meth:`LandmarkTable.rows`)."""

    variate: int
    shape: tuple[float, ...]  # (0, b_1, …, b_m), m its own order (≥ 1): no zero tail
    lo: float
    hi: float
    pivot: float
    xi_var: float
    model_var: float
    fit_half: float


def _own_order(shape: np.ndarray) -> tuple[float, ...]:
    """A zero-padded shape row without its zero tail, kept at least linear."""
    used = np.flatnonzero(shape)
    width = max(int(used[-1]) + 1 if used.size else 0, 2)
    return tuple(float(b) for b in shape[:width])


class LandmarkTable:
    """One robot's map: every landmark's id, shape, extent and scalars, row i = state 3 + i.

    The single record of the map (the EKF state holds only the c0s): ``ids`` (stable
    integers, row i's c0 at state index 3 + i), ``polys`` (shape and extent as an immutable
    :class:`Polynomial`: a change is a new object, so readers can tell by identity; its own
    c0 is the fit's, the current one is in the state), ``changed_at`` (the step the landmark
    was created, refit or merged), ``qbad`` (the points it approximates badly, by id; the
    association fills them), and the same shapes as arrays for the hot path, changed one
    row at a time: ``shape`` rows [0, b_1, …, b_M] zero-padded to the largest order so far,
    ``variate``, ``lo``/``hi``, ``eta_range`` (bounds on B over the extent, for the boxes),
    ``pivot`` (ξ of the centroid the landmark was fitted around), ``xi_var`` (the pose
    variance along ξ when it was made), ``model_var`` (its fit variance beyond the range
    noise), ``side`` (the face its beams saw, see ``merging``) and ``fit_half`` (half the
    extent it was fitted over; see PolySlam).

    Arrays are replaced, never written in place, so a :class:`PackedPolynomials` handed out
    earlier stays valid; ``ids`` is changed in place (readers may hold it).
    """

    def __init__(self) -> None:
        self.ids: list[int] = []  # (n,) stable ids in state order
        self.polys: list[Polynomial] = []  # (n,) shape and extent
        self.changed_at: list[int] = []  # (n,) step created, refit or merged
        self.qbad: dict[int, list[StoredPoint]] = {}  # id → its badly approximated points
        self.variate = np.zeros(0, dtype=np.int64)  # (n,)
        self.order = np.zeros(0, dtype=np.int64)  # (n,) each shape's own order
        self.shape = np.zeros((0, 2))  # (n, M+1)
        self.lo = np.zeros(0)  # (n,)
        self.hi = np.zeros(0)  # (n,)
        self.eta_range = np.zeros((0, 2))  # (n, 2) bounds on B over the extent (no c0)
        self.pivot = np.zeros(0)  # (n,)
        self.xi_var = np.zeros(0)  # (n,)
        self.model_var = np.zeros(0)  # (n,)
        self.fit_half = np.zeros(0)  # (n,) half the extent it was fitted over
        self.side = np.zeros(0, dtype=int)  # (n,) face seen: +1 from +η, −1 from −η, 0 unknown
        self.evidence = np.zeros((0, 2))  # (n, 2) ξ-interval of the hits supporting it
        self.shapes = ShapesView(self)
        self.version = 0  # bumped by every change, for caches built on the table
        self._next_id = 0
        self._row_of: dict[int, int] | None = None  # id → row, rebuilt after append/remove
        self._packed: PackedPolynomials | None = None
        self._rows: list[LandmarkRow] | None = None
        self._boxes_key: tuple[int, int] | None = None
        self._boxes = np.zeros((0, 4))

    def __len__(self) -> int:
        return len(self.ids)

    def __contains__(self, landmark_id: object) -> bool:
        return landmark_id in self._rows_by_id()

    # -- ids --------------------------------------------------------------------------------
    def index_of(self, landmark_id: int) -> int:
        """Row of the landmark (state index − 3); KeyError if it is not in the map."""
        return self._rows_by_id()[landmark_id]

    def state_index(self, landmark_id: int) -> int:
        """Index of the landmark's c0 in the EKF state."""
        return 3 + self.index_of(landmark_id)

    def _rows_by_id(self) -> dict[int, int]:
        if self._row_of is None:
            self._row_of = {lid: i for i, lid in enumerate(self.ids)}
        return self._row_of

    # -- changes ----------------------------------------------------------------------------
    def append(
        self,
        poly: Polynomial,
        pivot: float,
        xi_var: float,
        model_var: float,
        fit_half: float,
        step: int = 0,
        side: int = 0,
        evidence: tuple[float, float] | None = None,
    ) -> int:
        """Add a landmark at the end (its c0 was appended to the state); returns its new id.

        ``evidence`` (default: the extent) is the ξ-interval of the hits that support it; the
        extent must lie within it ± :data:`EXTENT_MARGIN` (the caller clips, see
        :func:`clip_to_evidence`)."""
        landmark_id = self._next_id
        self._next_id += 1
        self.ids.append(landmark_id)
        self.polys.append(poly)
        self.changed_at.append(step)
        self.qbad[landmark_id] = []
        width = max(self.shape.shape[1], poly.order + 1)
        row = np.zeros((1, width))  # (1, M+1)
        row[0, 1 : poly.order + 1] = poly.shape
        shape = np.zeros((len(self), width))
        shape[:-1, : self.shape.shape[1]] = self.shape
        shape[-1] = row[0]
        self.shape = shape
        self.variate = np.append(self.variate, poly.variate)
        self.order = np.append(self.order, len(_own_order(row[0])) - 1)
        self.lo = np.append(self.lo, poly.lo)
        self.hi = np.append(self.hi, poly.hi)
        rng = shape_range(row, np.array([poly.lo]), np.array([poly.hi]))  # (1, 2)
        self.eta_range = np.concatenate([self.eta_range, rng])
        self.pivot = np.append(self.pivot, pivot)
        self.xi_var = np.append(self.xi_var, xi_var)
        self.model_var = np.append(self.model_var, model_var)
        self.fit_half = np.append(self.fit_half, fit_half)
        self.side = np.append(self.side, int(side))
        ev = (poly.lo, poly.hi) if evidence is None else evidence
        self.evidence = np.concatenate([self.evidence, np.array([ev], dtype=float)])
        self._changed(ids=True)
        return landmark_id

    def remove(self, index: int) -> int:
        """Drop row ``index`` (its c0 left the state); returns its id."""
        landmark_id = self.ids.pop(index)
        del self.polys[index]
        del self.changed_at[index]
        del self.qbad[landmark_id]
        names = ("variate", "order", "shape", "lo", "hi", "eta_range", "pivot", "xi_var")
        for name in (*names, "model_var", "fit_half", "side", "evidence"):
            setattr(self, name, np.delete(getattr(self, name), index, axis=0))
        self._changed(ids=True)
        return landmark_id

    def extend_to_hit(self, index: int, xi: float) -> None:
        """Stretch landmark ``index``'s extent and evidence to a supporting hit at ``xi``."""
        ev_lo, ev_hi = self.evidence[index]
        self.evidence = self.evidence.copy()
        self.evidence[index] = min(ev_lo, xi), max(ev_hi, xi)
        poly = self.polys[index]
        self.set_extent(index, min(poly.lo, xi), max(poly.hi, xi))

    def set_extent(self, index: int, lo: float, hi: float) -> None:
        """New extent [lo, hi] of landmark ``index`` (same shape)."""
        poly = self.polys[index]
        self.polys[index] = Polynomial(poly.variate, poly.coeffs, lo, hi)
        self.lo, self.hi = self.lo.copy(), self.hi.copy()
        self.lo[index], self.hi[index] = lo, hi
        self._reshaped(index)

    def set_shape(self, index: int, poly: Polynomial) -> None:
        """New shape of landmark ``index`` (same variate, extent and order at most the
        table's widest, e.g. a line turned by a link's estimate of its turn)."""
        if poly.variate != self.variate[index] or (poly.lo, poly.hi) != (
            self.lo[index],
            self.hi[index],
        ):
            raise ValueError("set_shape: the variate and extent must stay")
        if poly.order + 1 > self.shape.shape[1]:
            raise ValueError(f"set_shape: order {poly.order} above the table's")
        self.polys[index] = poly
        shape, order = self.shape.copy(), self.order.copy()
        shape[index] = 0.0
        shape[index, 1 : poly.order + 1] = poly.shape
        order[index] = len(_own_order(shape[index])) - 1
        self.shape, self.order = shape, order
        self._reshaped(index)

    def _reshaped(self, index: int) -> None:
        """Landmark ``index``'s shape or extent changed: its η range again, caches dropped."""
        rng = shape_range(
            self.shape[index : index + 1], self.lo[index : index + 1], self.hi[index : index + 1]
        )
        self.eta_range = self.eta_range.copy()
        self.eta_range[index] = rng[0]
        self._changed(ids=False)

    def _changed(self, ids: bool) -> None:
        self._packed = None
        self._rows = None
        if ids:
            self._row_of = None
        self.version += 1

    # -- views --------------------------------------------------------------------------------
    def polynomials(self, c0s: Sequence[float] | np.ndarray) -> list[Polynomial]:
        """Every landmark with its c0 from ``c0s`` (n,), in state order."""
        return [p.with_c0(c) for p, c in zip(self.polys, c0s, strict=True)]

    def packed(self) -> PackedPolynomials:
        """The shapes as arrays (cached until the next change)."""
        if self._packed is None:
            self._packed = PackedPolynomials(self.variate, self.shape, self.lo, self.hi)
        return self._packed

    def arrays(self) -> ShapeArrays:
        """The shapes as the kernels take them (the table's own arrays, no copy)."""
        return ShapeArrays(self.variate, self.order, self.shape, self.lo, self.hi)

    def rows(self) -> list[LandmarkRow]:
        """Row i as plain Python numbers (cached until the next change)."""
        if self._rows is None:
            columns = zip(
                self.variate.tolist(),
                self.shape,
                self.lo.tolist(),
                self.hi.tolist(),
                self.pivot.tolist(),
                self.xi_var.tolist(),
                self.model_var.tolist(),
                self.fit_half.tolist(),
                strict=True,
            )
            self._rows = [
                LandmarkRow(v, _own_order(shape), lo, hi, pivot, xi_var, model_var, fit_half)
                for v, shape, lo, hi, pivot, xi_var, model_var, fit_half in columns
            ]
        return self._rows

    def boxes(self, c0s: np.ndarray, state_version: int | None = None) -> np.ndarray:
        """Axis-aligned boxes (n, 4) = (x_min, x_max, y_min, y_max) holding each curve.

        With ``state_version`` (the caller's count of changes to ``c0s``) the result is
        cached until the table or that version changes (the association and an update
        without map change share them)."""
        key = None if state_version is None else (self.version, state_version)
        if key is not None and key == self._boxes_key:
            return self._boxes
        c0s = np.ascontiguousarray(c0s, dtype=float)
        boxes = kernels.boxes(c0s, self.variate, self.lo, self.hi, self.eta_range)
        if key is not None:
            self._boxes, self._boxes_key = boxes, key
        return boxes

    def near(self, box: np.ndarray, c0s: np.ndarray, distance: float) -> np.ndarray:
        """Indices (ascending) of the landmarks whose box lies within ``distance`` of ``box``
        (4,) = (x_min, x_max, y_min, y_max); a point is a box with min = max."""
        return boxes_near(self.boxes(c0s), box, distance)


class ShapesView(Mapping[int, Polynomial]):
    """Read-only id → shape-and-extent mapping over a :class:`LandmarkTable` (state order)."""

    def __init__(self, table: LandmarkTable) -> None:
        self._table = table

    def __getitem__(self, landmark_id: int) -> Polynomial:
        return self._table.polys[self._table.index_of(landmark_id)]

    def __iter__(self) -> Iterator[int]:
        return iter(list(self._table.ids))

    def __len__(self) -> int:
        return len(self._table)

    def __contains__(self, landmark_id: object) -> bool:
        return landmark_id in self._table


def clip_to_evidence(poly: Polynomial, evidence: tuple[float, float]) -> Polynomial:
    """``poly`` with its extent cut to ``evidence`` ± :data:`EXTENT_MARGIN` (same object if
    it already lies within)."""
    lo = max(poly.lo, evidence[0] - EXTENT_MARGIN)
    hi = min(poly.hi, evidence[1] + EXTENT_MARGIN)
    if lo == poly.lo and hi == poly.hi:
        return poly
    if hi < lo:  # no overlap at all (cannot happen for a fit to its own evidence): keep ends
        lo = hi = min(max(0.5 * (evidence[0] + evidence[1]), poly.lo), poly.hi)
    return Polynomial(poly.variate, poly.coeffs, lo, hi)


def evidence_on(
    evidence: tuple[float, float], old: Polynomial, new: Polynomial, samples: int = 16
) -> tuple[float, float]:
    """The ξ-interval, on ``new``'s axis, of ``old``'s curve over its ``evidence`` interval
    (both with their current c0; their variates may differ): ``samples`` points of the curve
    are projected, so a bulge between the ends counts."""
    xi = np.linspace(evidence[0], evidence[1], samples)
    xy = old.points_at(xi)  # (S, 2)
    on_new = xy[:, 0] if new.variate == 1 else xy[:, 1]
    return float(on_new.min()), float(on_new.max())


def hull(*intervals: tuple[float, float]) -> tuple[float, float]:
    """The smallest interval holding all ``intervals``."""
    return min(a for a, _ in intervals), max(b for _, b in intervals)


def boxes_near(boxes: np.ndarray, box: np.ndarray, distance: float) -> np.ndarray:
    """Indices (ascending, int64) of ``boxes`` (n, 4) within ``distance`` of ``box`` (4,)."""
    boxes = np.ascontiguousarray(boxes, dtype=float).reshape(-1, 4)
    box = np.ascontiguousarray(box, dtype=float)
    if box.shape != (4,):
        raise ValueError(f"boxes_near: box must have shape (4,), got {box.shape}")
    return kernels.boxes_near(boxes, box, float(distance))

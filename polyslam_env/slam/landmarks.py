"""The landmark table of one robot's map (:class:`LandmarkTable`), kept in state order.

:class:`~polyslam_env.slam.robot.PolySlam` keeps its whole map here (the EKF state holds only
the c0s): stable ids, each landmark's shape, extent and scalars as the columns of field-major
buffers (:mod:`~polyslam_env.slam.columns`), which the compiled step reads and writes whole
(association, ray casting, the shape coupling of the update, the merge check), and each
landmark as an immutable :class:`~polyslam_env.slam.polynomial.Polynomial`, built when read.
The table changes one column when the map changes (append, remove, new extent).

It also keeps a conservative η range of each shape over its extent, so that a landmark's
axis-aligned bounding box follows from its current c0 in O(1). A beam can only hit, and a
merge partner can only lie near, landmarks whose box is near: :meth:`LandmarkTable.near`
selects them without changing what the exact tests downstream decide.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol, overload

import numpy as np

from polyslam_env.slam import kernels, map_kernels
from polyslam_env.slam.columns import (
    CHANGED_AT,
    ETA_HI,
    ETA_LO,
    EV_HI,
    EV_LO,
    FIT_HALF,
    HI,
    LO,
    MODEL_VAR,
    N_INDEX,
    N_REAL,
    ORDER,
    PIVOT,
    RECEIVED,
    SHIFT_SLOPE,
    SIDE,
    STAMP,
    VARIATE,
    XI_VAR,
)
from polyslam_env.slam.polynomial import Polynomial

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
    box tests rely on that); loose only by the curvature terms of short segments. Compiled
    row by row (:func:`~polyslam_env.slam.map_kernels.eta_range`).
    """
    shape = np.ascontiguousarray(shape, dtype=float)
    if shape.shape[1] > kernels.MAX_ORDER + 1:
        raise ValueError(f"shape order {shape.shape[1] - 1} above {kernels.MAX_ORDER}")
    out = np.empty((len(shape), 2))
    for i in range(len(shape)):
        out[i] = map_kernels.eta_range(shape[i], float(lo[i]), float(hi[i]))
    return out


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
    """A zero-padded shape row without its zero tail, kept at least linear
    (:func:`~polyslam_env.slam.map_kernels.own_order` + 1 coefficients)."""
    return tuple(shape[: map_kernels.own_order(shape) + 1].tolist())


class LandmarkTable:
    """One robot's map: every landmark's id, shape, extent and scalars, row i = state 3 + i.

    The single record of the map (the EKF state holds only the c0s), kept as field-major
    buffers (STYLE habit 21; :mod:`~polyslam_env.slam.columns` names the fields): ``real``
    (N_REAL, capacity) — extent ``lo``/``hi``, ``eta_range`` (bounds on B over the extent, for
    the boxes), ``evidence`` (the ξ-interval of the hits that support it), ``pivot`` (ξ of the
    centroid it was fitted around), ``xi_var`` (the pose variance along ξ when it was made),
    ``model_var`` (its fit variance beyond the range noise), ``fit_half`` (half the extent it
    was fitted over; see PolySlam); ``index`` (N_INDEX, capacity) — its stable ``id``,
    ``variate``, own ``order``, ``side`` (the face its beams saw, see ``merging``),
    ``changed_at`` (the step it was created, refit or merged), ``stamp`` (bumped whenever
    its shape or extent changes) and ``received`` (it holds a received landmark's data);
    and ``shape_buffer`` (capacity, M+1), rows [0, b_1, …, b_M] zero-padded to the largest
    order so far. The first ``n`` columns are in use; the named properties (``lo``,
    ``variate``, ``shape``, …) are views of them. The compiled step
    writes the extents in place (:mod:`~polyslam_env.slam.map_kernels`); appends and removals
    shift whole columns.

    ``ids`` (a list, changed in place: readers may hold it) mirrors the id field; ``polys[i]``
    is landmark i's shape and extent as an immutable :class:`Polynomial` (its own c0 is the
    fit's, the current one is in the state), built when read after a change: a change gives a
    new object, so readers can tell by identity. ``version`` moves with every change, for
    caches built on the table (:meth:`boxes`).
    """

    def __init__(self, capacity: int = 16) -> None:
        self.ids: list[int] = []  # (n,) stable ids in state order
        self.real = np.zeros((N_REAL, capacity))
        self.index = np.zeros((N_INDEX, capacity), dtype=np.int64)
        self.shape_buffer = np.zeros((capacity, 2))  # (capacity, M+1)
        self.shapes = ShapesView(self)
        self.polys = PolynomialsView(self)
        self.version = 0  # bumped by every change, for caches built on the table
        self._next_id = 0
        self._built: list[Polynomial] = []  # the last Polynomial built for each row
        self._built_stamp: list[int] = []  # … and the stamp it was built at
        self._sizes: np.ndarray | None = None  # (n,) int64 their coefficient counts, or None
        self._row_of: dict[int, int] | None = None  # id → row, rebuilt after append/remove
        self._packed: PackedPolynomials | None = None
        self._rows: list[LandmarkRow] | None = None
        self._boxes_key: tuple[int, int] | None = None
        self._boxes = np.zeros((0, 4))

    def __len__(self) -> int:
        return len(self.ids)

    def __contains__(self, landmark_id: object) -> bool:
        return landmark_id in self._rows_by_id()

    # -- the fields, as views of the rows in use ----------------------------------------------
    @property
    def buffers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(real, index, shape_buffer), whole, as the kernels take them with ``len(table)``."""
        return self.real, self.index, self.shape_buffer

    @property
    def lo(self) -> np.ndarray:  # (n,) extent on ξ
        return self.real[LO, : len(self.ids)]

    @property
    def hi(self) -> np.ndarray:  # (n,)
        return self.real[HI, : len(self.ids)]

    @property
    def eta_range(self) -> np.ndarray:  # (n, 2) bounds on B over the extent (no c0)
        return self.real[ETA_LO : ETA_HI + 1, : len(self.ids)].T

    @property
    def evidence(self) -> np.ndarray:  # (n, 2) ξ-interval of the hits supporting it
        return self.real[EV_LO : EV_HI + 1, : len(self.ids)].T

    @property
    def pivot(self) -> np.ndarray:  # (n,)
        return self.real[PIVOT, : len(self.ids)]

    @property
    def xi_var(self) -> np.ndarray:  # (n,)
        return self.real[XI_VAR, : len(self.ids)]

    @property
    def shift_slope(self) -> np.ndarray:  # (n,)
        return self.real[SHIFT_SLOPE, : len(self.ids)]

    @property
    def model_var(self) -> np.ndarray:  # (n,)
        return self.real[MODEL_VAR, : len(self.ids)]

    @property
    def fit_half(self) -> np.ndarray:  # (n,)
        return self.real[FIT_HALF, : len(self.ids)]

    @property
    def variate(self) -> np.ndarray:  # (n,) int64, 1 or 2
        return self.index[VARIATE, : len(self.ids)]

    @property
    def order(self) -> np.ndarray:  # (n,) int64 each shape's own order
        return self.index[ORDER, : len(self.ids)]

    @property
    def side(self) -> np.ndarray:  # (n,) int64 face seen: +1 from +η, −1 from −η, 0 unknown
        return self.index[SIDE, : len(self.ids)]

    @property
    def changed_at(self) -> np.ndarray:  # (n,) int64 step created, refit or merged
        return self.index[CHANGED_AT, : len(self.ids)]

    @property
    def received(self) -> np.ndarray:  # (n,) int64 1: holds a received landmark's data
        return self.index[RECEIVED, : len(self.ids)]

    @property
    def stamp(self) -> np.ndarray:  # (n,) int64 moves with every change of shape or extent
        return self.index[STAMP, : len(self.ids)]

    @property
    def shape(self) -> np.ndarray:  # (n, M+1) [0, b_1, …, b_M]
        return self.shape_buffer[: len(self.ids)]

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
        received: bool = False,
        shift_slope: float = math.nan,
    ) -> int:
        """Add a landmark at the end (its c0 was appended to the state); returns its new id.

        ``evidence`` (default: the extent) is the ξ-interval of the hits that support it; the
        extent must lie within it ± :data:`EXTENT_MARGIN` (the caller clips, see
        :func:`clip_to_evidence`); ``received``: it holds a received landmark's data."""
        landmark_id = self._next_id
        self._next_id += 1
        i = len(self.ids)
        self._make_room(i + 1, poly.order + 1)
        map_kernels.write_row(
            *self.buffers, i, poly.coeffs, poly.variate, poly.lo, poly.hi,
            (poly.lo, poly.hi) if evidence is None else evidence, pivot, xi_var, model_var,
            fit_half, shift_slope, landmark_id, int(side), step, int(received),
        )  # fmt: skip
        self.ids.append(landmark_id)
        self._built.append(poly)
        self._built_stamp.append(0)
        self._sizes = None
        self._changed(ids=True)
        return landmark_id

    def _make_room(self, rows: int, width: int) -> None:
        """Buffers for at least ``rows`` landmarks and shapes ``width`` coefficients wide."""
        capacity, old_width = self.shape_buffer.shape
        if rows <= capacity and width <= old_width:
            return
        size = max(rows, 2 * capacity) if rows > capacity else capacity
        n = len(self.ids)
        real, index = np.zeros((N_REAL, size)), np.zeros((N_INDEX, size), dtype=np.int64)
        real[:, :n], index[:, :n] = self.real[:, :n], self.index[:, :n]
        shape = np.zeros((size, max(width, old_width)))
        shape[:n, :old_width] = self.shape_buffer[:n]
        self.real, self.index, self.shape_buffer = real, index, shape

    def remove(self, index: int) -> int:
        """Drop row ``index`` (its c0 left the state); returns its id. The rows after it move
        up one."""
        n = len(self.ids)
        landmark_id = self.ids.pop(index)
        del self._built[index], self._built_stamp[index]
        self._sizes = None
        self.real[:, index : n - 1] = self.real[:, index + 1 : n]
        self.index[:, index : n - 1] = self.index[:, index + 1 : n]
        self.shape_buffer[index : n - 1] = self.shape_buffer[index + 1 : n]
        self._changed(ids=True)
        return landmark_id

    def extend_to_hit(self, index: int, xi: float) -> None:
        """Stretch landmark ``index``'s extent and evidence to a supporting hit at ``xi``."""
        map_kernels.extend_to_hit(*self.buffers, index, float(xi))
        self._changed(ids=False)

    def set_extent(self, index: int, lo: float, hi: float) -> None:
        """New extent [lo, hi] of landmark ``index`` (same shape)."""
        map_kernels.set_extent(*self.buffers, index, float(lo), float(hi))
        self._changed(ids=False)

    def set_shape(self, index: int, poly: Polynomial) -> None:
        """New shape of landmark ``index`` (same variate, extent and order at most the
        table's widest, e.g. a line turned by a link's estimate of its turn)."""
        if poly.variate != self.index[VARIATE, index] or (poly.lo, poly.hi) != (
            self.real[LO, index],
            self.real[HI, index],
        ):
            raise ValueError("set_shape: the variate and extent must stay")
        if poly.order + 1 > self.shape_buffer.shape[1]:
            raise ValueError(f"set_shape: order {poly.order} above the table's")
        shape = self.shape_buffer[index]
        shape[:] = 0.0
        shape[1 : poly.order + 1] = poly.shape
        self.index[ORDER, index] = map_kernels.own_order(shape)
        map_kernels.set_extent(*self.buffers, index, poly.lo, poly.hi)  # η range, stamp
        self._built[index] = poly
        self._built_stamp[index] = int(self.index[STAMP, index])
        self._sizes = None
        self._changed(ids=False)

    def extents_changed(self) -> None:
        """The compiled step stretched extents in place: drop the caches built on them."""
        self._changed(ids=False)

    def _changed(self, ids: bool) -> None:
        self._packed = None
        self._rows = None
        if ids:
            self._row_of = None
        self.version += 1

    # -- views --------------------------------------------------------------------------------
    def poly(self, index: int) -> Polynomial:
        """Landmark ``index``'s shape and extent (its fit's c0; the current one is in the
        state), the same object until the landmark changes."""
        stamp = int(self.index[STAMP, index])
        if self._built_stamp[index] != stamp:
            old = self._built[index]
            self._built[index] = Polynomial.unchecked(  # the extents the kernels stretch
                old.variate, old.coeffs, float(self.real[LO, index]), float(self.real[HI, index])
            )
            self._built_stamp[index] = stamp
        return self._built[index]

    @property
    def sizes(self) -> np.ndarray:
        """(n,) int64: each landmark's number of coefficients as :meth:`poly` gives it (its
        polynomial's order as inserted or set, which a zero top coefficient keeps above the
        shape's own order), cached until a landmark is inserted, removed or reshaped."""
        if self._sizes is None:
            self._sizes = np.array([p.coeffs.size for p in self._built], dtype=np.int64)
        return self._sizes

    def polynomials(self, c0s: Sequence[float] | np.ndarray) -> list[Polynomial]:
        """Every landmark with its c0 from ``c0s`` (n,), in state order."""
        return [self.poly(i).with_c0(c) for i, c in enumerate(c0s)]

    def packed(self) -> PackedPolynomials:
        """The shapes as arrays (copies, cached until the next change: they stay valid)."""
        if self._packed is None:
            self._packed = PackedPolynomials(
                self.variate.copy(), self.shape.copy(), self.lo.copy(), self.hi.copy()
            )
        return self._packed

    def arrays(self) -> ShapeArrays:
        """The shapes as the kernels take them (views of the table's buffers, no copy)."""
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


class PolynomialsView(Sequence[Polynomial]):
    """Row → shape-and-extent sequence over a :class:`LandmarkTable` (``table.polys``)."""

    def __init__(self, table: LandmarkTable) -> None:
        self._table = table

    @overload
    def __getitem__(self, i: int) -> Polynomial: ...
    @overload
    def __getitem__(self, i: slice) -> list[Polynomial]: ...
    def __getitem__(self, i: int | slice) -> Polynomial | list[Polynomial]:
        n = len(self._table)
        if isinstance(i, slice):
            return [self._table.poly(k) for k in range(n)[i]]
        if not -n <= i < n:
            raise IndexError(f"landmark row {i} out of range ({n} landmarks)")
        return self._table.poly(i % n if i < 0 else i)

    def __len__(self) -> int:
        return len(self._table)


class ShapesView(Mapping[int, Polynomial]):
    """Read-only id → shape-and-extent mapping over a :class:`LandmarkTable` (state order)."""

    def __init__(self, table: LandmarkTable) -> None:
        self._table = table

    def __getitem__(self, landmark_id: int) -> Polynomial:
        return self._table.poly(self._table.index_of(landmark_id))

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
    are projected, so a bulge between the ends counts (``old.points_at(np.linspace(…))``'s
    floats in one compiled call, :func:`~polyslam_env.slam.map_kernels.equally_spaced`)."""
    lo, hi = float(evidence[0]), float(evidence[1])
    xy = map_kernels.equally_spaced(old.coeffs, old.variate, lo, hi, samples)  # (S, 2)
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

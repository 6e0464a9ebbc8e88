"""Beam points kept for later, as columns: :class:`StoredPoints` (STYLE habit 21).

The association (paper §3.1) keeps the points that no landmark explains in *clusters* (a new
landmark is fitted once one holds more than ε_Z) and those a landmark explains badly in its
*Q_bad* set (refit past ε_M). Every such point is one row of two field-major buffers
(:mod:`~polyslam_env.slam.columns`): where it was seen in frame 0, along which beam direction,
its range σ, its LMS weight, the pose estimate of its step; its beam, step, what holds it
(``KIND``: a cluster, a landmark's Q_bad, or this step's refit / new-landmark request),
which one (``OWNER``: the cluster's key, the landmark's id, the request's number) and its
order there (``RANK``). Rows are in no particular order: a holder's points are its rows sorted
by rank, clusters are ordered by key (oldest first), as the lists of the paper's description
were. The compiled association (:func:`~polyslam_env.slam.map_kernels.associate_scan`) adds
and moves points; this class does the rare rest (a cluster given back after a fit, a removed
landmark's Q_bad dropped) and carries every point with a pose correction (:meth:`carry`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from polyslam_env.slam import map_kernels
from polyslam_env.slam.columns import (
    BEAM,
    CLUSTER,
    KIND,
    N_COUNTERS,
    N_POINT_INDEX,
    N_POINT_REAL,
    NEXT_CLUSTER,
    NEXT_RANK,
    OWNER,
    PTH,
    PX,
    PY,
    QBAD,
    RANK,
    SIGMA,
    SIZE,
    STEP,
    UX,
    UY,
    WEIGHT,
    X,
    Y,
)


class PointArrays(NamedTuple):
    """Stored points as the fits read them (:func:`~polyslam_env.slam.fitting.stored_points`)."""

    xy: np.ndarray  # (N, 2) frame-0 coordinates
    direction: np.ndarray  # (N, 2) unit beam directions in frame 0
    sigma: np.ndarray  # (N,) range noise σ (m)
    weight: np.ndarray  # (N,) LMS weights 1/‖P_{k|k−1}‖ of their steps
    pose: np.ndarray  # (N, 3) pose estimates of their steps
    beam: np.ndarray  # (N,) int64 beam index at its step
    step: np.ndarray  # (N,) int64 step it was measured at

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def subset(self, rows: np.ndarray) -> PointArrays:
        """The points at ``rows`` (an index or mask array), in that order."""
        return PointArrays(
            self.xy[rows], self.direction[rows], self.sigma[rows], self.weight[rows],
            self.pose[rows], self.beam[rows], self.step[rows],
        )  # fmt: skip


def point_arrays(
    xy: np.ndarray,
    direction: np.ndarray,
    sigma: float | np.ndarray,
    weight: float | np.ndarray,
    pose: np.ndarray,
    beam: np.ndarray | None = None,
    step: int | np.ndarray = -1,
) -> PointArrays:
    """Points from columns; scalars (a common σ, weight, step; one pose (3,)) broadcast."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    count = len(xy)
    pose = np.asarray(pose, dtype=float)
    return PointArrays(
        xy,
        np.asarray(direction, dtype=float).reshape(count, 2),
        np.broadcast_to(np.asarray(sigma, dtype=float), (count,)).copy(),
        np.broadcast_to(np.asarray(weight, dtype=float), (count,)).copy(),
        np.broadcast_to(pose, (count, 3)).copy(),
        np.full(count, -1, dtype=np.int64) if beam is None else np.asarray(beam, np.int64),
        np.broadcast_to(np.asarray(step, dtype=np.int64), (count,)).copy(),
    )


class StoredPoints:
    """Every cluster and Q_bad point of one robot's map, as the rows of field-major buffers
    (module docstring): ``real`` (N_POINT_REAL, capacity) float64, ``index`` (N_POINT_INDEX,
    capacity) int64, ``counters`` (rows in use, next rank, next cluster key, this step's
    requests). The compiled association writes them; :meth:`reserve` makes room first."""

    def __init__(self, capacity: int = 64) -> None:
        self.real = np.zeros((N_POINT_REAL, capacity))
        self.index = np.zeros((N_POINT_INDEX, capacity), dtype=np.int64)
        self.counters = np.zeros(N_COUNTERS, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.counters[SIZE])

    @property
    def buffers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(real, index, counters), as the kernels take them."""
        return self.real, self.index, self.counters

    def reserve(self, extra: int) -> None:
        """Room for ``extra`` more points (the buffers grow by doubling)."""
        need = len(self) + extra
        capacity = self.real.shape[1]
        if need <= capacity:
            return
        size = max(need, 2 * capacity)
        real, index = np.zeros((N_POINT_REAL, size)), np.zeros((N_POINT_INDEX, size), np.int64)
        real[:, :capacity], index[:, :capacity] = self.real, self.index
        self.real, self.index = real, index

    # -- reading ----------------------------------------------------------------------------------
    def rows_of(self, kind: int, owner: int) -> np.ndarray:
        """Rows of the points one holder keeps, in rank order."""
        n = len(self)
        mine = np.flatnonzero((self.index[KIND, :n] == kind) & (self.index[OWNER, :n] == owner))
        if mine.size < 2:  # none (a received landmark's Q_bad) or one: in order already
            return mine
        return mine[np.argsort(self.index[RANK, mine], kind="stable")]

    def take(self, rows: np.ndarray) -> PointArrays:
        """The points at ``rows`` as arrays (copies), in that order."""
        real, index = self.real[:, rows], self.index[:, rows]
        return PointArrays(
            np.ascontiguousarray(real[X : Y + 1].T),
            np.ascontiguousarray(real[UX : UY + 1].T),
            real[SIGMA].copy(),
            real[WEIGHT].copy(),
            np.ascontiguousarray(real[PX : PTH + 1].T),
            index[BEAM].copy(),
            index[STEP].copy(),
        )

    def clusters(self) -> list[PointArrays]:
        """Every cluster's points, clusters oldest first."""
        n = len(self)
        is_cluster = self.index[KIND, :n] == CLUSTER
        keys = np.unique(self.index[OWNER, :n][is_cluster])
        return [self.take(self.rows_of(CLUSTER, int(key))) for key in keys]

    def qbad(self, landmark_id: int) -> PointArrays:
        """The points landmark ``landmark_id`` approximates badly (Q_bad), oldest first."""
        return self.take(self.rows_of(QBAD, landmark_id))

    # -- changes ----------------------------------------------------------------------------------
    def drop(self, rows: np.ndarray) -> None:
        """Forget the points at ``rows``: the last rows in use move into their places."""
        keep = np.ones(len(self), dtype=bool)
        keep[rows] = False
        kept = np.flatnonzero(keep)
        count = kept.size
        self.real[:, :count] = self.real[:, kept]
        self.index[:, :count] = self.index[:, kept]
        self.counters[SIZE] = count

    def drop_qbad(self, *landmark_ids: int) -> None:
        """Forget the Q_bad of landmarks ``landmark_ids`` (they left the map)."""
        n = len(self)
        kind, owner = self.index[KIND, :n], self.index[OWNER, :n]
        theirs = np.zeros(n, dtype=bool)
        for landmark_id in landmark_ids:
            theirs |= owner == landmark_id
        rows = np.flatnonzero(theirs & (kind == QBAD))
        if rows.size:
            self.drop(rows)

    def add_cluster(self, points: PointArrays) -> None:
        """A new cluster (the newest, last in cluster order) holding ``points`` in order."""
        count = len(points)
        if count == 0:
            return
        self.reserve(count)
        start = len(self)
        cols = slice(start, start + count)
        real, index = self.real, self.index
        real[X, cols], real[Y, cols] = points.xy[:, 0], points.xy[:, 1]
        real[UX, cols], real[UY, cols] = points.direction[:, 0], points.direction[:, 1]
        real[PX, cols], real[PY, cols], real[PTH, cols] = points.pose.T
        real[SIGMA, cols], real[WEIGHT, cols] = points.sigma, points.weight
        index[BEAM, cols], index[STEP, cols] = points.beam, points.step
        index[KIND, cols], index[OWNER, cols] = CLUSTER, self.counters[NEXT_CLUSTER]
        rank = self.counters[NEXT_RANK]
        index[RANK, cols] = np.arange(rank, rank + count)
        self.counters[NEXT_CLUSTER] += 1
        self.counters[NEXT_RANK] += count
        self.counters[SIZE] += count

    def carry(self, before: np.ndarray, after: np.ndarray) -> None:
        """Move every point rigidly with a pose correction from ``before`` (3,) to ``after``.

        Stored points were placed from the pose estimates of their steps, which odometry ties
        rigidly to the current pose; the fits model them so (∂π/∂X through the current pose).
        When the update corrects the current pose, the recent trajectory moves with it, and so
        must the points: else a new landmark mixes stale coordinates with the corrected pose.
        Position, direction and pose turn by the heading's change about the old position and
        follow the position's change.
        """
        n = len(self)
        if n == 0:
            return
        dtheta = float(after[2] - before[2])
        c, s = math.cos(dtheta), math.sin(dtheta)
        if n > 1:  # as numpy's (n, 7) × (7, 7) product computed it (BLAS gemm), compiled
            map_kernels.carry_points(self.real, n, before, after, c, s)
            return
        # A lone point: numpy's product of one row is BLAS's gemv, which rounds differently
        # from gemm's chain of fused multiply-adds; kept as it was.
        bx, by, ax, ay = float(before[0]), float(before[1]), float(after[0]), float(after[1])
        rows = np.ascontiguousarray(self.real[X : PTH + 1, :n].T)  # (1, 7)
        rows -= (bx, by, 0.0, 0.0, bx, by, 0.0)
        motion = np.array(
            [  # Rᵀ on xy, direction and pose xy (row vectors times Rᵀ)
                [c, s, 0.0, 0.0, 0.0, 0.0, 0.0],
                [-s, c, 0.0, 0.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, c, s, 0.0, 0.0, 0.0],
                [0.0, 0.0, -s, c, 0.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, c, s, 0.0],
                [0.0, 0.0, 0.0, 0.0, -s, c, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            ]
        )
        rows = rows @ motion
        rows += (ax, ay, 0.0, 0.0, ax, ay, dtheta)
        self.real[X : PTH + 1, :n] = rows.T

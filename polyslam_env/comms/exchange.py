"""Rendezvous map exchange wired into the robots' SLAM (SPEC §4, paper §3.2).

Once per control step, after every robot's SLAM step, :meth:`RendezvousExchange.step`

1. drops the queued messages to and from robots that failed (failure is permanent), counted
   as ``messages_dropped``;
2. finds the **mutual sightings**: i's camera sees j and j's sees i, both robots active, and
   both measured distances within the channel range;
3. for every pair whose mutual sighting starts a **meeting** (a new rendezvous, counted once
   per meeting: the pair was out of mutual sight for at least ``meeting_gap`` steps, so a
   flickering camera does not make a new one, and its last meeting began at least
   ``meeting_interval`` steps ago) builds one message each way and queues it on the
   :class:`Channel`: the sender's landmarks changed (created, refit, merged) since its last
   meeting with that receiver, except those it received from that receiver and has not
   changed since (no echo), its pose estimate and its bearing measurement of the receiver;
4. lets the channel deliver (loss, retry at the next step in view, bandwidth cap, expiry);
5. applies every delivered message exactly once at its receiver: relative pose from the
   receiver's range and bearing of the sender (taken at the step the message was sent) and
   the sender's bearing from the header; ``T_{l0,j0} = T_{j,j0} T_{l,j} T_{l,l0}⁻¹``, refined
   on the walls the receiver already holds (``align_maps``; :mod:`.alignment`: the mean and
   its posterior covariance, which decides which received points are kept; with
   ``SlamConfig.square_walls`` a refinement that turns the sender's straight walls off square
   to the receiver's is refused, :meth:`RendezvousExchange._off_square`); each polynomial
   → piecewise-linear chain (chord error ≤ ``chord_tol``, 5 mm) → points every ``spacing``
   (5 cm) along it → into the receiver's frame → weighted LMS refit within ``refit_tol``
   (2.5 mm) of those points, halving the chain where one polynomial cannot follow it
   (:func:`refit_received`) → fused by the rules below.
   Each received landmark thus lies within 7.5 mm of the sender's curve mapped through the
   estimated transform.

**Fusion: never the same information twice.** The correlation between a received polynomial
and what the receiver holds is unknown (the sender's map may contain data that came from the
receiver, or an earlier version of the same wall). Each received piece is compared with the
receiver's landmarks of the same wall (those PolySlam's merge test pairs it with) by the
variance of their offset along the curve's normal (:func:`normal_variance`):

* rule 1, keep the better: covariance intersection of two scalar estimates with unknown
  correlation, min over ω of (ω/σ₁² + (1−ω)/σ₂²)⁻¹, is the smaller of the two variances (ω ∈
  {0, 1}): the better estimate alone. So where a held landmark is at least as good, the
  piece's points it covers are dropped; only the uncovered runs of the chain (at least
  ``merge_min_overlap`` long) are refitted and fused in turn. A received polynomial thus never
  overwrites or moves a better own one, and fusing the same message twice changes nothing.
  Checked first on the received chain: where held walls no worse than any refit of it could
  be (:func:`refit_variance_floor`) cover all its kept points, it is not refitted at all
  (:attr:`RendezvousExchange.covered`);
* rule 2, a newer version replaces the older: when the piece is better than every held
  landmark of its wall, those holding data from the same sender (an earlier version it sent,
  or a merge with one; provenance is kept per landmark and carried over the receiver's refits
  and merges) are removed from the state before the piece is inserted;
* rule 3: the piece is inserted with :meth:`PolySlam.insert_landmark`, whose merge check fuses
  it with an overlapping landmark made of independent data (own beams, or a third robot's).
  Through a third robot only unchanged copies keep their provenance ("Versions" below): a
  copy the third robot merged with its own data is its own new version.

**Wire frame.** A message on the channel is ``encode(message)`` (``messages.py``) followed by
an exchange trailer: the sender's pose variances σ²_x, σ²_y, σ²_θ (3 floats of the message's
width F) and a CRC-32 of everything before it (4 bytes), i.e. 3F + 4 bytes more. The
sender's pose covariance is not in the message header but the receiver needs it: the
transform depends on the sender's pose estimate. The trailer is counted in every byte figure.
In alignment mode the trailer starts with the sender's feature map and the changes of its free
space since what the receiver holds (:func:`frame_message`, ``comms/free_space.py``).

**Noise model of a received polynomial.** The refit's points depend on the receiver's state
only through its pose (d_state: the first three columns of the transform's (3, 9) Jacobian),
and on a 7-vector of noise: the sender's c0 (its variance from the message), the relative
pose (3, covariance :func:`relative_pose_covariance` of the camera noise) and the sender's
pose estimate (3, diagonal covariance from the trailer). The sender's c0 and pose are
correlated in its own filter; that correlation is not sent and is neglected.

**Late delivery.** A lost message is retried while the robots stay in view; by then the
receiver has moved. Its relative-pose measurement and pose estimate from the send step are
kept, and the old pose is expressed as ``x_now ⊕ Δ⁻¹`` with Δ the estimated motion since, so
the transform's Jacobian is taken w.r.t. the *current* pose (identity chain when Δ = 0).

**Bookkeeping.** Per ordered pair (sender, receiver): the sender's SLAM step at their last
meeting; only landmarks with ``changed_at`` after it are sent. Landmarks inserted from a
message get ``changed_at`` = the receiver's step, so they are not sent back at the same
meeting. Landmarks of a message that expires (``max_age``) are sent again at the next
meeting of that pair. Nothing is applied twice: every delivery is checked against the set of
applied message ids.

**Versions.** Every record names the version it carries: (origin robot, landmark id in the
origin's map), unique because the SLAM never reuses an id and a refit or merge makes a new
one (``slam/lineage.py``). A landmark the receiver inserted unchanged (not merged) is a copy
of that version and is forwarded under it; anything the receiver refits or merges is its
own new version. So a wall that travels along a chain of meetings keeps its name, and

* a receiver skips, before any transform or refit, a record of its own making (an echo
  through a third robot) or of a version it has integrated before (a forwarded copy of what
  it got directly, or the other way round): the integration of received walls is bounded by
  the number of versions made on the floor, not by the number of meetings
  (:attr:`RendezvousExchange.skipped`, :attr:`RendezvousExchange.refits`);
* a sender does not send a version its peer made, one it delivered to that peer before (the
  channel acknowledges deliveries; a lost message is sent again), or one the peer sent it.

A skipped version's points are not taken again from a later copy (its transform may be
better): the same information is never fused twice, and the first copy is the one kept.

**Other payloads.** With ``payload="points"`` (beam hits since the last meeting) or
``"grid"`` (occupancy raster of the sender's whole map), the receiver decodes the message
and counts its bytes but does not change its SLAM: these payloads exist to measure the cost
of the alternatives (the SLAM integrates polynomials only). ``compare_payloads=True`` records,
for every message built, the size every payload kind and precision would have had
(:attr:`RendezvousExchange.payload_log`), so one episode compares all of them.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy.spatial import cKDTree

from polyslam_env.comms import polyline
from polyslam_env.comms.alignment import (
    WallArrays,
    frame_points,
    pack_walls,
    refine_transform,
    square_turn,
    straight_walls,
)
from polyslam_env.comms.channel import Channel, ChannelConfig, Delivered, Expired
from polyslam_env.comms.free_space import FreeCells, FreeSpace
from polyslam_env.comms.kernels import (
    better_cover,
    chain_fit,
    kept_runs,
    longest_straight,
    normal_variances,
    point_jacobians,
    received_cover,
    table_walls,
    variance_floor,
)
from polyslam_env.comms.kernels import received_geometry as kernel_geometry
from polyslam_env.comms.messages import (
    GridMessage,
    Header,
    Message,
    PointsMessage,
    PolynomialMessage,
    PolynomialRecord,
    decode,
    encode,
)
from polyslam_env.comms.payloads import ScanLog, occupancy_grid
from polyslam_env.comms.relative_pose import delivery_transform, rendezvous_transform
from polyslam_env.core.geometry import (
    compose,
    compose_with_jacobians,
    inverse,
    rotation,
    wrap_scalar,
)
from polyslam_env.slam.alignment import Alignment, FeatureMap, align
from polyslam_env.slam.corners import wall_corners
from polyslam_env.slam.features import FeatureBook
from polyslam_env.slam.fitting import Fit, PointSet, check_fit_size
from polyslam_env.slam.lineage import MERGED, REMOVED, REPLACED
from polyslam_env.slam.links import SQUARE_MIN_LENGTH
from polyslam_env.slam.map_kernels import curve_box
from polyslam_env.slam.merging import MERGE_ANGLE_DEG, near_merge_gammas
from polyslam_env.slam.polynomial import Polynomial

if TYPE_CHECKING:
    from polyslam_env.slam.robot import PolySlam

_TRAILER_CRC = struct.Struct("<I")
# Alignment mode's free space (comms/free_space.py): cells of 0.1 m, a received wall sampled at
# the same spacing; beams count as free up to 0.3 m before their return, the aligners' support
# threshold th2 (walls aligned within it of the receiver's own are not contradictions).
FREE_RESOLUTION = 0.1
FREE_MARGIN = 0.3
# A sent wall point agrees with the receiver's map within 0.1 m of one of its walls: two maps'
# errors of up to 5 cm each (the map_precision tolerance), wall samples 5 cm apart.
AGREE_DISTANCE = 0.1
_FLOAT: dict[int, np.dtype[np.floating]] = {4: np.dtype("<f4"), 8: np.dtype("<f8")}
PAYLOAD_KINDS = ("polynomials", "points", "grid")
PRECISIONS = ("float32", "float64")
_MAX_SPLIT_DEPTH = 3  # a received polynomial is cut into at most 2**3 pieces to refit
_MAX_TRIM_DEPTH = 2  # trimming covered points off a piece, then off its remainders: no more
_BOX_SAMPLES = 16  # samples of a received curve for its bounding box (γ_M covers the rest)
#: Relative margin when comparing normal-offset variances: the same fit recomputed on a grown
#: state differs by round-off only, and must count as "no better" (rule 1 keeps the held one).
_ROUNDOFF = 1.0 + 1e-9


class DetectionLike(Protocol):
    """What the exchange reads of a camera detection (``world.sensors.Detection``)."""

    @property
    def target(self) -> int: ...
    @property
    def distance(self) -> float: ...
    @property
    def bearing(self) -> float: ...


# -- results --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DeliveredMessage:
    """A message applied at its receiver."""

    msg_id: int
    sender: int
    receiver: int
    kind: str  # "polynomials", "points" or "grid"
    bytes: int  # size on the wire, trailer included
    n_polynomials: int  # records in the message (0 for the other kinds)
    sent_step: int
    delivered_step: int
    attempts: int
    # refits in the receiver's frame, before any merge (a record that better held walls cover
    # wholly has none: RendezvousExchange.covered)
    received: tuple[Polynomial, ...]
    landmark_ids: tuple[int, ...]  # receiver's landmarks holding them after the merge check


@dataclass(frozen=True)
class PayloadSizes:
    """Bytes one message would take with every payload kind and precision."""

    sender: int
    receiver: int
    step: int
    n_polynomials: int
    n_points: int
    grid_shape: tuple[int, int]
    sizes: dict[str, int]  # "kind/precision" → bytes on the wire, trailer included


@dataclass(frozen=True, eq=False)
class ExchangeStep:
    """What one exchange step did."""

    step: int
    in_view: tuple[tuple[int, int], ...]  # mutual sightings (i < j)
    new_rendezvous: tuple[tuple[int, int], ...]  # pairs (i < j) whose sighting began now
    sent: tuple[tuple[int, int, int], ...]  # (sender, receiver, bytes) queued this step
    delivered: tuple[DeliveredMessage, ...]
    expired: tuple[Expired, ...]
    dropped: tuple[Expired, ...] = ()  # messages to or from robots that failed this step


@dataclass(frozen=True, eq=False)
class AlignmentAttempt:
    """One alignment of a received feature map with the receiver's (alignment mode)."""

    step: int  # delivery step
    sender: int
    receiver: int
    result: Alignment  # its transform maps the sender's frame into the receiver's


@dataclass(frozen=True, eq=False)
class _Sighting:
    """What a robot measured of another at a rendezvous, and its own pose estimate then."""

    pose: np.ndarray  # (3,) own pose estimate at that step
    distance: float  # m
    bearing: float  # rad


# -- wire frame ----------------------------------------------------------------------------------
_FEATURE_HEAD = struct.Struct("<HB")  # features n, descriptor length d (| _ORIENTED)
_ORIENTED = 0x80  # flag in the descriptor-length byte: rows carry a heading
# free-space block: corner's lattice index (col, row), rows, cols, deflated length
_FREE_HEAD = struct.Struct("<iiHHI")
NO_FREE_CELLS: FreeCells = ((0, 0), np.zeros((0, 0), dtype=bool))


def frame_message(
    message: bytes,
    pose_var: np.ndarray,
    features: FeatureMap | None = None,
    free: FreeCells | None = None,
) -> bytes:
    """Message bytes followed by the exchange trailer: the sender's feature map when given
    (alignment mode: n rows of position, heading if the features are oriented, and
    descriptor in the message's float width, then n as uint16 and a uint8 holding the
    descriptor length d with bit 7 set for oriented features) and after it the changes of its
    free space (``free``, none when not given; :meth:`FreeSpace.changes`: the block's bits row
    by row, packed 8 to a byte and deflated (zlib), then the corner's lattice index (col, row)
    as int32, the block's rows and columns as uint16 and the deflated length as uint32), the
    pose variances and a CRC-32."""
    width = message[3]  # the message header's float width
    var = np.asarray(pose_var, dtype=float).reshape(3)
    if not all(math.isfinite(v) and v >= 0 for v in var.tolist()):
        raise ValueError(f"pose variances must be finite and >= 0, got {var}")
    if free is not None and features is None:
        raise ValueError("a free-space block goes with a feature map (alignment mode)")
    body = message
    if features is not None:
        n, d = features.descriptors.shape
        if n >= 2**16 or d >= _ORIENTED:
            raise ValueError(f"feature map too large for the frame: {n} features of {d} numbers")
        columns = [features.positions, features.descriptors]
        if features.headings is not None:
            columns.insert(1, features.headings[:, None])
            d |= _ORIENTED
        block = np.hstack(columns).astype(_FLOAT[width])
        body += block.tobytes() + _FEATURE_HEAD.pack(n, d)
        (col, row), cells = free if free is not None else NO_FREE_CELLS
        rows, cols = cells.shape
        if max(rows, cols) >= 2**16:
            raise ValueError(f"free-space block too large for the frame: {rows} × {cols} cells")
        packed = zlib.compress(np.packbits(cells.astype(bool), axis=None).tobytes(), 9)
        body += packed + _FREE_HEAD.pack(col, row, rows, cols, len(packed))
    body += var.astype(_FLOAT[width]).tobytes()
    return body + _TRAILER_CRC.pack(zlib.crc32(body))


def unframe_message(
    data: bytes, with_features: bool = False
) -> tuple[Message, np.ndarray, FeatureMap | None, FreeCells | None]:
    """Inverse of :func:`frame_message`: the decoded message, the pose variances (3,), the
    feature map and the free-space block (both None unless ``with_features``: alignment
    mode's frames carry both)."""
    if len(data) < 4 or data[3] not in _FLOAT:
        raise ValueError("truncated or corrupt exchange frame")
    width = data[3]
    size = 3 * width + _TRAILER_CRC.size
    body = data[: -_TRAILER_CRC.size]
    (crc,) = _TRAILER_CRC.unpack(data[-_TRAILER_CRC.size :])
    if len(data) <= size or zlib.crc32(body) != crc:
        raise ValueError("corrupt exchange frame: trailer CRC-32 mismatch")
    var = np.frombuffer(body[-3 * width :], dtype=_FLOAT[width]).astype(float)
    body = body[: -3 * width]
    features = free = None
    if with_features:
        body, free = _split_free(body)
        body, features = _split_features(body, width)
    return decode(body), var, features, free


def _split_free(body: bytes) -> tuple[bytes, FreeCells]:
    """The bytes before the free-space block that ends ``body``, and the block."""
    if len(body) < _FREE_HEAD.size:
        raise ValueError("corrupt exchange frame: no free-space block")
    col, row, rows, cols, size = _FREE_HEAD.unpack(body[-_FREE_HEAD.size :])
    end = len(body) - _FREE_HEAD.size
    if size > end:
        raise ValueError("corrupt exchange frame: free-space block longer than the frame")
    try:
        packed = np.frombuffer(zlib.decompress(body[end - size : end]), dtype=np.uint8)
    except zlib.error as err:
        raise ValueError(f"corrupt exchange frame: free-space block ({err})") from None
    if 8 * len(packed) < rows * cols:
        raise ValueError("corrupt exchange frame: free-space block shorter than its shape")
    cells = np.unpackbits(packed, count=rows * cols).astype(bool).reshape(rows, cols)
    return body[: end - size], ((col, row), cells)


def _split_features(body: bytes, width: int) -> tuple[bytes, FeatureMap]:
    """The message bytes and the feature block that ends ``body`` (read from its end)."""
    if len(body) < _FEATURE_HEAD.size:
        raise ValueError("corrupt exchange frame: no feature block")
    n, flagged = _FEATURE_HEAD.unpack(body[-_FEATURE_HEAD.size :])
    oriented = bool(flagged & _ORIENTED)
    d = flagged & ~_ORIENTED
    lead = 3 if oriented else 2  # position (and heading) before the descriptor
    size = n * (lead + d) * width
    end = len(body) - _FEATURE_HEAD.size
    if size > end:
        raise ValueError("corrupt exchange frame: feature block longer than the frame")
    block = np.frombuffer(body[end - size : end], dtype=_FLOAT[width]).astype(float)
    block = block.reshape(n, lead + d)
    headings = block[:, 2] if oriented else None
    return body[: end - size], FeatureMap(block[:, :2], block[:, lead:], headings)


# -- received polynomial → points in the receiver's frame ----------------------------------------
def received_point_set(
    record: PolynomialRecord,
    transform: np.ndarray,
    d_transform_state: np.ndarray,
    d_transform_noise: np.ndarray,
    noise_cov: np.ndarray,
    n_state: int,
    chord_tol: float = 0.005,
    spacing: float = 0.05,
) -> PointSet:
    """Points on a received polynomial mapped into the receiver's frame, with derivatives.

    ``transform`` (3,) is T_{l0,j0}; ``d_transform_state`` (3, 3) its Jacobian w.r.t. the
    receiver's pose, ``d_transform_noise`` (3, K) w.r.t. the noise it depends on, whose
    covariance is ``noise_cov`` (K, K): at a rendezvous [relative pose | sender's pose] (K = 6),
    after an alignment the transform's own error (K = 3). The point set's noise is
    [sender's c0 ; those K].
    """
    q = chain_points(record.polynomial, chord_tol, spacing)  # (N, 2) sender frame
    xy, dp_dt = frame_points(q, transform)  # (N, 2), (N, 2, 3) ∂p/∂T
    return _point_set(
        record, transform, xy, dp_dt, d_transform_state, d_transform_noise, noise_cov, n_state
    )


def _point_set(
    record: PolynomialRecord,
    transform: np.ndarray,
    xy: np.ndarray,
    dp_dt: np.ndarray,
    d_transform_state: np.ndarray,
    d_transform_noise: np.ndarray,
    noise_cov: np.ndarray,
    n_state: int,
    shift: np.ndarray | None = None,
) -> PointSet:
    """:func:`received_point_set` from the chain's points ``xy`` (N, 2) in the receiver's
    frame and their ∂p/∂T ``dp_dt`` (N, 2, 3) (:func:`frame_points`); the Jacobians in one
    compiled call (:func:`~polyslam_env.comms.kernels.point_jacobians`). ``shift``: the
    sender's η axis turned by the transform, R(θ) e_η (computed when not given)."""
    if shift is None:
        shift = rotation(transform[2]) @ _ETA_AXIS[record.polynomial.variate]  # (2,)
    d_state, d_noise = point_jacobians(
        dp_dt, np.ascontiguousarray(d_transform_state, dtype=float),
        np.ascontiguousarray(d_transform_noise, dtype=float), shift, n_state,
    )  # fmt: skip
    # made to PointSet's shapes here (N, 2), (N, 2, S), (N, 2, 1 + K), (1 + K, 1 + K), ones
    return PointSet.unchecked(
        xy,
        d_state,
        d_noise,
        _with_c0_variance(record.c0_var, noise_cov) / RECEIVED_CI_WEIGHT,
        np.ones(len(xy)),
    )


def _with_c0_variance(c0_var: float, noise_cov: np.ndarray) -> np.ndarray:
    """The block diagonal [[c0_var, 0], [0, noise_cov]] (as ``scipy.linalg.block_diag``,
    which costs ~100 µs a call in its argument handling, once per received record)."""
    k = len(noise_cov)
    out = np.zeros((1 + k, 1 + k))
    out[0, 0] = c0_var
    out[1:, 1:] = noise_cov
    return out


def chain_points(poly: Polynomial, chord_tol: float, spacing: float) -> np.ndarray:
    """(N, 2) points every ``spacing`` (m) along the piecewise-linear chain of ``poly``
    (chord error ≤ ``chord_tol``), in its own frame; read-only.

    Integrating a record asks for its chain three times (the points, their normal sigma, the
    alignment; a chain is one compiled call, ~0.1 ms); the last :data:`_CHAIN_CACHE_SIZE`
    chains are kept, keyed by the polynomial's exact contents, so every caller gets the very
    same points.
    """
    key = (poly.variate, poly.coeffs.tobytes(), poly.lo, poly.hi, chord_tol, spacing)
    q = _CHAIN_CACHE.pop(key, None)
    if q is None:
        q = polyline.chain_points(poly, chord_tol, spacing)
        q.setflags(write=False)
    _CHAIN_CACHE[key] = q  # (re)inserted last: the most recently used
    while len(_CHAIN_CACHE) > _CHAIN_CACHE_SIZE:
        _CHAIN_CACHE.pop(next(iter(_CHAIN_CACHE)))  # the least recently used
    return q


_CHAIN_CACHE_SIZE = 64  # 0: no cache
_ETA_AXIS = {1: np.array([0.0, 1.0]), 2: np.array([1.0, 0.0])}  # variate → its η axis (x, y)
_CHAIN_CACHE: dict[tuple[object, ...], np.ndarray] = {}


def _subset(points: PointSet, rows: slice) -> PointSet:
    """The points of a run of ``points``' rows (a run of a checked set: no checks again)."""
    return PointSet.unchecked(
        points.xy[rows], points.d_state[rows], points.d_noise[rows], points.noise_cov,
        points.weights[rows],
    )  # fmt: skip


def refit_received(
    points: PointSet, order: int, auto_order: bool, tol: float, depth: int = 0
) -> list[Fit]:
    """Weighted LMS fits of a received chain, each within ``tol`` of its points.

    The chain's points carry no noise of their own (their noise is common to all of them), so
    the SLAM's χ² order test does not apply: with ``auto_order`` the lowest order whose largest
    residual is within ``tol`` is taken, else ``order``. A curve turned into another frame may
    bend past what one polynomial of either variate describes; while the fit misses by more
    than ``tol`` the chain is halved (at most :data:`_MAX_SPLIT_DEPTH` times). Coefficients are
    padded to ``order + 1``; fits with non-finite values are dropped.
    """
    return [fit for _, fit in refit_pieces(points, order, auto_order, tol, depth)]


def refit_pieces(
    points: PointSet, order: int, auto_order: bool, tol: float, depth: int = 0
) -> list[tuple[PointSet, Fit]]:
    """:func:`refit_received` with, for each fit, the points (a run of the chain) it fits."""
    fit, worst, finite = _fit_chain(points, order, auto_order, tol)
    n_pts = points.n_points
    if worst > tol and depth < _MAX_SPLIT_DEPTH and n_pts >= 4:
        mid = n_pts // 2
        halves = (slice(0, mid + 1), slice(mid, n_pts))  # they share the middle point
        return [
            piece
            for rows in halves
            for piece in refit_pieces(_subset(points, rows), order, auto_order, tol, depth + 1)
        ]
    return [(points, fit)] if finite else []


def _fit_chain(
    points: PointSet, order: int, auto_order: bool, tol: float
) -> tuple[Fit, float, bool]:
    """The fit (coefficients padded to ``order + 1``), its largest |η residual| (m) and
    whether its c0 and Jacobians are finite: the lowest order whose largest residual is within
    ``tol`` with ``auto_order``, else ``order`` (one compiled call:
    :func:`~polyslam_env.comms.kernels.chain_fit`)."""
    check_fit_size(points.n_points, order)
    valid, var, m, coeffs, lo, hi, rms, gx, gy, worst, finite = chain_fit(
        np.ascontiguousarray(points.xy, dtype=float), points.weights, points.d_state,
        points.d_noise, order, auto_order, tol,
    )  # fmt: skip
    # a fit of a known variate with finite numbers is a valid polynomial (a zero tail
    # included); any other gets Polynomial's checks, and their error
    poly = Polynomial.unchecked(var, coeffs, lo, hi) if valid else Polynomial(var, coeffs, lo, hi)
    fit = Fit(poly, float(coeffs[0]), gx[None, :], gy[None, :], points.noise_cov, rms, m)
    return fit, worst, finite


def map_transform(
    receiver_pose: np.ndarray,
    motion_since: np.ndarray,
    distance: float,
    bearing_receiver: float,
    bearing_sender: float,
    sender_pose: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T_{l0,j0} (3,) mapping the sender's frame into the receiver's, and its Jacobians.

    The receiver (j) measured ``distance`` and ``bearing_receiver`` to the sender (l) when its
    pose was ``receiver_pose ⊕ motion_since⁻¹`` (``motion_since`` = zero pose when the message
    arrives at the step it was sent); ``bearing_sender`` and ``sender_pose`` come from the
    header. Returns T, ∂T/∂(receiver's current pose) (3, 3) with the motion held fixed, and
    ∂T/∂[relative pose | sender pose] (3, 6). One compiled call
    (:func:`~polyslam_env.comms.relative_pose.rendezvous_transform`).
    """
    out = rendezvous_transform(
        np.asarray(receiver_pose, dtype=float), np.asarray(motion_since, dtype=float),
        float(distance),
        float(bearing_receiver), float(bearing_sender), np.asarray(sender_pose, dtype=float),
        0.0, 0.0, np.zeros(3),
    )  # fmt: skip
    return out[0], out[1], out[2]


def _mutual_sightings(
    detections: Sequence[Sequence[DetectionLike]], active: np.ndarray, max_range: float
) -> dict[tuple[int, int], tuple[DetectionLike, DetectionLike]]:
    """(i, j) with i < j → (i's detection of j, j's detection of i), for mutual sightings."""
    seen = {(i, d.target): d for i, dets in enumerate(detections) for d in dets}
    up = active.tolist()  # Python bools: no numpy scalar per lookup
    out: dict[tuple[int, int], tuple[DetectionLike, DetectionLike]] = {}
    for i, j in sorted(pair for pair in seen if pair[0] < pair[1]):
        d_ji = seen.get((j, i))
        if d_ji is None or not (up[i] and up[j]):
            continue
        d_ij = seen[(i, j)]
        if max(d_ij.distance, d_ji.distance) <= max_range:
            out[(i, j)] = (d_ij, d_ji)
    return out


# -- the exchange ------------------------------------------------------------------------------
class RendezvousExchange:
    """Rendezvous detection, message building, channel and integration for a team.

    See the module docstring for the protocol. ``camera_sigma_d`` (m) and
    ``camera_sigma_bearing`` (rad) are the camera noise the relative-pose covariance uses;
    ``slam_order``/``auto_order`` are the SLAM's fit settings (used for the refits).
    """

    def __init__(
        self,
        config: ChannelConfig,
        num_robots: int,
        rng: np.random.Generator,
        camera_sigma_d: float,
        camera_sigma_bearing: float,
        slam_order: int = 3,
        auto_order: bool = True,
        *,
        chord_tol: float = 0.005,
        spacing: float = 0.05,
        refit_tol: float = 0.0025,
        grid_resolution: float = 0.05,
        max_range: float = 2.0,
        compare_payloads: bool = False,
        align_rng: np.random.Generator | None = None,
    ) -> None:
        if num_robots < 1:
            raise ValueError(f"num_robots must be >= 1, got {num_robots}")
        self.config = config
        self.num_robots = num_robots
        self.channel = Channel(config, rng)
        self.sigma_d, self.sigma_bearing = float(camera_sigma_d), float(camera_sigma_bearing)
        self.order, self.auto_order = slam_order, auto_order
        self.chord_tol, self.spacing, self.refit_tol = chord_tol, spacing, refit_tol
        self.grid_resolution = grid_resolution
        self.compare_payloads = compare_payloads
        self.payload_log: list[PayloadSizes] = []
        self.history: list[DeliveredMessage] = []  # every applied message, in order
        self.alignments: list[AlignmentAttempt] = []  # alignment mode: every attempt, in order
        if config.mode == "alignment" and align_rng is None:
            raise ValueError("alignment mode needs align_rng (RANSAC's and ICP's draws)")
        self._align_rng = align_rng
        self.scan_logs = [ScanLog(max_range) for _ in range(num_robots)]
        # alignment mode: every wall a receiver has been sent by each sender (per version,
        # sender frame), fused or not: what the free-space test checks
        self._heard: dict[tuple[int, int], dict[tuple[int, int], Polynomial]] = {}
        # alignment mode: where each robot's beams have been, to veto wrong alignments
        self.free_space = (
            [FreeSpace(FREE_RESOLUTION, FREE_MARGIN, max_range) for _ in range(num_robots)]
            if config.mode == "alignment"
            else []
        )
        # alignment mode: each sender's free space as its receiver holds it (sender frame),
        # kept by the receiver (heard) and by the sender (sent, to send only changes)
        self._heard_free: dict[tuple[int, int], FreeSpace] = {}
        self._sent_free: dict[tuple[int, int], FreeSpace] = {}
        self._free_changes: dict[int, FreeCells] = {}  # msg → the changes it carries
        self._max_range = float(max_range)
        self._last_meeting: dict[tuple[int, int], int] = {}  # (s, r) → s's SLAM step
        self._last_log: dict[tuple[int, int], int] = {}  # (s, r) → s's scan-log length
        # versions (origin robot, its landmark id; messages.py): per robot, its landmarks that
        # are unchanged copies of a received version; per receiver, the versions it has
        # integrated; per ordered pair (s, r), the versions s knows r holds
        self._copies: list[dict[int, tuple[tuple[int, int], int]]] = [
            {} for _ in range(num_robots)
        ]  # landmark id → (version, revision) it is an unchanged copy of
        # per receiver, each version it integrated → the highest revision integrated; per
        # ordered pair (s, r), each version s knows r holds → its revision
        self._seen: list[dict[tuple[int, int], int]] = [{} for _ in range(num_robots)]
        self._peer_holds: dict[tuple[int, int], dict[tuple[int, int], int]] = {}
        # per robot, its own versions' revisions (absent: 0) and each landmark's extent (lo,
        # hi) when its version or revision was made (:meth:`_revise`)
        self._revision: list[dict[int, int]] = [{} for _ in range(num_robots)]
        self._extent_at: list[dict[int, tuple[float, float]]] = [{} for _ in range(num_robots)]
        self._resend: dict[tuple[int, int], set[int]] = {}  # expired landmark ids per pair
        self._sent_ids: dict[int, tuple[int, int, tuple[int, ...]]] = {}  # msg → s, r, ids
        self._sightings: dict[tuple[int, int, int], _Sighting] = {}  # (r, s, step) → r's view
        self._seq: dict[tuple[int, int], int] = {}
        self._applied: set[int] = set()
        self._last_seen: dict[tuple[int, int], int] = {}  # pair → last step in mutual sight
        self._last_start: dict[tuple[int, int], int] = {}  # pair → step its last meeting began
        self._failed: set[int] = set()
        # provenance, per receiver: landmark id → senders whose data it holds (rules 1–3),
        # carried over its SLAM's refits and merges by their lineage events (read up to here)
        self._sources: list[dict[int, frozenset[int]]] = [{} for _ in range(num_robots)]
        self._lineage_at = [0] * num_robots
        self.superseded = [0] * num_robots  # landmarks replaced by a newer version (rule 2)
        self.dropped_points = [0] * num_robots  # received points too uncertain to keep
        self.off_square = [0] * num_robots  # refined transforms refused as off square (_align)
        self.skipped = [0] * num_robots  # received records of versions already held, skipped
        self.refits = [0] * num_robots  # received chains refitted (refit_pieces calls)
        self.fused = [0] * num_robots  # refitted pieces fused (_fuse calls)
        # fresh records that held walls better than any refit of them cover wholly (rule 1
        # before the refit: refit_variance_floor), skipped with no refit
        self.covered = [0] * num_robots
        self._rendezvous = [0] * num_robots
        self._polys_sent = [0] * num_robots
        self._polys_received = [0] * num_robots

    # -- public API --------------------------------------------------------------------------------
    def record_scan(
        self, i: int, pose_est: np.ndarray, ranges: np.ndarray, beam_angles: np.ndarray
    ) -> None:
        """Log robot i's scan (placed with its pose estimate) for the points/grid payloads,
        and in alignment mode mark the free space it crossed."""
        if self.config.payload != "polynomials" or self.compare_payloads:
            self.scan_logs[i].record(pose_est, ranges, beam_angles)
        if self.free_space:
            self.free_space[i].add(pose_est, ranges, beam_angles)

    def step(
        self,
        k: int,
        slams: Sequence[PolySlam],
        detections: Sequence[Sequence[DetectionLike]],
        active: np.ndarray,
        *,
        in_range: Sequence[tuple[int, int]] = (),
        features: Sequence[FeatureBook] = (),
    ) -> ExchangeStep:
        """Detect rendezvous, send, deliver and apply; see the module docstring.

        Alignment mode reads ``in_range`` (pairs i < j within radio range, from the world)
        instead of the camera's ``detections``, and every robot's ``features``."""
        if len(slams) != self.num_robots or len(detections) != self.num_robots:
            raise ValueError(
                f"expected {self.num_robots} robots, got {len(slams)} SLAMs and"
                f" {len(detections)} detection lists"
            )
        active = np.asarray(active, bool)
        dropped = self._drop_failed(k, active)
        aligning = self.config.mode == "alignment"
        pillars = aligning and self.config.features == "pillars"
        if pillars and len(features) != self.num_robots:
            raise ValueError(f"alignment mode on pillars needs {self.num_robots} feature books")
        sightings: dict[tuple[int, int], tuple[DetectionLike, DetectionLike] | None]
        if aligning:
            sightings = {(i, j): None for i, j in sorted(in_range) if active[i] and active[j]}
        else:
            sightings = dict(_mutual_sightings(detections, active, self.config.range))
        new = tuple(pair for pair in sightings if self._is_meeting(k, pair))
        sent = [
            out for pair in new for out in self._meet(k, pair, sightings[pair], slams, features)
        ]
        linked: Callable[[int, int], bool] = lambda s, r: (min(s, r), max(s, r)) in sightings  # noqa: E731
        delivered = [self._apply(d, slams, features) for d in self.channel.deliver(k, linked)]
        self.history += delivered
        expired = self.channel.last_expired
        for e in expired:
            s, r, ids = self._sent_ids.pop(e.msg_id)
            self._resend.setdefault((s, r), set()).update(ids)
            if e.msg_id in self._free_changes:  # undone: they go again at the next meeting
                self._sent_free[(s, r)].toggle(*self._free_changes.pop(e.msg_id))
            self._sightings.pop((r, s, e.sent_step), None)
        for pair in sightings:
            self._last_seen[pair] = k
        for pair in new:
            self._last_start[pair] = k
        return ExchangeStep(
            k, tuple(sightings), new, tuple(sent), tuple(delivered), expired, dropped
        )

    def _is_meeting(self, k: int, pair: tuple[int, int]) -> bool:
        """Whether the pair's mutual sighting (alignment mode: being in radio range) at step k
        starts a meeting (ChannelConfig's ``meeting_gap`` and ``meeting_interval``; in
        alignment mode a pair that stays in range meets again every ``meeting_interval``)."""
        last = self._last_seen.get(pair)
        if last is None:
            return True
        if self.config.mode == "alignment" and k - last == 1:
            return k - self._last_start[pair] >= max(self.config.meeting_interval, 1)
        out_of_sight = k - last - 1  # steps between the last sighting and this one
        if out_of_sight < max(self.config.meeting_gap, 1):
            return False  # the same sighting goes on (or flickered)
        return k - self._last_start[pair] >= self.config.meeting_interval

    def _drop_failed(self, k: int, active: np.ndarray) -> tuple[Expired, ...]:
        """Drop the queued messages to and from robots that failed (failure is permanent)."""
        if np.count_nonzero(active) == active.size:  # nobody failed (a C call, every step)
            return ()
        dropped: list[Expired] = []
        for i in np.flatnonzero(~active).tolist():
            if i not in self._failed:
                self._failed.add(i)
                dropped += self.channel.drop_robot(i, k)
        for e in dropped:
            self._sent_ids.pop(e.msg_id)
            self._sightings.pop((e.receiver, e.sender, e.sent_step), None)
        return tuple(dropped)

    def rendezvous(self, i: int) -> int:
        """Robot i's rendezvous so far (``counters(i)["rendezvous"]`` without the copy)."""
        return self._rendezvous[i]

    def bytes_sent(self, i: int) -> int:
        """Bytes robot i has sent so far (``counters(i)["bytes_sent"]`` without the copy)."""
        return self.channel.bytes_sent(i)

    def counters(self, i: int) -> dict[str, int]:
        """Robot i's traffic: bytes, rendezvous, messages and polynomials, the received
        points it did not take (too uncertain, see :data:`RECEIVED_SIGMAS`) and the refined
        transforms it refused as off square (:meth:`_off_square`)."""
        c = self.channel.counters(i)
        return {
            "bytes_sent": c.bytes_sent,
            "bytes_received": c.bytes_received,
            "rendezvous": self._rendezvous[i],
            "messages_sent": c.messages_sent,
            "messages_delivered": c.messages_delivered,
            "messages_received": c.messages_received,
            "messages_lost": c.messages_lost,
            "messages_expired": c.messages_expired,
            "messages_dropped": c.messages_dropped,
            "messages_pending": self.channel.pending(sender=i),
            "polynomials_sent": self._polys_sent[i],
            "polynomials_received": self._polys_received[i],
            "polynomials_skipped": self.skipped[i],
            "received_points_dropped": self.dropped_points[i],
            "refinements_off_square": self.off_square[i],
            "alignments_attempted": sum(a.receiver == i for a in self.alignments),
            "alignments_accepted": sum(a.receiver == i and a.result.accepted
                                       for a in self.alignments),
        }  # fmt: skip

    # -- sending -----------------------------------------------------------------------------------
    def _meet(
        self,
        k: int,
        pair: tuple[int, int],
        views: tuple[DetectionLike, DetectionLike] | None,
        slams: Sequence[PolySlam],
        features: Sequence[FeatureBook],
    ) -> list[tuple[int, int, int]]:
        """A new rendezvous: store both sightings (alignment mode: the receivers' poses, for
        the radio-range test), queue one message each way."""
        i, j = pair
        for robot in pair:
            self._rendezvous[robot] += 1
        bearing = {(i, j): 0.0, (j, i): 0.0}  # (observer, target) → bearing; 0: not measured
        if views is not None:
            view_of = {(i, j): views[0], (j, i): views[1]}  # (observer, target) → detection
            for s, r in ((i, j), (j, i)):
                d = view_of[(r, s)]
                self._sightings[(r, s, k)] = _Sighting(slams[r].pose, d.distance, d.bearing)
                bearing[(s, r)] = view_of[(s, r)].bearing
        out = []
        aligning = self.config.mode == "alignment"
        for s, r in ((i, j), (j, i)):
            own = None
            if aligning:
                self._sightings[(r, s, k)] = _Sighting(slams[r].pose, math.nan, math.nan)
                own = self._feature_map(s, slams, features)
            payload, ids, changes = self._build(k, s, r, bearing[(s, r)], slams[s], own)
            msg_id = self.channel.send(s, r, payload, k)
            self._sent_ids[msg_id] = (s, r, ids)
            if changes is not None:
                self._free_changes[msg_id] = changes
            self._polys_sent[s] += len(ids)
            out.append((s, r, len(payload)))
        return out

    def version(self, robot: int, landmark_id: int) -> tuple[int, int]:
        """The version (origin robot, landmark id in its map) a robot's landmark holds: that of
        the received record it is an unchanged copy of, else its own (robot, id)."""
        copy = self._copies[robot].get(landmark_id)
        return (robot, landmark_id) if copy is None else copy[0]

    def revision(self, robot: int, landmark_id: int) -> int:
        """The revision of the version a robot's landmark holds (:meth:`_revise`)."""
        copy = self._copies[robot].get(landmark_id)
        return self._revision[robot].get(landmark_id, 0) if copy is None else copy[1]

    def _revise(self, robot: int, landmark_id: int, lo: float, hi: float, grow: float) -> None:
        """Bump the revision of a robot's own landmark whose SLAM stretched its extent in place
        (ids are kept) by at least ``grow`` (m, ``merge_min_overlap``) at an end since its
        last revision: a receiver takes no uncovered run shorter than that (:meth:`_fuse`),
        so a smaller stretch would be sent for nothing. A copy of a received version that the
        robot's own beams stretched so is its own version from then on."""
        extent = self._extent_at[robot]
        was = extent.get(landmark_id)
        if was is None:
            extent[landmark_id] = (lo, hi)
        elif was[0] - lo >= grow or hi - was[1] >= grow:
            extent[landmark_id] = (lo, hi)
            if self._copies[robot].pop(landmark_id, None) is None:
                revisions = self._revision[robot]
                revisions[landmark_id] = revisions.get(landmark_id, 0) + 1

    def _landmarks_to_send(self, s: int, r: int, slam: PolySlam) -> tuple[int, ...]:
        """s's landmarks changed since it last met r (or lost on the way to r), but for the
        versions s knows r holds: r's own, those acknowledged (delivered) to r, those r sent;
        and those r holds at an older revision (stretched since: :meth:`_revise`)."""
        since = self._last_meeting.get((s, r), -1)
        wanted = set(slam.changed_since(since)) | self._resend.pop((s, r), set())
        holds = self._peer_holds.get((s, r), {})
        grow = slam.config.merge_min_overlap
        table = slam.table
        out = []
        for lid, lo, hi in zip(table.ids, table.lo.tolist(), table.hi.tolist(), strict=True):
            self._revise(s, lid, lo, hi, grow)
            origin, _ = tag = self.version(s, lid)
            if origin == r:
                continue
            held = holds.get(tag)
            if (lid in wanted and held is None) or (
                held is not None and held < self.revision(s, lid)
            ):
                out.append(lid)
        return tuple(out)

    def _build(
        self,
        k: int,
        s: int,
        r: int,
        bearing: float,
        slam: PolySlam,
        features: FeatureMap | None = None,
    ) -> tuple[bytes, tuple[int, ...], FreeCells | None]:
        """Wire bytes of s's message to r (with s's ``features`` and the changes of its free
        space since what r holds in alignment mode), the landmark ids it carries and those
        changes (None without features)."""
        ids = self._landmarks_to_send(s, r, slam)
        seq = self._seq.get((s, r), 0)
        self._seq[(s, r)] = seq + 1
        header = Header(s, r, seq, slam.pose, bearing)
        kind, precision = self.config.payload, self.config.precision
        # the whole map only where a grid or the free space needs it: a record's polynomial
        # is its row's (the same floats as slam.polynomials() gives it)
        whole = kind == "grid" or self.compare_payloads or features is not None
        polys = slam.polynomials() if whole else []
        table, c0s = slam.table, slam.c0s
        rows = [table.index_of(lid) for lid in ids]
        versions = [self.version(s, lid) for lid in ids]  # (origin, its landmark id)
        records = tuple(
            PolynomialRecord(
                landmark,
                table.poly(row).with_c0(c0s[row]),
                max(slam.c0_variance(lid), 0.0),
                origin,
                self.revision(s, lid),
            )
            for lid, row, (origin, landmark) in zip(ids, rows, versions, strict=True)
        )
        since_log = self._last_log.get((s, r), 0)
        self._last_meeting[(s, r)] = slam.step_count
        self._last_log[(s, r)] = len(self.scan_logs[s])
        pose_var = np.diag(slam.pose_cov_relative).clip(min=0.0)
        variants = self._variants(header, records, s, since_log, polys, kind)
        if self.compare_payloads:
            self._log_sizes(k, s, r, variants, pose_var, len(records))
        message = variants[kind]
        changes = None
        if features is not None:
            sent = self._sent_free.setdefault((s, r), self._new_free_space())
            walls = [p.sample_arclength(0.5 * FREE_RESOLUTION) for p in polys]
            points = np.concatenate(walls) if walls else np.zeros((0, 2))
            clear = self.free_space[s].clear_of(points)  # s knows its whole map
            changes = sent.changes(clear)
            sent.toggle(*changes)
        framed = frame_message(encode(message, precision), pose_var, features, changes)
        return framed, ids, changes

    def _new_free_space(self) -> FreeSpace:
        return FreeSpace(FREE_RESOLUTION, FREE_MARGIN, self._max_range)

    def _variants(
        self,
        header: Header,
        records: tuple[PolynomialRecord, ...],
        s: int,
        since_log: int,
        polys: list[Polynomial],
        kind: str,
    ) -> dict[str, Message]:
        """The message in each payload kind needed now (all when comparing)."""
        out: dict[str, Message] = {"polynomials": PolynomialMessage(header, records)}
        log = self.scan_logs[s]
        if kind == "points" or self.compare_payloads:
            out["points"] = PointsMessage(header, log.hits_since(since_log))
        if kind == "grid" or self.compare_payloads:
            origin, cells = occupancy_grid(polys, *log.rays(), resolution=self.grid_resolution)
            out["grid"] = GridMessage(header, origin, self.grid_resolution, cells)
        return out

    def _log_sizes(
        self,
        k: int,
        s: int,
        r: int,
        variants: dict[str, Message],
        pose_var: np.ndarray,
        n_polys: int,
    ) -> None:
        sizes = {
            f"{kind}/{precision}": len(frame_message(encode(msg, precision), pose_var))  # type: ignore[arg-type]
            for kind, msg in variants.items()
            for precision in PRECISIONS
        }
        points = variants["points"]
        grid = variants["grid"]
        assert isinstance(points, PointsMessage) and isinstance(grid, GridMessage)
        shape = (int(grid.cells.shape[0]), int(grid.cells.shape[1]))
        self.payload_log.append(PayloadSizes(s, r, k, n_polys, len(points.points), shape, sizes))

    # -- receiving ---------------------------------------------------------------------------------
    def _apply(
        self, delivered: Delivered, slams: Sequence[PolySlam], features: Sequence[FeatureBook]
    ) -> DeliveredMessage:
        """Integrate one delivered message at its receiver (exactly once)."""
        if delivered.msg_id in self._applied:
            raise RuntimeError(f"message {delivered.msg_id} delivered twice")
        self._applied.add(delivered.msg_id)
        s, r = delivered.sender, delivered.receiver
        sent_ids = self._sent_ids.pop(delivered.msg_id, None)
        aligning = self.config.mode == "alignment"
        self._free_changes.pop(delivered.msg_id, None)
        message, pose_var, theirs, changes = unframe_message(delivered.payload, aligning)
        if changes is not None:
            self._heard_free.setdefault((s, r), self._new_free_space()).toggle(*changes)
        received: list[Polynomial] = []
        ids: list[int] = []
        n_records = 0
        if isinstance(message, PolynomialMessage):
            n_records = len(message.records)
            sighting = self._sightings.pop((r, s, delivered.sent_step))
            if aligning:
                assert theirs is not None
                mine = self._feature_map(r, slams, features)
                near = (message.header.pose[:2], sighting.pose[:2])
                heard = self._heard.setdefault((s, r), {})
                heard.update((_version(rec), rec.polynomial) for rec in message.records)
                walls = list(heard.values())
                transform = self._aligned_transform(delivered, mine, theirs, near, walls, slams[r])
                if transform is None and sent_ids is not None:
                    # nothing fused: send these landmarks again at the pair's next meeting
                    self._resend.setdefault((s, r), set()).update(sent_ids[2])
            else:
                transform = self._transform(slams[r].pose, sighting, message.header, pose_var)
            if transform is not None:
                received, ids = self._integrate(slams[r], message, transform, s)
                for pair in ((s, r), (r, s)):  # acknowledged to s; s sent them to r
                    holds = self._peer_holds.setdefault(pair, {})
                    for rec in message.records:
                        version = _version(rec)
                        holds[version] = max(holds.get(version, 0), rec.revision)
            self._polys_received[r] += n_records
        return DeliveredMessage(
            delivered.msg_id,
            s,
            r,
            _kind_name(message),
            len(delivered.payload),
            n_records,
            delivered.sent_step,
            delivered.delivered_step,
            delivered.attempts,
            tuple(received),
            tuple(ids),
        )

    def _transform(
        self, receiver_pose: np.ndarray, sighting: _Sighting, header: Header, pose_var: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:func:`map_transform` for a delivery (the motion since the sighting estimated as
        ``sighting.pose⁻¹ ⊕ receiver_pose``), plus the covariance (6, 6) of its noise, block
        diagonal: the relative pose's (:func:`relative_pose_covariance`), the sender's pose's
        (``pose_var`` on the diagonal). One compiled call
        (:func:`~polyslam_env.comms.relative_pose.delivery_transform`)."""
        return delivery_transform(
            np.asarray(receiver_pose, dtype=float), sighting.pose, float(sighting.distance),
            float(sighting.bearing), float(header.bearing), header.pose, self.sigma_d**2,
            self.sigma_bearing**2, np.asarray(pose_var, dtype=float),
        )  # fmt: skip

    def _feature_map(
        self, robot: int, slams: Sequence[PolySlam], features: Sequence[FeatureBook]
    ) -> FeatureMap:
        """Robot's features for alignment: its pillar map, or its walls' corners."""
        if self.config.features == "walls":
            slam = slams[robot]
            return wall_corners(slam.polynomials(), slam.table.side.tolist(), self.config.corners)
        return features[robot].feature_map(self.config.feature_min_sightings)

    def _aligned_transform(
        self,
        delivered: Delivered,
        mine: FeatureMap,
        theirs: FeatureMap,
        near: tuple[np.ndarray, np.ndarray],
        walls: Sequence[Polynomial],
        receiver: PolySlam,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Alignment mode: the sender's frame in the receiver's from their feature maps, as
        :meth:`_transform` gives it (T, ∂T/∂receiver pose, ∂T/∂noise = I, the aligner's
        covariance), or None when the aligner declines.

        T places the sender's walls on the receiver's *map* (the features within radio range,
        placed with its recent pose estimates), so they share that map's error, which is the
        receiver's pose error, not an error of their own: T is taken as x̂ ⊕ (x̂⁻¹ ⊕ T) with the
        second factor fixed, and ∂T/∂x̂ its compounding Jacobian, as at a rendezvous. With
        ∂T/∂x̂ = 0 the fused walls were independent of the pose, and a robot seeing them again
        took them for an absolute reference: `nees_rel` 5.2 with the exchange against 2.7
        without it on the pillar hall, 4.3 against 3.1 on the warehouse's walls; tied to the
        pose, 2.6 and 2.9 (README "Merging maps by alignment").

        ``near``: the sender's and the receiver's estimated positions when the message left
        (each in its own frame); a transform that puts them further apart than the radio's
        range (+ ``range_margin``) is refused, and so is one that lays more than
        ``max_conflict`` of the ``walls`` the sender has sent it (sender frame; this message's
        and earlier ones') in the receiver's free space, away from its own walls
        (:class:`~polyslam_env.comms.free_space.FreeSpace`), or that lays more than that of the
        receiver's own walls in the sender's free space (as the sender's messages have carried
        it: cells clear of the sender's walls); a refused attempt is logged as declined. Every
        attempt is logged in :attr:`alignments`."""
        assert self._align_rng is not None
        free_space = self.free_space[delivered.receiver]
        own_walls = receiver.polynomials()
        sampled = [w.sample_arclength(FREE_RESOLUTION) for w in walls]
        points = np.concatenate(sampled) if sampled else np.zeros((0, 2))
        own = [p.sample_arclength(0.5 * FREE_RESOLUTION) for p in own_walls]
        own_points = np.concatenate(own) if own else np.zeros((0, 2))
        own_tree = cKDTree(own_points) if len(own_points) else None
        # the other way: the receiver's walls in the sender's free space (clear of its walls)
        their_free = self._heard_free.get((delivered.sender, delivered.receiver))
        limit = self.config.range + self.config.range_margin

        def score(t: np.ndarray) -> float:
            """Length (m) of the sent walls that ``t`` lays on the receiver's own."""
            if own_tree is None or len(points) == 0:
                return 0.0
            moved = points @ rotation(float(t[2])).T + t[:2]
            dist, _ = own_tree.query(moved, distance_upper_bound=AGREE_DISTANCE)
            return float(np.isfinite(dist).sum()) * FREE_RESOLUTION

        def veto(t: np.ndarray) -> str:
            turn = rotation(float(t[2]))
            apart = float(np.hypot(*(turn @ near[0] + t[:2] - near[1])))
            if apart > limit:
                return f"puts the robots {apart:.1f} m apart, beyond the radio's {limit:.1f} m"
            conflict = free_space.conflict(points @ turn.T + t[:2], own_tree)
            if conflict > self.config.max_conflict:
                return (
                    f"lays {conflict:.0%} of the received walls in the receiver's free space"
                    f" (max_conflict {self.config.max_conflict:.0%})"
                )
            if their_free is not None:
                back = inverse(t)
                moved = own_points @ rotation(float(back[2])).T + back[:2]
                conflict = their_free.conflict(moved, None)
                if conflict > self.config.max_conflict:
                    return (
                        f"lays {conflict:.0%} of the receiver's walls in the sender's free space"
                        f" (max_conflict {self.config.max_conflict:.0%})"
                    )
            return ""

        cfg = self.config.alignment
        walls_score = score if self.config.features == "walls" else None
        result = align(self.config.aligner, mine, theirs, self._align_rng, cfg, veto, walls_score)
        if result.transform is not None and self.config.features == "walls":
            agreement = score(result.transform)
            if agreement < self.config.min_agreement:
                reason = (
                    f"the walls agree over {agreement:.1f} m < min_agreement"
                    f" {self.config.min_agreement:g} m"
                )
                result = dataclasses.replace(result, transform=None, covariance=None, reason=reason)
        self.alignments.append(
            AlignmentAttempt(delivered.delivered_step, delivered.sender, delivered.receiver, result)
        )
        if result.transform is None or result.covariance is None:
            return None
        pose = receiver.pose
        _, d_pose, _ = compose_with_jacobians(pose, compose(inverse(pose), result.transform))
        return result.transform, d_pose, np.eye(3), result.covariance

    def _integrate(
        self,
        slam: PolySlam,
        message: PolynomialMessage,
        transform: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        sender: int,
    ) -> tuple[list[Polynomial], list[int]]:
        """Refit every record in the receiver's frame with ``transform`` (T, ∂T/∂receiver
        pose, ∂T/∂noise, noise covariance) and fuse it (see "Fusion" in the module docstring);
        returns the refits (before any trimming or merge) and the ids now holding what was
        inserted."""
        r = message.header.receiver
        self._follow_lineage(r, slam)
        t, d_state, d_noise, noise_cov = transform
        cov_t = d_noise @ noise_cov @ d_noise.T
        seen = self._seen[r]
        fresh = [rec for rec in message.records if not _held(rec, r, seen)]
        self.skipped[r] += len(message.records) - len(fresh)  # no transform, no refit
        # each record's chain in the sender's frame: the alignment's and the refit's points
        chains = [chain_points(rec.polynomial, self.chord_tol, self.spacing) for rec in fresh]
        if self.config.align_maps and fresh:
            # on the new versions only: a held copy would pull T back to its meeting's error
            t, cov_t = self._align(slam, r, fresh, chains, t, cov_t, sender)
        limit = slam.config.rho_min / RECEIVED_SIGMAS
        # a received wall is turned from the truth by the transform's turn (its part through
        # the receiver's pose, and the rest's variance), not by the receiver's heading alone
        turn = (np.asarray(d_state, dtype=float)[2, :3].copy(), float(cov_t[2, 2]))
        received: list[Polynomial] = []
        ids: list[int] = []
        # the transform's whole covariance as a refit sees it (through the receiver's pose and
        # through the noise, the latter as fused: divided by ω): what refit_variance_floor needs
        pose_part = d_state @ slam.cov[:3, :3] @ d_state.T
        fused_cov_t = pose_part + d_noise @ noise_cov @ d_noise.T / RECEIVED_CI_WEIGHT
        cfg = slam.config
        min_overlap = cfg.merge_min_overlap
        turned = rotation(float(t[2]))
        for record, q in zip(fresh, chains, strict=True):
            version = _version(record)
            seen[version] = record.revision
            # received_point_set and transform_normal_sigma on one chain and one ∂p/∂T; on
            # the pose columns only (the rest are zeros): _fuse sizes G_x to the state
            xy, dp_dt, normals, sigma = received_geometry(q, t, turned, cov_t)
            # the points the transform moves little, their runs (uncovered_runs), and rule 1
            # before the refit: whether held landmarks of the same wall better than any refit
            # of this chain could be (normal variance at most refit_variance_floor, with
            # _ROUNDOFF's margin) cover every such run (inside their extents, within γ_M,
            # tangents within the merge test's angle, over runs of at least
            # merge_min_overlap), so that nothing would be taken; one compiled call
            shift = turned @ _ETA_AXIS[record.polynomial.variate]
            table = slam.table  # as the map stands: each fused record changes it
            runs, dropped, covered = received_cover(
                xy, normals, sigma, limit, fused_cov_t, shift, record.c0_var / RECEIVED_CI_WEIGHT,
                slam.landmark_boxes(), table.variate, table.shape, slam.c0s, table.lo, table.hi,
                slam.cov, _ROUNDOFF, cfg.gamma_max, _COS_MERGE, min_overlap,
            )  # fmt: skip
            self.dropped_points[r] += dropped
            if not len(runs):
                continue
            if covered:
                self.covered[r] += 1
                continue
            pts = _point_set(record, t, xy, dp_dt, d_state, d_noise, noise_cov, 3, shift)
            for rows in (slice(a, b) for a, b in runs.tolist()):
                for piece, fit in self._refit(r, _subset(pts, rows)):
                    received.append(fit.poly)
                    ids += self._fuse(
                        slam, piece, fit, (sender, version, record.revision), r, 0, turn
                    )
        return received, ids

    def _refit(self, r: int, points: PointSet) -> list[tuple[PointSet, Fit]]:
        """:func:`refit_pieces` with the exchange's fit settings, counted in :attr:`refits`."""
        self.refits[r] += 1
        return refit_pieces(points, self.order, self.auto_order, self.refit_tol)

    def _align(
        self,
        slam: PolySlam,
        r: int,
        records: Sequence[PolynomialRecord],
        chains: Sequence[np.ndarray],
        t: np.ndarray,
        cov_t: np.ndarray,
        sender: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The transform refined on the receiver's walls and its covariance
        (:func:`refine_transform`) from ``records`` and their ``chains`` (sender frame): anchors
        are its landmarks holding no data of this sender (an earlier copy would pull T back
        to that meeting's error); one (chain, wall) pair weighs as one offset whose variance
        is the range noise's plus both landmarks' normal variances (the sender's from its
        record, the receiver's from its state: :func:`normal_variance`)."""
        table = slam.table
        # the landmarks holding the sender's data (few, often none): every other row anchors
        held = {lid for lid, senders in self._sources[r].items() if sender in senders}
        if held:
            rows = np.array(
                [i for i, lid in enumerate(table.ids) if lid not in held], dtype=np.int64
            )
        else:
            rows = np.arange(len(table.ids), dtype=np.int64)
        walls, wall_var = _table_walls(slam, rows)
        sent = pack_walls([rec.polynomial for rec in records])
        refined, cov_refined = refine_transform(
            t,
            cov_t,
            chains,
            walls,
            slam.config.range_sigma,
            # normal_variance of each record and each wall, compiled (the same floats)
            chain_var=normal_variances(
                sent.order, sent.coeffs, sent.extent, np.array([rec.c0_var for rec in records])
            ),
            wall_var=wall_var,
            restarts=self.config.align_restarts,
        )
        # not np.array_equal(refined, t), on their floats (NaN equal to nothing, −0 to 0)
        if refined.tolist() != t.tolist() and self._off_square(
            slam, records, t, refined, cov_refined
        ):
            self.off_square[r] += 1
            return t, cov_t
        return refined, cov_refined

    @staticmethod
    def _off_square(
        slam: PolySlam,
        records: Sequence[PolynomialRecord],
        t: np.ndarray,
        refined: np.ndarray,
        cov_refined: np.ndarray,
    ) -> bool:
        """Whether the refined transform turns the sender's straight walls off square to the
        receiver's (its map's landmarks; ``SlamConfig.square_walls``;
        :func:`~polyslam_env.comms.alignment.square_turn`) by more than
        :data:`SQUARE_SIGMAS` σ: σ² is the refined turn's variance
        plus twice the turn variance of the receiver's longest straight wall (the sender's
        walls are taken to know their directions as well; its record carries no turn). The
        refinement then matched the walls to the wrong ones: on the warehouse's shelf rows one
        was 4.2° off the truth where the camera was 1.4° off, with a posterior σ of 0.15°
        (README "SLAM on large floor plans"). Like the ties, only where the receiver's own
        map says its floor is rectilinear (``SlamConfig.square_evidence``;
        :meth:`~polyslam_env.slam.walls.WallGraph.rectilinear`)."""
        cfg = slam.config
        if not (cfg.square_walls and cfg.rotation_states):
            return False
        if cfg.square_evidence and not slam.walls.rectilinear():
            return False
        table = slam.table
        # is_straight_wall from the table's columns: the longest (the first of ties), or none
        k = longest_straight(table.shape, table.lo, table.hi, SQUARE_MIN_LENGTH)
        sent = straight_walls([rec.polynomial for rec in records])
        if k < 0 or not sent:
            return False
        # its direction and length (its c0 changes neither)
        square = square_turn(sent, straight_walls([table.poly(k)]), float(t[2]))
        assert square is not None
        turn_var = slam.turn_variance(slam.table.ids[k])
        sigma = math.sqrt(float(cov_refined[2, 2]) + 2.0 * turn_var)
        return abs(wrap_scalar(float(refined[2]) - square)) > SQUARE_SIGMAS * sigma

    def _fuse(
        self,
        slam: PolySlam,
        points: PointSet,
        fit: Fit,
        origin: tuple[int, tuple[int, int], int],
        r: int,
        depth: int,
        turn: tuple[np.ndarray, float] | None = None,
    ) -> list[int]:
        """Fuse one received piece into receiver r's map; returns the ids that hold it.
        ``origin``: the sender, the record's version and its revision; ``turn``: the
        transform's turn (:meth:`PolySlam.insert_landmark`).

        Rule 1 (keep the better): where a landmark of the same wall (PolySlam's merge test)
        has a normal-offset variance no larger than the piece's, the piece's points it covers
        are dropped and only the uncovered runs (at least ``merge_min_overlap`` long) are
        refitted and fused. Rule 2 (newer version): otherwise landmarks of that wall holding
        information from the same sender are removed first. Rule 3: the piece is inserted with
        :meth:`PolySlam.insert_landmark`, whose merge check fuses it with an overlapping
        landmark built from independent (own or third-party) data.
        """
        self.fused[r] += 1
        sender, version, revision = origin
        fit = _on_state(fit, slam.mean.size)
        cfg = slam.config
        var = normal_variance(fit.poly, _c0_variance(fit, slam.cov))
        rows = _same_wall(slam, fit.poly.with_c0(fit.c0))
        table = slam.table
        walls = [table.ids[j] for j in rows.tolist()]
        # rule 1: the landmarks of the same wall at least as good as the piece, and the
        # piece's points they cover, in one compiled call
        better, covered = better_cover(
            np.ascontiguousarray(points.xy, dtype=float), rows, var * _ROUNDOFF, table.variate,
            table.shape, table.order, table.sizes, slam.c0s, table.lo, table.hi, slam.cov,
            cfg.gamma_max,
        )  # fmt: skip
        if better:
            if depth >= _MAX_TRIM_DEPTH:
                return []
            keep = ~covered
            return [
                lid
                for rows in uncovered_runs(keep, points.xy, cfg.merge_min_overlap)
                for piece, sub in self._refit(r, _subset(points, rows))
                for lid in self._fuse(slam, piece, sub, origin, r, depth + 1, turn)
            ]
        sources = self._sources[r]
        for lid in walls:
            if sender in sources.get(lid, ()):
                slam.remove_landmark(lid)
                self.superseded[r] += 1
        self._follow_lineage(r, slam)
        lid = slam.insert_landmark(_on_state(fit, slam.mean.size), turn=turn)
        events = slam.lineage.since(self._lineage_at[r])
        sources[events[0].landmark_id] = frozenset({sender})  # the inserted piece
        self._follow_lineage(r, slam)  # its merges carry this sender with their partners'
        if not any(event.kind == MERGED for event in events):
            # an unchanged copy of the sent version: forwarded under it, never echoed back
            self._copies[r][lid] = (version, revision)
            row = slam.table.index_of(lid)
            self._extent_at[r][lid] = (float(slam.table.lo[row]), float(slam.table.hi[row]))
        return [lid]

    def _follow_lineage(self, r: int, slam: PolySlam) -> None:
        """Carry the provenance of receiver r's landmarks over the changes its SLAM made
        since the last call (:mod:`~polyslam_env.slam.lineage`): a refit or merge holds the
        senders of its parents, a removed landmark none; O(changes), exactly."""
        sources, copies, extent = self._sources[r], self._copies[r], self._extent_at[r]
        for event in slam.lineage.since(self._lineage_at[r]):
            for gone in (*event.parents, *((event.landmark_id,) if event.kind == REMOVED else ())):
                copies.pop(gone, None)  # a parent's heir holds this robot's own version
                extent.pop(gone, None)
                self._revision[r].pop(gone, None)
            if event.kind in (REPLACED, MERGED):
                inherited = [sources.pop(p) for p in event.parents if p in sources]
                if inherited:
                    sources[event.landmark_id] = frozenset().union(*inherited)
            elif event.kind == REMOVED:
                sources.pop(event.landmark_id, None)
        self._lineage_at[r] = slam.lineage.cursor


_COS_MERGE = math.cos(math.radians(MERGE_ANGLE_DEG))  # the merge test's angle, as a cosine

#: A refined transform whose turn lays the sender's straight walls further off square to the
#: receiver's than this many σ is refused (:meth:`RendezvousExchange._off_square`): 3σ, the
#: two-sided 99.7 % of a normal turn error.
SQUARE_SIGMAS = 3.0

#: Covariance-intersection weight ω of a received piece: its noise covariance is divided by ω.
#: The piece's error is correlated with the receiver's state in ways the state does not hold
#: (the sender's pose estimate, earlier exchanges between the two, walls both have seen), so
#: it is fused as covariance intersection fuses an estimate of unknown correlation, with the
#: even weight ω = ½ (Julier & Uhlmann); treating it as independent made receivers
#: overconfident (`polyslam fidelity --maps loop --seeds 4`: `nees_rel` with the exchange 6.6
#: as independent, 5.2 with ω = ½, 5.0 without the exchange).
RECEIVED_CI_WEIGHT = 0.5

#: A received point is kept only if the transform's uncertainty moves it along the wall's
#: normal by at most ρ_min / RECEIVED_SIGMAS at 1σ: its 3σ band then stays within the
#: receiver's own good-approximation threshold at zero uncertainty, ρ_min. Points further off
#: (far from the meeting point when the camera alone fixes the heading to ~1.4°) would be
#: walls the receiver could not even recognise as its own: a wrong wall is worse than none.
RECEIVED_SIGMAS = 3.0


def transform_normal_sigma(
    poly: Polynomial, transform: np.ndarray, cov_t: np.ndarray, chord_tol: float, spacing: float
) -> np.ndarray:
    """Per chain point of a received ``poly`` (as :func:`received_point_set` samples it), the
    standard deviation (m) of its position along the curve's normal that the transform's
    covariance ``cov_t`` (3, 3) causes, in the receiver's frame."""
    q = chain_points(poly, chord_tol, spacing)
    return received_geometry(q, transform, rotation(float(transform[2])), cov_t)[3]


def received_geometry(
    q: np.ndarray, transform: np.ndarray, turned: np.ndarray, cov_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A received chain ``q`` (N, 2, sender frame) in the receiver's frame: its points (N, 2)
    and their ∂p/∂T (N, 2, 3) (:func:`~polyslam_env.comms.alignment.frame_points`), its unit
    normals (N, 2) and each point's σ along its normal from the transform's covariance
    ``cov_t`` (3, 3) (:func:`transform_normal_sigma`); ``turned`` = R(θ) of ``transform``.
    One compiled call: :func:`~polyslam_env.comms.kernels.received_geometry`."""
    t = np.asarray(transform, dtype=float)
    return kernel_geometry(q, t, turned, np.asarray(cov_t, dtype=float))


def normal_variance(poly: Polynomial, c0_var: float) -> float:
    """Variance (m²) of a landmark's offset along the curve's normal.

    A shape landmark moves only through c0, along η; the normal component of that shift at
    the middle of the extent is c0 · cos(atan B'), so var_n = var(c0) / (1 + B'²). Unlike
    var(c0) it compares landmarks of either variate.
    """
    slope = poly.slope_at(0.5 * (poly.lo + poly.hi))
    return c0_var / (1.0 + slope * slope)


def refit_variance_floor(
    normals: np.ndarray, cov_t: np.ndarray, shift: np.ndarray, shift_var: float
) -> float:
    """A lower bound (m²) of the normal-offset variance (:func:`normal_variance`) of a piece
    refitted on a received chain whose unit normals in the receiver's frame are ``normals``
    (N, 2); ``cov_t`` (3, 3) is the transform's covariance as the refit carries it (through
    the receiver's pose, and through the noise divided by ω), ``shift`` (2,) the direction in
    which the sender's c0 moves every point (its η axis, turned by T) and ``shift_var`` that
    c0's variance divided by ω.

    The refit is shape-fixed, so ∂c0/∂p_i = (−B'(ξ_i), 1)/N in (ξ, η) (unit weights,
    :func:`~polyslam_env.slam.fitting.fit_polynomial`): with a = Σ_i ∂c0/∂p_i, a translation
    u of every point moves c0 by a·u, and T = (t, θ) moves it by a·δt + b δθ. So var(c0) =
    [a, b] Σ_T [a, b]ᵀ + shift_var (a·shift)² ≥ aᵀ Q a, Q = Σ_tt − Σ_tθ Σ_θθ⁻¹ Σ_θt (the
    translation's covariance given the turn: the smallest the first term gets over b) +
    shift_var · shift shiftᵀ (a 2 × 2, PSD). a = (−s̄, 1) for the mean slope s̄ of the piece,
    i.e. √(1 + s̄²) times its unit normal at that slope; for a straight piece (s̄ = B'
    everywhere) the normal variance var(c0)/(1 + B'²) is then at least nᵀQn, n its normal.
    The chain's normals stand for the piece's (the refit follows the chain within
    ``refit_tol``): the least nᵀQn over them. For curved pieces the mean-slope normal lies among
    the chain's normals but the factor (1 + s̄²)/(1 + B'_mid²) is not exactly 1; the floor is
    checked against the refits of random curved records in ``tests/comms/test_exchange.py``.
    Compiled: :func:`~polyslam_env.comms.kernels.variance_floor`."""
    return float(
        variance_floor(
            np.asarray(normals, dtype=float).reshape(-1, 2), np.asarray(cov_t, dtype=float),
            np.asarray(shift, dtype=float), float(shift_var),
        )
    )  # fmt: skip


def uncovered_runs(keep: np.ndarray, xy: np.ndarray, min_length: float) -> list[slice]:
    """Maximal runs of consecutive ``keep`` points (N,) of a chain (N, 2) whose length along
    the chain is at least ``min_length`` (m): each run's own steps summed as numpy sums them
    (compiled: :func:`~polyslam_env.comms.kernels.kept_runs`)."""
    keep = np.ascontiguousarray(keep, dtype=np.bool_)
    bounds = kept_runs(keep, np.ascontiguousarray(xy, dtype=float), float(min_length))
    return [slice(a, b) for a, b in bounds.tolist()]


def _same_wall(slam: PolySlam, poly: Polynomial) -> np.ndarray:
    """Rows (ascending, int64) of the landmarks PolySlam's merge test pairs with ``poly`` one
    by one (γ below γ_M with the tangents agreeing: :func:`~polyslam_env.slam.merging.
    merge_gammas`, joins aside)."""
    cfg = slam.config
    # the box of poly.equally_spaced's points in one compiled call (the same floats)
    box = curve_box(poly.coeffs, poly.variate, poly.lo, poly.hi, _BOX_SAMPLES)
    near, gammas, _ = near_merge_gammas(
        poly, slam.table, slam.c0s, slam.landmark_boxes(), box, cfg.gamma_max,
        cfg.merge_min_overlap,
    )  # fmt: skip
    return near[gammas < cfg.gamma_max]  # nan: not the same wall


def _table_walls(slam: PolySlam, rows: np.ndarray) -> tuple[WallArrays, np.ndarray]:
    """Landmarks ``rows`` of a SLAM's map as :class:`~polyslam_env.comms.alignment.
    WallArrays`, from its table's columns (no polynomial objects): each row at its own order,
    its current c0 first; and their normal variances (:func:`normal_variance`). One compiled
    call (:func:`~polyslam_env.comms.kernels.table_walls`)."""
    table = slam.table
    order, variate, coeffs, extent, wall_var = table_walls(
        rows, table.order, table.variate, table.shape, slam.c0s, table.lo, table.hi, slam.cov
    )
    return WallArrays(order, variate, coeffs, extent), wall_var


def _c0_variance(fit: Fit, cov: np.ndarray) -> float:
    """var(c0) of a fit once augmented: G_x P G_xᵀ + G_y V G_yᵀ (paper eq. 5)."""
    gx, gy = fit.Gx.reshape(-1), fit.Gy.reshape(-1)
    return float(gx @ cov @ gx + gy @ fit.V @ gy)


def _on_state(fit: Fit, n_state: int) -> Fit:
    """The fit with G_x sized to the receiver's current state (it changes with every insert
    and removal). A received fit depends on the state only through the pose (first three
    columns; :func:`received_point_set`), so the rest is zeros."""
    if fit.Gx.shape[1] == n_state:
        return fit
    gx = np.zeros((1, n_state))
    gx[:, :3] = fit.Gx[:, :3]
    return Fit(fit.poly, fit.c0, gx, fit.Gy, fit.V, fit.rms, fit.order)


def _held(record: PolynomialRecord, r: int, seen: dict[tuple[int, int], int]) -> bool:
    """Whether receiver r holds a record's version: its own making, or one it integrated at
    this revision or a later one."""
    version = _version(record)
    return version[0] == r or seen.get(version, -1) >= record.revision


def _version(record: PolynomialRecord) -> tuple[int, int]:
    """A received record's version: (origin robot, landmark id in its map)."""
    assert record.origin is not None  # decoded records always name it
    return record.origin, record.landmark_id


def _kind_name(message: Message) -> str:
    if isinstance(message, PolynomialMessage):
        return "polynomials"
    return "points" if isinstance(message, PointsMessage) else "grid"

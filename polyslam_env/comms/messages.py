"""Rendezvous messages and their compact binary format (SPEC §4).

A message is what one robot sends another at a rendezvous: who sends to whom, a sequence
number, the sender's pose estimate (in its own start frame) and its bearing measurement of the
receiver, and a payload. The payload is the polynomials extracted since the last rendezvous
(the paper's method) or, for comparison, the raw beam points or an occupancy grid. The byte
count of the encoding is what the communication cost counts.

Byte layout (all little-endian; ``F`` = 4 bytes for float32, 8 for float64)::

    offset      size        field
    ---------   ---------   -------------------------------------------------------------
    header (12 + 4F bytes)
    0           1           magic 0x50 ('P')                                   uint8
    1           1           format version = 3                                 uint8
    2           1           payload kind: 1 polynomials, 2 points, 3 grid      uint8
    3           1           float width F: 4 or 8                              uint8
    4           2           sender id                                          uint16
    6           2           receiver id                                        uint16
    8           4           sequence number                                    uint32
    12          3F          sender pose estimate x, y, θ                       float
    12+3F       F           sender's bearing to the receiver (rad)             float
    payload, kind 1 (polynomials): 2 + Σ_i (10 + (m_i + 4) F) bytes
    +0          2           number of records n                                uint16
    per record
    +0          4           landmark id in its origin robot's map              uint32
    +4          2           origin robot (whose map made this version)         uint16
    +6          2           revision (the origin's extent stretches of it)     uint16
    +8          1           variate flag (1 or 2)                              uint8
    +9          1           order m (>= 1)                                     uint8
    +10         (m+1)F      coefficients c0, b1 … bm                           float
    +10+(m+1)F  F           variance of c0                                     float
    +10+(m+2)F  2F          extent lo, hi                                      float
    payload, kind 2 (points): 4 + 2NF bytes
    +0          4           number of points N                                 uint32
    +4          2NF         x0, y0, x1, y1, …                                  float
    payload, kind 3 (grid): 3F + 8 + ceil(rows·cols / 4) bytes
    +0          2F          origin x, y (corner of cell [0, 0])                float
    +2F         F           resolution (cell side, m)                          float
    +3F         4           rows                                               uint32
    +3F+4       4           cols                                               uint32
    +3F+8       ⌈rc/4⌉      cells, row-major, 2 bits each, first cell in the
                            two most significant bits; 0 unknown, 1 free,
                            2 occupied (3 is invalid); zero padding           uint8
    trailer (4 bytes)
    end-4       4           CRC-32 (zlib) of every preceding byte              uint32

So a polynomial message with orders m_i is ``12 + 4F + 2 + Σ(10 + (m_i + 4)F) + 4`` bytes:
72 bytes for one cubic in float32, 116 in float64.

A record's **origin** (robot, landmark id) names one version of a wall: the SLAM never reuses
a landmark id, and a refit or merge makes a new one (``slam/lineage.py``), so the pair is the
version. A robot forwarding a wall it received unchanged sends it under its origin's pair, so
a receiver that already holds that version (or a sender that knows its peer does) skips it
before any transform or refit (``comms/exchange.py``, "Versions"). A landmark keeps its id
when its SLAM stretches its extent in place (a hit just past an end), so the record also
carries a **revision**: the origin bumps it when the extent has grown by at least
``merge_min_overlap`` since the last revision, and a peer holding an older revision takes the
newer one (the stretch; the part it holds is dropped as covered). Format version 2 added the
origin (version 1 records had the sender's id only), version 3 the revision. :func:`decode`
rejects a wrong magic, version, kind, width, length or checksum with a ``ValueError``; it
never returns a partial message. Grid cell ``[r, c]`` covers
``origin + resolution · ([c, c+1] × [r, r+1])``.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass
from typing import Literal

import numpy as np

from polyslam_env.slam.polynomial import Polynomial

Precision = Literal["float32", "float64"]

MAGIC = 0x50
VERSION = 3
KIND_POLYNOMIALS = 1
KIND_POINTS = 2
KIND_GRID = 3
CELL_UNKNOWN, CELL_FREE, CELL_OCCUPIED = 0, 1, 2

_HEAD = struct.Struct("<BBBBHHI")  # magic, version, kind, width, sender, receiver, seq
_CRC = struct.Struct("<I")
_RECORD = struct.Struct("<IHHBB")  # landmark id, origin robot, revision, variate, order
_WIDTH = {"float32": 4, "float64": 8}
_DTYPE: dict[int, np.dtype[np.floating]] = {4: np.dtype("<f4"), 8: np.dtype("<f8")}
_CODE = {4: "f", 8: "d"}  # struct's format of a float of each width
_FEW = 16  # floats read or written through struct, not numpy, up to this many (same bytes)


@dataclass(frozen=True, eq=False)
class Header:
    """Fields every message carries."""

    sender: int
    receiver: int
    seq: int
    pose: np.ndarray  # (3,): sender's pose estimate x, y, θ in its own start frame
    bearing: float  # rad: sender's bearing measurement of the receiver

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", np.asarray(self.pose, dtype=float).reshape(3))


@dataclass(frozen=True, eq=False)
class PolynomialRecord:
    """One landmark as sent: its version (origin robot and landmark id in that robot's map)
    and the version's revision (its extent stretches), geometry (shape, c0 and extent) and c0
    variance. ``origin`` None: the sender's own landmark (encoded as the header's sender; a
    decoded record always names it)."""

    landmark_id: int
    polynomial: Polynomial
    c0_var: float
    origin: int | None = None
    revision: int = 0


@dataclass(frozen=True, eq=False)
class PolynomialMessage:
    header: Header
    records: tuple[PolynomialRecord, ...]


@dataclass(frozen=True, eq=False)
class PointsMessage:
    header: Header
    points: np.ndarray  # (N, 2): beam hits since the last rendezvous, sender's frame


@dataclass(frozen=True, eq=False)
class GridMessage:
    header: Header
    origin: np.ndarray  # (2,): corner of cell [0, 0]
    resolution: float  # m, cell side
    cells: np.ndarray  # (rows, cols) uint8: CELL_UNKNOWN / CELL_FREE / CELL_OCCUPIED


Message = PolynomialMessage | PointsMessage | GridMessage


# -- encoding -------------------------------------------------------------------------------------
def _floats(values: np.ndarray | list[float], width: int, what: str) -> bytes:
    """Little-endian floats of the given width; refuses values that are not finite after cast.
    A list of a few (a header's, a record's) goes through ``struct``, whose float32 is the
    same C cast as numpy's, without numpy's per-call cost."""
    if isinstance(values, list) and len(values) <= _FEW:
        try:
            out = struct.pack(f"<{len(values)}{_CODE[width]}", *values)
        except OverflowError:  # finite, but beyond float32's range: numpy's cast gives inf
            out = None
        if out is not None and all(math.isfinite(v) for v in values):
            return out
    arr = np.asarray(values, dtype=float).ravel()
    with np.errstate(over="ignore"):
        cast = arr.astype(_DTYPE[width])
    if not np.all(np.isfinite(cast)):
        raise ValueError(f"{what}: values must be finite in float{8 * width}, got {arr}")
    return cast.tobytes()


def _width(precision: str) -> int:
    if precision not in _WIDTH:
        raise ValueError(f"precision must be 'float32' or 'float64', got {precision!r}")
    return _WIDTH[precision]


def _check_uint(name: str, value: int, bits: int) -> None:
    if not (0 <= value < 2**bits):
        raise ValueError(f"{name} must fit in uint{bits}, got {value!r}")


def _header_bytes(header: Header, kind: int, width: int) -> bytes:
    _check_uint("sender", header.sender, 16)
    _check_uint("receiver", header.receiver, 16)
    _check_uint("seq", header.seq, 32)
    head = _HEAD.pack(MAGIC, VERSION, kind, width, header.sender, header.receiver, header.seq)
    return head + _floats([*header.pose, header.bearing], width, "header pose/bearing")


def _seal(body: bytes) -> bytes:
    return body + _CRC.pack(zlib.crc32(body))


def _record_bytes(rec: PolynomialRecord, sender: int, width: int) -> bytes:
    poly = rec.polynomial
    origin = sender if rec.origin is None else rec.origin
    _check_uint("landmark_id", rec.landmark_id, 32)
    _check_uint("origin", origin, 16)
    _check_uint("revision", rec.revision, 16)
    if not 1 <= poly.order <= 255:
        raise ValueError(f"polynomial order must be in 1..255, got {poly.order}")
    if not (math.isfinite(rec.c0_var) and rec.c0_var >= 0):
        raise ValueError(f"c0_var must be finite and >= 0, got {rec.c0_var!r}")
    head = _RECORD.pack(rec.landmark_id, origin, rec.revision, poly.variate, poly.order)
    floats = [*poly.coeffs.tolist(), rec.c0_var, poly.lo, poly.hi]  # no numpy scalars
    return head + _floats(floats, width, f"landmark {rec.landmark_id}")


def encode_polynomials(msg: PolynomialMessage, precision: Precision = "float64") -> bytes:
    """Bytes of a polynomial message (layout in the module docstring)."""
    width = _width(precision)
    _check_uint("number of records", len(msg.records), 16)
    body = [_header_bytes(msg.header, KIND_POLYNOMIALS, width), struct.pack("<H", len(msg.records))]
    body += [_record_bytes(rec, msg.header.sender, width) for rec in msg.records]
    return _seal(b"".join(body))


def encode_points(msg: PointsMessage, precision: Precision = "float64") -> bytes:
    """Bytes of a raw-points message."""
    width = _width(precision)
    pts = np.asarray(msg.points, dtype=float).reshape(-1, 2)
    _check_uint("number of points", len(pts), 32)
    head = _header_bytes(msg.header, KIND_POINTS, width) + struct.pack("<I", len(pts))
    return _seal(head + _floats(pts, width, "points"))


def pack_cells(cells: np.ndarray) -> bytes:
    """Cells (rows, cols) with values 0..2 packed 2 bits each, row-major, MSB first."""
    flat = np.asarray(cells).ravel()
    if flat.size and (flat.min() < 0 or flat.max() > CELL_OCCUPIED):
        raise ValueError("grid cells must be 0 (unknown), 1 (free) or 2 (occupied)")
    flat = flat.astype(np.uint8)
    bits = np.stack([(flat >> 1) & 1, flat & 1], axis=-1)  # (n, 2): high bit, low bit
    return np.packbits(bits.ravel(), bitorder="big").tobytes()


def unpack_cells(data: bytes, rows: int, cols: int) -> np.ndarray:
    """Inverse of :func:`pack_cells`: (rows, cols) uint8."""
    n = rows * cols
    bits = np.unpackbits(np.frombuffer(data, dtype=np.uint8), count=2 * n, bitorder="big")
    pairs = bits.reshape(n, 2)
    cells = (pairs[:, 0] << 1) | pairs[:, 1]
    if np.any(cells > CELL_OCCUPIED):
        raise ValueError("corrupt grid: cell value 3 is not a valid cell state")
    return cells.reshape(rows, cols).astype(np.uint8)


def encode_grid(msg: GridMessage, precision: Precision = "float64") -> bytes:
    """Bytes of an occupancy-grid message."""
    width = _width(precision)
    cells = np.asarray(msg.cells)
    if cells.ndim != 2:
        raise ValueError(f"grid cells must be 2-D, got shape {cells.shape}")
    if not (np.isfinite(msg.resolution) and msg.resolution > 0):
        raise ValueError(f"grid resolution must be > 0, got {msg.resolution!r}")
    rows, cols = cells.shape
    _check_uint("grid rows", rows, 32)
    _check_uint("grid cols", cols, 32)
    geometry = _floats([*np.asarray(msg.origin).reshape(2), msg.resolution], width, "grid")
    body = _header_bytes(msg.header, KIND_GRID, width) + geometry + struct.pack("<II", rows, cols)
    return _seal(body + pack_cells(cells))


def encode(msg: Message, precision: Precision = "float64") -> bytes:
    """Bytes of any message kind."""
    if isinstance(msg, PolynomialMessage):
        return encode_polynomials(msg, precision)
    if isinstance(msg, PointsMessage):
        return encode_points(msg, precision)
    if isinstance(msg, GridMessage):
        return encode_grid(msg, precision)
    raise TypeError(f"not a message: {type(msg).__name__}")


def payload_size(msg: Message, precision: Precision = "float64") -> int:
    """Bytes on the wire for ``msg`` (simply the length of its encoding)."""
    return len(encode(msg, precision))


# -- decoding -------------------------------------------------------------------------------------
class _Reader:
    """Bounds-checked cursor over a byte string; running past the end is a ValueError."""

    def __init__(self, data: bytes, width: int) -> None:
        self.data = data
        self.pos = 0
        self.width = width

    def take(self, n: int, what: str) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise ValueError(f"truncated message: {what} needs {n} bytes at offset {self.pos}")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def unpack(self, fmt: str, what: str) -> tuple[int, ...]:
        return struct.unpack(fmt, self.take(struct.calcsize(fmt), what))

    def floats(self, n: int, what: str) -> np.ndarray:
        data = self.take(n * self.width, what)
        if n <= _FEW:  # struct's float32 → float is exact, as numpy's cast
            values = struct.unpack(f"<{n}{_CODE[self.width]}", data)
            if not all(math.isfinite(v) for v in values):
                raise ValueError(f"corrupt message: non-finite value in {what}")
            return np.array(values, dtype=float)
        raw = np.frombuffer(data, dtype=_DTYPE[self.width])
        out = raw.astype(float)
        if not np.all(np.isfinite(out)):
            raise ValueError(f"corrupt message: non-finite value in {what}")
        return out


def decode(data: bytes) -> Message:
    """Parse bytes made by :func:`encode`; any inconsistency raises ``ValueError``."""
    data = bytes(data)
    if len(data) < _HEAD.size + _CRC.size:
        raise ValueError(f"truncated message: {len(data)} bytes is shorter than any header")
    (crc,) = _CRC.unpack(data[-_CRC.size :])
    body = data[: -_CRC.size]
    if zlib.crc32(body) != crc:
        raise ValueError("corrupt or truncated message: CRC-32 mismatch")
    magic, version, kind, width, sender, receiver, seq = _HEAD.unpack(body[: _HEAD.size])
    if magic != MAGIC:
        raise ValueError(f"not a polyslam message: magic byte {magic:#04x} != {MAGIC:#04x}")
    if version != VERSION:
        raise ValueError(f"unsupported message version {version} (this reader: {VERSION})")
    if width not in _DTYPE:
        raise ValueError(f"corrupt message: float width {width} is neither 4 nor 8")
    reader = _Reader(body, width)
    reader.pos = _HEAD.size
    pose_bearing = reader.floats(4, "header pose/bearing")
    header = Header(sender, receiver, seq, pose_bearing[:3], float(pose_bearing[3]))
    msg: Message
    if kind == KIND_POLYNOMIALS:
        msg = _parse_polynomials(reader, header)
    elif kind == KIND_POINTS:
        msg = _parse_points(reader, header)
    elif kind == KIND_GRID:
        msg = _parse_grid(reader, header)
    else:
        raise ValueError(f"unknown payload kind {kind}")
    if reader.pos != len(body):
        raise ValueError(f"corrupt message: {len(body) - reader.pos} unexpected trailing bytes")
    return msg


def _parse_polynomials(reader: _Reader, header: Header) -> PolynomialMessage:
    (count,) = reader.unpack("<H", "record count")
    return PolynomialMessage(header, tuple(_parse_record(reader, i) for i in range(count)))


def _parse_record(reader: _Reader, index: int) -> PolynomialRecord:
    landmark_id, origin, revision, variate, order = reader.unpack(_RECORD.format, f"record {index}")
    if variate not in (1, 2) or order < 1:
        raise ValueError(f"corrupt record {index}: variate {variate}, order {order}")
    values = reader.floats(order + 4, f"record {index}")
    coeffs, c0_var, lo, hi = values[: order + 1], values[-3], values[-2], values[-1]
    if c0_var < 0 or hi < lo:
        raise ValueError(f"corrupt record {index}: c0 variance {c0_var}, extent [{lo}, {hi}]")
    # what Polynomial's own checks would refuse was refused above (variate, order ≥ 1, finite)
    poly = Polynomial.unchecked(variate, coeffs, lo, hi)
    return PolynomialRecord(int(landmark_id), poly, float(c0_var), int(origin), int(revision))


def _parse_points(reader: _Reader, header: Header) -> PointsMessage:
    (count,) = reader.unpack("<I", "point count")
    return PointsMessage(header, reader.floats(2 * count, "points").reshape(count, 2))


def _parse_grid(reader: _Reader, header: Header) -> GridMessage:
    geometry = reader.floats(3, "grid origin/resolution")
    rows, cols = reader.unpack("<II", "grid shape")
    if geometry[2] <= 0:
        raise ValueError(f"corrupt grid: resolution {geometry[2]}")
    packed = reader.take(-(-2 * rows * cols // 8), "grid cells")
    cells = unpack_cells(packed, rows, cols)
    return GridMessage(header, geometry[:2].copy(), float(geometry[2]), cells)

"""Binary message format: round trips, documented sizes, and refusal of bad bytes."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.comms.messages import (
    GridMessage,
    Header,
    PointsMessage,
    PolynomialMessage,
    PolynomialRecord,
    decode,
    encode,
    encode_grid,
    encode_points,
    encode_polynomials,
    pack_cells,
    payload_size,
    unpack_cells,
)
from polyslam_env.slam.polynomial import Polynomial

F32_RTOL = 2.0**-23  # float32 keeps 24 significant bits: rounding error <= 2^-24 relative


def _header(rng: np.random.Generator) -> Header:
    return Header(
        sender=int(rng.integers(0, 2**16)),
        receiver=int(rng.integers(0, 2**16)),
        seq=int(rng.integers(0, 2**32)),
        pose=rng.uniform(-10, 10, 3),
        bearing=float(rng.uniform(-np.pi, np.pi)),
    )


def _records(rng: np.random.Generator, orders: list[int]) -> tuple[PolynomialRecord, ...]:
    out = []
    for i, m in enumerate(orders):
        lo = float(rng.uniform(-3, 3))
        poly = Polynomial(int(rng.integers(1, 3)), rng.normal(0, 1, m + 1), lo, lo + 1.5)
        lid = int(rng.integers(0, 2**32)) if i else 7
        origin = int(rng.integers(0, 2**16)) if i % 2 else None  # forwarded / the sender's own
        revision = int(rng.integers(0, 2**16)) if i % 3 else 0
        out.append(PolynomialRecord(lid, poly, 1e-4 * (i + 1), origin, revision))
    return tuple(out)


def _poly_message(seed: int, orders: list[int]) -> PolynomialMessage:
    rng = np.random.default_rng(seed)
    return PolynomialMessage(_header(rng), _records(rng, orders))


def _assert_header(a: Header, b: Header, rtol: float) -> None:
    assert (a.sender, a.receiver, a.seq) == (b.sender, b.receiver, b.seq)
    np.testing.assert_allclose(a.pose, b.pose, rtol=rtol, atol=0)
    np.testing.assert_allclose(a.bearing, b.bearing, rtol=rtol, atol=0)


def _assert_poly_messages(a: PolynomialMessage, b: PolynomialMessage, rtol: float) -> None:
    _assert_header(a.header, b.header, rtol)
    assert len(a.records) == len(b.records)
    for ra, rb in zip(a.records, b.records, strict=True):
        pa, pb = ra.polynomial, rb.polynomial
        assert (ra.landmark_id, pa.variate, pa.order) == (rb.landmark_id, pb.variate, pb.order)
        assert ra.revision == rb.revision
        origin = a.header.sender if ra.origin is None else ra.origin
        assert rb.origin == origin  # a decoded record always names its version's origin
        np.testing.assert_allclose(pa.coeffs, pb.coeffs, rtol=rtol, atol=0)
        np.testing.assert_allclose(
            [ra.c0_var, pa.lo, pa.hi], [rb.c0_var, pb.lo, pb.hi], rtol=rtol, atol=0
        )


def _poly_size(orders: list[int], width: int) -> int:
    """The size formula written in the messages module docstring."""
    return 12 + 4 * width + 2 + sum(10 + (m + 4) * width for m in orders) + 4


@pytest.mark.parametrize("orders", [[], [3], [1, 2, 3, 4, 5], [3] * 20])
def test_polynomial_message__float64_round_trip_is_exact(orders: list[int]) -> None:
    msg = _poly_message(0, orders)
    back = decode(encode_polynomials(msg, "float64"))
    assert isinstance(back, PolynomialMessage)
    _assert_poly_messages(msg, back, rtol=0.0)


@pytest.mark.parametrize("orders", [[3], [1, 2, 3, 4, 5]])
def test_polynomial_message__float32_round_trip_within_float32_precision(
    orders: list[int],
) -> None:
    msg = _poly_message(1, orders)
    back = decode(encode_polynomials(msg, "float32"))
    assert isinstance(back, PolynomialMessage)
    _assert_poly_messages(msg, back, rtol=F32_RTOL)
    # and not exactly: the float32 path really narrowed the values
    assert not np.array_equal(msg.header.pose, back.header.pose)


@pytest.mark.parametrize("precision,width", [("float32", 4), ("float64", 8)])
@pytest.mark.parametrize("orders", [[], [3], [1, 3, 5], [3] * 10])
def test_polynomial_message__size_matches_documented_layout(
    precision: str, width: int, orders: list[int]
) -> None:
    msg = _poly_message(2, orders)
    assert payload_size(msg, precision) == _poly_size(orders, width)  # type: ignore[arg-type]


def test_polynomial_message__one_cubic_sizes_quoted_in_docstring() -> None:
    msg = _poly_message(3, [3])
    assert len(encode(msg, "float32")) == 72
    assert len(encode(msg, "float64")) == 116


@pytest.mark.parametrize("precision,width", [("float32", 4), ("float64", 8)])
def test_points_message__round_trip_and_size(precision: str, width: int) -> None:
    rng = np.random.default_rng(4)
    for n in (0, 1, 57):
        msg = PointsMessage(_header(rng), rng.uniform(-5, 5, (n, 2)))
        data = encode_points(msg, precision)  # type: ignore[arg-type]
        assert len(data) == 12 + 4 * width + 4 + 2 * n * width + 4
        back = decode(data)
        assert isinstance(back, PointsMessage)
        assert back.points.shape == (n, 2)
        rtol = F32_RTOL if width == 4 else 0.0
        np.testing.assert_allclose(back.points, msg.points, rtol=rtol, atol=0)
        _assert_header(back.header, msg.header, rtol)


@pytest.mark.parametrize("shape", [(0, 0), (1, 1), (7, 5), (40, 64)])
def test_grid_message__round_trip_and_size(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(5)
    cells = rng.integers(0, 3, shape).astype(np.uint8)
    msg = GridMessage(_header(rng), np.array([-1.25, 2.5]), 0.05, cells)
    data = encode_grid(msg, "float64")
    rows, cols = shape
    assert len(data) == 12 + 4 * 8 + 3 * 8 + 8 + -(-rows * cols // 4) + 4
    back = decode(data)
    assert isinstance(back, GridMessage)
    np.testing.assert_array_equal(back.cells, cells)
    np.testing.assert_array_equal(back.origin, msg.origin)
    assert back.resolution == msg.resolution


def test_pack_cells__two_bits_per_cell_msb_first() -> None:
    # cells 2, 1, 0, 2 -> bits 10 01 00 10 -> 0b10010010; the fifth cell 1 -> 01 000000
    packed = pack_cells(np.array([[2, 1, 0, 2, 1]]))
    assert packed == bytes([0b10010010, 0b01000000])
    np.testing.assert_array_equal(unpack_cells(packed, 1, 5), [[2, 1, 0, 2, 1]])


def test_pack_cells__rejects_invalid_state() -> None:
    with pytest.raises(ValueError, match="cells"):
        pack_cells(np.array([[0, 3]]))


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_decode__every_truncation_raises(precision: str) -> None:
    data = encode(_poly_message(6, [3, 2]), precision)  # type: ignore[arg-type]
    for cut in range(len(data)):
        with pytest.raises(ValueError):
            decode(data[:cut])


def test_decode__every_single_bit_flip_raises() -> None:
    data = bytearray(encode(_poly_message(7, [3]), "float32"))
    for i in range(len(data)):
        for bit in (0, 7):
            bad = data.copy()
            bad[i] ^= 1 << bit
            with pytest.raises(ValueError):
                decode(bytes(bad))


def _reseal(body: bytes) -> bytes:
    """Recompute the CRC so a test reaches the field checks behind it."""
    return body + struct.pack("<I", zlib.crc32(body))


@pytest.mark.parametrize(
    "offset,value,match",
    [(0, 0x51, "magic"), (1, 9, "version"), (2, 9, "payload kind"), (3, 5, "width")],
)
def test_decode__bad_header_field_named(offset: int, value: int, match: str) -> None:
    body = bytearray(encode(_poly_message(8, [3]))[:-4])
    body[offset] = value
    with pytest.raises(ValueError, match=match):
        decode(_reseal(bytes(body)))


def test_decode__trailing_bytes_rejected() -> None:
    body = encode(_poly_message(9, [3]))[:-4] + b"\x00\x00"
    with pytest.raises(ValueError, match="trailing"):
        decode(_reseal(body))


def test_decode__bad_variate_rejected() -> None:
    body = bytearray(encode(_poly_message(10, [3]), "float64")[:-4])
    # the first record's variate flag: header 12+4F, count 2, id 4, origin 2, revision 2
    body[44 + 2 + 4 + 2 + 2] = 3
    with pytest.raises(ValueError, match="variate"):
        decode(_reseal(bytes(body)))


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=200))
def test_decode__random_bytes_raise_value_error(data: bytes) -> None:
    with pytest.raises(ValueError):
        decode(data)


def test_encode__float32_overflow_rejected() -> None:
    rng = np.random.default_rng(11)
    msg = PointsMessage(_header(rng), np.array([[1e39, 0.0]]))
    with pytest.raises(ValueError, match="finite"):
        encode(msg, "float32")
    assert len(encode(msg, "float64")) > 0  # fine in float64


def test_encode__ids_out_of_range_rejected() -> None:
    msg = _poly_message(12, [3])
    bad = PolynomialMessage(Header(2**16, 0, 0, np.zeros(3), 0.0), msg.records)
    with pytest.raises(ValueError, match="sender"):
        encode(bad)
    with pytest.raises(ValueError, match="precision"):
        encode(msg, "float16")  # type: ignore[arg-type]


def test_few_floats__struct_gives_numpys_bytes_and_floats() -> None:
    """A header's or a record's few floats go through ``struct`` (``messages._floats`` and
    ``_Reader.floats`` up to ``_FEW``): the bytes numpy's cast wrote, the same refusals
    (non-finite, or beyond float32's range), and the floats numpy's read gave, in both
    widths, from subnormal to past float32's largest."""
    from polyslam_env.comms import messages

    rng = np.random.default_rng(2)
    largest = float(np.finfo(np.float32).max)
    refused = 0
    for width in (4, 8):
        for _ in range(3000):
            n = int(rng.integers(0, messages._FEW + 1))
            values = (rng.normal(size=n) * 10.0 ** rng.integers(-45, 45, n)).tolist()
            if n and rng.random() < 0.2:
                values[0] = largest * float(rng.choice([1.0, 1.0 + 2**-25, 1.0 + 2**-23, 2.0]))
            if n and rng.random() < 0.05:
                values[-1] = float(rng.choice([np.inf, -np.inf, np.nan]))
            with np.errstate(over="ignore"):
                cast = np.asarray(values, dtype=float).astype(messages._DTYPE[width])
            if not np.all(np.isfinite(cast)):
                with pytest.raises(ValueError, match="must be finite"):
                    messages._floats(values, width, "test")
                refused += 1
                continue
            data = messages._floats(values, width, "test")
            assert data == cast.tobytes()
            got = messages._Reader(data, width).floats(n, "test")
            assert got.dtype == np.float64 and got.tobytes() == cast.astype(float).tobytes()
    assert refused > 100

"""Rendezvous map exchange: geometry, Jacobians, bookkeeping, channel, and the paper episode."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from polyslam_env import metrics
from polyslam_env.apps.simulate import SimulationResult, simulate
from polyslam_env.comms.channel import ChannelConfig
from polyslam_env.comms.exchange import (
    _ETA_AXIS,
    RECEIVED_CI_WEIGHT,
    RendezvousExchange,
    _c0_variance,
    chain_points,
    frame_message,
    map_transform,
    normal_variance,
    received_geometry,
    received_point_set,
    refit_pieces,
    refit_variance_floor,
    transform_normal_sigma,
    uncovered_runs,
    unframe_message,
)
from polyslam_env.comms.kernels import covered_by_walls
from polyslam_env.comms.messages import Header, PolynomialMessage, PolynomialRecord, encode
from polyslam_env.comms.relative_pose import frame_transform, relative_pose, wrap_angle
from polyslam_env.core.geometry import compose, inverse, rotation, transform_points
from polyslam_env.core.seeding import make_rngs
from polyslam_env.slam.alignment import FeatureMap
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import PointSet, fit_polynomial
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import WorldConfig
from tests.comms import reference_geometry as ref

WCFG = WorldConfig()
# An alignment-mode frame's empty free-space block: deflated nothing, then its 16-byte head
# (corner col and row int32, rows and cols uint16, deflated length uint32).
NO_FREE = len(zlib.compress(b"", 9)) + 16


@dataclass(frozen=True)
class Det:
    """A camera detection (same fields as ``world.sensors.Detection``)."""

    target: int
    distance: float
    bearing: float


# -- helpers -----------------------------------------------------------------------------------
def _slam(pose: np.ndarray, config: SlamConfig | None = None) -> PolySlam:
    config = config or SlamConfig()
    slam = PolySlam(config, WCFG.range_sensor.angles, WCFG.range_sensor.max_range)
    slam.mean = np.asarray(pose, dtype=float).copy()
    return slam


def _add_wall(
    slam: PolySlam, points_abs: np.ndarray, frame: np.ndarray, sigma: float = 1e-3
) -> int:
    """Insert a landmark fitted to absolute wall points seen from a robot whose frame is
    ``frame``; the points hang on its pose with ``sigma`` (m) noise, as a SLAM fit would."""
    xy = transform_points(points_abs, inverse(frame))  # (N, 2) robot frame
    n = len(xy)
    d_state = np.zeros((n, 2, slam.mean.size))
    d_state[:, :, :2] = np.eye(2)
    d_noise = np.zeros((n, 2, n))
    d_noise[np.arange(n), 1, np.arange(n)] = 1.0
    pts = PointSet(xy, d_state, d_noise, np.eye(n) * sigma**2, np.ones(n))
    return slam.insert_landmark(fit_polynomial(pts, 3, shape_fixed=True), merge=False)


def _sighting(observer: np.ndarray, target: np.ndarray, who: int) -> Det:
    """Noise-free detection of absolute pose ``target`` from absolute pose ``observer``."""
    d = target[:2] - observer[:2]
    bearing = float(wrap_angle(np.arctan2(d[1], d[0]) - observer[2]))
    return Det(who, float(np.hypot(*d)), bearing)


def _exchange(**channel: object) -> RendezvousExchange:
    return RendezvousExchange(
        ChannelConfig(**channel),  # type: ignore[arg-type]
        2,
        np.random.default_rng(3),
        WCFG.camera.sigma_d,
        WCFG.camera.sigma_bearing,
    )


def _mutual(p0: np.ndarray, p1: np.ndarray) -> list[list[Det]]:
    return [[_sighting(p0, p1, 1)], [_sighting(p1, p0, 0)]]


def _psd(cov: np.ndarray) -> bool:
    # symmetric to 1e-12 relative (round-off of P ← G P Gᵀ); eigenvalues ≥ −1e-12·‖P‖
    scale = float(np.abs(cov).max())
    sym = np.allclose(cov, cov.T, rtol=0.0, atol=1e-12 * scale)
    return sym and float(np.linalg.eigvalsh(0.5 * (cov + cov.T)).min()) >= -1e-12 * scale


# A curved wall (absolute frame): y = 1.6 + 0.3 (x − 0.4)², x ∈ [−0.5, 1.2]
WALL = np.stack(
    [np.linspace(-0.5, 1.2, 40), 1.6 + 0.3 * (np.linspace(-0.5, 1.2, 40) - 0.4) ** 2], 1
)


# -- wire frame ----------------------------------------------------------------------------------
def test_frame_message__round_trips_and_rejects_corruption() -> None:
    poly = Polynomial(1, [0.5, 0.1, -0.2, 0.03], -1.0, 2.0)
    msg = PolynomialMessage(
        Header(1, 2, 7, np.array([0.1, -0.2, 0.3]), 0.4), (PolynomialRecord(5, poly, 1e-3),)
    )
    var = np.array([1e-4, 2e-4, 3e-5])
    for precision, width in (("float32", 4), ("float64", 8)):
        raw = encode(msg, precision)  # type: ignore[arg-type]
        data = frame_message(raw, var)
        assert len(data) == len(raw) + 3 * width + 4
        out, var_out, none, no_free = unframe_message(data)
        assert isinstance(out, PolynomialMessage) and out.records[0].landmark_id == 5
        assert none is None and no_free is None
        np.testing.assert_allclose(var_out, var, rtol=1e-6)  # float32 round-off
        bad = bytearray(data)
        bad[-6] ^= 0xFF
        with pytest.raises(ValueError):
            unframe_message(bytes(bad))


def test_frame_message__carries_a_feature_map_counted_in_its_bytes() -> None:
    poly = Polynomial(1, [0.5, 0.1, -0.2, 0.03], -1.0, 2.0)
    msg = PolynomialMessage(
        Header(1, 2, 7, np.array([0.1, -0.2, 0.3]), 0.0), (PolynomialRecord(5, poly, 1e-3),)
    )
    rng = np.random.default_rng(3)
    features = FeatureMap(rng.normal(size=(7, 2)), rng.normal(size=(7, 8)))
    var = np.array([1e-4, 2e-4, 3e-5])
    for precision, width in (("float32", 4), ("float64", 8)):
        raw = encode(msg, precision)  # type: ignore[arg-type]
        data = frame_message(raw, var, features)
        # 7 rows of 2 + 8 numbers, then n (uint16) and d (uint8), and an empty free block
        assert len(data) == len(raw) + 7 * 10 * width + 3 + NO_FREE + 3 * width + 4
        out, var_out, got, free = unframe_message(data, with_features=True)
        assert isinstance(out, PolynomialMessage) and out.records[0].landmark_id == 5
        assert got is not None and free is not None and free[1].size == 0
        tol = 1e-6 if width == 4 else 0.0  # float32 round-off
        np.testing.assert_allclose(got.positions, features.positions, rtol=tol, atol=tol)
        np.testing.assert_allclose(got.descriptors, features.descriptors, rtol=tol, atol=tol)
        np.testing.assert_allclose(var_out, var, rtol=1e-6)
    empty = frame_message(encode(msg), var, FeatureMap(np.zeros((0, 2)), np.zeros((0, 8))))
    got = unframe_message(empty, with_features=True)[2]
    assert got is not None and len(got) == 0


def test_frame_message__oriented_features_carry_their_headings() -> None:
    """Corners (slam/corners.py): rows of position, heading and a 2-number descriptor, the
    descriptor-length byte flagged; unflagged frames still read as points (no headings)."""
    poly = Polynomial(1, [0.5, 0.1], -1.0, 2.0)
    msg = PolynomialMessage(
        Header(1, 2, 7, np.array([0.1, -0.2, 0.3]), 0.0), (PolynomialRecord(5, poly, 1e-3),)
    )
    rng = np.random.default_rng(4)
    corners = FeatureMap(rng.normal(size=(5, 2)), rng.normal(size=(5, 2)), rng.normal(size=5))
    var = np.array([1e-4, 2e-4, 3e-5])
    raw = encode(msg, "float64")
    data = frame_message(raw, var, corners)
    assert len(data) == len(raw) + 5 * (2 + 1 + 2) * 8 + 3 + NO_FREE + 3 * 8 + 4
    got = unframe_message(data, with_features=True)[2]
    assert got is not None and got.headings is not None
    np.testing.assert_array_equal(got.positions, corners.positions)
    np.testing.assert_array_equal(got.headings, corners.headings)
    np.testing.assert_array_equal(got.descriptors, corners.descriptors)
    points = FeatureMap(corners.positions, corners.descriptors)
    again = unframe_message(frame_message(raw, var, points), with_features=True)[2]
    assert again is not None and again.headings is None
    with pytest.raises(ValueError, match="too large"):
        frame_message(raw, var, FeatureMap(np.zeros((1, 2)), np.zeros((1, 128))))


def test_frame_message__carries_a_free_space_block_counted_in_its_bytes() -> None:
    """Alignment mode's free cells (FreeSpace.new_cells) go deflated after the features and
    come back cell for cell with their lattice corner (negative indices too); a corrupt block
    is a ValueError, not a wrong grid."""
    msg = PolynomialMessage(Header(1, 2, 7, np.zeros(3), 0.0), ())
    raw, var = encode(msg, "float32"), np.array([1e-4, 2e-4, 3e-5])
    corners = FeatureMap(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    cells = np.random.default_rng(5).random((37, 91)) < 0.3
    data = frame_message(raw, var, corners, ((-120, 45), cells))
    packed = zlib.compress(np.packbits(cells, axis=None).tobytes(), 9)
    assert len(data) == len(raw) + 3 + len(packed) + 16 + 3 * 4 + 4
    got = unframe_message(data, with_features=True)[3]
    assert got is not None
    assert got[0] == (-120, 45)
    np.testing.assert_array_equal(got[1], cells)
    head = len(data) - 4 - 3 * 4 - 16  # where the block's head starts
    bad = bytearray(data)
    bad[head - 2] ^= 0xFF  # inside the deflated bytes
    body = bytes(bad[:-4])
    bad[-4:] = zlib.crc32(body).to_bytes(4, "little")  # a valid CRC over the corrupt block
    with pytest.raises(ValueError, match="free-space block"):
        unframe_message(bytes(bad), with_features=True)


# -- geometry and Jacobians ----------------------------------------------------------------------
def test_map_transform_jacobians__match_finite_differences() -> None:
    rng = np.random.default_rng(0)
    x_r, motion, x_s = rng.normal(size=3), rng.normal(scale=0.3, size=3), rng.normal(size=3)
    d, a_r, a_s = 1.2, 0.7, -2.1
    t0, j_state, j_noise = map_transform(x_r, motion, d, a_r, a_s, x_s)
    eps = 1e-6

    def t_of(x: np.ndarray, rel_shift: np.ndarray, sender: np.ndarray) -> np.ndarray:
        """T as a function of the receiver's pose (motion held fixed), the relative pose and
        the sender's pose estimate."""
        then = compose(x, inverse(motion))
        return frame_transform(then, relative_pose(d, a_r, a_s) + rel_shift, sender)

    np.testing.assert_allclose(t_of(x_r, np.zeros(3), x_s), t0, atol=1e-12)
    for col in range(3):
        e = np.zeros(3)
        e[col] = eps
        num = (t_of(x_r + e, np.zeros(3), x_s) - t_of(x_r - e, np.zeros(3), x_s)) / (2 * eps)
        np.testing.assert_allclose(num, j_state[:, col], atol=1e-7)  # central FD error ~eps²
        num = (t_of(x_r, e, x_s) - t_of(x_r, -e, x_s)) / (2 * eps)
        np.testing.assert_allclose(num, j_noise[:, col], atol=1e-7)
        num = (t_of(x_r, np.zeros(3), x_s + e) - t_of(x_r, np.zeros(3), x_s - e)) / (2 * eps)
        np.testing.assert_allclose(num, j_noise[:, 3 + col], atol=1e-7)


def test_received_point_set__derivatives_match_finite_differences() -> None:
    poly = Polynomial(2, [0.3, 0.2, -0.4, 0.1], -0.5, 0.8)
    rec = PolynomialRecord(1, poly, 4e-4)
    t = np.array([0.4, -1.0, 0.6])
    j_noise = np.hstack([np.eye(3), np.zeros((3, 3))])
    pts = received_point_set(rec, t, np.eye(3), j_noise, np.eye(6), 5)
    eps = 1e-6
    for col in range(3):
        e = np.zeros(3)
        e[col] = eps
        plus = received_point_set(rec, t + e, np.eye(3), j_noise, np.eye(6), 5).xy
        minus = received_point_set(rec, t - e, np.eye(3), j_noise, np.eye(6), 5).xy
        np.testing.assert_allclose((plus - minus) / (2 * eps), pts.d_state[:, :, col], atol=1e-7)
        np.testing.assert_allclose(
            (plus - minus) / (2 * eps), pts.d_noise[:, :, 1 + col], atol=1e-7
        )
    shifted = PolynomialRecord(1, poly.with_c0(poly.c0 + eps), 4e-4)
    plus = received_point_set(shifted, t, np.eye(3), j_noise, np.eye(6), 5).xy
    # c0 moves the chain rigidly (same ξ knots), so the FD is exact up to round-off
    np.testing.assert_allclose((plus - pts.xy) / eps, pts.d_noise[:, :, 0], atol=1e-6)
    # the sender's c0 variance, divided by the covariance-intersection weight
    assert pts.noise_cov[0, 0] == 4e-4 / RECEIVED_CI_WEIGHT


@settings(max_examples=20, deadline=None)
@given(
    frame_s=st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-np.pi, np.pi)),
    frame_r=st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-np.pi, np.pi)),
    heading_s=st.floats(-np.pi, np.pi),
    heading_r=st.floats(-np.pi, np.pi),
)
def test_exchange__received_wall_lands_on_the_sender_wall_in_the_receiver_frame(
    frame_s: tuple[float, float, float],
    frame_r: tuple[float, float, float],
    heading_s: float,
    heading_r: float,
) -> None:
    """Noise-free: the received polynomial, taken to the absolute frame through the receiver's
    true start frame, lies on the sender's polynomial taken there through the sender's."""
    f_s, f_r = np.array(frame_s), np.array(frame_r)
    p_s, p_r = np.array([0.0, 0.5, heading_s]), np.array([1.0, 0.3, heading_r])  # absolute
    sender, receiver = _slam(compose(inverse(f_s), p_s)), _slam(compose(inverse(f_r), p_r))
    _add_wall(sender, WALL, f_s)
    ex = _exchange()
    step = ex.step(0, [sender, receiver], _mutual(p_s, p_r), np.ones(2, bool))
    got = next(d for d in step.delivered if d.receiver == 1)
    assert got.n_polynomials == 1 and len(got.received) >= 1
    truth = transform_points(sender.polynomials()[0].sample_arclength(0.001), f_s)  # (M, 2) abs
    tree = cKDTree(truth)
    for poly in got.received:
        dist, _ = tree.query(transform_points(poly.sample_arclength(0.01), f_r))
        # chord error ≤ 5 mm (chord_tol) plus the refit's residual on the chord points
        # ≤ 2.5 mm (refit_tol), plus 0.5 mm for sampling the truth every 1 mm
        assert dist.max() < 0.008
    assert _psd(receiver.cov)


# -- bookkeeping ---------------------------------------------------------------------------------
def _two_robot_setup() -> tuple[PolySlam, PolySlam, np.ndarray, np.ndarray]:
    f = np.zeros(3)
    p_s, p_r = np.array([0.0, 0.5, 0.0]), np.array([1.0, 0.3, np.pi])
    # ρ_min at ρ_max: the receivers keep every received point (the uncertainty gate of
    # exchange.RECEIVED_SIGMAS has its own test); these tests are about meetings and versions
    lenient = SlamConfig(rho_min=SlamConfig().rho_max)
    sender, receiver = _slam(p_s, lenient), _slam(p_r, lenient)
    for slam in (sender, receiver):  # some pose uncertainty, as after a while of driving
        slam.cov[:2, :2] = np.eye(2) * 0.05**2
    _add_wall(sender, WALL, f)
    _add_wall(receiver, np.stack([np.full(20, 2.0), np.linspace(-1.0, 1.0, 20)], 1), f)
    return sender, receiver, p_s, p_r


def test_exchange__meeting_twice_sends_only_what_is_new() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange()
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    first = ex.step(0, slams, view, active)
    assert first.new_rendezvous == ((0, 1),)
    assert sorted(d.n_polynomials for d in first.delivered) == [1, 1]
    still = ex.step(1, slams, view, active)  # same meeting: nothing new is sent
    assert still.new_rendezvous == () and still.sent == ()
    ex.step(2, slams, apart, active)
    for slam in slams:
        slam.step_count += 5  # time passes
    new_wall = np.stack([np.linspace(-1.5, -0.5, 20), np.full(20, -1.0)], 1)
    _add_wall(sender, new_wall, np.zeros(3))
    again = ex.config.meeting_interval  # apart long enough for a new meeting
    second = ex.step(again, slams, view, active)
    assert second.new_rendezvous == ((0, 1),)
    by_sender = {d.sender: d.n_polynomials for d in second.delivered}
    # sender: only the new wall; receiver: nothing new of its own, and what it received
    # from the sender at the first meeting is not echoed back
    assert by_sender == {0: 1, 1: 0}
    assert ex.counters(0)["rendezvous"] == 2 and ex.counters(1)["rendezvous"] == 2


def test_exchange__lossy_channel_delivers_every_message_exactly_once_while_in_view() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange(loss_prob=0.5)
    slams, active, view = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r)
    sizes_before = (sender.n_landmarks, receiver.n_landmarks)
    delivered = [d for k in range(30) for d in ex.step(k, slams, view, active).delivered]
    assert sorted((d.sender, d.receiver) for d in delivered) == [(0, 1), (1, 0)]
    assert len({d.msg_id for d in delivered}) == 2
    lost = ex.counters(0)["messages_lost"] + ex.counters(1)["messages_lost"]
    assert lost > 0  # seed 3 loses some attempts: the retry path is exercised
    for i in range(2):
        c = ex.counters(i)
        assert c["messages_sent"] == c["messages_delivered"] == 1 and c["messages_pending"] == 0
        assert c["bytes_sent"] >= c["bytes_received"] > 0  # lost attempts cost bytes too
    # each robot gained at most one landmark per received polynomial (merges may fold it)
    assert sender.n_landmarks <= sizes_before[0] + 1 and receiver.n_landmarks <= sizes_before[1] + 1
    assert _psd(sender.cov) and _psd(receiver.cov)


def test_exchange__message_pending_out_of_view_is_kept_not_dropped() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange(loss_prob=1.0)
    slams, active = [sender, receiver], np.ones(2, bool)
    ex.step(0, slams, _mutual(p_s, p_r), active)
    for k in range(1, 4):
        ex.step(k, slams, [[], []], active)
    assert ex.counters(0)["messages_pending"] == 1 and ex.counters(0)["messages_lost"] == 1


def test_exchange__inactive_or_one_sided_sighting_is_no_rendezvous() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange()
    view = _mutual(p_s, p_r)
    assert ex.step(0, [sender, receiver], [view[0], []], np.ones(2, bool)).in_view == ()
    assert ex.step(1, [sender, receiver], view, np.array([True, False])).in_view == ()
    assert ex.counters(0)["bytes_sent"] == 0


@pytest.mark.parametrize("payload", ["points", "grid"])
def test_exchange__other_payloads_count_bytes_without_touching_the_slam(payload: str) -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange(payload=payload)
    beams = len(WCFG.range_sensor.angles)
    ranges = np.resize(np.array([1.0, np.inf, 1.5, 0.8, np.inf]), beams)
    for i, slam in enumerate((sender, receiver)):
        ex.record_scan(i, slam.pose, ranges, np.asarray(WCFG.range_sensor.angles))
    before = receiver.mean.copy()
    out = ex.step(0, [sender, receiver], _mutual(p_s, p_r), np.ones(2, bool))
    assert {d.kind for d in out.delivered} == {payload}
    assert ex.counters(1)["bytes_received"] > 0
    np.testing.assert_array_equal(receiver.mean, before)


# -- meetings --------------------------------------------------------------------------------
def test_meeting__flickering_sight_is_not_a_new_rendezvous() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange()
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    gap = ex.config.meeting_gap
    assert gap >= 3  # the default tolerates a camera losing the other robot for two frames
    ex.step(0, slams, view, active)
    for k in (1, 2):
        ex.step(k, slams, apart, active)
    back = ex.step(3, slams, view, active)
    assert back.new_rendezvous == () and back.sent == ()
    assert ex.counters(0)["rendezvous"] == ex.counters(1)["rendezvous"] == 1
    assert ex.counters(0)["messages_sent"] == 1


def test_meeting__needs_both_the_gap_and_the_interval() -> None:
    cfg = {"meeting_gap": 4, "meeting_interval": 30}
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange(**cfg)
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    starts = []
    for k in range(100):
        seen = k in (0, 10, 11, 35, 60, 66, 90)  # isolated sightings
        if ex.step(k, slams, view if seen else apart, active).new_rendezvous:
            starts.append(k)
    # 10: only 10 steps after the meeting at 0; 11: continues 10; 35: 35 after 0, 23 steps
    # unseen; 60: only 25 after 35; 66: 31 after 35, 5 steps unseen (≥ 4); 90: 24 after 66
    assert starts == [0, 35, 66]


@settings(max_examples=30, deadline=None)
@given(
    seen=st.lists(st.booleans(), min_size=60, max_size=60),
    gap=st.integers(0, 6),
    interval=st.integers(0, 25),
)
def test_meeting__starts_follow_the_stated_rule(seen: list[bool], gap: int, interval: int) -> None:
    """Oracle: a sighting at k starts a meeting iff it is the pair's first, or the pair was
    unseen for ≥ max(gap, 1) steps before k and the last meeting began ≥ interval steps ago."""
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange(meeting_gap=gap, meeting_interval=interval)
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    got = [
        bool(ex.step(k, slams, view if v else apart, active).new_rendezvous)
        for k, v in enumerate(seen)
    ]
    expected: list[bool] = []
    last_seen: int | None = None  # the pair's last step in mutual sight
    last_start = 0  # the step its last meeting began (set by the first sighting)
    for k, v in enumerate(seen):
        start = v and (
            last_seen is None or (k - last_seen - 1 >= max(gap, 1) and k - last_start >= interval)
        )
        expected.append(start)
        last_seen = k if v else last_seen
        last_start = k if start else last_start
    assert got == expected
    assert ex.counters(0)["rendezvous"] == ex.counters(0)["messages_sent"] == sum(expected)


def _version(slam: PolySlam, old: int, wall: np.ndarray, pose_var: float) -> int:
    """A newer version of landmark ``old``: the robot localised (pose variance ``pose_var``
    on x and y) and refit the wall, which gets a new id (as PolySlam's refits do)."""
    slam.remove_landmark(old)
    slam.cov[:2, :2] = np.eye(2) * pose_var
    new = _add_wall(slam, wall, np.zeros(3))
    slam.table.changed_at[slam.table.index_of(new)] = slam.step_count
    return new


def test_exchange__repeated_meetings_send_only_changes_and_do_not_grow_the_map() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange()
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    every = ex.config.meeting_interval
    wall_id = sender.landmark_ids[0]
    counts, by_pair = [], []
    for n in range(5):
        k = n * every
        for slam in slams:
            slam.step_count = k
        if n:  # between meetings the sender improves its wall: a new version each time
            wall_id = _version(sender, wall_id, WALL, 1e-3 / 4**n)
        out = ex.step(k, slams, view, active)
        assert out.new_rendezvous == ((0, 1),)
        assert all(size > 0 for _, _, size in out.sent)  # every message costs bytes
        by_pair.append({d.sender: d.n_polynomials for d in out.delivered})
        ex.step(k + 1, slams, apart, active)
        counts.append(receiver.n_landmarks)
    # first meeting: each sends its one wall; then the sender sends only its new version and
    # the receiver nothing (its wall is unchanged, the copy it holds is not echoed back)
    assert by_pair == [{0: 1, 1: 1}] + [{0: 1, 1: 0}] * 4
    # the receiver holds its own wall and one copy of the sender's: every newer version
    # replaces the earlier copy (rule 2) instead of piling up
    assert counts == [counts[0]] * 5
    assert ex.superseded[1] == 4
    assert ex.counters(0)["bytes_sent"] == sum(d.bytes for d in ex.history if d.sender == 0)


def _snapshot(receiver: PolySlam) -> tuple[np.ndarray, np.ndarray, list[int]]:
    return receiver.mean.copy(), receiver.cov.copy(), receiver.landmark_ids


def test_exchange__receiving_the_same_landmark_twice_changes_nothing() -> None:
    """The sender's wall is marked changed without changing (as a refreshed extent would): the
    receiver acknowledged that version at the first meeting, so it is not sent again, and the
    receiver's state stays bit-identical — the variance is not reduced twice."""
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange()
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    ex.step(0, slams, view, active)
    ex.step(1, slams, apart, active)
    once = _snapshot(receiver)
    k = ex.config.meeting_interval
    for slam in slams:
        slam.step_count = k
    sender.table.changed_at[0] = k  # the same wall, marked changed
    again = ex.step(k, slams, view, active)
    assert {d.sender: d.n_polynomials for d in again.delivered} == {0: 0, 1: 0}
    mean, cov, ids = once
    assert receiver.landmark_ids == ids
    np.testing.assert_array_equal(receiver.mean, mean)
    np.testing.assert_array_equal(receiver.cov, cov)


# Four robots on a 1 m square (every pair within the channel's 1.5 m), each holding one wall
# of its own, in a frame shared by all (start frames equal): a fixed floor.
TEAM_POSES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, np.pi], [1.0, 1.0, np.pi], [0.0, 1.0, 0.0]])
TEAM_WALLS = [
    np.stack([np.linspace(-1.0, 2.0, 30), np.full(30, -1.5)], 1),
    np.stack([np.full(30, 2.5), np.linspace(-1.0, 2.0, 30)], 1),
    np.stack([np.linspace(-1.0, 2.0, 30), np.full(30, 2.5)], 1),
    np.stack([np.full(30, -1.5), np.linspace(-1.0, 2.0, 30)], 1),
]


def _team_meetings(cycles: int) -> tuple[RendezvousExchange, list[PolySlam], list[int]]:
    """The four robots meet pair by pair, every pair once per cycle (each meeting alone in
    view, long enough apart to count as a new one); returns the exchange, the SLAMs and the
    refits done in each cycle."""
    lenient = SlamConfig(rho_min=SlamConfig().rho_max)  # every received point kept
    slams = [_slam(pose, lenient) for pose in TEAM_POSES]
    for slam, wall in zip(slams, TEAM_WALLS, strict=True):
        slam.cov[:2, :2] = np.eye(2) * 0.05**2
        _add_wall(slam, wall, np.zeros(3))
    ex = RendezvousExchange(
        ChannelConfig(), 4, np.random.default_rng(3), WCFG.camera.sigma_d,
        WCFG.camera.sigma_bearing,
    )  # fmt: skip
    pairs = [(0, 1), (1, 2), (2, 3), (0, 2), (1, 3), (0, 3)]  # a wall travels along chains
    k, per_cycle = 0, []
    for _ in range(cycles):
        before = sum(ex.refits)
        for i, j in pairs:
            k += ex.config.meeting_interval
            for slam in slams:
                slam.step_count = k
            view: list[list[Det]] = [[] for _ in range(4)]
            view[i] = [_sighting(TEAM_POSES[i], TEAM_POSES[j], j)]
            view[j] = [_sighting(TEAM_POSES[j], TEAM_POSES[i], i)]
            assert ex.step(k, slams, view, np.ones(4, bool)).new_rendezvous == ((i, j),)
            ex.step(k + 1, slams, [[] for _ in range(4)], np.ones(4, bool))
        per_cycle.append(sum(ex.refits) - before)
    return ex, slams, per_cycle


def test_exchange__integration_per_meeting_does_not_grow_with_meetings_on_a_fixed_floor() -> None:
    """Every robot's wall reaches every other robot, directly or forwarded by a third, and
    each receiver refits each version at most once: a forwarded copy or an echo of a version
    it holds is skipped before any transform or refit. So once every robot holds every wall,
    more meetings refit nothing (the work is bounded by the versions, not the meetings)."""
    ex, slams, per_cycle = _team_meetings(cycles=3)
    for r, slam in enumerate(slams):  # its own wall and one copy of each of the three others
        assert slam.n_landmarks == 4
        assert ex.refits[r] <= 3  # one chain per version it did not hold (no trims: disjoint)
    assert per_cycle[0] == 4 * 3 and per_cycle[1:] == [0, 0]
    assert sum(ex.fused) == 4 * 3  # one piece fused per version and receiver, in cycle 1
    # what was received twice (forwarded, or sent by its origin after a forward) was skipped
    received = sum(ex.counters(r)["polynomials_received"] for r in range(4))
    assert sum(ex.skipped) == received - sum(ex.refits) > 0


def test_exchange__received_wall_never_replaces_a_better_own_one() -> None:
    f = np.zeros(3)
    p_s, p_r = np.array([0.0, 0.5, 0.0]), np.array([1.0, 0.3, np.pi])
    sender, receiver = _slam(p_s), _slam(p_r)
    receiver.cov[:3, :3] = np.diag([1e-6, 1e-6, 1e-8])  # a well-localised receiver
    own = _add_wall(receiver, WALL, f)
    _add_wall(sender, WALL[5:-5] + np.array([0.0, 0.03]), f)  # the same wall, 3 cm off, less of it
    k = receiver.table.state_index(own)
    before = receiver.mean[k], receiver.cov[k, k], receiver.n_landmarks
    ex = _exchange()
    out = ex.step(0, [sender, receiver], _mutual(p_s, p_r), np.ones(2, bool))
    got = next(d for d in out.delivered if d.receiver == 1)
    assert got.n_polynomials == 1 and got.landmark_ids == ()  # covered: nothing inserted
    # the own wall is better than any refit of the received chain could be and covers all
    # of it: skipped before the refit (rule 1 before the refit)
    assert ex.covered[1] == 1 and ex.refits[1] == 0 and got.received == ()
    k = receiver.table.state_index(own)
    assert (receiver.mean[k], receiver.cov[k, k], receiver.n_landmarks) == before


def test_exchange__better_received_wall_merges_with_a_worse_independent_one() -> None:
    f = np.zeros(3)
    p_s, p_r = np.array([0.0, 0.5, 0.0]), np.array([1.0, 0.3, np.pi])
    sender, receiver = _slam(p_s), _slam(p_r)
    for slam in (sender, receiver):
        slam.cov[:3, :3] = np.diag([1e-6, 1e-6, 1e-8])  # both well localised
    _add_wall(sender, WALL, f)
    # the receiver's own fit of the wall, 3 cm off, from very noisy points (σ = 0.3 m)
    own = _add_wall(receiver, WALL + np.array([0.0, 0.03]), f, sigma=0.3)
    var_own = normal_variance(receiver.shapes[own], receiver.c0_variance(own))
    out = _exchange().step(0, [sender, receiver], _mutual(p_s, p_r), np.ones(2, bool))
    (lid,) = next(d for d in out.delivered if d.receiver == 1).landmark_ids
    assert receiver.n_landmarks == 1 and own not in receiver.landmark_ids  # one wall
    assert normal_variance(receiver.shapes[lid], receiver.c0_variance(lid)) < var_own
    assert _psd(receiver.cov)


def _far_wall_error(align: bool) -> tuple[float | None, RendezvousExchange]:
    """Mean distance (m) of the received copy of a wall 3 m from the meeting to the true
    wall, when the receiver's bearing of the sender is 1.1° off and it holds two other walls
    of the sender's map (a corner) exactly (None if the receiver did not take the wall), and
    the exchange."""
    lines = [
        np.stack([np.linspace(-0.5, 1.5, 40), np.full(40, 1.6)], 1),  # y = 1.6
        np.stack([np.full(40, 2.0), np.linspace(-1.0, 1.5, 40)], 1),  # x = 2
    ]
    far = np.stack([np.linspace(-3.0, -1.0, 40), np.full(40, -2.0)], 1)  # y = −2
    p_s, p_r = np.array([0.0, 0.5, 0.0]), np.array([1.0, 0.3, np.pi])
    sender, receiver = _slam(p_s), _slam(p_r)
    for slam in (sender, receiver):
        slam.cov[:3, :3] = np.diag([1e-6, 1e-6, 1e-8])  # well localised: own walls are exact
    for wall in (*lines, far):
        _add_wall(sender, wall, np.zeros(3))
    for wall in lines:
        _add_wall(receiver, wall, np.zeros(3))
    view = _mutual(p_s, p_r)
    biased = Det(0, view[1][0].distance, view[1][0].bearing + 0.02)
    ex = _exchange(align_maps=align)
    ex.step(0, [sender, receiver], [view[0], [biased]], np.ones(2, bool))
    new = set(receiver.landmark_ids) - {0, 1}  # the only wall it did not hold
    if not new:
        return None, ex
    (lid,) = new
    k = receiver.table.state_index(lid)
    pts = receiver.shapes[lid].with_c0(receiver.mean[k]).sample_arclength(0.05)
    return float(np.mean(np.abs(pts[:, 1] + 2.0))), ex


def test_exchange__provenance_follows_the_receivers_merges_exactly() -> None:
    """A received wall (from robot 1) merged with the receiver's own piece of it: the merged
    landmark holds robot 1's data; a wall the receiver maps at the corner meanwhile, within
    γ_M of where the received one was, holds none (it descends from nothing received)."""
    exchange = RendezvousExchange(ChannelConfig(), 2, np.random.default_rng(0), 0.05, 0.02)
    receiver = _slam(np.zeros(3))
    wall = np.column_stack([np.linspace(0.0, 2.0, 21), np.full(21, 1.0)])
    received_id = _add_wall(receiver, wall, np.zeros(3))
    exchange._sources[0][received_id] = frozenset({1})
    own = np.column_stack([np.linspace(1.6, 3.0, 15), np.full(15, 1.0)])  # overlaps it
    merged_id = _add_wall(receiver, own, np.zeros(3))
    assert receiver.maintenance.merge_into_map(merged_id) == 1
    corner = np.column_stack([np.full(11, -0.1), np.linspace(1.0, 2.0, 11)])  # x¹ = −0.1
    corner_id = _add_wall(receiver, corner, np.zeros(3))
    assert receiver.n_landmarks == 2 and corner_id in receiver.landmark_ids
    heir = receiver.lineage.events[-2].landmark_id  # the merge, then the corner's insert
    exchange._follow_lineage(0, receiver)
    assert exchange._sources[0] == {heir: frozenset({1})}


def test_exchange__far_wall_too_uncertain_is_not_taken() -> None:
    """The camera alone fixes the heading to ~1.4° (σ): 3 m from the meeting that is ~7 cm
    along the far wall's normal, beyond ρ_min / RECEIVED_SIGMAS = 2.7 cm, so the far wall is
    not taken (a wrong wall is worse than none), while the corner walls near the meeting are
    held already."""
    error, ex = _far_wall_error(align=False)
    assert error is None
    assert ex.counters(1)["received_points_dropped"] > 0  # counted, not silent


def test_transform_normal_sigma__matches_monte_carlo() -> None:
    """σ of a received point along its normal under T ~ N(t, Σ_T): the first-order formula
    against 20,000 draws, within 5 % (the sampling error of a standard deviation from n draws
    is 1/√(2n) ≈ 0.5 %; the rest covers the linearisation at a 1° heading σ)."""
    poly = Polynomial(1, np.array([-2.0, 0.0, 0.0, 0.0]), -3.0, -1.0)  # y = −2, x ∈ [−3, −1]
    t = np.array([0.4, -0.2, 0.3])
    cov_t = np.diag([0.01**2, 0.015**2, np.radians(1.0) ** 2])
    sigma = transform_normal_sigma(poly, t, cov_t, 0.005, 0.05)
    q = chain_points(poly, 0.005, 0.05)
    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal(t, cov_t, size=20_000)
    normal = rotation(t[2]) @ np.array([0.0, 1.0])  # the wall's normal in the receiver frame
    for k in (0, len(q) // 2, len(q) - 1):
        pts = np.array([rotation(d[2]) @ q[k] + d[:2] for d in draws])
        offsets = pts @ normal
        assert abs(offsets.std() / sigma[k] - 1.0) < 0.05


def test_exchange__messages_to_a_failed_robot_are_dropped_not_pending() -> None:
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange(loss_prob=1.0)  # nothing gets through: both messages stay queued
    slams = [sender, receiver]
    ex.step(0, slams, _mutual(p_s, p_r), np.ones(2, bool))
    assert ex.counters(0)["messages_pending"] == ex.counters(1)["messages_pending"] == 1
    out = ex.step(1, slams, [[], []], np.array([True, False]))
    assert sorted((e.sender, e.receiver) for e in out.dropped) == [(0, 1), (1, 0)]
    for i in range(2):
        c = ex.counters(i)
        assert (c["messages_pending"], c["messages_dropped"]) == (0, 1)
        assert c["bytes_sent"] > 0  # the lost attempt still counts


# -- the paper episode -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_runs() -> tuple[SimulationResult, SimulationResult, RendezvousExchange]:
    ex = RendezvousExchange(
        ChannelConfig(),
        3,
        make_rngs(0, ["channel"])["channel"],
        WCFG.camera.sigma_d,
        WCFG.camera.sigma_bearing,
        compare_payloads=True,
    )
    return simulate("paper", seed=0), simulate("paper", seed=0, exchange=ex), ex


def test_paper__r2_and_r3_exchange_once_and_r1_never(
    paper_runs: tuple[SimulationResult, SimulationResult, RendezvousExchange],
) -> None:
    alone, shared, _ = paper_runs
    m = shared.metrics()
    assert m[0]["bytes_sent"] == m[0]["bytes_received"] == m[0]["rendezvous"] == 0
    for r in (1, 2):
        assert m[r]["bytes_sent"] > 0 and m[r]["bytes_received"] > 0 and m[r]["rendezvous"] == 1
    assert alone.metrics()[0]["completeness"] == m[0]["completeness"]  # r1 unaffected
    assert m[0]["completeness"] < 0.8  # r1 alone keeps a partial map


def test_paper__exchange_off_is_identical_to_no_exchange() -> None:
    a = simulate("paper", seed=0, steps=60)
    b = simulate("paper", seed=0, steps=60, exchange=False)
    for ra, rb in zip(a.runs, b.runs, strict=True):
        np.testing.assert_array_equal(ra.est_poses, rb.est_poses)
    assert a.metrics()[1]["bytes_sent"] == 0


def test_paper__received_maps_land_on_the_true_walls(
    paper_runs: tuple[SimulationResult, SimulationResult, RendezvousExchange],
) -> None:
    _, shared, ex = paper_runs
    assert {(d.sender, d.receiver) for d in ex.history} == {(1, 2), (2, 1)}
    for d in ex.history:
        frame = shared.runs[d.receiver].start_pose
        nu_mean = metrics.nu_mean(list(d.received), frame, shared.layout)
        # relative heading σ = √2·1° ≈ 0.025 rad over walls up to ~2.5 m from the meeting
        # point (≈ 3 cm on average), plus the sender's own map error (≈ 2 cm): 6 cm
        assert nu_mean < 0.06


def _region_nu_mean(
    polys: list[Polynomial], frame: np.ndarray, result: SimulationResult, covered: np.ndarray
) -> float:
    """Mean δ of the map samples whose nearest true boundary point is in ``covered``."""
    boundary = metrics.boundary_points(result.layout)
    pts = np.vstack(metrics.map_points(polys, frame))
    _, nearest = cKDTree(boundary).query(pts)
    keep = covered[nearest]
    return float(metrics.distance_to_boundary(pts[keep], result.layout).mean())


def test_paper__exchange_makes_r3_more_complete_without_spoiling_what_it_mapped(
    paper_runs: tuple[SimulationResult, SimulationResult, RendezvousExchange],
) -> None:
    alone, shared, _ = paper_runs
    r3_alone, r3_shared = alone.runs[2], shared.runs[2]
    assert shared.metrics()[2]["completeness"] > alone.metrics()[2]["completeness"] + 0.05
    own = np.vstack(metrics.map_points(r3_alone.polynomials, r3_alone.start_pose))
    dist, _ = cKDTree(own).query(metrics.boundary_points(alone.layout))
    covered = dist <= 0.05  # the boundary r3 mapped by itself (completeness tolerance)
    before = _region_nu_mean(r3_alone.polynomials, r3_alone.start_pose, alone, covered)
    after = _region_nu_mean(r3_shared.polynomials, r3_shared.start_pose, shared, covered)
    # merging with received walls (offset by the relative-pose error, a few cm) is weighted
    # by c0 variances and moves r3's own walls by a fraction of that: allow 5 mm (¼ of the
    # range noise σ) on a region mean of about 2 cm
    assert after <= before + 0.005


def test_paper__polynomials_are_the_cheapest_payload(
    paper_runs: tuple[SimulationResult, SimulationResult, RendezvousExchange],
) -> None:
    _, _, ex = paper_runs
    assert len(ex.payload_log) == 2
    for entry in ex.payload_log:
        s = entry.sizes
        assert s["polynomials/float32"] < s["polynomials/float64"]
        assert s["polynomials/float64"] < min(s["points/float32"], s["grid/float32"])


def test_chain_points__cached_chain_is_the_fresh_one_and_read_only() -> None:
    from polyslam_env.comms.polyline import piecewise_linear, polyline_points

    poly = Polynomial(1, np.array([0.3, 0.2, -0.4, 0.1]), -0.8, 1.1)
    fresh = polyline_points(piecewise_linear(poly, 0.005), 0.05)
    first = chain_points(poly, 0.005, 0.05)
    again = chain_points(Polynomial(1, poly.coeffs.copy(), poly.lo, poly.hi), 0.005, 0.05)
    np.testing.assert_array_equal(first, fresh)  # the same operations: exactly equal
    assert again is first  # equal contents: the cached chain
    assert not first.flags.writeable
    other = chain_points(poly, 0.005, 0.04)  # another spacing: another chain
    assert len(other) > len(first)


def test_chain_points__cache_changes_no_exchange(monkeypatch: pytest.MonkeyPatch) -> None:
    """The paper episode with exchange is bit-identical whether every chain is computed anew
    (no cache) or cached."""
    from polyslam_env.comms import exchange

    def run() -> SimulationResult:
        exchange._CHAIN_CACHE.clear()
        return simulate("paper", seed=3, exchange=True)

    cached = run()
    monkeypatch.setattr(exchange, "_CHAIN_CACHE_SIZE", 0)
    fresh = run()
    assert cached.meta["exchange"] and cached.meta["exchange"] == fresh.meta["exchange"]
    for a, b in zip(cached.runs, fresh.runs, strict=True):
        np.testing.assert_array_equal(a.est_poses, b.est_poses)
        assert [p.coeffs.tobytes() for p in a.polynomials] == [
            p.coeffs.tobytes() for p in b.polynomials
        ]


def test_exchange__a_wall_stretched_in_place_reaches_a_peer_holding_it_shorter() -> None:
    """A hit just past a wall's end stretches its extent in place: the landmark keeps its id
    (so the version's name), and its changed_at (no new fit). The receiver, holding the
    shorter wall, must still get the longer one at the next meeting: the stretch bumps the
    version's revision. Without it the sender sent nothing and the stretch never arrived."""
    sender, receiver, p_s, p_r = _two_robot_setup()
    ex = _exchange()
    slams, active, view, apart = [sender, receiver], np.ones(2, bool), _mutual(p_s, p_r), [[], []]
    ex.step(0, slams, view, active)
    ex.step(1, slams, apart, active)
    wall = sender.polynomials()[0]  # x ∈ [−0.5, 1.2] of WALL's curve
    longer = wall.hi + 0.4
    sender.table.extend_to_hit(0, longer)
    k = ex.config.meeting_interval
    for slam in slams:
        slam.step_count = k
    stretch = wall.points_at(np.linspace(wall.hi + 0.15, longer - 0.01, 8))  # past the old end

    def covered() -> bool:  # within 2 cm of the receiver's walls (the chain and refit tols)
        return bool(ref.covered_points(stretch, receiver.polynomials(), 0.02).all())

    assert not covered()
    again = ex.step(k, slams, view, active)
    assert {d.sender: d.n_polynomials for d in again.delivered} == {0: 1, 1: 0}
    assert covered()
    # the same revision is not sent again, and a stretch below merge_min_overlap is none
    sender.table.extend_to_hit(0, longer + 0.5 * sender.config.merge_min_overlap)
    ex.step(k + 1, slams, apart, active)
    for slam in slams:
        slam.step_count = 2 * k
    third = ex.step(2 * k, slams, view, active)
    assert {d.sender: d.n_polynomials for d in third.delivered} == {0: 0, 1: 0}


def test_uncovered_runs__each_run_as_its_own_chain_measures_it() -> None:
    """The maximal runs of kept points at least ``min_length`` long, each run's length the sum
    of its own steps, bit for bit as the run cut out and measured alone (the oracle), on
    random masks over random chains from 1 to 400 points (runs past numpy's 8- and 128-term
    blocks of pairwise summation), lengths at the threshold included."""
    rng = np.random.default_rng(20)

    def oracle(keep: np.ndarray, xy: np.ndarray, min_length: float) -> list[slice]:
        edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(int), [0]])))
        return [
            slice(int(a), int(b))
            for a, b in zip(edges[::2], edges[1::2], strict=True)
            if float(np.linalg.norm(np.diff(xy[a:b], axis=0), axis=1).sum()) >= min_length
        ]

    for _ in range(300):
        n = int(rng.integers(1, 400))
        xy = np.cumsum(rng.normal(0.0, 0.03, (n, 2)), axis=0)
        keep = rng.random(n) < rng.choice([0.3, 0.9, 1.0])
        want = oracle(keep, xy, 0.0)
        lengths = [float(np.linalg.norm(np.diff(xy[r], axis=0), axis=1).sum()) for r in want]
        for min_length in (0.1, *lengths[:3]):  # a run exactly at the threshold is kept
            assert uncovered_runs(keep, xy, min_length) == oracle(keep, xy, min_length)
    assert uncovered_runs(np.zeros(4, dtype=bool), np.zeros((4, 2)), 0.1) == []


def _random_record(rng: np.random.Generator) -> PolynomialRecord:
    """A straight or curved received wall (either variate, up to a cubic) of 0.3–3 m."""
    lo = float(rng.uniform(-2.0, 1.0))
    coeffs = np.zeros(4)
    coeffs[0] = rng.uniform(-2.0, 2.0)
    coeffs[1] = rng.uniform(-0.8, 0.8)
    if rng.random() < 0.5:  # curved
        coeffs[2] = rng.uniform(-0.3, 0.3)
        coeffs[3] = rng.uniform(-0.1, 0.1)
    poly = Polynomial(int(rng.integers(1, 3)), coeffs, lo, lo + float(rng.uniform(0.3, 3.0)))
    return PolynomialRecord(0, poly, float(rng.uniform(0.0, 4e-4)), 0, 0)


def _random_psd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    a = rng.normal(0.0, scale, (n, n))
    return a @ a.T


def test_refit_variance_floor__bounds_the_refits_of_random_records() -> None:
    """The floor the exchange compares held walls with before refitting a received chain
    (rule 1 before the refit) is at most the normal variance of every piece refitted from
    it, as ``_fuse`` computes that variance, on random straight and curved records, random
    transforms and random transform, pose and c0 covariances (the floor is exact for
    straight pieces: equality up to round-off is allowed, 1e-9 relative)."""
    rng = np.random.default_rng(41)
    tight = []
    for _ in range(150):
        record = _random_record(rng)
        t = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-np.pi, np.pi)])
        d_state, d_noise = rng.normal(0.0, 1.0, (3, 3)), rng.normal(0.0, 1.0, (3, 6))
        noise_cov = _random_psd(rng, 6, 0.01)
        pose_cov = _random_psd(rng, 3, 0.01)
        pts = received_point_set(record, t, d_state, d_noise, noise_cov, 3)
        q = chain_points(record.polynomial, 0.005, 0.05)
        cov_t = (
            d_state @ pose_cov @ d_state.T + d_noise @ noise_cov @ d_noise.T / RECEIVED_CI_WEIGHT
        )
        shift = rotation(float(t[2])) @ _ETA_AXIS[record.polynomial.variate]
        normals = received_geometry(q, t, rotation(float(t[2])), cov_t)[2]
        floor = refit_variance_floor(normals, cov_t, shift, record.c0_var / RECEIVED_CI_WEIGHT)
        for _, fit in refit_pieces(pts, 3, True, 0.0025):
            var = normal_variance(fit.poly, _c0_variance(fit, pose_cov))
            assert var >= floor * (1.0 - 1e-9)
            tight.append(var / floor)
    assert min(tight) < 1.0 + 1e-6  # and it is reached (straight pieces)


def _covered_oracle(
    xy: np.ndarray, normals: np.ndarray, walls: list[Polynomial], c0_var: np.ndarray,
    max_var: float, reach: float, cos_max: float, min_overlap: float,
) -> np.ndarray:  # fmt: skip
    """numpy's ``covered_by_walls``, wall by wall."""
    out = np.zeros(len(xy), dtype=bool)
    for wall, var in zip(walls, c0_var, strict=True):
        mid = float(wall.slope(0.5 * (wall.lo + wall.hi)))
        if var / (1.0 + mid * mid) > max_var:
            continue
        xi, eta = wall.from_xy(xy)
        n_xi, n_eta = wall.from_xy(normals)
        s = wall.slope(xi)
        on = (xi >= wall.lo) & (xi <= wall.hi) & (np.abs(eta - wall.value(xi)) <= reach)
        on &= np.abs(n_eta - s * n_xi) >= cos_max * np.sqrt(1.0 + s * s)
        for run in uncovered_runs(on, xy, 0.0):
            steps = np.diff(xy[run], axis=0)
            length = 0.0
            for dx, dy in steps.tolist():
                length += float(np.sqrt(dx * dx + dy * dy))
            if length >= min_overlap:
                out[run] = True
    return out


def _chain_near_walls(
    rng: np.random.Generator, max_walls: int, min_points: int, noises: tuple[float, float]
) -> tuple[list[Polynomial], np.ndarray, np.ndarray, np.ndarray]:
    """1 … ``max_walls`` random walls, a chain of points along the first (past its ends, η noise
    one of ``noises``), the chain's unit normals, and the walls' coefficients zero-padded
    (rows): the random cases of the received-chain coverage tests."""
    walls = [_random_record(rng).polynomial.with_c0(float(rng.uniform(-1, 1)))
             for _ in range(int(rng.integers(1, max_walls + 1)))]  # fmt: skip
    base = walls[0]
    xi = np.linspace(base.lo - 0.3, base.hi + 0.3, int(rng.integers(min_points, 80)))
    eta = base.value(xi) + rng.normal(0.0, rng.choice(noises), xi.size)
    xy = base.to_xy(xi, eta)
    d = np.gradient(xy, axis=0) if len(xy) > 1 else np.array([[1.0, 0.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    normals = np.stack([-d[:, 1], d[:, 0]], axis=1)
    coeffs = np.zeros((len(walls), max(w.order for w in walls) + 1))
    for k, w in enumerate(walls):
        coeffs[k, : w.order + 1] = w.coeffs
    return walls, xy, normals, coeffs


def test_covered_by_walls__matches_the_numpy_oracle() -> None:
    """The compiled coverage of a received chain by held walls is numpy's, point for point,
    on random chains near random walls (some covered, some crossing, some too uncertain)."""
    rng = np.random.default_rng(7)
    cos_max = float(np.cos(np.radians(30.0)))
    hits = 0
    for _ in range(200):
        walls, xy, normals, coeffs = _chain_near_walls(rng, 3, 2, (0.01, 0.2))
        c0_var = rng.uniform(0.0, 1e-3, len(walls))
        args = (0.35, cos_max, float(rng.choice([0.0, 0.1, 0.5])))
        max_var = float(rng.uniform(0.0, 1e-3))
        cov = np.zeros((3 + len(walls), 3 + len(walls)))
        cov[3:, 3:] = np.diag(c0_var)  # the kernel reads a state covariance's diagonal
        got = covered_by_walls(
            xy, normals, np.arange(len(walls)), np.array([w.variate for w in walls]), coeffs,
            coeffs[:, 0].copy(), np.array([w.lo for w in walls]), np.array([w.hi for w in walls]),
            cov, max_var, *args,
        )  # fmt: skip
        np.testing.assert_array_equal(
            got, _covered_oracle(xy, normals, walls, c0_var, max_var, *args)
        )
        hits += int(got.any() and not got.all())
    assert hits > 20  # partly covered chains were among the cases


def _received_cover_oracle(
    xy: np.ndarray, normals: np.ndarray, sigma: np.ndarray, limit: float, cov_t: np.ndarray,
    shift: np.ndarray, shift_var: float, boxes: np.ndarray, columns: tuple[np.ndarray, ...],
    cov: np.ndarray, reach: float, cos_max: float, min_overlap: float,
) -> tuple[list[slice], int, bool]:  # fmt: skip
    """The exchange's tests of a received chain before its refit as it ran them call by call
    (what the compiled ``comms.kernels.received_cover`` replaced): the kept points' runs, the
    floor, the chain's box, the landmarks near it, their coverage, the runs left."""
    from polyslam_env.comms.exchange import _ROUNDOFF
    from polyslam_env.slam.landmarks import boxes_near

    sure = sigma <= limit
    dropped = int(np.count_nonzero(~sure))
    runs = uncovered_runs(sure, xy, min_overlap)
    if not runs:
        return runs, dropped, False
    floor = refit_variance_floor(normals[sure], cov_t, shift, shift_var)
    box = np.array([xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()])
    near = boxes_near(boxes, box, reach)
    covered = np.zeros(len(xy), dtype=bool)
    if len(near):
        covered = covered_by_walls(
            xy, normals, near, *columns, cov, floor * _ROUNDOFF, reach, cos_max, min_overlap
        )
    return runs, dropped, not uncovered_runs(sure & ~covered, xy, min_overlap)


def test_received_cover__is_the_exchange_calls_it_replaced() -> None:
    """One compiled call for a received chain's kept runs, dropped points and rule 1's
    coverage answers as the calls it replaced, on random chains near random walls (kept
    and dropped points, walls better and worse than the floor, boxes near and far)."""
    from polyslam_env.comms.kernels import received_cover

    rng = np.random.default_rng(17)
    cos_max = float(np.cos(np.radians(30.0)))
    outcomes: set[tuple[bool, bool]] = set()
    for _ in range(300):
        walls, xy, normals, coeffs = _chain_near_walls(rng, 4, 1, (0.005, 0.2))
        sigma = rng.uniform(0.0, 0.02, len(xy)) * rng.choice([0.5, 1.0, 3.0])
        columns = (
            np.array([w.variate for w in walls]), coeffs, coeffs[:, 0].copy(),
            np.array([w.lo for w in walls]), np.array([w.hi for w in walls]),
        )  # fmt: skip
        pts = [w.sample_arclength(0.05) for w in walls]
        boxes = np.array([[p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()]
                          for p in pts]) + rng.choice([0.0, 5.0])  # near, or all far  # fmt: skip
        cov = np.zeros((3 + len(walls), 3 + len(walls)))
        cov[3:, 3:] = np.diag(rng.uniform(0.0, 2e-4, len(walls)))
        cov_t = _random_psd(rng, 3, 0.005)
        shift = rotation(float(rng.uniform(-np.pi, np.pi))) @ np.array([0.0, 1.0])
        args = (xy, normals, sigma, 0.01, cov_t, shift, float(rng.uniform(0.0, 2e-4)), boxes)
        tail = (0.35, cos_max, float(rng.choice([0.0, 0.1, 0.5])))
        runs, dropped, covered = received_cover(*args, *columns, cov, 1.0 + 1e-9, *tail)
        want = _received_cover_oracle(*args, columns, cov, *tail)
        assert [slice(a, b) for a, b in runs.tolist()] == want[0]
        assert (dropped, covered) == want[1:]
        outcomes.add((bool(want[0]), want[2]))
    assert outcomes == {(False, False), (True, False), (True, True)}

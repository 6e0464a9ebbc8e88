"""The radio between robots: range, bandwidth cap, packet loss, and honest byte counting.

Semantics (SPEC §4):

* ``send`` queues a message (bytes) from one robot to another; nothing moves until ``deliver``.
* ``deliver(step, in_view)`` runs once per control step. For every queued message, in the
  order they were sent, whose two robots are in view (``in_view(sender, receiver)`` is the
  caller's mutual camera detection; when ``distance`` is given the robots must also be within
  ``config.range``), the channel makes one **transmission attempt**:

  - with a bandwidth cap ``B > 0``, a sender transmits at most ``B`` bytes per step over all
    its messages. A message larger than what is left is sent in chunks over several steps;
    chunks have no framing overhead of their own, the progress is kept while the robots are
    out of view, and the message is delivered when its last chunk arrives;
  - each attempt (a whole message, or one chunk) is lost with probability ``loss_prob``. A lost
    attempt is counted, its bytes still count as sent (the radio spent them) and it is retried
    at the next step the robots see each other — not within the same step;
  - a delivered message is returned exactly once and leaves the queue.

* A message whose age ``step − sent_step`` exceeds ``max_age`` (``None``: never) is dropped
  before the step's attempts and counted as expired; the drops of the last call are listed in
  ``last_expired``.
* :meth:`Channel.drop_robot` drops every queued message to or from a failed robot (failure is
  permanent: such a message could never be delivered) and counts it as dropped.

Nothing is ever lost silently.

Counters per robot: as sender ``messages_sent`` (queued), ``attempts``, ``messages_lost``
(lost attempts), ``bytes_sent`` (every attempt's bytes), ``bytes_lost``, ``messages_delivered``,
``messages_expired``, ``messages_dropped``; as receiver ``messages_received`` and
``bytes_received`` (full size of delivered messages). Without a cap,
``attempts == messages_delivered + messages_lost`` and
``bytes_sent == bytes_received + bytes_lost`` summed over robots; always
``messages_sent == messages_delivered + messages_expired + messages_dropped + pending``.

The only randomness is one ``rng.random()`` draw per attempt, in queue order, so a channel is
deterministic given its generator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from polyslam_env.core.config import Config, check_positive, check_range
from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.alignment import ALIGNERS, AlignConfig
from polyslam_env.slam.corners import CornerConfig

_UNLIMITED = 2**62  # bytes per step when there is no cap


@dataclass(frozen=True)
class ChannelConfig(Config):
    """The radio link used at rendezvous."""

    range: float = 1.5  # m, maximum distance for a link
    bandwidth_bytes_per_step: int = 0  # bytes per sender per step; 0 = unlimited
    loss_prob: float = 0.0  # probability that one transmission attempt is lost
    precision: Literal["float32", "float64"] = "float64"  # float width in messages
    payload: Literal["polynomials", "points", "grid"] = "polynomials"  # what is exchanged
    max_age: int | None = None  # steps a message may wait; None = until delivered
    # A pair's mutual sighting that starts is a new rendezvous (a meeting) only if the pair
    # has been out of mutual sight for at least ``meeting_gap`` steps (a camera that loses the
    # other robot for a frame or two does not make a new meeting) and the pair's last meeting
    # started at least ``meeting_interval`` steps ago (robots that keep crossing exchange at
    # most once per interval). 0 and 0: every start of a mutual sighting is a meeting.
    # Defaults, at the paper's T = 1 s: 5 steps is more than a frame or two of flicker; in 20
    # steps a robot at v_max (0.3 m/s) covers up to 6 m, four camera ranges, enough to have
    # mapped something new (a longer interval cost completeness on held-out maps).
    meeting_gap: int = 5  # steps out of mutual sight
    meeting_interval: int = 20  # steps between the starts of two meetings of one pair
    # Refine the camera's frame transform on the walls both maps hold before fusing received
    # walls (comms/alignment.py); False: the paper's camera-only transform.
    align_maps: bool = True
    # With align_maps, refuse a refinement that started again from ±2σ of the camera's
    # estimate ends elsewhere (two basins: repeating shelf rows, comms/alignment.py). An
    # option: it also refuses some right refinements, and on the loop the exchange then
    # no longer raises completeness (docs/design/exchange.md)
    align_restarts: bool = False
    # How robots meet and find the transform between their frames:
    # "rendezvous" (the paper): a mutual camera sighting within ``range``; the camera's range
    #   and bearings give the transform.
    # "alignment" (seed 004): two robots within radio ``range`` of each other, seen or not; a
    #   message also carries the sender's feature map (``features``), and the receiver finds
    #   the transform by aligning it with its own (``aligner``, thresholds ``alignment``)
    #   before fusing; a declined alignment fuses nothing. A pair in range meets again every
    #   ``meeting_interval`` steps.
    mode: Literal["rendezvous", "alignment"] = "rendezvous"
    # Alignment mode's features: "pillars" (positions and appearance descriptors from the
    # pillar sensor, slam/features.py) or "walls" (the corners of the polynomial map, with
    # their headings and local shape, slam/corners.py: no extra sensor).
    features: Literal["pillars", "walls"] = "pillars"
    corners: CornerConfig = field(default_factory=CornerConfig)
    # The radio says the two robots were within ``range`` when the message left: an alignment
    # that puts the sender's position then further than range + range_margin from the
    # receiver's is refused (m; the margin holds the two pose estimates' drift and the motion
    # between sending and delivery).
    range_margin: float = 1.0
    # An alignment that lays more than this fraction of the received walls in the receiver's
    # free space (cells its beams crossed), or of the receiver's walls in the sender's (sent
    # with its walls), is refused: correctly aligned, a wall lies in the other's free space
    # only where a map is grossly wrong (> 0.3 m off), and the maps' map_precision (length
    # within 5 cm of a true wall) is ≥ 0.95 on average.
    max_conflict: float = 0.05
    # features: walls: the best corner hypothesis must lay at least this much of the sent
    # walls (m) within 0.1 m of the receiver's own: about two sides of a room, walls in two
    # directions, so that the transform is fixed in all three coordinates.
    min_agreement: float = 5.0
    aligner: str = "ransac"  # alignment mode: ransac, svd, icp or imp_icp (slam/alignment/)
    # Fewest supports of an accepted alignment: 6 correspondences leave 2·6 − 3 = 9 degrees of
    # freedom for the covariance the refinement estimates from its residuals; the aligners'
    # own chance test (a wrong transform's supports at probability 1e-6) raises it on dense
    # maps.
    alignment: AlignConfig = field(default_factory=lambda: AlignConfig(min_support=6))
    feature_min_sightings: int = 3  # a pillar seen fewer times is not sent or matched

    def validate(self) -> None:
        check_positive("range", self.range)
        if self.bandwidth_bytes_per_step < 0:
            raise ConfigError(
                f"bandwidth_bytes_per_step: must be >= 0 (0 = unlimited),"
                f" got {self.bandwidth_bytes_per_step!r}"
            )
        check_range("loss_prob", self.loss_prob, 0.0, 1.0)
        if self.max_age is not None and self.max_age < 0:
            raise ConfigError(f"max_age: must be >= 0 or null, got {self.max_age!r}")
        if self.mode not in ("rendezvous", "alignment"):
            raise ConfigError(f"mode: must be 'rendezvous' or 'alignment', got {self.mode!r}")
        if self.features not in ("pillars", "walls"):
            raise ConfigError(f"features: must be 'pillars' or 'walls', got {self.features!r}")
        check_range("max_conflict", self.max_conflict, 0.0, 1.0)
        check_positive("min_agreement", self.min_agreement)
        if self.range_margin < 0:
            raise ConfigError(f"range_margin: must be >= 0 (m), got {self.range_margin!r}")
        if self.aligner not in ALIGNERS:
            raise ConfigError(
                f"aligner: must be one of {', '.join(ALIGNERS)}, got {self.aligner!r}"
            )
        for name in ("meeting_gap", "meeting_interval", "feature_min_sightings"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ConfigError(f"{name}: must be an integer >= 0 (steps), got {value!r}")


@dataclass
class Counters:
    """Traffic of one robot (see the module docstring for what each counts)."""

    messages_sent: int = 0
    attempts: int = 0
    messages_lost: int = 0
    messages_delivered: int = 0
    messages_expired: int = 0
    messages_dropped: int = 0  # dropped because the sender or the receiver failed
    messages_received: int = 0
    bytes_sent: int = 0
    bytes_lost: int = 0
    bytes_received: int = 0


@dataclass(frozen=True)
class Delivered:
    """A message that reached its receiver."""

    msg_id: int
    sender: int
    receiver: int
    payload: bytes
    sent_step: int
    delivered_step: int
    attempts: int  # transmission attempts it took (chunks and lost ones included)


@dataclass(frozen=True)
class Expired:
    """A message dropped after waiting longer than ``max_age`` steps, or (``drop_robot``)
    because its sender or receiver failed; ``expired_step`` is the step it was dropped."""

    msg_id: int
    sender: int
    receiver: int
    size: int
    sent_step: int
    expired_step: int
    bytes_done: int  # bytes that had got through before it was dropped


@dataclass
class _Queued:
    msg_id: int
    sender: int
    receiver: int
    payload: bytes
    sent_step: int
    done: int = 0  # bytes already received (chunked transfers)
    attempts: int = 0


def in_radio_range(positions: np.ndarray, radius: float) -> np.ndarray:  # (N, N) bool
    """Which robots are within ``radius`` of each other, from their true ``positions`` (N, ≥2)
    (the radio's range is physics); the diagonal is True."""
    xy = np.asarray(positions, dtype=float)[:, :2]
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    return np.asarray(d <= radius)


class Channel:
    """Message queue between robots with loss, bandwidth cap and expiry; see module docstring."""

    def __init__(self, config: ChannelConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        self._queue: list[_Queued] = []
        self._counters: dict[int, Counters] = {}
        self._next_id = 0
        self._last_step: int | None = None
        self.last_expired: tuple[Expired, ...] = ()

    # -- public API ----------------------------------------------------------------------------
    def send(self, sender: int, receiver: int, payload: bytes, step: int) -> int:
        """Queue ``payload`` from ``sender`` to ``receiver``; returns the message id."""
        if sender == receiver:
            raise ValueError(f"a robot cannot send to itself (robot {sender})")
        if not payload:
            raise ValueError("payload must be non-empty bytes")
        if self._last_step is not None and step < self._last_step:
            raise ValueError(f"send at step {step} after deliver at step {self._last_step}")
        msg = _Queued(self._next_id, sender, receiver, bytes(payload), step)
        self._next_id += 1
        self._queue.append(msg)
        self._counter(sender).messages_sent += 1
        return msg.msg_id

    def deliver(
        self,
        step: int,
        in_view: Callable[[int, int], bool],
        distance: Callable[[int, int], float] | None = None,
    ) -> list[Delivered]:
        """Expire old messages, then attempt every queued message whose robots are linked."""
        if self._last_step is not None and step <= self._last_step:
            raise ValueError(f"deliver steps must increase: {step} after {self._last_step}")
        self._last_step = step
        self.last_expired = self._expire(step)
        budget: dict[int, int] = {}
        delivered: list[Delivered] = []
        for msg in list(self._queue):
            if not self._linked(msg, in_view, distance):
                continue
            left = budget.setdefault(msg.sender, self._cap())
            if left <= 0:
                continue
            chunk = min(len(msg.payload) - msg.done, left)
            budget[msg.sender] = left - chunk
            if self._attempt(msg, chunk):
                self._queue.remove(msg)
                delivered.append(self._complete(msg, step))
        return delivered

    def drop_robot(self, robot: int, step: int) -> tuple[Expired, ...]:
        """Drop every queued message to or from ``robot`` (it failed), counted per sender as
        ``messages_dropped``; returns the drops."""
        gone = [m for m in self._queue if robot in (m.sender, m.receiver)]
        for m in gone:
            self._queue.remove(m)
            self._counter(m.sender).messages_dropped += 1
        return tuple(
            Expired(m.msg_id, m.sender, m.receiver, len(m.payload), m.sent_step, step, m.done)
            for m in gone
        )

    def pending(self, sender: int | None = None, receiver: int | None = None) -> int:
        """Number of queued messages, optionally only those of one sender and/or receiver."""
        return sum(
            1
            for m in self._queue
            if (sender is None or m.sender == sender)
            and (receiver is None or m.receiver == receiver)
        )

    def bytes_sent(self, robot: int) -> int:
        """One robot's bytes sent so far (``counters(robot).bytes_sent`` without the copy)."""
        counter = self._counters.get(robot)
        return 0 if counter is None else counter.bytes_sent

    def counters(self, robot: int) -> Counters:
        """A copy of one robot's counters (zeros if it never used the channel)."""
        return Counters(**vars(self._counter(robot)))

    def totals(self) -> Counters:
        """Counters summed over all robots."""
        total = Counters()
        for c in self._counters.values():
            for name, value in vars(c).items():
                setattr(total, name, getattr(total, name) + value)
        return total

    # -- internals --------------------------------------------------------------------------------
    def _counter(self, robot: int) -> Counters:
        return self._counters.setdefault(robot, Counters())

    def _cap(self) -> int:
        cap = self.config.bandwidth_bytes_per_step
        return cap if cap > 0 else _UNLIMITED

    def _linked(
        self,
        msg: _Queued,
        in_view: Callable[[int, int], bool],
        distance: Callable[[int, int], float] | None,
    ) -> bool:
        if not in_view(msg.sender, msg.receiver):
            return False
        return distance is None or distance(msg.sender, msg.receiver) <= self.config.range

    def _attempt(self, msg: _Queued, chunk: int) -> bool:
        """One transmission of ``chunk`` bytes; True when the message is now complete."""
        counter = self._counter(msg.sender)
        counter.attempts += 1
        counter.bytes_sent += chunk
        msg.attempts += 1
        if self._rng.random() < self.config.loss_prob:
            counter.messages_lost += 1
            counter.bytes_lost += chunk
            return False
        msg.done += chunk
        return msg.done == len(msg.payload)

    def _complete(self, msg: _Queued, step: int) -> Delivered:
        self._counter(msg.sender).messages_delivered += 1
        receiver = self._counter(msg.receiver)
        receiver.messages_received += 1
        receiver.bytes_received += len(msg.payload)
        return Delivered(
            msg.msg_id, msg.sender, msg.receiver, msg.payload, msg.sent_step, step, msg.attempts
        )

    def _expire(self, step: int) -> tuple[Expired, ...]:
        max_age = self.config.max_age
        if max_age is None:
            return ()
        old = [m for m in self._queue if step - m.sent_step > max_age]
        for m in old:
            self._queue.remove(m)
            self._counter(m.sender).messages_expired += 1
        return tuple(
            Expired(m.msg_id, m.sender, m.receiver, len(m.payload), m.sent_step, step, m.done)
            for m in old
        )

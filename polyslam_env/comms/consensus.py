"""MBLCC's landmark consensus over the channel (seed 003, eq. 12), for ``slam.backend: mblcc``.

After every step each active robot offers its best particle's estimates of the pillars it saw
in that sweep (:class:`~polyslam_env.slam.points.interface.LandmarkMessage`). It sends them to
every other active robot within radio range (``channel.range``, distance between the true
positions: the radio is physics), through the same :class:`~polyslam_env.comms.channel.Channel`
as the map exchange, so bytes, loss and bandwidth are counted like any other message.

MBLCC works in one known frame. Each robot's filter runs in its own frame, whose pose in the
world is its nominal start (``start_poses``, known to the team; with ``initial_error`` the true
start is off it by the start error, which the consensus ignores as the seed's "known initial
poses" do). The receiver maps the sender's estimates into its own frame with the two nominal
starts and keeps them for its next step, where eq. 12 pulls each landmark it re-observes
towards them.

A consensus message describes one sweep: one the link cannot deliver in the step it was sent
is dropped at the next step (it would only pull towards stale estimates), whatever
``channel.max_age`` says; the drop is counted as ``messages_expired``.

Wire format per message: uint32 count m, then m int32 pillar ids and m (x, y) pairs in the
channel's ``precision``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

from polyslam_env.comms.channel import Channel, ChannelConfig, in_radio_range
from polyslam_env.core.geometry import compose, inverse, transform_points
from polyslam_env.slam.backends import PointSlamRobot
from polyslam_env.slam.points.interface import LandmarkMessage

__all__ = ["ConsensusExchange", "decode", "encode"]


def encode(message: LandmarkMessage, precision: str) -> bytes:
    """The wire bytes of ``message`` (see the module docstring)."""
    ids = np.asarray(message.ids, dtype="<i4")
    means = np.asarray(message.means, dtype="<f4" if precision == "float32" else "<f8")
    return struct.pack("<I", len(ids)) + ids.tobytes() + means.tobytes()


def decode(payload: bytes, sender: int, precision: str) -> LandmarkMessage:
    """The message whose wire bytes are ``payload``."""
    (m,) = struct.unpack_from("<I", payload)
    ids = np.frombuffer(payload, dtype="<i4", count=m, offset=4).astype(np.int64)
    width = np.dtype("<f4" if precision == "float32" else "<f8")
    means = np.frombuffer(payload, dtype=width, count=2 * m, offset=4 + 4 * m)
    return LandmarkMessage(sender, ids, means.astype(float).reshape(m, 2))


class ConsensusExchange:
    """The team's consensus messages (see the module docstring); ``start_poses`` (N, 3) are
    the robots' nominal frames, ``rng`` the channel's stream."""

    def __init__(
        self, config: ChannelConfig, start_poses: np.ndarray, rng: np.random.Generator
    ) -> None:
        self.config = config
        self.channel = Channel(config.replace(max_age=0), rng)
        self.start_poses = np.asarray(start_poses, dtype=float)
        self.num_robots = len(self.start_poses)

    def step(
        self,
        step: int,
        slams: Sequence[PointSlamRobot],
        active: np.ndarray,
        positions: np.ndarray,
    ) -> int:
        """After SLAM step ``step``: send every active robot's message to the active robots in
        range of its true ``positions`` (N, 2), deliver, and hand each receiver what reached it
        (changes the SLAMs' inboxes). Returns the number of messages delivered."""
        near = in_radio_range(positions, self.config.range)
        linked = active[:, None] & active[None, :] & near
        for s in range(self.num_robots):
            if not active[s]:
                continue
            message = slams[s].export_message()
            if len(message.ids) == 0:
                continue
            payload = encode(message, self.config.precision)
            for r in np.flatnonzero(linked[s]).tolist():
                if r != s:
                    self.channel.send(s, r, payload, step)
        delivered = self.channel.deliver(step, lambda s, r: bool(linked[s, r]))
        inbox: list[list[LandmarkMessage]] = [[] for _ in range(self.num_robots)]
        for msg in delivered:
            received = decode(msg.payload, msg.sender, self.config.precision)
            inbox[msg.receiver].append(self._into_frame(received, msg.receiver))
        for r, messages in enumerate(inbox):
            if active[r]:
                slams[r].import_messages(messages)
        return len(delivered)

    def counters(self, robot: int) -> dict[str, float]:
        """Robot ``robot``'s traffic for the end-of-episode metrics."""
        c = self.channel.counters(robot)
        return {"bytes_sent": c.bytes_sent, "bytes_received": c.bytes_received}

    def _into_frame(self, message: LandmarkMessage, receiver: int) -> LandmarkMessage:
        """``message`` with its estimates moved from the sender's frame into the receiver's."""
        pose = compose(inverse(self.start_poses[receiver]), self.start_poses[message.sender])
        return LandmarkMessage(message.sender, message.ids, transform_points(message.means, pose))

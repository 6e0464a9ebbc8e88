"""SEIF map fusion between robots in the env (seed 001, §4), for ``slam.backend: seif`` with
``channel.mode: alignment``.

Two robots within radio range (``channel.range``, true positions: the radio is physics) meet
at most once per ``meeting_interval`` steps. At a meeting each sends the other its **own**
map: the landmark means and their joint information with the pose eliminated
(:meth:`PointSeif.landmark_information`), through the same
:class:`~polyslam_env.comms.channel.Channel` as every other message, so bytes, loss and
bandwidth are counted. The receiver searches the correspondences and the transform between the
two maps without any relative pose (:func:`~polyslam_env.slam.points.seif_fusion.find_fusion`:
triangle hypotheses, likelihood gain against a penalty per collapsed landmark, chance test) and,
if it accepts, keeps the sender's map with its transform as a **source**.

A robot's map (:meth:`PointSlamRobot.landmarks`) is then its own SEIF map with its sources
fused in (:func:`~polyslam_env.slam.points.seif_fusion.fuse_with_transform`: correspondences
found again against the current maps, the transform re-estimated jointly with the landmarks and
marginalised, so that the fused map stays consistent). Nothing received ever enters the
robot's filter, and what a robot sends is only its own filter's map: no information can come
back to where it started, so repeated meetings never count the same observation twice (a newer
map of a sender replaces the older one). The robot's pose estimate is its own filter's.

Wire format: uint32 n, then n (x, y) means and the upper triangle (row by row) of the 2n × 2n
information matrix, in the channel's ``precision``. The landmarks' pillar ids ride outside the
bytes, for evaluation only; matching never reads them.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

from polyslam_env.comms.channel import Channel, ChannelConfig, in_radio_range
from polyslam_env.comms.exchange import AlignmentAttempt
from polyslam_env.slam.alignment import Alignment
from polyslam_env.slam.backends import PointSlamRobot
from polyslam_env.slam.points.seif_fusion import (
    FusionConfig,
    InformationMap,
    find_fusion,
    transform_covariance,
)

__all__ = ["SeifMapExchange", "decode_map", "encode_map"]


def _width(precision: str) -> np.dtype[np.floating]:
    return np.dtype("<f4" if precision == "float32" else "<f8")


def encode_map(means: np.ndarray, information: np.ndarray, precision: str) -> bytes:
    """The wire bytes of a map: means (n, 2) and information (2n, 2n), see the docstring."""
    n = len(means)
    upper = information[np.triu_indices(2 * n)]
    body = np.concatenate([np.asarray(means, dtype=float).ravel(), upper])
    return struct.pack("<I", n) + body.astype(_width(precision)).tobytes()


def decode_map(payload: bytes, precision: str) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`encode_map`: means (n, 2) and the symmetric information (2n, 2n)."""
    (n,) = struct.unpack_from("<I", payload)
    size = 2 * n
    count = size + size * (size + 1) // 2
    values = np.frombuffer(payload, dtype=_width(precision), count=count, offset=4)
    values = values.astype(float)
    information = np.zeros((size, size))
    information[np.triu_indices(size)] = values[size:]
    information = information + np.triu(information, 1).T
    return values[:size].reshape(n, 2), information


class SeifMapExchange:
    """The team's SEIF map fusion (see the module docstring); ``rng`` is the channel's stream,
    ``fusion_rng`` the correspondence search's."""

    def __init__(
        self,
        config: ChannelConfig,
        num_robots: int,
        rng: np.random.Generator,
        fusion_rng: np.random.Generator,
        fusion: FusionConfig | None = None,
    ) -> None:
        self.config = config
        self.num_robots = num_robots
        self.channel = Channel(config, rng)
        self.fusion = fusion or FusionConfig()
        self._fusion_rng = fusion_rng
        self._last_start: dict[tuple[int, int], int] = {}
        self._ids: dict[int, np.ndarray] = {}  # message id → the map's pillar ids (evaluation)
        self.alignments: list[AlignmentAttempt] = []  # every fusion attempt, in order

    def step(
        self,
        step: int,
        robots: Sequence[PointSlamRobot],
        active: np.ndarray,
        positions: np.ndarray,
    ) -> int:
        """After SLAM step ``step``: meetings of active pairs in range of their true
        ``positions`` (N, 2), one map sent each way, deliveries fused at their receivers
        (changes the robots' sources). Returns the number of messages delivered."""
        near = in_radio_range(positions, self.config.range)
        linked = active[:, None] & active[None, :] & near
        interval = max(self.config.meeting_interval, 1)
        for i, j in zip(*np.nonzero(np.triu(linked, k=1)), strict=True):
            pair = (int(i), int(j))
            if step - self._last_start.get(pair, -interval) < interval:
                continue
            self._last_start[pair] = step
            for s, r in (pair, pair[::-1]):
                own = robots[s].information_map()
                if len(own) == 0:
                    continue
                payload = encode_map(own.means, own.information, self.config.precision)
                self._ids[self.channel.send(s, r, payload, step)] = own.ids
        delivered = self.channel.deliver(step, lambda s, r: bool(linked[s, r]))
        for msg in delivered:
            means, information = decode_map(msg.payload, self.config.precision)
            theirs = InformationMap(means, information, self._ids.pop(msg.msg_id))
            self._fuse(msg.delivered_step, msg.sender, msg.receiver, robots[msg.receiver], theirs)
        for e in self.channel.last_expired:
            self._ids.pop(e.msg_id, None)
        return len(delivered)

    def _fuse(
        self, step: int, sender: int, receiver: int, robot: PointSlamRobot, theirs: InformationMap
    ) -> None:
        mine = robot.information_map()
        found = find_fusion(mine, theirs, self._fusion_rng, self.fusion)
        if found is None:  # an earlier accepted map of the sender, if any, stays a source
            result = Alignment("seif_fusion", None, None, 0, len(theirs), "no fusion accepted")
        else:
            result = Alignment("seif_fusion", found.transform, None, len(found.pairs), len(theirs))
            cov = transform_covariance(mine, theirs, found)
            robot.add_fusion_source(sender, theirs, found.transform, cov)
        self.alignments.append(AlignmentAttempt(step, sender, receiver, result))

    def counters(self, robot: int) -> dict[str, float]:
        """Robot ``robot``'s traffic and fusion attempts for the end-of-episode metrics."""
        c = self.channel.counters(robot)
        mine = [a for a in self.alignments if a.receiver == robot]
        return {
            "bytes_sent": c.bytes_sent,
            "bytes_received": c.bytes_received,
            "messages_sent": c.messages_sent,
            "messages_received": c.messages_received,
            "alignments_attempted": len(mine),
            "alignments_accepted": sum(a.result.accepted for a in mine),
        }

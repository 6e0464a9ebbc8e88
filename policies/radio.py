"""Goal messages between team-mates (``frontier_team``): their bytes, the team's radio, and how a
receiver places a team-mate's goal in its own frame from a mutual camera sighting.

The env's channel carries the rendezvous map exchange only; a policy's action is (v, ω), so
policies have no message path through it. Goal messages go through a :class:`Radio` that the
team's policies share and that models the same link: a message is sent only while its sender
sees another robot, and it reaches a team-mate only if both saw each other at the step it was
sent (a mutual camera sighting, as a rendezvous; the camera's range is the channel's, 1.5 m by
default), one step later. Every message sent is counted in bytes (its encoded length, below)
whether or not anyone receives it; the policy reports them (``goal_bytes_sent``) and
``polyslam evaluate`` adds them to the bytes the robots sent. The env's ``bytes`` reward term
does not see them.

A robot sees anonymous detections (distance, bearing), not who is who; so a message carries the
sender's own detections, and a receiver takes it as coming from the one robot it saw at the
same distance (within ``tol``), the pair's mutual sighting. The two bearings then give the
sender's pose in the receiver's body frame (SPEC §4, the rendezvous geometry of
``comms/relative_pose.py``: l at ``d (cos α_j, sin α_j)``, ``θ_l − θ_j = π + α_j − α_l``), and
the goal, which the message holds in the sender's body frame, follows.

Byte layout (little-endian, floats float32), ``14 + 8k + 8g`` bytes for k detections and g
goals (the current one first, then the last ones it had, newest first)::

    offset     size   field
    0          1      magic 0x47 ('G')                                     uint8
    1          1      format version = 1                                   uint8
    2          2      sender id                                            uint16
    4          4      step it was sent                                     uint32
    8          1      number of detections k                               uint8
    9          1      number of goals g (>= 1)                             uint8
    10         8k     distance (m), bearing (rad) of each robot it sees    float32
    10+8k      8g     its goals in its body frame: x ahead, y left (m)     float32
    10+8k+8g   4      CRC-32 (zlib) of every preceding byte                uint32
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.geometry import compose, transform_points

__all__ = ["GoalMessage", "Radio", "decode", "encode", "goal_in_own_frame", "mutual_sighting"]

MAGIC, VERSION = 0x47, 1
_HEAD = struct.Struct("<BBHIBB")  # magic, version, sender, step, k, g
_CRC = struct.Struct("<I")


@dataclass(frozen=True, eq=False)
class GoalMessage:
    """What a robot announces: its goals, and the robots it sees (to be recognised by them)."""

    sender: int
    step: int
    detections: np.ndarray  # (k, 2) distance m, bearing rad of the robots it sees
    goals: np.ndarray  # (g, 2) m, its current then last goals in its body frame (x ahead)


def encode(message: GoalMessage) -> bytes:
    """The message's bytes (module doc's layout); at most 255 detections and goals."""
    seen = np.asarray(message.detections, dtype="<f4").reshape(-1, 2)
    goals = np.asarray(message.goals, dtype="<f4").reshape(-1, 2)
    head = _HEAD.pack(MAGIC, VERSION, message.sender, message.step, len(seen), len(goals))
    body = head + seen.tobytes() + goals.tobytes()
    return body + _CRC.pack(zlib.crc32(body))


def decode(data: bytes) -> GoalMessage:
    """The message in ``data``; a wrong magic, version, length or checksum is a ValueError."""
    if len(data) < _HEAD.size + _CRC.size:
        raise ValueError(f"goal message: {len(data)} bytes is too short")
    magic, version, sender, step, k, g = _HEAD.unpack_from(data)
    if magic != MAGIC or version != VERSION:
        raise ValueError(f"goal message: magic {magic:#x} version {version}, expected 0x47 1")
    if len(data) != _HEAD.size + 8 * (k + g) + _CRC.size:
        raise ValueError(f"goal message: {len(data)} bytes for {k} detections and {g} goals")
    if zlib.crc32(data[: -_CRC.size]) != _CRC.unpack_from(data, len(data) - _CRC.size)[0]:
        raise ValueError("goal message: checksum mismatch")
    floats = np.frombuffer(data, dtype="<f4", count=2 * (k + g), offset=_HEAD.size)
    pairs = floats.astype(float).reshape(k + g, 2)
    return GoalMessage(sender, step, pairs[:k], pairs[k:])


class Radio:
    """The team's goal radio: each robot's last message, and what it sent (module doc).

    ``send`` posts a robot's message (its previous one is gone); a team-mate reads the posts
    with ``heard`` and decides from its own sightings which reached it. Counters per robot:
    ``messages_sent``, ``bytes_sent``, ``messages_received``."""

    def __init__(self, robots: int) -> None:
        self._posts: dict[int, bytes] = {}
        self.messages_sent = [0] * robots
        self.bytes_sent = [0] * robots
        self.messages_received = [0] * robots

    def reset(self, robot: int) -> None:
        """Forget robot ``robot``'s post and zero its counters (a new episode)."""
        self._posts.pop(robot, None)
        self.messages_sent[robot] = self.bytes_sent[robot] = self.messages_received[robot] = 0

    def send(self, robot: int, data: bytes) -> None:
        """Post ``data`` from robot ``robot`` and count it."""
        self._posts[robot] = bytes(data)
        self.messages_sent[robot] += 1
        self.bytes_sent[robot] += len(data)

    def heard(self, robot: int) -> list[bytes]:
        """The team-mates' posts, in robot order (what robot ``robot``'s radio picks up)."""
        return [data for sender, data in sorted(self._posts.items()) if sender != robot]


def mutual_sighting(own: np.ndarray, theirs: np.ndarray, tol: float) -> tuple[int, int] | None:
    """The pair (j, k) of the receiver's detection ``own[j]`` and the sender's ``theirs[k]``
    ((k, 2) distance, bearing each) that is their mutual sighting: the only detection of the
    receiver within ``tol`` m in distance of one of the sender's (None if none, or if two of
    the receiver's fit: then it cannot tell which robot sent the message)."""
    if len(own) == 0 or len(theirs) == 0:
        return None
    gap = np.abs(own[:, None, 0] - theirs[None, :, 0])  # (J, K) m
    fits = np.flatnonzero(gap.min(axis=1) <= tol)
    if len(fits) != 1:
        return None
    j = int(fits[0])
    return j, int(np.argmin(gap[j]))


def goal_in_own_frame(
    pose: np.ndarray, seen: np.ndarray, bearing_back: float, goal: np.ndarray
) -> np.ndarray:  # (…, 2)
    """A team-mate's ``goal`` (…, 2) given in its body frame, in the receiver's own frame: the
    receiver at ``pose`` (3,) saw it at ``seen`` (distance, bearing) while it saw the receiver
    at bearing ``bearing_back`` (module doc)."""
    d, alpha = float(seen[0]), float(seen[1])
    mate = np.array([d * np.cos(alpha), d * np.sin(alpha), np.pi + alpha - bearing_back])
    return np.asarray(transform_points(goal, compose(pose, mate)))

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

**A radio range longer than the camera's** (the env's ``channel.range`` above
``world.camera.range``, a public fact, ``radio_range``): the radio then also has the medium's
distance test (``links``: the env's ``radio_links()``, which robots are within
``channel.range`` of each other now, from their true positions, as the env's channel decides
its own deliveries; the radio keeps only whom a post reached, never a position). A message
then also carries its sender's pose in its own frame (version 3, or the area's pose in version
2), so that a receiver that once placed the sender by a mutual sighting keeps the transform
between their two start frames (:func:`own_frame_of`) and places the sender's later messages
through it, with no sighting, whenever the medium says they reached it (:meth:`Radio.reached`).

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

**Explored area** (version 2: a message that also carries the area its sender knows explored,
:class:`Area`, ``37 + 8k + 8g + L`` bytes): after the goals and before the CRC::

    offset     size   field
    A          12     the sender's pose x, y (m), θ (rad) in its own frame  float32
    A+12       4      lattice index (col, row) of the grid's lower-left cell int16
    A+16       4      grid width w, height h (cells)                        uint16
    A+20       1      cell size (cm)                                        uint8
    A+21       2      L, the length of the packed cells                     uint16
    A+23       L      the w·h cells row by row (row 0 = the lowest), one bit each
                      (``numpy.packbits``), deflated (``zlib``, level 9)

with A = 10 + 8k + 8g.

**Sender's pose** (version 3: a message without an area that carries its sender's pose in its
own frame, sent only over a radio longer than the camera, ``26 + 8k + 8g`` bytes): after the
goals and before the CRC, the pose x, y (m), θ (rad), three float32 (as the area's).

The area's cells are in the sender's own (start) frame; with its pose there,
a receiver that places the sender's body from a mutual sighting places the grid too
(:func:`area_in_own_frame`). Mostly-explored rooms are long runs of ones and unexplored space
long runs of zeros, which deflate shrinks to a few hundred bytes for an office floor.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from policies.base import PolicyContext
from polyslam_env.core.geometry import compose, inverse, transform_points

__all__ = [
    "Area",
    "GoalMessage",
    "Links",
    "Radio",
    "area_in_frame",
    "area_in_own_frame",
    "decode",
    "encode",
    "goal_in_own_frame",
    "mate_in_own_frame",
    "mutual_sighting",
    "own_frame_of",
    "team_radio",
]

#: the medium's distance test: () → (N, N) bool, which robots are within radio range now
Links = Callable[[], np.ndarray]

MAGIC, VERSION, VERSION_AREA, VERSION_POSE = 0x47, 1, 2, 3
_HEAD = struct.Struct("<BBHIBB")  # magic, version, sender, step, k, g
_AREA = struct.Struct("<3fhhHHBH")  # pose, col0, row0, w, h, cell cm, L
_POSE = struct.Struct("<3f")  # x, y, θ
_CRC = struct.Struct("<I")


@dataclass(frozen=True, eq=False)
class Area:
    """The area a robot knows explored, as a message carries it: ``cells`` (h, w) bool of a
    grid of ``cell`` m in its own frame whose lower-left cell has lattice index ``corner``
    (col, row) (its corner at ``corner · cell``), and the robot's ``pose`` (3,) in that frame
    when it sent it."""

    pose: np.ndarray  # (3,) x, y m, θ rad in the sender's own frame
    corner: tuple[int, int]  # (col, row) lattice index of cells[0, 0]
    cells: np.ndarray  # (h, w) bool, row 0 = the lowest y
    cell: float  # m, a whole number of cm

    def centres(self) -> np.ndarray:  # (M, 2)
        """The own-frame centres of the explored cells."""
        rows, cols = np.nonzero(self.cells)
        lattice = np.column_stack([cols + self.corner[0], rows + self.corner[1]])
        return (lattice + 0.5) * self.cell


@dataclass(frozen=True, eq=False)
class GoalMessage:
    """What a robot announces: its goals, and the robots it sees (to be recognised by them)."""

    sender: int
    step: int
    detections: np.ndarray  # (k, 2) distance m, bearing rad of the robots it sees
    goals: np.ndarray  # (g, 2) m, its current then last goals in its body frame (x ahead)
    area: Area | None = None  # the area it knows explored (version 2), or None
    #: its pose (3,) in its own frame (version 3; version 2 carries it as the area's), or None
    pose: np.ndarray | None = None


def encode(message: GoalMessage) -> bytes:
    """The message's bytes (module doc's layout); at most 255 detections and goals, an area
    grid of at most 65,535 cells a side and 65,535 bytes deflated. With an area, ``pose`` is
    the area's (a different one is a ValueError)."""
    seen = np.asarray(message.detections, dtype="<f4").reshape(-1, 2)
    goals = np.asarray(message.goals, dtype="<f4").reshape(-1, 2)
    area, pose = message.area, message.pose
    if area is not None and pose is not None and not np.array_equal(area.pose, pose):
        raise ValueError("goal message: a pose other than its area's")
    version = VERSION_AREA if area is not None else VERSION if pose is None else VERSION_POSE
    head = _HEAD.pack(MAGIC, version, message.sender, message.step, len(seen), len(goals))
    body = head + seen.tobytes() + goals.tobytes()
    if area is None and pose is not None:
        body += _POSE.pack(*(float(v) for v in pose))
    if area is not None:
        h, w = area.cells.shape
        packed = zlib.compress(np.packbits(area.cells, axis=None).tobytes(), 9)
        cm = round(area.cell * 100.0)
        x, y, theta = (float(v) for v in area.pose)
        body += _AREA.pack(x, y, theta, *area.corner, w, h, cm, len(packed)) + packed
    return body + _CRC.pack(zlib.crc32(body))


def decode(data: bytes) -> GoalMessage:
    """The message in ``data``; a wrong magic, version, length or checksum is a ValueError."""
    if len(data) < _HEAD.size + _CRC.size:
        raise ValueError(f"goal message: {len(data)} bytes is too short")
    magic, version, sender, step, k, g = _HEAD.unpack_from(data)
    if magic != MAGIC or version not in (VERSION, VERSION_AREA, VERSION_POSE):
        raise ValueError(
            f"goal message: magic {magic:#x} version {version}, expected 0x47 and 1, 2 or 3"
        )
    at = _HEAD.size + 8 * (k + g)  # where the area (version 2), the pose (3) or the CRC begins
    extra = {VERSION: 0, VERSION_AREA: _AREA.size, VERSION_POSE: _POSE.size}[version]
    size = at + _CRC.size + extra
    if len(data) < size:
        raise ValueError(f"goal message: {len(data)} bytes for {k} detections and {g} goals")
    if version == VERSION_AREA:
        size += _AREA.unpack_from(data, at)[-1]
    if len(data) != size:
        raise ValueError(f"goal message: {len(data)} bytes, its fields say {size}")
    if zlib.crc32(data[: -_CRC.size]) != _CRC.unpack_from(data, len(data) - _CRC.size)[0]:
        raise ValueError("goal message: checksum mismatch")
    floats = np.frombuffer(data, dtype="<f4", count=2 * (k + g), offset=_HEAD.size)
    pairs = floats.astype(float).reshape(k + g, 2)
    area = _area(data, at) if version == VERSION_AREA else None
    pose = area.pose if area is not None else None
    if version == VERSION_POSE:
        pose = np.array(_POSE.unpack_from(data, at), dtype=float)
    return GoalMessage(sender, step, pairs[:k], pairs[k:], area, pose)


def _area(data: bytes, at: int) -> Area:
    """The :class:`Area` of a version-2 message whose area section begins at ``at``."""
    x, y, theta, col, row, w, h, cm, n = _AREA.unpack_from(data, at)
    start = at + _AREA.size
    try:
        packed = zlib.decompress(data[start : start + n])
    except zlib.error as exc:
        raise ValueError(f"goal message: area cells do not inflate ({exc})") from None
    if len(packed) != (w * h + 7) // 8 or cm == 0:
        raise ValueError(f"goal message: area of {w} x {h} cells of {cm} cm in {len(packed)} bytes")
    bits = np.unpackbits(np.frombuffer(packed, dtype=np.uint8), count=w * h).astype(bool)
    pose = np.array([x, y, theta], dtype=float)
    return Area(pose, (col, row), bits.reshape(h, w), cm / 100.0)


class Radio:
    """The team's goal radio: each robot's last message, and what it sent (module doc).

    ``send`` posts a robot's message (its previous one is gone); a team-mate reads the posts
    with ``heard`` and decides from its own sightings which reached it. With ``links`` (the
    medium's distance test, a callable giving the (N, N) bool of robots within radio range of
    each other now: a radio longer than the camera, module doc) a post also reaches the
    team-mates within range when it was sent (:meth:`reached`). Counters per robot:
    ``messages_sent``, ``bytes_sent``, ``messages_received``."""

    def __init__(self, robots: int, links: Links | None = None) -> None:
        self.links = links
        self._posts: dict[int, bytes] = {}
        self._reach: dict[int, np.ndarray] = {}  # sender → (N,) bool, in range at its post
        self.messages_sent = [0] * robots
        self.bytes_sent = [0] * robots
        self.messages_received = [0] * robots

    def reset(self, robot: int) -> None:
        """Forget robot ``robot``'s post and zero its counters (a new episode)."""
        self._posts.pop(robot, None)
        self._reach.pop(robot, None)
        self.messages_sent[robot] = self.bytes_sent[robot] = self.messages_received[robot] = 0

    def send(self, robot: int, data: bytes) -> None:
        """Post ``data`` from robot ``robot`` and count it (with ``links``, note whom it
        reaches: the team-mates within radio range now)."""
        self._posts[robot] = bytes(data)
        if self.links is not None:
            self._reach[robot] = np.array(self.links()[robot], dtype=bool)
        self.messages_sent[robot] += 1
        self.bytes_sent[robot] += len(data)

    def reached(self, sender: int, robot: int) -> bool:
        """Whether ``sender``'s post reached ``robot`` over the radio's range (always False
        without ``links``: then only a mutual sighting carries it)."""
        reach = self._reach.get(sender)
        return reach is not None and sender != robot and bool(reach[robot])

    def heard(self, robot: int) -> list[bytes]:
        """The team-mates' posts, in robot order (what robot ``robot``'s radio picks up)."""
        return [data for sender, data in sorted(self._posts.items()) if sender != robot]


def team_radio(contexts: Sequence[PolicyContext], links: Links | None = None) -> Radio:
    """The radio a team of ``contexts`` shares: with the env's ``links`` when its channel
    reaches farther than the camera (the public fact ``radio_range`` > ``camera_range``, module
    doc), else one that carries a message over a mutual sighting only (``links`` unused)."""
    far = bool(contexts) and contexts[0].radio_range > contexts[0].camera_range
    return Radio(len(contexts), links if far else None)


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


def mate_in_own_frame(pose: np.ndarray, seen: np.ndarray, bearing_back: float) -> np.ndarray:
    """A team-mate's body pose (3,) in the receiver's own frame: the receiver at ``pose`` (3,)
    saw it at ``seen`` (distance, bearing) while it saw the receiver at bearing
    ``bearing_back`` (module doc)."""
    return np.asarray(compose(pose, _mate(seen, bearing_back)))


def own_frame_of(body: np.ndarray, pose: np.ndarray) -> np.ndarray:  # (3,)
    """A team-mate's own (start) frame in the receiver's: its ``body`` pose (3,) in the
    receiver's frame (:func:`mate_in_own_frame`) with its ``pose`` (3,) in its own frame at the
    same time. Both frames are fixed, so the transform holds for the episode (its error is the
    sighting's and the two pose estimates' then)."""
    return np.asarray(compose(body, inverse(pose)))


def goal_in_own_frame(
    pose: np.ndarray, seen: np.ndarray, bearing_back: float, goal: np.ndarray
) -> np.ndarray:  # (…, 2)
    """A team-mate's ``goal`` (…, 2) given in its body frame, in the receiver's own frame: the
    receiver at ``pose`` (3,) saw it at ``seen`` (distance, bearing) while it saw the receiver
    at bearing ``bearing_back`` (module doc)."""
    return np.asarray(transform_points(goal, mate_in_own_frame(pose, seen, bearing_back)))


def area_in_own_frame(
    pose: np.ndarray, seen: np.ndarray, bearing_back: float, area: Area
) -> np.ndarray:  # (4M, 2)
    """:func:`area_in_frame` placed from a mutual sighting as :func:`goal_in_own_frame` places
    a goal: the sender's own frame is its pose there composed with its body's pose in the
    receiver's frame (:func:`own_frame_of`)."""
    body = mate_in_own_frame(pose, seen, bearing_back)
    return area_in_frame(area, own_frame_of(body, area.pose))


def area_in_frame(area: Area, frame: np.ndarray) -> np.ndarray:  # (4M, 2)
    """Points that cover a team-mate's explored ``area`` (its M cells, each by the centres of
    its four quarters, so that a cell of the receiver's grid half its size, turned any way, is
    hit where the area covers most of it), in the receiver's own frame, where the sender's own
    frame is ``frame`` (3,)."""
    offsets = 0.25 * area.cell * np.array([[-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]])
    points = (area.centres()[:, None, :] + offsets[None]).reshape(-1, 2)
    return np.asarray(transform_points(points, frame))


def _mate(seen: np.ndarray, bearing_back: float) -> np.ndarray:  # (3,)
    """The pose of a team-mate in the receiver's body frame, from the receiver's sighting
    ``seen`` (distance, bearing) and the team-mate's bearing back (SPEC §4)."""
    d, alpha = float(seen[0]), float(seen[1])
    return np.array([d * np.cos(alpha), d * np.sin(alpha), np.pi + alpha - bearing_back])

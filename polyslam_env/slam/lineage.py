"""Where each landmark came from: the SLAM's lineage events (:class:`Lineage`).

Every change of the map's set of landmarks is one event, in order: a landmark *created* from
this robot's beams, *inserted* from outside (a received wall), *replaced* by its refit,
*merged* with another into a new one, or *removed*. Ids are stable and never reused, so the
log tells exactly which landmarks hold whose data: the map exchange follows it to carry each
landmark's provenance (the senders whose data it holds) over the receiver's refits and merges
in O(changes), and the wall graph (:mod:`~polyslam_env.slam.walls`) follows it to keep its
groups. Readers keep a cursor (:attr:`Lineage.cursor`) and read what came after it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

CREATED = "created"  # from a cluster of this robot's beam hits
INSERTED = "inserted"  # from outside (PolySlam.insert_landmark: a received wall)
REPLACED = "replaced"  # refit on its Q_bad points: one parent
MERGED = "merged"  # one polynomial through two landmarks: two parents
REMOVED = "removed"  # left the map without an heir (PolySlam.remove_landmark)
KINDS = (CREATED, INSERTED, REPLACED, MERGED, REMOVED)


class LineageEvent(NamedTuple):
    """One change of the map's landmarks."""

    kind: str  # one of KINDS
    landmark_id: int  # the new landmark (the removed one for REMOVED)
    parents: tuple[int, ...]  # the landmarks it replaces (REPLACED: one, MERGED: two)
    step: int  # the SLAM step it happened in


class Lineage:
    """The ordered log of one SLAM's lineage events, with listeners called on each."""

    def __init__(self) -> None:
        self.events: list[LineageEvent] = []
        self._listeners: list[Callable[[LineageEvent], None]] = []

    @property
    def cursor(self) -> int:
        """Where the next event will be: read :meth:`since` a cursor taken earlier."""
        return len(self.events)

    def since(self, cursor: int) -> list[LineageEvent]:
        """The events after ``cursor``, in order."""
        return self.events[cursor:]

    def listen(self, listener: Callable[[LineageEvent], None]) -> None:
        """Call ``listener(event)`` on every event from now on, as it is recorded."""
        self._listeners.append(listener)

    def record(self, kind: str, landmark_id: int, parents: tuple[int, ...], step: int) -> None:
        event = LineageEvent(kind, landmark_id, parents, step)
        self.events.append(event)
        for listener in self._listeners:
            listener(event)

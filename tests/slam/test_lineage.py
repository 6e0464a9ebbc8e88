"""The SLAM's lineage events: every change of the map's landmarks, with exact parents, and the
wall graph and the exchange's provenance that follow them."""

from __future__ import annotations

import numpy as np

from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.lineage import CREATED, INSERTED, MERGED, REMOVED, REPLACED
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from tests.slam.test_map_building import drive, straight

WALLS = np.array(
    [
        [[-1.0, 1.0], [12.0, 1.0]],  # left
        [[-1.0, -1.0], [5.0, -1.0]],  # right, a doorway from 5 to 5.8
        [[5.8, -1.0], [12.0, -1.0]],
    ]
)


def received(slam: PolySlam, lo: float, hi: float, offset: float = 1.0) -> Fit:
    """A straight wall x² = ``offset`` on x¹ ∈ [lo, hi] as a received fit would be."""
    poly = Polynomial(1, np.array([offset, 0.0, 0.0, 0.0]), lo, hi)
    gx = np.zeros((1, slam.mean.size))
    gx[0, 1] = 1.0
    return Fit(poly, offset, gx, np.ones((1, 1)), np.eye(1) * 1e-4, 0.01, 1)


def test_lineage__events_account_for_every_landmark_of_an_episode() -> None:
    """Along two walls and a doorway: each landmark in the map was created or made by its
    last event, every parent left the map when its heir came, ids are never reused, and the
    map's ids are exactly what the events leave."""
    slam, *_ = drive(WALLS, straight(8.0), seed=3)
    events = slam.lineage.events
    kinds = {event.kind for event in events}
    assert CREATED in kinds and kinds & {MERGED, REPLACED}, kinds
    alive: set[int] = set()
    born: set[int] = set()
    for event in events:
        assert event.landmark_id not in born or event.kind == REMOVED  # ids never come back
        if event.kind == REMOVED:
            alive.remove(event.landmark_id)
            continue
        for parent in event.parents:
            alive.remove(parent)  # a parent was alive, and is gone once its heir exists
        alive.add(event.landmark_id)
        born.add(event.landmark_id)
        assert len(event.parents) == {CREATED: 0, REPLACED: 1, MERGED: 2}[event.kind]
    assert alive == set(slam.landmark_ids)
    assert [e.step for e in events] == sorted(e.step for e in events)


def test_lineage__insert_merge_and_remove_with_their_parents() -> None:
    slam = PolySlam(SlamConfig(), np.radians([90.0]), 2.0)
    first = slam.insert_landmark(received(slam, 0.0, 2.0))
    cursor = slam.lineage.cursor
    held = slam.insert_landmark(received(slam, 1.5, 4.0))  # overlaps the first: one wall
    events = slam.lineage.since(cursor)
    assert [e.kind for e in events] == [INSERTED, MERGED]
    second = events[0].landmark_id
    assert events[1].landmark_id == held and set(events[1].parents) == {first, second}
    assert slam.landmark_ids == [held]
    assert slam.table.received[0] == 1  # merged from received data: still received
    assert slam.wall_groups == {held: held}
    slam.remove_landmark(held)
    assert slam.lineage.events[-1].kind == REMOVED and slam.lineage.events[-1].landmark_id == held
    assert slam.n_landmarks == 0 and slam.wall_groups == {}

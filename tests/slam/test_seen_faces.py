"""``SlamConfig.seen_faces``: a beam that meets a landmark from behind (the side opposite to the
face the landmark's beams saw) moves nothing. Each half of the rule is also checked bit for bit
against a readable version: the association's in ``tests/slam/test_association.py``, the
update's in ``tests/slam/test_kernels.py``."""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.apps.benchmark_components import BEAM_ANGLES, make_slam
from polyslam_env.slam.columns import SIDE
from polyslam_env.slam.config import PRESETS, SlamConfig
from polyslam_env.slam.polynomial import Polynomial

#: m: the board's thickness, the range noise's 1.5 σ (the χ² gate passes it)
THICKNESS = 0.03


def _c0_after_one_step(seen_faces: bool, side: int) -> float:
    """A 3 m wall at y = −0.5 (the robot at the origin, above it), its face seen from ``side``;
    the beam pointing straight down reads the top of a board lying on the wall's line,
    THICKNESS nearer than the wall; one step with no motion. Returns the wall's c0 after it."""
    wall = Polynomial(1, np.array([-0.5, 0.0, 0.0, 0.0]), -1.5, 1.5)
    slam = make_slam([wall], SlamConfig(seen_faces=seen_faces, update_spacing_deg=0.0))
    slam.table.buffers[1][SIDE, 0] = side
    down = int(np.argmin(np.abs(BEAM_ANGLES + math.pi / 2)))
    assert math.isclose(BEAM_ANGLES[down], -math.pi / 2)
    ranges = np.full(BEAM_ANGLES.size, math.inf)
    ranges[down] = 0.5 - THICKNESS
    slam.step(np.zeros(3), ranges)
    return float(slam.mean[3])


def test_seen_faces__a_beam_from_behind_moves_nothing_a_beam_on_the_seen_face_does() -> None:
    # the down beam travels towards −y: it meets the wall from the +η side
    from_behind = _c0_after_one_step(seen_faces=True, side=-1)  # seen from below only
    assert from_behind == -0.5  # not associated, not updated: the wall stays where it was
    # the same beam on the face it can hit, on a face seen from both sides, or with the rule
    # off: the update takes the board's top for the wall and moves it towards the robot by
    # about half the thickness (the wall's c0 and the reading are equally uncertain)
    for seen_faces, side in ((True, 1), (True, 0), (False, -1)):
        moved = _c0_after_one_step(seen_faces, side) - (-0.5)
        assert 0.25 * THICKNESS < moved < 0.75 * THICKNESS, (seen_faces, side, moved)


def test_seen_faces__off_by_default_and_in_the_paper_preset() -> None:
    assert not SlamConfig().seen_faces and not PRESETS["paper"].seen_faces

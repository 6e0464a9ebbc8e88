"""One step's sensor readings of the whole team, as the stages pass them on."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from polyslam_env.world.sensors import CameraFrame, Detection

if TYPE_CHECKING:
    from polyslam_env.world.point_sensor import PillarReading

__all__ = ["Sensing"]


@dataclass(frozen=True)
class Sensing:
    """What the sensors read at the end of one step (or at reset).

    ``true_ranges`` are the noiseless ranges of the same ray cast as ``ranges``: they place the
    beam hit points of the histories (the true points the beams hit), never observations.
    ``camera`` holds the detections as arrays (what the observations read), ``detections``
    the same as lists (what the exchange reads).
    """

    ranges: np.ndarray  # (N, B) noisy, inf = no return
    true_ranges: np.ndarray  # (N, B) noiseless, inf = no return
    camera: CameraFrame  # (N, N) arrays: who sees whom, at what distance and bearing
    pillars: tuple[PillarReading, ...] = ()  # per robot, with the pillar sensor on

    @cached_property
    def detections(self) -> list[list[Detection]]:
        """Per robot, the robots its camera sees (target order); made at the first read (the
        exchange stage reads it twice a step)."""
        return self.camera.lists()

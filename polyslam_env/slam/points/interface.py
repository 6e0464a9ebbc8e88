"""What every point-landmark back-end takes and gives (see the package docstring)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


def _ids(values: Sequence[int] | np.ndarray = ()) -> np.ndarray:
    return np.asarray(values, dtype=np.int64).reshape(-1)


@dataclass(frozen=True)
class PointMeasurements:
    """Range-bearing measurements of landmarks with known identities (one sensor sweep)."""

    ids: np.ndarray = field(default_factory=lambda: _ids())  # (m,) int64
    z: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (m, 2): range m, bearing rad

    def __post_init__(self) -> None:
        if self.z.shape != (len(self.ids), 2):
            raise ValueError(f"z must have shape ({len(self.ids)}, 2), got {self.z.shape}")
        if len(np.unique(self.ids)) != len(self.ids):
            raise ValueError("one measurement per landmark id and sweep")


@dataclass(frozen=True)
class LandmarkMap:
    """A back-end's landmark estimates, for metrics and display."""

    ids: np.ndarray  # (M,) int64, in order of first sighting
    means: np.ndarray  # (M, 2) m
    covs: np.ndarray  # (M, 2, 2) m²


@dataclass(frozen=True)
class LandmarkMessage:
    """What MBLCC robots exchange: the best particle's estimates of the landmarks the sender
    observed in its last sweep (the μ^{n,max}_{j,k−1} of eq. 12). 16 bytes per landmark plus
    8 per id in float64/int64."""

    sender: int
    ids: np.ndarray  # (m,) int64
    means: np.ndarray  # (m, 2) m

    @property
    def nbytes(self) -> int:
        """The message's size in bytes: its ids and means."""
        return int(self.ids.nbytes + self.means.nbytes)


class PointSlamBackend(Protocol):
    """One robot's point-landmark SLAM."""

    def step(self, controls: np.ndarray, measurements: PointMeasurements) -> None:
        """Advance over controls (K, 2) = measured (V m/s, G rad), one per period dt, then
        take one sensor sweep (possibly empty)."""
        ...

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Pose estimate (3,) [x, y, φ] and its covariance (3, 3)."""
        ...

    def landmarks(self) -> LandmarkMap:
        """The current landmark map estimate."""
        ...

    def export_message(self) -> LandmarkMessage:
        """What this robot offers the others after its last step."""
        ...

    def import_messages(self, messages: Sequence[LandmarkMessage]) -> None:
        """Others' messages, used by the next :meth:`step` (ignored by non-consensus filters)."""
        ...

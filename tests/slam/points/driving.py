"""A minimal driver for the point back-ends in tests: one kinematic episode, sweep by sweep."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from polyslam_env.slam.points import PointMeasurements, PointSlamBackend
from polyslam_env.world.kinematic import SEED_PATHS, KinematicConfig, KinematicEpisode

#: The seed's world with paths cut to their first three waypoints (≈ 80 m, a few seconds).
SHORT_WORLD = KinematicConfig(paths=tuple(p[:3] for p in SEED_PATHS))


def drive(
    backends: Sequence[PointSlamBackend],
    episode: KinematicEpisode,
    exchange: bool = True,
    after_step: Callable[[int, PointSlamBackend], None] | None = None,
) -> None:
    """Step every robot through its sweeps; messages of sweep k−1 reach the others at k."""
    messages = []
    for k in range(episode.sweeps):
        active = [i for i, r in enumerate(episode.robots) if k < len(r.sweeps)]
        for i in active:
            if exchange:
                backends[i].import_messages(messages)
            ids, z = episode.robots[i].sweeps[k]
            backends[i].step(episode.robots[i].controls[k], PointMeasurements(ids, z))
            if after_step:
                after_step(i, backends[i])
        messages = [backends[i].export_message() for i in active]


def landmark_errors(backend: PointSlamBackend, landmarks: np.ndarray) -> np.ndarray:
    """Position error (M,) of every landmark in the back-end's map."""
    lm = backend.landmarks()
    return np.hypot(*(lm.means - landmarks[lm.ids]).T)

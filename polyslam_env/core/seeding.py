"""One episode seed, named child generators (STYLE habit 3).

Every source of randomness gets its own ``numpy.random.Generator`` derived from the episode
seed *and its name*, so adding a new stream never changes the numbers an existing one draws.
Nothing in the package uses global ``np.random``, ``random`` or torch seeding.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable

import numpy as np

#: The streams an episode uses. Others may be asked for by name.
STREAMS: tuple[str, ...] = (
    "layout",
    "motion",
    "sensor",
    "camera",
    "channel",
    "policy",
    "faults",
    "start_error",
    "alignment",
    "pillars",
    "pillar_sensor",
    "particles",
)


def _name_key(name: str) -> int:
    return zlib.crc32(name.encode("utf-8"))


def make_rngs(seed: int | None, names: Iterable[str] = STREAMS) -> dict[str, np.random.Generator]:
    """A generator per named stream, all derived from one episode seed.

    ``seed=None`` draws fresh OS entropy once for the whole episode, so the streams stay
    independent of each other but the episode is not reproducible.
    """
    root = np.random.SeedSequence(seed)
    return {
        name: np.random.Generator(
            np.random.PCG64(np.random.SeedSequence(root.entropy, spawn_key=(_name_key(name),)))
        )
        for name in names
    }

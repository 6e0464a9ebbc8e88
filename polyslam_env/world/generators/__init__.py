"""Seeded procedural layouts (STYLE habit 5): a generator object, ``generator(rng) -> Layout``.

One module per floor family, all on :class:`~.base.GeneratorBase` (the shared fields and the
retry template that checks every draw; see :mod:`.base` for the guarantees):

* :mod:`.rooms` — ``rooms``: axis-aligned rooms by recursive division, doors, corridors;
* :mod:`.caves` — ``cave``: a smooth closed outline with rock islands (a few metres);
* :mod:`.offices` — ``office_floor``: rooms off one or two long corridors;
* :mod:`.warehouses` — ``warehouse``: shelf rows, aisles, pillars in a loading area;
* :mod:`.loops` — ``loop``: a corridor loop around a solid block;
* :mod:`.halls` — ``pillar_hall``: round columns on a jittered grid, partition walls;

and the families beyond Manhattan floors (issue 42), 20–40 m:

* :mod:`.caves` — ``cave_system``: chambers with curved walls, winding narrow passages, rock
  islands;
* :mod:`.angled` — ``angled_floor``: walls and corridors at arbitrary angles, polygonal rooms,
  turned furniture;
* :mod:`.curved` — ``curved_floor``: round halls, curved and straight corridors, rooms of
  curved and straight walls.

The curved families are drawn as a field traced into walls (:mod:`.fields`).

:data:`GENERATORS` maps each name (``map: "generator:<name>"`` in an env config) to its class;
:func:`make_generator` builds one with its parameters validated.
"""

from __future__ import annotations

from typing import Any

from polyslam_env.world.generators.angled import AngledFloorGenerator
from polyslam_env.world.generators.base import (
    SHARED_FIELDS,
    GenerationError,
    GeneratorBase,
    LayoutGenerator,
    is_enclosed,
)
from polyslam_env.world.generators.caves import CaveGenerator, CaveSystemGenerator
from polyslam_env.world.generators.curved import CurvedFloorGenerator
from polyslam_env.world.generators.halls import PillarHallGenerator
from polyslam_env.world.generators.loops import LoopGenerator
from polyslam_env.world.generators.offices import OfficeFloorGenerator
from polyslam_env.world.generators.rooms import RoomsGenerator
from polyslam_env.world.generators.warehouses import WarehouseGenerator

__all__ = [
    "GENERATORS",
    "HELD_OUT_SEED",
    "SHARED_FIELDS",
    "AngledFloorGenerator",
    "CaveGenerator",
    "CaveSystemGenerator",
    "CurvedFloorGenerator",
    "GenerationError",
    "GeneratorBase",
    "LayoutGenerator",
    "LoopGenerator",
    "OfficeFloorGenerator",
    "PillarHallGenerator",
    "RoomsGenerator",
    "WarehouseGenerator",
    "is_enclosed",
    "make_generator",
]

GENERATORS: dict[str, type[GeneratorBase]] = {
    "rooms": RoomsGenerator,
    "cave": CaveGenerator,
    "office_floor": OfficeFloorGenerator,
    "warehouse": WarehouseGenerator,
    "loop": LoopGenerator,
    "pillar_hall": PillarHallGenerator,
    "cave_system": CaveSystemGenerator,
    "angled_floor": AngledFloorGenerator,
    "curved_floor": CurvedFloorGenerator,
}


#: Layouts kept for testing only (issue 42): develop and tune on seeds below this one; a
#: release's fidelity on new layouts is measured from it (``polyslam fidelity --seed
#: 1000000``). The package's tests draw no layout at or above it.
HELD_OUT_SEED = 1_000_000


def make_generator(name: str, **kwargs: Any) -> GeneratorBase:
    """A generator by name (a key of :data:`GENERATORS`) with its parameters validated."""
    cls = GENERATORS.get(name)
    if cls is None:
        raise ValueError(
            f"unknown layout generator {name!r}; valid names: {', '.join(sorted(GENERATORS))}"
        )
    return cls.from_dict(kwargs, where=name)

"""One episode seed, named independent streams."""

from __future__ import annotations

import numpy as np

from polyslam_env.core.seeding import make_rngs


def test_make_rngs__same_seed_same_numbers() -> None:
    a, b = make_rngs(7), make_rngs(7)
    for name in a:
        np.testing.assert_array_equal(a[name].random(5), b[name].random(5))


def test_make_rngs__streams_differ_and_seeds_differ() -> None:
    a = make_rngs(7)
    draws = {name: g.random(4).tobytes() for name, g in a.items()}
    assert len(set(draws.values())) == len(draws)
    assert make_rngs(8)["motion"].random() != make_rngs(7)["motion"].random()


def test_make_rngs__adding_a_stream_does_not_shift_others() -> None:
    few = make_rngs(3, ["motion", "sensor"])
    more = make_rngs(3, ["layout", "motion", "extra", "sensor"])
    assert few["motion"].random() == more["motion"].random()
    assert few["sensor"].random() == more["sensor"].random()

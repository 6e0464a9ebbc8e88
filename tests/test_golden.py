"""The episodes are bit-identical to those recorded (``tests/golden/episodes.py``), played with
the pinned floating-point kernels they were recorded with."""

from __future__ import annotations

import json

import pytest

from tests.golden.episodes import ENV_EPISODES, GOLDEN, SIMULATE_KEY, play_pinned

RECORDED: dict[str, list[str]] = json.loads(GOLDEN.read_text())


def _first_difference(expected: list[str], got: list[str]) -> str:
    for k, (a, b) in enumerate(zip(expected, got, strict=False)):
        if a != b:
            return f"first differing step {k} of {len(expected)}"
    return f"lengths differ: {len(expected)} recorded, {len(got)} now"


@pytest.mark.parametrize(
    ("name", "seed", "steps", "overrides"), ENV_EPISODES, ids=[e[0] for e in ENV_EPISODES]
)
def test_env_episode__bit_identical_to_recorded(
    name: str, seed: int, steps: int, overrides: dict[str, object]
) -> None:
    key = f"{name}/seed{seed}"
    expected = RECORDED[key]
    got = play_pinned([key])[key]
    assert got == expected, _first_difference(expected, got)


def test_simulate__bit_identical_to_recorded() -> None:
    expected = RECORDED[SIMULATE_KEY]
    got = play_pinned([SIMULATE_KEY])[SIMULATE_KEY]
    assert got == expected, _first_difference(expected, got)

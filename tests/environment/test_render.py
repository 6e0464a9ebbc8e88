"""Rendering through the env: PettingZoo's render_test; rendering never feeds observations."""

from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # headless pygame

import numpy as np
from pettingzoo.test import render_test

import polyslam_env


def test_env__passes_pettingzoo_render_test() -> None:
    render_test(
        lambda render_mode=None: polyslam_env.env(
            map="two_rooms", num_robots=2, max_steps=20, render_mode=render_mode
        )
    )


def test_render__never_changes_what_the_robots_observe() -> None:
    """Same seed and actions with and without rgb_array rendering: identical observations."""
    envs = [
        polyslam_env.parallel_env(map="paper", max_steps=30, render_mode=mode)
        for mode in (None, "rgb_array")
    ]
    obs = [e.reset(seed=3)[0] for e in envs]
    rng = np.random.default_rng(0)
    for _ in range(30):
        if not envs[0].agents:
            break
        space = envs[0].action_space(envs[0].agents[0])
        actions = {a: rng.uniform(space.low, space.high) for a in envs[0].agents}
        frame = envs[1].render()
        assert frame is not None and frame.dtype == np.uint8 and frame.ndim == 3
        obs = [e.step(actions)[0] for e in envs]
        for agent in obs[0]:
            np.testing.assert_array_equal(obs[0][agent], obs[1][agent])
    for e in envs:
        e.close()

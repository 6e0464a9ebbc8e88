"""The driving training env: PettingZoo's API, action repeat, the progress term, and the
same episode as ``ppo_drive``'s run-time loop."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from policies.drive import FEATURES, remaining
from polyslam_env.apps.drive_env import DriveEnv
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig

SMALL = {"map": "generator:office_floor", "num_robots": 2, "max_steps": 24, "slam_enabled": False}


def _config(**kwargs: object) -> EnvConfig:
    return EnvConfig.from_dict({**SMALL, **kwargs})


def test_drive_env__passes_pettingzoo_parallel_api_test() -> None:
    parallel_api_test(DriveEnv([_config()]), num_cycles=8)


def test_drive_env__one_step_is_repeat_env_steps_and_features_are_in_the_box() -> None:
    env = DriveEnv([_config()], repeat=3)
    obs, _ = env.reset(seed=1)
    box = env.observation_space("robot_0")
    steps = []
    while env.agents:
        for o in obs.values():
            assert box.contains(o)
        obs, *_ = env.step(dict.fromkeys(env.agents, np.array([1.0, 0.0], np.float32)))
        assert env.env.episode is not None
        steps.append(env.env.episode.step_count)
    assert steps == [3, 6, 9, 12, 15, 18, 21, 24]


def test_remaining__is_the_distance_to_the_nearest_waypoint_then_along_the_path() -> None:
    rng = np.random.default_rng(0)
    path = np.cumsum(rng.uniform(-0.2, 0.2, (30, 2)), axis=0)  # (P, 2)
    for x, y in rng.uniform(-1.0, 1.0, (20, 2)):
        d = [np.hypot(px - x, py - y) for px, py in path]
        i = int(np.argmin(d))
        brute = d[i] + sum(np.hypot(*(path[k + 1] - path[k])) for k in range(i, len(path) - 1))
        assert remaining(path, x, y) == pytest.approx(brute, rel=1e-12)


def test_drive_env__following_the_path_earns_progress_and_turning_away_loses_it() -> None:
    # The reward with progress weight 1 less the one with weight 0 is the progress term: for
    # a robot that steers to its near path point at full speed it sums to metres gained
    # (positive, at most v_max · dt per step); driving backwards earns none.
    def run(progress: float, forward: bool) -> float:
        env = DriveEnv([_config(num_robots=1)], progress=progress)
        obs, _ = env.reset(seed=2)
        total = 0.0
        while env.agents:
            f = obs["robot_0"]
            k = 17 + FEATURES.index("near_cos")
            alpha = float(np.arctan2(f[k + 1], f[k]))
            v = (1.0 if abs(alpha) < 0.5 else 0.0) if forward else -1.0
            obs, rew, *_ = env.step({"robot_0": np.array([v, np.clip(alpha / 1.5, -1, 1)])})
            total += rew["robot_0"]
        return total

    gained = run(1.0, True) - run(0.0, True)
    assert 0.3 < gained <= 24 * 0.3 + 1e-9  # v_max 0.3 m/s, dt 1 s, 24 steps
    assert run(1.0, False) - run(0.0, False) <= 0.0


@pytest.mark.parametrize(
    ("configs", "kwargs", "match"),
    [
        ([], {}, "no env config"),
        ([_config(), _config(num_robots=3)], {}, "same num_robots"),
        ([_config()], {"repeat": 0}, "repeat"),
        ([_config(action={"mode": "discrete"})], {}, "continuous"),
    ],
)
def test_drive_env__bad_configs_are_named(
    configs: list[EnvConfig], kwargs: dict[str, int], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        DriveEnv(configs, **kwargs)

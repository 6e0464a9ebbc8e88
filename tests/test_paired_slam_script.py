"""scripts/paired_slam.py: its overrides, and a replay that reproduces the driven episode."""

from __future__ import annotations

from types import ModuleType

import pytest

from polyslam_env.apps.fidelity import FidelityConfig, episode_config
from polyslam_env.core.errors import ConfigError
from tests.scripts_module import load_script


def _script() -> ModuleType:
    return load_script("paired_slam")


def test_setting__nested_yaml_values_and_a_one_line_error() -> None:
    script = _script()
    base = episode_config(FidelityConfig(), "loop", True)
    got = script.setting(base, ["slam.eps_z=10", "slam.stretch_ends=false", "channel.range=2.5"])
    assert (got["slam"]["eps_z"], got["slam"]["stretch_ends"], got["channel"]["range"]) == (
        10,
        False,
        2.5,
    )
    # the other fields are the base's
    assert got["slam"]["order"] == base["slam"]["order"]
    assert got["max_steps"] == base["max_steps"]
    with pytest.raises(SystemExit, match="KEY=VALUE"):
        script.setting(base, ["slam.eps_z"])
    with pytest.raises(ConfigError, match="stretch_end"):
        script.setting(base, ["slam.stretch_end=false"])


def test_pair__the_same_setting_replayed_gives_the_same_metrics() -> None:
    # B replays A's recorded actions: with the same setting, the SLAM sees the same
    # measurements along the same trajectories, so every robot's metrics are equal
    script = _script()
    config = episode_config(FidelityConfig(), "loop", True)
    config["max_steps"] = 40
    out = script.pair((config, config, 3))
    assert out["a"] == out["b"]
    config_b = script.setting(config, ["slam.stretch_ends=false"])
    assert script.pair((config, config_b, 3))["a"] == out["a"]  # A is unchanged by B

"""scripts/paired_slam.py: its overrides, and a replay that reproduces the driven episode."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from polyslam_env.apps.fidelity import FidelityConfig, episode_config


def _script() -> ModuleType:
    path = Path(__file__).resolve().parents[1] / "scripts" / "paired_slam.py"
    spec = importlib.util.spec_from_file_location("paired_slam", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_overrides__nested_yaml_values_and_a_one_line_error() -> None:
    script = _script()
    got = script.overrides(["slam.eps_z=10", "slam.stretch_ends=false", "channel.range=2.5"])
    assert got == {"slam": {"eps_z": 10, "stretch_ends": False}, "channel": {"range": 2.5}}
    base = {"slam": {"eps_z": 15, "order": 3}, "max_steps": 600}
    assert script._merged(base, got)["slam"] == {"eps_z": 10, "order": 3, "stretch_ends": False}
    with pytest.raises(SystemExit, match="KEY=VALUE"):
        script.overrides(["slam.eps_z"])


def test_pair__the_same_setting_replayed_gives_the_same_metrics() -> None:
    # B replays A's recorded actions: with the same setting, the SLAM sees the same
    # measurements along the same trajectories, so every robot's metrics are equal
    script = _script()
    config = episode_config(FidelityConfig(), "loop", True)
    config["max_steps"] = 40
    out = script.pair((config, config, 3))
    assert out["a"] == out["b"]
    config_b = script._merged(config, script.overrides(["slam.stretch_ends=false"]))
    assert script.pair((config, config_b, 3))["a"] == out["a"]  # A is unchanged by B

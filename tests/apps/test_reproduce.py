"""The paper reproduction: config, the r3 shadow, the summary's checks, the command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from polyslam_env.apps.reproduce import (
    ReproduceConfig,
    _study_map,
    default_config,
    reproduce,
    run_one,
    summarise,
)
from polyslam_env.apps.simulate import simulate
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.config import slam_preset


def test_default_config__holds_the_papers_parameters() -> None:
    cfg = default_config()
    assert (cfg.num_robots, cfg.steps, cfg.runs, cfg.map) == (3, 200, 100, "paper")
    assert cfg.world.odometry.sigma_xy == 0.001 and cfg.world.range_sensor.sigma == 0.02
    assert cfg.slam.p0_sigma == (0.05, 0.05, 0.0175) and cfg.slam.k_divergence == 150
    # the shipped file is the paper's algorithm: the same filter as the `paper` preset, so a
    # new default of ours cannot slip into the reproduction
    assert cfg.slam == slam_preset("paper")
    with pytest.raises(ConfigError, match="num_robots"):
        ReproduceConfig(num_robots=2)


def test_shadow__is_the_same_robot_alone_on_the_same_episode() -> None:
    """Without exchange the shadow sees identical inputs, so it must equal the robot itself."""
    result = simulate("paper", steps=60, seed=1, shadow=(2,))
    lone, robot = result.shadow_runs[2], result.runs[2]
    np.testing.assert_array_equal(lone.est_poses, robot.est_poses)
    np.testing.assert_array_equal(lone.true_poses, robot.true_poses)
    assert len(result.runs) == 3


def test_reproduce__two_runs_pass_the_papers_checks() -> None:
    runs = reproduce(default_config().replace(runs=2), workers=1)
    summary = summarise(runs)
    checks = summary["checks"]
    assert checks["r1_never_exchanges"] and checks["r2_r3_meet_once"]
    assert checks["r3_multi_beats_single_completeness"]
    assert summary["table"]["bytes_sent"][0]["max"] == 0  # r1 sends nothing
    assert summary["bytes_per_message"]["min"] > 100  # 11 polynomials ≈ 0.7 kB in float64


def test_cli__reproduce_writes_table_summary_and_figures(tmp_path: Path) -> None:
    code = main(["reproduce", "--runs", "2", "--workers", "2", "--out", str(tmp_path), "--quiet"])
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 2
    assert "nees_paper,r1" in (tmp_path / "table.csv").read_text()
    for name in ("figs5-7_multi_robot.png", "fig8_r3_single_vs_multi.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def _without_timings(value: object) -> object:
    """``value`` (a summary or metrics) without the wall-clock figures (``slam_time_ms*``)."""
    if isinstance(value, dict):
        return {
            k: _without_timings(v) for k, v in value.items() if not k.startswith("slam_time_ms")
        }
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def _same(a: object, b: object) -> bool:
    """Equal key by key, NaN equal to NaN (JSON text of both, sorted keys, 17 digits)."""
    return json.dumps(_without_timings(a), sort_keys=True) == json.dumps(
        _without_timings(b), sort_keys=True
    )


def test_reproduce__summary_is_identical_with_one_or_two_workers() -> None:
    config = default_config().replace(runs=3, steps=60)
    one = summarise(reproduce(config, workers=1))
    two = summarise(reproduce(config, workers=2))
    assert _same(one, two)


def test_run_one__the_shared_map_changes_nothing() -> None:
    """Runs of a process share the study's map (read once); a run on a freshly read map is
    the same run."""
    config = default_config().replace(steps=40)
    _study_map.cache_clear()
    fresh = run_one(config, 5)
    shared = run_one(config, 5)
    assert _study_map.cache_info().hits >= 1
    assert _same(fresh.metrics, shared.metrics) and _same(fresh.single, shared.single)
    assert _same(fresh.messages, shared.messages)

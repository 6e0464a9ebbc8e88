"""The paper reproduction: config, the r3 shadow, the summary's checks, the command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from polyslam_env.apps.reproduce import ReproduceConfig, default_config, reproduce, summarise
from polyslam_env.apps.simulate import simulate
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError


def test_default_config__holds_the_papers_parameters() -> None:
    cfg = default_config()
    assert (cfg.num_robots, cfg.steps, cfg.runs, cfg.map) == (3, 200, 100, "paper")
    assert cfg.world.odometry.sigma_xy == 0.001 and cfg.world.range_sensor.sigma == 0.02
    assert cfg.slam.p0_sigma == (0.05, 0.05, 0.0175) and cfg.slam.k_divergence == 150
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

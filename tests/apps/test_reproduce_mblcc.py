"""Seed 003's experiment: the summary's shape and checks, and the command end to end."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from polyslam_env.apps.reproduce_mblcc import (
    ALGORITHMS,
    MblccReproduceConfig,
    run_one,
    summarise,
)
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError
from polyslam_env.world.kinematic import SEED_PATHS, KinematicConfig

#: The seed's world with each path cut to its first leg (≈ 40 m): seconds, not minutes.
SMALL = MblccReproduceConfig(
    world=KinematicConfig(paths=tuple(p[:2] for p in SEED_PATHS)),
    fig5_particles=(3, 10),
    fig5_runs=1,
)


def test_default_config__holds_the_seeds_settings() -> None:
    cfg = MblccReproduceConfig()
    assert cfg.runs == 50 and cfg.slam.particles == 10
    assert cfg.slam.em_mobility == (0.008, 0.005, 0.001) and cfg.slam.resample_fraction == 0.75
    assert cfg.world.speeds == (4.0, 3.8, 3.5) and cfg.world.max_range == 30.0
    w = cfg.world
    assert (w.sigma_v, w.sigma_g_deg, w.sigma_r, w.sigma_b_deg) == (0.3, 3.0, 0.2, 2.0)
    with pytest.raises(ConfigError, match="fig5_particles"):
        MblccReproduceConfig(fig5_particles=(0,))


def test_summarise__per_robot_mean_and_std_and_named_checks() -> None:
    runs = [run_one(SMALL, seed=s) for s in range(2)]
    assert run_one(SMALL, seed=1) == runs[1]  # bit-identical for a seed
    summary = summarise(runs)
    for metric in ("pose_error", "landmark_error"):
        assert set(summary["table"][metric]) == set(ALGORITHMS)
        for alg in ALGORITHMS:
            cells = summary["table"][metric][alg]
            assert len(cells) == 3 and all(c["mean"] > 0 and c["std"] >= 0 for c in cells)
    assert len(summary["checks"]) == 6
    assert all(isinstance(v, bool) for v in summary["checks"].values())
    em_vs_fs2 = summary["paired"]["pose_error"]["em_fastslam-fastslam2"][0]
    table = summary["table"]["pose_error"]
    diff = table["em_fastslam"][0]["mean"] - table["fastslam2"][0]["mean"]
    assert em_vs_fs2["mean"] == pytest.approx(diff, abs=1e-12) and em_vs_fs2["se"] >= 0


def test_cli__reproduce_mblcc_writes_summary_and_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "mblcc.yaml"
    config.write_text(yaml.safe_dump(SMALL.to_dict()))
    out = tmp_path / "out"
    code = main(
        [
            "reproduce",
            "--paper",
            "mblcc",
            "--runs",
            "2",
            "--config",
            str(config),
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == 2
    assert set(summary["table"]) >= {"pose_error", "landmark_error"}
    for metric in ("pose_error", "landmark_error"):
        for alg in ("fastslam2", "em_fastslam", "multirobot_known_start", "mblcc"):
            assert [set(c) >= {"mean", "std"} for c in summary["table"][metric][alg]] == [True] * 3
    assert set(summary["armse_by_particles"]["mblcc"]) == {"3", "10"}
    assert (out / "fig5_armse.png").stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "multirobot_known_start" in text and "check mblcc_lowest_pose_error" in text

"""Seed 003's experiment: the summary's shape and checks, and the command end to end."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from polyslam_env.apps import reproduce_mblcc
from polyslam_env.apps.reproduce_mblcc import (
    ALGORITHMS,
    COLUMNS,
    DIVERSITY,
    METRICS,
    MblccReproduceConfig,
    reproduce,
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
    em_scales=(1.0, 10.0),
    em_passes=(1,),
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
    # the EM sweep reuses the table's EM-FastSLAM for R × 1 and the table's moves per sweep
    assert run_one(SMALL, seed=1, em=(1.0, 1)) == {"em_fastslam": runs[1]["em_fastslam"]}
    summary = summarise(runs)
    for metric in ("pose_error", "landmark_error"):
        assert set(summary["table"][metric]) == set(COLUMNS) > set(ALGORITHMS)
        for alg in COLUMNS:
            cells = summary["table"][metric][alg]
            assert len(cells) == 3 and all(c["mean"] > 0 and c["std"] >= 0 for c in cells)
    assert len(summary["checks"]) == 10
    assert all(isinstance(v, bool) for v in summary["checks"].values())
    n = SMALL.slam.particles
    for alg in COLUMNS:
        assert all(0 < c["mean"] <= 1 for c in summary["diversity"]["effective_size"][alg])
        assert all(1 <= c["mean"] <= n for c in summary["diversity"]["lineages_1"][alg])
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
    assert [(c["scale"], c["passes"]) for c in summary["em_sweep"]] == [(1.0, 1), (10.0, 1)]
    assert set(summary["diversity"]) == set(DIVERSITY)
    assert "shared_map_motion_proposal" in summary["table"]["pose_error"]
    assert (out / "fig5_armse.png").stat().st_size > 10_000
    assert (out / "diversity.png").stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "multirobot_known_start" in text and "check mblcc_lowest_pose_error" in text
    # through the results log: a resumed study runs nothing and gives the same tables
    (out / "summary.json").unlink()
    args = ["reproduce", "--paper", "mblcc", "--runs", "2", "--config", str(config)]
    assert main([*args, "--out", str(out), "--quiet", "--resume"]) == 0
    resumed = json.loads((out / "summary.json").read_text())
    assert "5 of 5 runs already in"  # 2 table, 1 Fig 5, 2 EM in capsys.readouterr().err
    for key in ("table", "paired", "em_sweep", "diversity", "armse_by_particles"):
        assert resumed[key] == summary[key]


def _fake_runs(rng: np.random.Generator, runs: int, columns: tuple[str, ...]) -> list:
    return [
        {
            alg: [
                {m: float(rng.uniform(0.1, 2.0)) for m in (*METRICS, "landmark_rmse", *DIVERSITY)}
                for _ in range(3)
            ]
            for alg in columns
        }
        for _ in range(runs)
    ]


def test_em_sweep__paired_differences_equal_a_direct_computation() -> None:
    """Per setting and robot, mean and standard error (ddof 1) of EM − FastSLAM 2.0 over the
    runs, run k of the setting against run k of the table; the team's as the robots' mean."""
    rng = np.random.default_rng(0)
    runs = _fake_runs(rng, 7, COLUMNS)
    by_em = {
        (s, p): [
            {**em, "fastslam2": run["fastslam2"]}
            for em, run in zip(_fake_runs(rng, 7, ("em_fastslam",)), runs, strict=True)
        ]
        for s in (1.0, 10.0)
        for p in (1, 5)
    }
    summary = summarise(runs, by_em=by_em)
    assert [(c["scale"], c["passes"]) for c in summary["em_sweep"]] == list(by_em)
    for cell, em_runs in zip(summary["em_sweep"], by_em.values(), strict=True):
        for metric in METRICS:
            em = np.array([[r[metric] for r in run["em_fastslam"]] for run in em_runs])
            fs2 = np.array([[r[metric] for r in run["fastslam2"]] for run in runs])
            d = em - fs2  # (runs, robots)
            got = cell["paired"][metric]
            for r in range(3):
                assert got["robots"][r]["mean"] == pytest.approx(d[:, r].mean(), rel=1e-12)
                se = d[:, r].std(ddof=1) / np.sqrt(7)
                assert got["robots"][r]["se"] == pytest.approx(se, rel=1e-12)
            team = d.mean(axis=1)
            assert got["team"]["mean"] == pytest.approx(team.mean(), rel=1e-12)
            assert got["team"]["se"] == pytest.approx(team.std(ddof=1) / np.sqrt(7), rel=1e-12)
            assert cell["table"][metric][0]["mean"] == pytest.approx(em[:, 0].mean(), rel=1e-12)
        spread = np.array([[r["spread"] for r in run["em_fastslam"]] for run in em_runs])
        assert cell["diversity"]["spread"][2]["mean"] == pytest.approx(spread[:, 2].mean())


def test_reproduce__em_runs_pair_with_the_table_runs_of_the_same_seeds() -> None:
    """One pool for every job; the EM sweep's runs come back keyed by setting, one per table
    seed, the R × 1 setting being the table's own EM-FastSLAM."""
    cfg = SMALL.replace(runs=1, fig5_particles=(10,), fig5_runs=1)
    runs, by_n, by_em = reproduce(cfg, workers=1)
    assert list(by_n) == [10] and len(runs) == 1
    assert list(by_em) == [(1.0, 1), (10.0, 1)]
    assert [r["em_fastslam"] for r in by_em[(1.0, 1)]] == [r["em_fastslam"] for r in runs]
    assert [r["fastslam2"] for r in by_em[(10.0, 1)]] == [r["fastslam2"] for r in runs]
    alone = run_one(cfg, seed=0, em=(10.0, 1))["em_fastslam"]
    assert by_em[(10.0, 1)][0]["em_fastslam"] == alone
    assert alone != runs[0]["em_fastslam"]


def test_reproduce__a_failed_run_drops_only_its_own_pairs(monkeypatch: pytest.MonkeyPatch) -> None:
    """A job that fails twice leaves ``None`` in its place (apps.jobs); the EM sweep then
    pairs the other seeds, each EM run with the FastSLAM 2.0 run of its own seed."""
    cfg = SMALL.replace(runs=2, fig5_particles=(10,), fig5_runs=1)
    real = reproduce_mblcc._job

    def failing(job: reproduce_mblcc.Job) -> reproduce_mblcc.RunMetrics:
        if job[1] == 0 and job[3] == (10.0, 1):
            raise RuntimeError("lost worker")
        return real(job)

    monkeypatch.setattr(reproduce_mblcc, "_job", failing)
    runs, _, by_em = reproduce(cfg, workers=1)
    assert len(runs) == 2 and len(by_em[(1.0, 1)]) == 2
    [pair] = by_em[(10.0, 1)]
    assert pair["fastslam2"] == runs[1]["fastslam2"]
    assert pair["em_fastslam"] == run_one(cfg, seed=1, em=(10.0, 1))["em_fastslam"]

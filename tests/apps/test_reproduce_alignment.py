"""``polyslam reproduce --paper alignment`` end to end on a small setting."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from polyslam_env.apps.reproduce_alignment import (
    METHODS,
    AlignmentReproduceConfig,
    reproduce,
    run_one,
    summarise,
)
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError


def test_run_one__same_seed_same_records() -> None:
    cfg = AlignmentReproduceConfig(runs=1, stages=2)
    a, b = run_one(cfg, 3), run_one(cfg, 3)
    strip = [{k: v for k, v in r.items() if k != "time_s"} for r in a]
    assert strip == [{k: v for k, v in r.items() if k != "time_s"} for r in b]
    assert {r["method"] for r in a} == set(METHODS)


def test_summary__maps_sharing_nothing_decline_and_grown_maps_align() -> None:
    """The robots start 150 m apart (range 30 m): at the first of 7 stages their maps share
    no landmark and every aligner declines; at the last every accepted RANSAC alignment is
    right (within 1 m and 3°)."""
    cfg = AlignmentReproduceConfig(runs=2)
    summary = summarise(cfg, reproduce(cfg, workers=1))
    for method in METHODS:
        assert summary["table"][method][0]["accepted"] == 0.0
    last = summary["table"]["ransac"][-1]
    assert last["accepted"] > 0 and last["wrong"] == 0.0
    assert all(isinstance(v, bool) for v in summary["checks"].values())


def test_cli__writes_summary_and_figures(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = main(
        [
            "reproduce",
            "--paper",
            "alignment",
            "--runs",
            "1",
            "--workers",
            "1",
            "--quiet",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["table"]) == set(METHODS) and summary["runs"] == 1
    assert (tmp_path / "figs3-5_errors.png").stat().st_size > 0
    assert (tmp_path / "fig6_time.png").stat().st_size > 0
    assert "check ransac_most_accurate_at_largest_maps" in capsys.readouterr().out


def test_config__same_robot_twice__is_a_named_error() -> None:
    with pytest.raises(ConfigError, match="robots"):
        AlignmentReproduceConfig(robots=(1, 1))


def test_cli__seif_reproduction_writes_summary(tmp_path: Path) -> None:
    """``--paper seif`` on one run: the summary's table and boolean checks."""
    code = main(
        [
            "reproduce",
            "--paper",
            "seif",
            "--runs",
            "1",
            "--workers",
            "1",
            "--quiet",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 1 and summary["pieces"] == 8
    assert all(isinstance(v, bool) for v in summary["checks"].values())
    assert summary["table"]["wrong_collapses"] == 0

"""``polyslam run`` and ``polyslam evaluate``: outputs and one-line errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from polyslam_env.cli.main import main


def test_run__writes_metrics_json_and_picture(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    code = main(["run", "--map", "two_rooms", "--steps", "12", "--seed", "3", "--out", str(out)])
    assert code == 0
    data = json.loads((out / "metrics.json").read_text())
    assert data["policy"] == "frontier" and data["seed"] == 3
    assert sorted(data["robots"]) == ["robot_0", "robot_1", "robot_2"]
    assert "collisions" in data["robots"]["robot_0"] and "coverage" in data["team"]
    assert len(data["coverage"]) == data["steps"] + 1
    assert (out / "final.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "completeness" in printed and "team:" in printed


def test_run__video_gif_is_written(tmp_path: Path) -> None:
    video = tmp_path / "ep.gif"
    args = ["run", "--map", "two_rooms", "--robots", "2", "--steps", "3", "--out", str(tmp_path)]
    assert main([*args, "--video", str(video)]) == 0
    assert video.read_bytes()[:6] == b"GIF89a"


def test_evaluate__two_episodes_two_workers_write_json_csv_plot(tmp_path: Path) -> None:
    paths = {k: tmp_path / f"e.{k}" for k in ("json", "csv", "png")}
    code = main(
        [
            "evaluate", "--policy", "wall_follow", "--episodes", "2", "--workers", "2",
            "--map", "two_rooms", "--robots", "2", "--steps", "10", "--seed", "4",
            "--json", str(paths["json"]), "--csv", str(paths["csv"]), "--plot", str(paths["png"]),
        ]
    )  # fmt: skip
    assert code == 0
    data = json.loads(paths["json"].read_text())
    assert data["seeds"] == [4, 5] and len(data["episodes"]) == 2
    cov = data["summary"]["team"]["coverage"]
    assert cov["min"] <= cov["mean"] <= cov["max"]
    rows = list(csv.DictReader(paths["csv"].open()))
    assert len(rows) == 4  # 2 episodes × 2 robots
    assert {r["seed"] for r in rows} == {"4", "5"}
    assert paths["png"].read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["run", "--policy", "nope"], "unknown policy 'nope'"),
        (["evaluate", "--episodes", "1", "--checkpoint", "missing.zip"], "missing.zip"),
        (["run", "--policy", "paper", "--map", "office"], "office"),
    ],
)
def test_cli__bad_input_exits_2_with_one_line(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


def test_cli__bad_config_key_exits_2_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "bad.yaml"
    config.write_text("num_robots: 3\nbogus_key: 1\n")
    assert main(["run", "--config", str(config), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "bogus_key" in err and len(err.splitlines()) == 1

"""``polyslam run`` and ``polyslam evaluate``: outputs and one-line errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

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


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


QUICK = ["--map", "two_rooms", "--robots", "1", "--steps", "2", "--quiet"]


def test_run__bad_output_paths_exit_2_with_one_line_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["run", *QUICK, "--out", str(afile / "sub")]) == 2
    assert "--out" in _one_line_error(capsys)
    out = ["--out", str(tmp_path / "o")]
    assert main(["run", *QUICK, *out, "--video", str(tmp_path / "x.xyz")]) == 2
    assert "x.xyz" in _one_line_error(capsys)
    (tmp_path / "v.gif").mkdir()
    assert main(["run", *QUICK, *out, "--video", str(tmp_path / "v.gif")]) == 2
    assert "folder" in _one_line_error(capsys)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("flag", ["--json", "--csv", "--plot"])
def test_evaluate__output_file_that_is_a_folder_exits_2_with_one_line(
    flag: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", "--episodes", "1", *QUICK, flag, str(tmp_path)]) == 2
    err = _one_line_error(capsys)
    assert flag in err and "folder" in err


def test_run__full_disk_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import errno
    import os

    def full(*_args: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    assert main(["run", *QUICK, "--out", str(tmp_path)]) == 2
    assert "No space left" in _one_line_error(capsys)


def test_run__binary_config_file_exits_2_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "binary.yaml"
    config.write_bytes(bytes(range(128, 256)))
    assert main(["run", *QUICK, "--config", str(config), "--out", str(tmp_path)]) == 2
    assert "binary.yaml" in _one_line_error(capsys)


def test_run__empty_config_file_is_all_defaults(tmp_path: Path) -> None:
    config = tmp_path / "empty.yaml"
    config.write_text("")
    assert main(["run", *QUICK, "--config", str(config), "--out", str(tmp_path)]) == 0


def test_run__ppo_without_a_usable_checkpoint_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import policies.ppo

    monkeypatch.setattr(policies.ppo, "SHIPPED", tmp_path / "gone.zip")
    assert main(["run", "--policy", "ppo", *QUICK, "--out", str(tmp_path)]) == 2
    err = _one_line_error(capsys)
    assert "ppo" in err and "gone.zip" in err and "--checkpoint" in err
    missing = str(tmp_path / "missing.zip")
    assert main(["run", "--policy", "ppo", "--checkpoint", missing, *QUICK]) == 2
    assert "missing.zip" in _one_line_error(capsys)


@pytest.mark.parametrize("policy", ["ppo", "ppo_goals", "ppo_drive", "ppo_careful"])
def test_run_and_evaluate__the_shipped_ppo_needs_no_checkpoint_flag(
    policy: str, tmp_path: Path
) -> None:
    from policies.drive import SHIPPED_CAREFUL, SHIPPED_DRIVE
    from policies.ppo import SHIPPED, SHIPPED_GOALS

    shipped = {
        "ppo": SHIPPED,
        "ppo_goals": SHIPPED_GOALS,
        "ppo_drive": SHIPPED_DRIVE,
        "ppo_careful": SHIPPED_CAREFUL,
    }
    assert shipped[policy].is_file()
    large = ["--map", "generator:warehouse", "--steps", "40", "--seed", "10000"]
    assert main(["run", "--policy", policy, *large, "--out", str(tmp_path)]) == 0
    report = tmp_path / "eval.json"
    args = ["evaluate", "--policy", policy, *large, "--episodes", "1", "--quiet"]
    assert main([*args, "--json", str(report)]) == 0
    assert json.loads(report.read_text())["summary"]["team"]["coverage"]["mean"] > 0


def test_run__render_without_a_display_says_to_save_a_video(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["run", *QUICK, "--render", "--out", str(tmp_path)]) == 2
    assert "--video out.gif" in _one_line_error(capsys)


def test_run__video_gif_has_ordinary_permissions(tmp_path: Path) -> None:
    import os

    video = tmp_path / "ep.gif"
    assert main(["run", *QUICK, "--out", str(tmp_path), "--video", str(video)]) == 0
    umask = os.umask(0)
    os.umask(umask)
    assert video.stat().st_mode & 0o777 == 0o666 & ~umask


def test_run__paper_policy_plays_the_paths_to_their_end_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--policy", "paper", "--quiet", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "map 'paper'" in err and "no end at a coverage target" in err
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert data["map"] == "paper" and data["config"]["coverage_target"] is None
    assert data["steps"] == 200  # the paths' length, not the default coverage target's end
    assert data["robots"]["robot_1"]["rendezvous"] >= 1  # r2 and r3 meet near the end
    assert data["robots"]["robot_2"]["rendezvous"] >= 1


def test_run__tables_name_robots_as_the_env_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", *QUICK, "--robots", "2", "--out", str(tmp_path)]) == 0
    header = capsys.readouterr().out.splitlines()[1]
    assert header.split() == ["unit", "robot_0", "robot_1"]


def test_evaluate__comma_list_compares_policies_on_the_same_seeds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = {k: tmp_path / f"e.{k}" for k in ("json", "csv", "png")}
    code = main(
        [
            "evaluate", "--policy", "frontier,random", "--episodes", "2", "--workers", "2",
            "--map", "two_rooms", "--robots", "2", "--steps", "10", "--seed", "4", "--quiet",
            "--json", str(paths["json"]), "--csv", str(paths["csv"]), "--plot", str(paths["png"]),
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out.splitlines()
    header = next(line for line in printed if line.startswith("policy"))
    for column in ("team coverage", "steps_to_90", "nu_mean", "completeness", "bytes sent"):
        assert column in header
    rows = [line for line in printed if line.split()[:1] in (["frontier"], ["random"])]
    assert len(rows) == 2 and all(line.count("±") >= 4 for line in rows)
    data = json.loads(paths["json"].read_text())
    assert data["policies"] == ["frontier", "random"] and data["seeds"] == [4, 5]
    for name in data["policies"]:
        assert [e["seed"] for e in data["episodes"][name]] == [4, 5]
        cov = data["comparison"][name]["coverage"]
        assert cov["min"] <= cov["mean"] <= cov["max"] and cov["std"] >= 0
        assert set(data["comparison"][name]) == {
            "coverage", "steps_to_90", "nu_mean", "completeness", "bytes_sent"
        }  # fmt: skip
    frontier, rnd = data["episodes"]["frontier"], data["episodes"]["random"]
    assert frontier[0]["coverage"][0] == rnd[0]["coverage"][0]  # same seed, same start
    rows_csv = list(csv.DictReader(paths["csv"].open()))
    assert len(rows_csv) == 8  # 2 policies × 2 episodes × 2 robots
    assert {(r["policy"], r["seed"]) for r in rows_csv} == {
        (p, s) for p in ("frontier", "random") for s in ("4", "5")
    }
    assert paths["png"].read_bytes()[:4] == b"\x89PNG"


def test_evaluate__comma_list_passes_the_checkpoint_to_ppo_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from stable_baselines3 import PPO

    from polyslam_env.environment.vector import make_vec_env

    venv = make_vec_env({"map": "two_rooms", "num_robots": 2, "max_steps": 5}, 1)
    ckpt = tmp_path / "small.zip"
    PPO("MlpPolicy", venv, n_steps=8, batch_size=8, policy_kwargs={"net_arch": [8]}).save(ckpt)
    venv.close()
    code = main(
        [
            "evaluate", "--policy", "random,ppo", "--checkpoint", str(ckpt), "--episodes", "1",
            "--map", "two_rooms", "--robots", "2", "--steps", "5", "--quiet",
        ]
    )  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert any(line.startswith("ppo ") for line in out.splitlines())


@pytest.mark.parametrize(
    ("policies", "needle"),
    [("frontier,frontier", "distinct"), ("paper,frontier", "give --map"), ("frontier,", "commas")],
)
def test_evaluate__bad_comma_list_exits_2_with_one_line(
    policies: str, needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", "--policy", policies, "--episodes", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


def test_run__table_shows_what_applies_grouped_json_keeps_all(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from polyslam_env.metrics.episode import ROBOT_METRIC_KEYS

    assert main(["run", *QUICK, "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    rows = [line.split()[0] for line in printed.splitlines() if line.startswith("  ")]
    for absent in ("has_map", "has_landmarks", "slam", "landmark_error", "alignments_wrong"):
        assert absent not in rows  # the polynomial back-end at camera rendezvous
    lines = printed.splitlines()
    assert [ln for ln in lines if ln in ("pose", "map", "exchange", "cost")] == [
        "pose",
        "map",
        "exchange",
        "cost",
    ]
    nees = next(i for i, ln in enumerate(lines) if ln.startswith("  nees (with start draw)"))
    assert lines[nees + 1].startswith("  nees_rel")  # beside it
    assert "nees carries each robot's start draw" in printed
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert set(ROBOT_METRIC_KEYS) <= set(data["robots"]["robot_0"])  # JSON keeps every metric
    assert data["kernels"]["warmup_steps"] == 2  # QUICK's 2 steps: the warm-up plays them all
    assert "kernels first used later in the episode" in printed


def test_run__warm_up_leaves_the_timed_episode_as_it_was() -> None:
    # The warm-up plays the same seeded episode's first steps; the timed episode must be the
    # one a run without warm-up plays, bit for bit (SLAM wall times aside).
    from policies.base import make_team
    from polyslam_env.apps.rollout import run_episode, warm_up
    from polyslam_env.environment.parallel import parallel_env

    def episode(warm: int) -> dict[str, Any]:
        env = parallel_env(map="two_rooms", num_robots=2, max_steps=15)
        team = make_team("frontier", env)
        if warm:
            warm_up(env, team, 4, warm)
        result = run_episode(env, team, 4)
        env.close()
        for metrics in result.robots.values():
            metrics.pop("slam_time_ms")
        return result.to_dict()

    assert episode(8) == episode(0)

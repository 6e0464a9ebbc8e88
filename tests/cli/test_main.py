"""The ``polyslam`` command as a user runs it (in-process through ``main``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from polyslam_env.cli.main import main


def test_simulate__writes_metrics_and_picture(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "simulate",
            "--map",
            "two_rooms",
            "--robots",
            "2",
            "--steps",
            "40",
            "--out",
            str(tmp_path),
            "--quiet",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "nu_mean" in out and "robot_1" in out
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert set(data["robots"]) == {"robot_0", "robot_1"}
    assert data["steps"] == 40
    assert (tmp_path / "maps.png").stat().st_size > 10_000


def test_simulate__bad_map_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--map", "no_such_map", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "unknown map 'no_such_map'" in err and "Traceback" not in err


def test_simulate__bad_config_file_names_file_and_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "slam.yaml"
    cfg.write_text("rho_mn: 0.1\n")
    assert main(["simulate", "--slam-config", str(cfg), "--steps", "2", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "slam.yaml" in err and "rho_mn" in err


def test_simulate__point_backend_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """simulate runs the polynomial EKF only: another back-end is refused, not ignored."""
    cfg = tmp_path / "slam.yaml"
    cfg.write_text("backend: seif\n")
    assert main(["simulate", "--slam-config", str(cfg), "--steps", "2", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "slam.backend" in err and "'seif'" in err and len(err.splitlines()) == 1


def test_main__rejects_non_positive_counts() -> None:
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--steps", "0"])
    assert exc.value.code == 2


def test_maps__lists_builtin_maps(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["maps"]) == 0
    out = capsys.readouterr().out
    assert "paper" in out and "two_rooms" in out


def test_main__missing_optional_dependency_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "torch", None)  # as if the rl extra were not installed
    code = main(
        [
            "train",
            "--config",
            str(Path(__file__).resolve().parents[2] / "configs" / "train_ppo.yaml"),
            "--timesteps",
            "64",
            "--out",
            str(tmp_path),
            "--quiet",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "needs torch" in err and "polyslam[rl]" in err and "Traceback" not in err


@pytest.mark.parametrize("command", ["run", "evaluate", "simulate"])
def test_main__negative_seed_exits_2_naming_it(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([command, "--seed", "-1", "--steps", "1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--seed: must be >= 0, got -1" in err and "Traceback" not in err


def test_simulate__more_robots_than_start_poses_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["simulate", "--robots", "10", "--steps", "2", "--out", str(tmp_path), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "start_poses" in err and "num_robots=10" in err and len(err.splitlines()) == 1


def test_simulate__out_under_a_file_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "afile").write_text("x")
    argv = ["simulate", "--steps", "2", "--out", str(tmp_path / "afile" / "sub"), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "--out" in err and len(err.splitlines()) == 1


def test_maps__lists_the_layout_generators_with_their_parameters(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["maps"]) == 0
    out = capsys.readouterr().out
    rooms = next(line for line in out.splitlines() if "generator:rooms" in line)
    cave = next(line for line in out.splitlines() if "generator:cave" in line)
    assert "min_room_size=1.2" in rooms and "harmonics=7" in cave
    assert "num_start_poses" not in out  # set by the env from num_robots

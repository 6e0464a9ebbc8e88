"""``polyslam train --backend rllib``: RLlib PPO on a local Ray instance and on a cluster.

The Ray tests need the ``ray`` extra and are skipped without it, and hold the lock of
:mod:`tests.apps.ray_cluster`.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from polyslam_env.apps.cluster import join_error
from polyslam_env.apps.training import EPISODE_TAGS
from polyslam_env.apps.training_rllib import rllib_checkpoints
from polyslam_env.cli.main import main
from tests.apps import ray_cluster as cluster


def _tiny_config(tmp_path: Path, **top: Any) -> Path:
    """two_rooms, 2 robots, 10-step episodes, 2 env runners, 32-robot-step train batches."""
    cfg = {
        "timesteps": 32,
        "num_envs": 2,
        "num_cpus": 2,
        "checkpoint_every": 32,
        "eval_episodes": 1,
        "env": {"map": "two_rooms", "num_robots": 2, "max_steps": 10, "slam_enabled": False},
        "ppo": {"n_steps": 8, "batch_size": 16, "n_epochs": 1, "net_arch": [16]},
        **top,
    }
    path = tmp_path / "train.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture
def ray_lock() -> Iterator[None]:
    """Ray installed, and no other Ray test running (see :mod:`tests.apps.ray_cluster`)."""
    with cluster.ray_lock():
        yield


@pytest.fixture
def ray_head(ray_lock: None, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A separate Ray head node (`ray start --head`) on a free port; always stopped."""
    with cluster.ray_head(monkeypatch) as address:
        yield address


def test_missing_ray__one_line_error_naming_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ModuleNotFoundError
    out = tmp_path / "out"
    config = _tiny_config(tmp_path)
    code = main(["train", "--backend", "rllib", "--config", str(config), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "polyslam[ray]" in err
    assert not out.exists()  # nothing written


def test_address__only_with_rllib(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["train", "--config", str(_tiny_config(tmp_path)), "--out", str(tmp_path / "o")]
    assert main([*args, "--address", "127.0.0.1:1"]) == 2
    assert "--backend rllib" in capsys.readouterr().err


@pytest.mark.slow
def test_rllib__trains_checkpoints_resumes_and_evaluates(
    ray_lock: None,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    # 6-step episodes: every 8-step sample of an env runner ends one
    env = {"map": "two_rooms", "num_robots": 2, "max_steps": 6, "slam_enabled": False}
    config, out = _tiny_config(tmp_path, env=env), tmp_path / "out"
    args = ["train", "--backend", "rllib", "--config", str(config), "--out", str(out), "--quiet"]
    assert main(args) == 0
    first = rllib_checkpoints(out / "checkpoints")
    assert first and first[-1][0] >= 32
    assert (first[-1][1] / "rllib_checkpoint.json").is_file()
    assert not [p for p in (out / "checkpoints").iterdir() if p.name.startswith(".")]
    report = json.loads((out / "final_eval.json").read_text())
    assert report["backend"] == "rllib" and report["seeds"] == [10_000]
    assert 0.0 < report["rllib"]["coverage_mean"] <= 1.0
    assert 0.0 < report["random"]["coverage_mean"] <= 1.0
    assert "team coverage rllib" in capsys.readouterr().out

    # a fresh run into the same folder is refused; --resume continues the counters
    assert main(args) == 2
    assert "--resume" in capsys.readouterr().err
    assert main([*args, "--resume", "--timesteps", str(first[-1][0] + 32)]) == 0
    steps = [s for s, _ in rllib_checkpoints(out / "checkpoints")]
    assert steps[-1] > first[-1][0] and steps[-1] >= first[-1][0] + 32
    assert "restoring" in capsys.readouterr().out

    # resuming a run that has its timesteps already trains nothing (and starts no Ray)
    assert main([*args, "--resume", "--timesteps", str(steps[-1])]) == 0
    assert "already has" in capsys.readouterr().out
    assert [s for s, _ in rllib_checkpoints(out / "checkpoints")] == steps

    # TensorBoard has the SB3 path's polyslam/ scalars, and the learning curve is drawn
    scalars = _scalars(out / "tb")
    expected = {f"polyslam/{tag}" for tag in EPISODE_TAGS if tag not in ("nu_mean", "completeness")}
    assert expected <= set(scalars)  # nu_mean and completeness need SLAM, off here
    assert all(0.0 <= v <= 1.0 for v in scalars["polyslam/team_coverage"])
    assert scalars["polyslam/episodes"][-1] >= 1
    assert (out / "learning_curve.png").is_file()

    # a damaged newest checkpoint is skipped, said so, and the one before it resumed: one
    # truncated mid-write (every file cut to half), then one without its network (which
    # RLlib itself would restore silently, untrained)
    for damage in ("truncated", "no network"):
        found = [path for _, path in rllib_checkpoints(out / "checkpoints")]
        if damage == "truncated":
            for f in found[-1].rglob("*"):
                if f.is_file():
                    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
        else:
            shutil.rmtree(found[-1] / "learner_group")
        more = rllib_checkpoints(out / "checkpoints")[-1][0] + 32
        assert main([*args, "--resume", "--timesteps", str(more)]) == 0
        captured = capsys.readouterr()
        assert captured.err.count("--resume: skipped") == 1, damage
        assert found[-1].name in captured.err
        assert f"restoring {found[-2]}" in captured.out


def _scalars(tb: Path) -> dict[str, list[float]]:
    """Every ``polyslam/`` scalar in the event files under ``tb``: tag → values."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[float]] = {}
    for events in tb.rglob("events.out.tfevents.*"):
        acc = EventAccumulator(str(events))
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            if tag.startswith("polyslam/"):
                out.setdefault(tag, []).extend(e.value for e in acc.Scalars(tag))
    return out


def test_rllib__sigterm_saves_a_checkpoint_and_exits_143(ray_lock: None, tmp_path: Path) -> None:
    # a real SIGTERM to the driver, as a scheduler sends: the iteration finishes, a
    # checkpoint is written, exit 143; --resume continues from it
    config = _tiny_config(tmp_path, timesteps=100_000, checkpoint_every=32, eval_episodes=0)
    out = tmp_path / "out"
    args = ["train", "--backend", "rllib", "--config", str(config), "--out", str(out), "--quiet"]
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "polyslam_env.cli", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 240
        while not rllib_checkpoints(out / "checkpoints") and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.5)
        assert rllib_checkpoints(out / "checkpoints"), "no checkpoint within 240 s"
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        proc.kill()
    assert proc.returncode == 143, stderr
    assert "terminated (SIGTERM): saved" in stdout
    saved = rllib_checkpoints(out / "checkpoints")[-1]
    assert str(saved[1]) in stdout
    resume = [*args, "--resume", "--timesteps", str(saved[0] + 16)]
    assert main(resume) == 0


@pytest.mark.slow
def test_rllib__joins_a_cluster_with_address(
    ray_head: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    config = _tiny_config(tmp_path, eval_episodes=0)
    args = ["train", "--backend", "rllib", "--config", str(config), "--out", str(out)]
    assert main([*args, "--address", ray_head]) == 0
    text = capsys.readouterr().out
    assert "iteration 1:" in text and "iteration 2:" not in text  # 1 iteration: 32 timesteps
    assert rllib_checkpoints(out / "checkpoints")
    assert os.environ.get("RAY_ADDRESS") is None


def test_join_error__names_the_token_fix() -> None:
    """Joining a cluster that asks for a token without one gives one line naming the fix;
    other failures give Ray's first line. (Ray's ConnectionError, with the authentication
    failure as its cause, as ray.init raises it.)"""
    try:
        try:
            raise RuntimeError("RPC error: InvalidAuthToken: Authentication token is missing")
        except RuntimeError as cause:
            raise ConnectionError("Failed to connect to Ray cluster at 10.0.0.1:6379") from cause
    except ConnectionError as err:
        text = join_error("10.0.0.1:6379", err)
    assert "\n" not in text and "RAY_AUTH_MODE=token" in text and "10.0.0.1:6379" in text
    other = join_error("h:1", ConnectionError("Could not find any running Ray instance.\nmore"))
    assert other == (
        "--address h:1: could not join the Ray cluster: Could not find any running Ray instance."
    )

"""``polyslam train``: config validation, checkpoints, resume, Ctrl-C, and ``PPOPolicy``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from policies.base import CheckpointError, PolicyContext, make_policy
from policies.ppo import PPOPolicy
from polyslam_env.apps import training
from polyslam_env.apps.training import TrainConfig, checkpoints
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.resources import configs_dir
from polyslam_env.environment.parallel import parallel_env


def _tiny_config(tmp_path: Path, **top: Any) -> Path:
    """A 2 m × 1.5 m box, 2 robots, 12-step episodes, tiny PPO rollouts: seconds per run."""
    box = [[0, 0], [2, 0], [2, 1.5], [0, 1.5], [0, 0]]
    starts = [[0.4, 0.4, 0.0], [1.6, 1.1, 3.14159]]
    map_path = tmp_path / "tiny.yaml"
    map_path.write_text(yaml.safe_dump({"name": "tiny", "walls": [box], "start_poses": starts}))
    cfg = {
        "timesteps": 192,
        "num_envs": 2,
        "checkpoint_every": 64,
        "eval_episodes": 1,
        "env": {"map": str(map_path), "num_robots": 2, "max_steps": 12, "slam_enabled": False},
        "ppo": {"n_steps": 16, "batch_size": 32, "n_epochs": 1, "net_arch": [16]},
        **top,
    }
    path = tmp_path / "train.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_shipped_train_config__loads() -> None:
    cfg = TrainConfig.from_yaml(configs_dir() / "train_ppo.yaml")
    assert cfg.timesteps >= 50_000 and cfg.env.observation.mode == "vector"


def test_train_config__unknown_key_is_named(tmp_path: Path) -> None:
    path = _tiny_config(tmp_path, ppo={"n_stepz": 3})
    with pytest.raises(ConfigError, match="n_stepz"):
        TrainConfig.from_yaml(path)


def test_cli_train__bad_config_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _tiny_config(tmp_path, learning_rat=0.1)
    assert main(["train", "--config", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "learning_rat" in err and len(err.strip().splitlines()) == 1


def test_cli_train__resume_without_checkpoint_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _tiny_config(tmp_path)
    args = ["train", "--config", str(path), "--out", str(tmp_path / "o"), "--resume", "--quiet"]
    assert main(args) == 2
    assert "no checkpoint" in capsys.readouterr().err


def test_cli_train__interrupt_resume_and_evaluate_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _tiny_config(tmp_path)
    out = tmp_path / "out"
    base = ["train", "--config", str(path), "--out", str(out), "--quiet"]
    # 1. a Ctrl-C in the middle of learning saves a checkpoint and exits 130
    original = training._progress_callback

    def interrupting(total: int, start: int, enabled: bool) -> Any:
        bar = original(total, start, enabled)
        step = bar._on_step

        def on_step() -> bool:
            if bar.model.num_timesteps >= 96:
                raise KeyboardInterrupt
            return step()

        bar._on_step = on_step
        return bar

    monkeypatch.setattr(training, "_progress_callback", interrupting)
    assert main(base) == 130
    monkeypatch.setattr(training, "_progress_callback", original)
    saved = checkpoints(out / "checkpoints")
    interrupted_at = saved[-1][0]
    assert 96 <= interrupted_at < 192  # stopped at the first vectorised step past 96
    assert not (out / "final_eval.json").exists()
    # 2. --resume continues the count to the first --timesteps, then to a larger one
    assert main([*base, "--resume"]) == 0
    first = checkpoints(out / "checkpoints")
    assert first[-1][0] >= 192 and len(first) > len(saved)
    assert main([*base, "--resume", "--timesteps", "320"]) == 0
    second = checkpoints(out / "checkpoints")
    assert second[-1][0] >= 320 and len(second) > len(first)
    assert {p.name for _, p in first} <= {p.name for _, p in second}
    assert any((out / "tb").rglob("events.out.tfevents.*"))
    report = json.loads((out / "final_eval.json").read_text())
    assert report["timesteps"] == second[-1][0]
    assert 0.0 <= report["ppo"]["coverage_mean"] <= 1.0
    assert 0.0 <= report["random"]["coverage_mean"] <= 1.0
    assert "ppo" in capsys.readouterr().out
    # 3. the checkpoint drives every robot through whole episodes, deterministically
    cfg = TrainConfig.from_yaml(path)
    coverages = []
    for _ in range(2):
        env = parallel_env(cfg.env)
        ckpt = second[-1][1]
        policies = {a: make_policy("ppo", env, a, checkpoint=ckpt) for a in env.possible_agents}
        obs, _ = env.reset(seed=5)
        rng = np.random.default_rng(0)
        while env.agents:
            actions = {a: policies[a].act(obs[a], rng) for a in env.agents}
            for a, act in actions.items():
                assert env.action_space(a).contains(act)
            obs, *_ = env.step(actions)
        coverages.append(env.episode.coverage.coverage)
    assert coverages[0] == coverages[1]


def test_ppo_policy__missing_corrupt_and_mismatched_checkpoints(tmp_path: Path) -> None:
    env = parallel_env(map="two_rooms", num_robots=2, max_steps=5)
    with pytest.raises(CheckpointError, match="no such file"):
        PPOPolicy(PolicyContext.from_env(env, "robot_0"), tmp_path / "nope.zip")
    bad = tmp_path / "bad.zip"
    bad.write_bytes(b"not a zip")
    with pytest.raises(CheckpointError, match="not an SB3"):
        PPOPolicy(PolicyContext.from_env(env, "robot_0"), bad)
    from stable_baselines3 import PPO

    from polyslam_env.environment.vector import make_vec_env

    venv = make_vec_env({"map": "two_rooms", "num_robots": 2, "max_steps": 5}, 1)
    ckpt = tmp_path / "small.zip"
    PPO("MlpPolicy", venv, n_steps=8, batch_size=8, policy_kwargs={"net_arch": [8]}).save(ckpt)
    venv.close()
    other = parallel_env(map="two_rooms", num_robots=3, max_steps=5)  # one more camera slot
    d2, d3 = env.observation_space("robot_0").shape, other.observation_space("robot_0").shape
    with pytest.raises(CheckpointError, match="observation space mismatch") as err:
        make_policy("ppo", other, "robot_0", checkpoint=ckpt)
    assert f"expects shape {d2}" in str(err.value) and f"gives {d3}" in str(err.value)

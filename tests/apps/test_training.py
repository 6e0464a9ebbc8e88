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


def _base_args(config: Path, out: Path) -> list[str]:
    return ["train", "--config", str(config), "--out", str(out), "--quiet"]


def test_cli_train__sigterm_saves_a_checkpoint_and_exits_143(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    path = _tiny_config(tmp_path, timesteps=1_000_000, eval_episodes=0)
    out = tmp_path / "out"
    repo = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen(
        [sys.executable, "-m", "polyslam_env.cli", *_base_args(path, out)],
        cwd=repo,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not checkpoints(out / "checkpoints"):  # a periodic one: it is stepping
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr
            time.sleep(0.1)
        before = checkpoints(out / "checkpoints")[-1][0]
        os.kill(proc.pid, signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, stderr
    steps, last = checkpoints(out / "checkpoints")[-1]
    assert "terminated (SIGTERM)" in stdout and str(last) in stdout and "--resume" in stdout
    assert steps > before  # written on the way out, not one of the periodic ones
    from policies.ppo import load_checkpoint

    assert load_checkpoint(last).num_timesteps == steps
    assert not list((out / "checkpoints").glob(".*"))  # no temporary file left


def test_cli_train__one_run_per_out_and_resume_skips_a_damaged_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _tiny_config(tmp_path, eval_episodes=0)
    out = tmp_path / "out"
    assert main(_base_args(path, out)) == 0
    saved = checkpoints(out / "checkpoints")
    assert [s for s, _ in saved] == [64, 128, 192]
    written = (out / "train_config.json").read_text()
    capsys.readouterr()
    # a fresh run into a folder with another run's checkpoints is refused, nothing touched
    assert main([*_base_args(path, out), "--seed", "7"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert str(out) in err and "--resume" in err and "new --out" in err
    assert checkpoints(out / "checkpoints") == saved
    assert (out / "train_config.json").read_text() == written
    # a truncated newest checkpoint: --resume says so and continues from the one before
    newest = saved[-1][1]
    newest.write_bytes(newest.read_bytes()[:1000])
    assert main([*_base_args(path, out), "--resume", "--timesteps", "256"]) == 0
    err = capsys.readouterr().err
    assert f"skipped checkpoint {str(newest)!r}" in err
    assert f"resuming from {saved[1][1]} (128 timesteps)" in err
    from policies.ppo import load_checkpoint

    after = checkpoints(out / "checkpoints")
    assert after[-1][0] >= 256 and load_checkpoint(after[-1][1]).num_timesteps == after[-1][0]
    assert load_checkpoint(newest).num_timesteps == 192  # rewritten by the resumed run


def test_save_checkpoint__a_failed_write_leaves_no_partial_file(tmp_path: Path) -> None:
    class Model:
        num_timesteps = 64

        def save(self, path: Path) -> None:
            Path(path).write_bytes(b"PK half a zip")
            raise OSError("disk full")

    folder = tmp_path / "checkpoints"
    with pytest.raises(OSError, match="disk full"):
        training.save_checkpoint(Model(), folder)
    assert list(folder.iterdir()) == []


def test_train__tensorboard_has_the_episode_metrics(tmp_path: Path) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    path = _tiny_config(tmp_path, eval_episodes=0)
    cfg = TrainConfig.from_yaml(path)
    cfg = cfg.replace(env=cfg.env.replace(slam_enabled=True))
    training.train(cfg, tmp_path / "out")
    (events,) = (tmp_path / "out" / "tb").rglob("events.out.tfevents.*")
    acc = EventAccumulator(str(events.parent))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert {f"polyslam/{t}" for t in training.EPISODE_TAGS} <= tags, tags
    coverage = [e.value for e in acc.Scalars("polyslam/team_coverage")]
    assert coverage and all(0.0 < c <= 1.0 for c in coverage)
    low = acc.Scalars("polyslam/robot_coverage_min")[-1].value
    assert low <= acc.Scalars("polyslam/robot_coverage_max")[-1].value


def test_shipped_goals_config__loads() -> None:
    cfg = TrainConfig.from_yaml(configs_dir() / "train_goals.yaml")
    assert cfg.control == "goals" and len(cfg.env_configs()) == 2
    assert {c.map for c in cfg.env_configs()} == {"generator:office_floor", "generator:warehouse"}


def test_shipped_drive_config__loads() -> None:
    cfg = TrainConfig.from_yaml(configs_dir() / "train_drive.yaml")
    assert cfg.control == "drive" and cfg.progress > 0 and not cfg.env.slam_enabled
    assert {c.map for c in cfg.env_configs()} == {"generator:office_floor", "generator:warehouse"}


def test_shipped_careful_config__loads() -> None:
    # fine-tuned from the shipped driver, with SLAM on (the map_error term needs a map) and
    # the map_error weight on
    cfg = TrainConfig.from_yaml(configs_dir() / "train_careful.yaml")
    assert cfg.control == "drive" and cfg.env.slam_enabled and cfg.env.reward.map_error > 0
    assert Path(cfg.init).name == "ppo_drive.zip"


def test_shipped_ppo_config__loads() -> None:
    # the network behind --policy ppo: fine-tuned from the shipped driver behind team guides
    cfg = TrainConfig.from_yaml(configs_dir() / "train_ppo_drive_team.yaml")
    assert cfg.control == "drive" and cfg.team and Path(cfg.init).name == "ppo_drive.zip"


def test_team_slam_config__loads() -> None:
    # the same fine-tune on the env --policy ppo is evaluated in: SLAM on, ppo_drive's reward
    cfg = TrainConfig.from_yaml(configs_dir() / "train_ppo_team_slam.yaml")
    assert cfg.control == "drive" and cfg.team and cfg.env.slam_enabled
    assert Path(cfg.init).name == "ppo_drive.zip" and cfg.env.reward.map_error == 0


@pytest.mark.parametrize(
    ("top", "match"),
    [
        ({"control": "legs"}, "control"),
        ({"maps": ["generator:loop"]}, "maps: only with"),
        ({"control": "drive", "progress": -1.0}, "progress"),
        ({"control": "drive", "repeat": 0}, "repeat"),
        ({"control": "goals", "team": True}, "team: only with control: drive"),
    ],
)
def test_train_config__bad_control_and_maps_are_named(
    tmp_path: Path, top: dict[str, Any], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        TrainConfig.from_yaml(_tiny_config(tmp_path, **top))


def test_cli_train__goals_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # control: goals on two maps: trains, writes the learning curve, evaluates against
    # random and frontier, and the checkpoint plays as the goal-choice ppo policy
    path = _tiny_config(
        tmp_path,
        control="goals",
        decide_every=4,
        maps=["generator:rooms", "generator:cave"],
        timesteps=96,
        checkpoint_every=48,
        env={"map": "generator:rooms", "num_robots": 2, "max_steps": 24},
    )
    out = tmp_path / "out"
    assert main(["train", "--config", str(path), "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "frontier" in printed and "learning curve" in printed
    report = json.loads((out / "final_eval.json").read_text())
    assert {"ppo", "random", "frontier"} <= set(report)
    assert (out / "learning_curve.png").stat().st_size > 0
    steps, coverage = np.loadtxt(out / "learning_curve.csv", delimiter=",", skiprows=1).T
    assert np.all(np.diff(steps) > 0) and np.all((coverage >= 0) & (coverage <= 1))
    _, ckpt = checkpoints(out / "checkpoints")[-1]
    env = parallel_env(map="generator:rooms", num_robots=2, max_steps=24)
    from policies.ppo import LearnedGoalPolicy

    assert isinstance(make_policy("ppo", env, "robot_0", checkpoint=ckpt), LearnedGoalPolicy)
    # a velocity checkpoint of the same folder layout loads as the (v, ω) network
    velocity = tmp_path / "velocity"
    path = _tiny_config(tmp_path, timesteps=32, eval_episodes=0)
    assert main(["train", "--config", str(path), "--out", str(velocity), "--quiet"]) == 0
    tiny = parallel_env(TrainConfig.from_yaml(path).env)
    ckpt = checkpoints(velocity / "checkpoints")[-1][1]
    assert isinstance(make_policy("ppo", tiny, "robot_0", checkpoint=ckpt), PPOPolicy)


def test_cli_train__drive_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # control: drive: trains, evaluates against random and frontier, and the checkpoint
    # plays as ppo_drive
    path = _tiny_config(tmp_path, control="drive", repeat=2, timesteps=64, checkpoint_every=32)
    out = tmp_path / "out"
    assert main(["train", "--config", str(path), "--out", str(out), "--quiet"]) == 0
    assert "frontier" in capsys.readouterr().out
    report = json.loads((out / "final_eval.json").read_text())
    assert {"ppo", "random", "frontier"} <= set(report)
    _, ckpt = checkpoints(out / "checkpoints")[-1]
    from policies.drive import DrivePolicy

    env = parallel_env(TrainConfig.from_yaml(path).env)
    assert isinstance(make_policy("ppo_drive", env, "robot_0", checkpoint=ckpt), DrivePolicy)
    # init: a run that starts from that checkpoint keeps its network (16 wide, not this
    # config's 8) and counts its own steps from 0 (two rollouts of 64, not one more after the
    # 64 of its start); a missing init file is named in one line
    tuned = tmp_path / "tuned"
    ppo = {"n_steps": 16, "batch_size": 32, "n_epochs": 1, "net_arch": [8]}
    path = _tiny_config(tmp_path, control="drive", init=str(ckpt), timesteps=128, ppo=ppo)
    assert main(["train", "--config", str(path), "--out", str(tuned), "--quiet"]) == 0
    steps, tuned_ckpt = checkpoints(tuned / "checkpoints")[-1]
    from stable_baselines3 import PPO

    assert steps == 128 and PPO.load(tuned_ckpt).policy.net_arch == [16]
    capsys.readouterr()
    path = _tiny_config(tmp_path, control="drive", init=str(tmp_path / "gone.zip"))
    assert main(["train", "--config", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "init" in err and "gone.zip" in err and "\n" not in err


def test_cli_train__goals_on_rllib_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _tiny_config(tmp_path, control="goals")
    args = ["train", "--backend", "rllib", "--config", str(path), "--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "sb3" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()

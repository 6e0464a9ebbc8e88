"""The benchmark's whole-command figures: what a user waits for, in wall time.

* :func:`bench_reproduce`: ``polyslam reproduce --runs N`` (the core paper's runs in 2 worker
  processes, as the command runs them), seconds;
* :func:`bench_train`: ``polyslam train --config configs/train_goals.yaml`` cut to a few
  rollouts (no checkpoints between, no final evaluation), env steps per second of the whole
  run, start of the worker processes and PPO's updates included. A goal-choice decision is
  ``decide_every`` env steps of the team (every decision is, but a last partial one when a
  coverage target ends an episode early, which the shipped config's 400-step episodes on
  large floors rarely reach), so the run's env steps are its timesteps (robot decisions)
  × ``decide_every`` / ``num_robots``.
"""

from __future__ import annotations

import tempfile
import time
from typing import Any

__all__ = ["bench_reproduce", "bench_train"]


def bench_reproduce(runs: int, workers: int = 2) -> dict[str, Any]:
    """Seconds of the core paper's reproduction over ``runs`` seeds in ``workers`` processes
    (the command's default), without its figures and files."""
    from polyslam_env.apps.reproduce import default_config, reproduce

    config = default_config().replace(runs=runs)
    start = time.perf_counter()
    reproduce(config, workers=workers, keep=(0,))
    return {"runs": runs, "workers": workers, "seconds": time.perf_counter() - start}


def bench_train(timesteps: int, config: str = "train_goals.yaml") -> dict[str, Any]:
    """Env steps per second of a training run of the shipped ``config`` cut to ``timesteps``
    robot decisions (module docstring), in a temporary output folder."""
    from polyslam_env.apps.training import TrainConfig, train
    from polyslam_env.core.resources import configs_dir

    cfg = TrainConfig.from_yaml(configs_dir() / config).replace(
        timesteps=timesteps, eval_episodes=0, checkpoint_every=timesteps
    )
    per_decision = cfg.decide_every if cfg.control == "goals" else 1
    env_steps = timesteps * per_decision / cfg.env.num_robots
    with tempfile.TemporaryDirectory(prefix="polyslam-bench-train-") as out:
        start = time.perf_counter()
        train(cfg, out)
        seconds = time.perf_counter() - start
    return {
        "config": config,
        "timesteps": timesteps,
        "env_steps": env_steps,
        "seconds": seconds,
        "env_steps_per_s": env_steps / seconds,
        "processes": cfg.num_cpus,
        "num_envs": cfg.num_envs,
    }

"""The benchmark's whole-command figures: what a user waits for, in wall time.

* :func:`bench_reproduce`: ``polyslam reproduce --runs N`` (the core paper's runs in 2 worker
  processes, as the command runs them), seconds;
* :func:`bench_train`: ``polyslam train --config configs/train_goals.yaml`` cut to a few
  rollouts (no checkpoints between, no final evaluation), env steps per second of the whole
  run, start of the worker processes and PPO's updates included. A goal-choice decision is
  ``decide_every`` env steps of the team (every decision is, but a last partial one when a
  coverage target ends an episode early, which the shipped config's 400-step episodes on
  large floors rarely reach), so the run's env steps are its timesteps (robot decisions)
  × ``decide_every`` / ``num_robots``. With a ``baseline`` source tree (``polyslam benchmark
  --train-baseline TREE``, e.g. issue 41's "today", ``main`` at d0c6831) both trees run the
  same cut config as ``polyslam train`` processes (:func:`train_in_tree`), baseline first, and
  the row carries this tree's env steps/s over the baseline's, measured in the same run, and
  the baseline's CPU time per env step (process and workers) over this tree's.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

__all__ = ["bench_reproduce", "bench_train", "train_in_tree"]

#: Runs the CLI of whichever ``polyslam_env`` is first on ``PYTHONPATH``.
CLI = "import sys; from polyslam_env.cli.main import main; sys.exit(main(sys.argv[1:]))"


def bench_reproduce(runs: int, workers: int = 2) -> dict[str, Any]:
    """Seconds of the core paper's reproduction over ``runs`` seeds in ``workers`` processes
    (the command's default), without its figures and files."""
    from polyslam_env.apps.reproduce import default_config, reproduce

    config = default_config().replace(runs=runs)
    start = time.perf_counter()
    reproduce(config, workers=workers, keep=(0,))
    return {"runs": runs, "workers": workers, "seconds": time.perf_counter() - start}


def train_in_tree(tree: Path, timesteps: int, config: str = "train_goals.yaml") -> dict[str, Any]:
    """One ``polyslam train`` process of the source ``tree`` (on ``PYTHONPATH``) on its
    ``configs/<config>`` cut to ``timesteps`` (module docstring): wall seconds of the whole
    process, env steps, env steps/s and CPU ms per env step of the process and its workers."""
    tree = Path(tree).resolve()
    source = tree / "configs" / config
    if not source.is_file():
        raise FileNotFoundError(f"{source}: no such training config in the tree {tree}")
    cfg = yaml.safe_load(source.read_text())
    cfg.update(timesteps=timesteps, eval_episodes=0, checkpoint_every=10 * timesteps)
    per_decision = cfg.get("decide_every", 1) if cfg.get("control") == "goals" else 1
    env_steps = timesteps * per_decision / cfg["env"]["num_robots"]
    with tempfile.TemporaryDirectory(prefix="polyslam-bench-train-") as tmp:
        path = Path(tmp) / config
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        env = {**os.environ, "PYTHONPATH": str(tree), "SDL_VIDEODRIVER": "dummy"}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, "-c", CLI, "train", "--config", str(path), "--out",
             str(Path(tmp) / "out"), "--quiet"],
            cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        seconds = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "tree": str(tree),
        "timesteps": timesteps,
        "env_steps": env_steps,
        "seconds": seconds,
        "env_steps_per_s": env_steps / seconds,
        "cpu_ms_per_env_step": 1e3 * cpu / env_steps,
    }


def bench_train(
    timesteps: int, config: str = "train_goals.yaml", baseline: Path | None = None
) -> dict[str, Any]:
    """Env steps per second of a training run of the shipped ``config`` cut to ``timesteps``
    robot decisions (module docstring), in a temporary output folder; with a ``baseline``
    tree, this tree and the baseline each in a ``polyslam train`` process, and their ratio."""
    if baseline is not None:
        import polyslam_env

        today = train_in_tree(baseline, timesteps, config)
        here = train_in_tree(Path(polyslam_env.__file__).resolve().parents[1], timesteps, config)
        return {
            "config": config,
            **{k: here[k] for k in ("timesteps", "env_steps", "seconds", "env_steps_per_s")},
            "cpu_ms_per_env_step": here["cpu_ms_per_env_step"],
            "baseline": today,
            "ratio_to_today": here["env_steps_per_s"] / today["env_steps_per_s"],
            # CPU per env step of the baseline over this tree's: steadier than the wall-clock
            # ratio on a loaded machine (a busy core slows both trees' wall clocks unevenly)
            "cpu_ratio_to_today": today["cpu_ms_per_env_step"] / here["cpu_ms_per_env_step"],
        }
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

"""The benchmark's whole-command figures: what a user waits for, in wall time.

* :func:`bench_reproduce`: ``polyslam reproduce --runs N`` (the core paper's runs in 2 worker
  processes, as the command runs them), seconds;
* :func:`bench_train`: ``polyslam train --config configs/train_goals.yaml`` cut to a few
  rollouts (no checkpoints between, no final evaluation), as a ``polyslam train`` process
  (:func:`train_in_tree`): env steps per second of its learning loop after the first rollout
  (rollouts and PPO's updates; :mod:`~polyslam_env.apps.train_marks` marks them from inside
  the process). The shipped run is 143 rollouts; the process start, imports, PPO's build
  (which imports ``torch._dynamo``), the workers' start and the kernels' first loads from
  numba's cache (some only when an episode first merges or meets a team-mate) happen once
  in it, under 1 % of its time, but were half of a 2-rollout cut run of this tree and a
  quarter of the baseline's: timing the whole cut process made the row mostly a measure of
  those fixed costs and of how the load moved them. The whole process's figures are kept in
  each run's record. A goal-choice decision is ``decide_every`` env steps of the team
  (every decision is, but a last partial one when a coverage target ends an episode early),
  so the env steps are the timesteps (robot decisions) × ``decide_every`` / ``num_robots``.
  With a ``baseline`` source tree (``polyslam benchmark --train-baseline TREE``, e.g. issue
  41's "today", ``main`` at d0c6831) both trees run the same cut config, ``repeats`` pairs of
  runs interleaved (baseline first, then this tree first, …), and the row carries the median
  over the pairs of this tree's env steps/s over the baseline's, each pair's two runs minutes
  apart, and likewise the baseline's CPU time per env step (process and workers) over this
  tree's.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
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


def train_in_tree(
    tree: Path, timesteps: int, config: str = "train_goals.yaml", n_steps: int | None = None
) -> dict[str, Any]:
    """One ``polyslam train`` process of the source ``tree`` (on ``PYTHONPATH``) on its
    ``configs/<config>`` cut to ``timesteps`` (module docstring; ``n_steps``, if given,
    replaces PPO's decisions per slot and rollout: short rollouts for a quick check), with
    :mod:`~polyslam_env.apps.train_marks` recording its rollouts: the whole process (wall
    seconds, env steps, env steps/s, CPU ms per env step of the process and its workers) and
    its learning loop after the first rollout (``steady``: the same figures)."""
    from polyslam_env.apps import train_marks

    tree = Path(tree).resolve()
    source = tree / "configs" / config
    if not source.is_file():
        raise FileNotFoundError(f"{source}: no such training config in the tree {tree}")
    cfg = yaml.safe_load(source.read_text())
    cfg.update(timesteps=timesteps, eval_episodes=0, checkpoint_every=10 * timesteps)
    if n_steps is not None:
        cfg.setdefault("ppo", {})["n_steps"] = n_steps
    per_decision = cfg.get("decide_every", 1) if cfg.get("control") == "goals" else 1
    env_steps_per = per_decision / cfg["env"]["num_robots"]  # env steps per robot decision
    program = Path(train_marks.__file__).read_text() + "\n" + CLI
    with tempfile.TemporaryDirectory(prefix="polyslam-bench-train-") as tmp:
        path, marks = Path(tmp) / config, Path(tmp) / "marks.json"
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        env = {**os.environ, "PYTHONPATH": str(tree), "SDL_VIDEODRIVER": "dummy",
               train_marks.ENV_VAR: str(marks)}  # fmt: skip
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, "-c", program, "train", "--config", str(path), "--out",
             str(Path(tmp) / "out"), "--quiet"],
            cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        seconds = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        loop = train_marks.steady(json.loads(marks.read_text()))
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    env_steps = timesteps * env_steps_per
    loop_steps = loop["timesteps"] * env_steps_per
    return {
        "tree": str(tree),
        "timesteps": timesteps,
        "env_steps": env_steps,
        "seconds": seconds,
        "env_steps_per_s": env_steps / seconds,
        "cpu_ms_per_env_step": 1e3 * cpu / env_steps,
        "steady": {
            "env_steps": loop_steps,
            "seconds": loop["seconds"],
            "env_steps_per_s": loop_steps / loop["seconds"],
            "cpu_ms_per_env_step": 1e3 * loop["cpu_s"] / loop_steps,
            "rollouts": loop["rollouts"],
            "before_s": loop["before_s"],
        },
    }


def bench_train(
    timesteps: int,
    config: str = "train_goals.yaml",
    baseline: Path | None = None,
    repeats: int = 3,
) -> dict[str, Any]:
    """Env steps per second of a training run of the shipped ``config`` cut to ``timesteps``
    robot decisions, in its learning loop after the first rollout (module docstring), as a
    ``polyslam train`` process of this tree; with a ``baseline`` tree, ``repeats`` pairs of
    runs of both trees, interleaved, and the median of the pairs' ratios."""
    import polyslam_env

    here_tree = Path(polyslam_env.__file__).resolve().parents[1]
    if baseline is None:
        here = train_in_tree(here_tree, timesteps, config)
        return {"config": config, **_train_figures([here])}
    if repeats < 1:
        raise ValueError(f"train repeats: must be >= 1, got {repeats}")
    pairs = []
    for k in range(repeats):
        # baseline first in even pairs, this tree first in odd ones: a load that drifts over
        # the minutes of a pair favours neither tree
        order = (baseline, here_tree) if k % 2 == 0 else (here_tree, baseline)
        runs = {tree: train_in_tree(tree, timesteps, config) for tree in order}
        pairs.append((runs[baseline], runs[here_tree]))
    today = [b for b, _ in pairs]
    here_runs = [h for _, h in pairs]

    def ratios(figure: str, cpu: bool = False, part: str = "steady") -> list[float]:
        out = []
        for b, h in pairs:
            got_b = b[part][figure] if part else b[figure]
            got_h = h[part][figure] if part else h[figure]
            out.append(got_b / got_h if cpu else got_h / got_b)
        return out

    rate = ratios("env_steps_per_s")
    cpu = ratios("cpu_ms_per_env_step", cpu=True)
    return {
        "config": config,
        **_train_figures(here_runs),
        "baseline": _train_figures(today),
        "repeats": repeats,
        # the median of the pairs' ratios: each pair's two runs share the minutes' load, and a
        # burst of someone else's work in one run moves that pair alone, which the median of
        # three or more pairs ignores and a mean would not
        "ratio_to_today": float(np.median(rate)),
        "ratios_to_today": rate,
        # CPU per env step of the baseline over this tree's: steadier than the wall clock on a
        # loaded machine (a busy core slows both trees' wall clocks unevenly)
        "cpu_ratio_to_today": float(np.median(cpu)),
        "cpu_ratios_to_today": cpu,
        # what the row gave before (whole processes: start, imports, model build included)
        "whole_ratios_to_today": ratios("env_steps_per_s", part=""),
    }


def _train_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The row's figures of one tree's ``runs`` (:func:`train_in_tree`): the medians of their
    learning loops after the first rollout, and every run."""
    loops = [r["steady"] for r in runs]
    return {
        "timesteps": runs[0]["timesteps"],
        "env_steps": loops[0]["env_steps"],
        "seconds": float(np.median([s["seconds"] for s in loops])),
        "env_steps_per_s": float(np.median([s["env_steps_per_s"] for s in loops])),
        "cpu_ms_per_env_step": float(np.median([s["cpu_ms_per_env_step"] for s in loops])),
        "runs": runs,
    }

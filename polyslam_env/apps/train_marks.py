"""Marks of a ``polyslam train`` process, recorded from inside it, for the benchmark's train row.

The source of this module runs as the start of the ``-c`` program of a ``polyslam train``
process of *any* source tree (:func:`polyslam_env.apps.benchmark_system.train_in_tree`, the
tree under test or a baseline checkout that has no such module), before that tree's CLI. So it
imports nothing of the package, only Stable-Baselines3 (one installed copy serves every tree):
:func:`install` wraps SB3's rollout collection and PPO's update to note, at the start and end
of each, the wall clock, the learner's timesteps (robot decisions) and the CPU seconds of the
process and of its worker processes (read from Linux's ``/proc``: ``getrusage`` knows the
children's CPU only once they have exited; NaN elsewhere). At exit the marks are written as
JSON to the path in :data:`ENV_VAR`.

The marks let the row time the learning loop after its first rollout (:func:`steady`): what a
full training run's throughput is, without the process start, imports, model build and the
kernels' first loads, which a full run pays once and a cut benchmark run pays in a large share.
"""

from __future__ import annotations

import atexit
import json
import math
import os
import resource
import time
from typing import Any

__all__ = ["ENV_VAR", "install", "steady"]

#: The environment variable naming the JSON file the marks are written to.
ENV_VAR = "POLYSLAM_TRAIN_MARKS"


def _process_cpu(pid: int) -> float:
    """CPU seconds (user + system) of the process ``pid`` so far (NaN without ``/proc``)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()  # from field 3 (state) on
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _workers(env: Any) -> list[int]:
    """The worker process ids behind an SB3 vec env (SuperSuit's ``ProcConcatVec.procs``,
    found down the ``venv`` chain of wrappers), none for an in-process one."""
    while env is not None:
        procs = getattr(env, "procs", None)
        if procs is not None:
            return [p.pid for p in procs]
        env = getattr(env, "venv", None)
    return []


def install(path: str | None = None) -> list[dict[str, Any]]:
    """Wrap SB3's ``collect_rollouts`` and ``PPO.train`` to record marks (module doc) and
    write them to ``path`` at exit (if given); the list of marks, as it grows."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    start = time.perf_counter()
    marks: list[dict[str, Any]] = []
    workers: list[int] = []

    def mark(what: str, model: Any) -> None:
        if not workers:
            workers.extend(_workers(model.env))
        own = resource.getrusage(resource.RUSAGE_SELF)
        marks.append({
            "what": what,
            "t": time.perf_counter() - start,
            "timesteps": int(model.num_timesteps),
            "cpu": own.ru_utime + own.ru_stime + sum(_process_cpu(p) for p in workers),
        })  # fmt: skip

    collect, update = OnPolicyAlgorithm.collect_rollouts, PPO.train

    def collect_marked(self: Any, *args: Any, **kwargs: Any) -> Any:
        mark("rollout", self)
        return collect(self, *args, **kwargs)

    def update_marked(self: Any) -> None:
        update(self)
        mark("updated", self)

    OnPolicyAlgorithm.collect_rollouts = collect_marked  # type: ignore[method-assign]
    PPO.train = update_marked  # type: ignore[method-assign]

    def write(to: str) -> None:
        with open(to, "w") as f:
            json.dump(marks, f)

    if path is not None:
        atexit.register(write, path)
    return marks


def steady(marks: list[dict[str, Any]]) -> dict[str, float]:
    """The learning loop after its first rollout and update: from the second rollout's start
    to the last update's end, its wall seconds, timesteps (robot decisions) and CPU seconds
    (process and workers); what came before it (process start to there) as ``before_s``."""
    starts = [m for m in marks if m["what"] == "rollout"]
    ends = [m for m in marks if m["what"] == "updated"]
    if len(starts) < 2 or len(ends) < 2:
        raise ValueError(
            f"train marks: {len(ends)} rollout(s) with an update; timing the loop after the"
            " first one needs at least two (raise the timesteps)"
        )
    first, last = starts[1], ends[-1]
    return {
        "seconds": last["t"] - first["t"],
        "timesteps": last["timesteps"] - first["timesteps"],
        "cpu_s": last["cpu"] - first["cpu"],
        "before_s": first["t"],
        "rollouts": len(ends) - 1,
    }


if __name__ == "__main__":  # as the start of a ``polyslam train`` process's ``-c`` program
    install(os.environ[ENV_VAR])

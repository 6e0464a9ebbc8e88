"""``polyslam benchmark``: every section in one run, and the issues' targets checked on it.

Figures from a loaded machine compare through their ratio to a reference measured in the same
process, and through cProfile's count of Python calls, which does not depend on the machine.
The sections, in the order they run (:data:`SECTIONS`), and where each lives:

* ``slam``, ``world`` (:mod:`~polyslam_env.apps.benchmark_components`): the SLAM step against
  the number of landmarks, the world step against the number of robots;
* ``reference``, ``env``, ``vec``, ``backends`` (:mod:`~polyslam_env.apps.benchmark_env`):
  PettingZoo MPE ``simple_spread`` (the reference of every ratio to MPE), env steps per second
  with and without SLAM, through the SB3 vectorised path, and per ``slam.backend``;
* ``floor`` (:mod:`~polyslam_env.apps.benchmark_floor`): the office-floor frontier episode of
  issue 41, env step and team act in ms, in MPE steps and in Python calls;
* ``team``, ``memory``, ``compile`` (:mod:`~polyslam_env.apps.benchmark_scaling`), and on
  request the env step's profile and multi-process scaling;
* ``reproduce``, ``train`` (:mod:`~polyslam_env.apps.benchmark_system`): the wall time of
  ``polyslam reproduce --runs 100`` and the env steps per second of a short
  ``polyslam train --config configs/train_goals.yaml`` (full plan only: minutes each).

The harness they share is :mod:`~polyslam_env.apps.benchmark_harness`; this module imports the
sections, no section imports another or this one. :func:`run_benchmark` returns a JSON-ready
dict; :func:`targets` checks issue 15's and issue 41's targets (:data:`TARGETS`) on it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from polyslam_env.apps.benchmark_components import (
    bench_slam,
    bench_world,
    make_inputs,
    make_slam,
    make_walls,
    scaling_exponent,
)
from polyslam_env.apps.benchmark_env import bench_backends, bench_env_turns, bench_mpe, bench_vec
from polyslam_env.apps.benchmark_harness import (
    ENV_CONFIG,
    PLANS,
    Plan,
    Stats,
    load_average,
    machine_info,
    rate,
    rate_samples,
    ratio,
    time_calls,
)

__all__ = [
    "ENV_CONFIG",
    "PLANS",
    "SECTIONS",
    "TARGETS",
    "Plan",
    "Stats",
    "make_inputs",
    "make_slam",
    "make_walls",
    "rate_samples",
    "run_benchmark",
    "scaling_exponent",
    "targets",
    "time_calls",
]

#: Sections of a benchmark run, in the order they run.
SECTIONS = (
    "slam",
    "world",
    "reference",
    "env",
    "vec",
    "backends",
    "floor",
    "team",
    "memory",
    "compile",
    "reproduce",
    "train",
)
#: The targets: (issues, name, goal, True when the figure must be at most the goal).
TARGETS: tuple[tuple[str, str, float, bool], ...] = (
    ("15, 41", "full-SLAM env / MPE simple_spread", 0.5, False),
    ("15", "slam_enabled=False env / MPE", 1.0, False),
    ("15, 41", "SLAM step µs, 30 landmarks", 60.0, True),
    ("15", "SLAM step µs, 300 landmarks", 200.0, True),
    ("41", "SLAM step µs, 300 landmarks", 250.0, True),
    ("15", "world step, 3 robots / pymunk", 4.0, True),
    ("15", "SB3 vec 2 procs / one process", 1.6, False),
    ("15, 41", "step cost 20 / 3 robots", 10.0, True),
    ("41", "floor env step, MPE steps", 5.0, True),
    ("41", "floor team act, MPE steps", 5.0, True),
    ("41", "floor Python calls per env step", 1500.0, True),
    ("41", "floor Python calls per team act", 600.0, True),
    ("41", "reproduce --runs 100, s", 15.0, True),
    ("41", "train env steps/s, × today (--train-baseline)", 3.0, False),
)


# -- the whole run ----------------------------------------------------------------------------
Report = Callable[[str, dict[str, Any]], None]


def _ignore(section: str, row: dict[str, Any]) -> None:
    """The default progress callback: print nothing."""


def run_benchmark(
    plan: Plan,
    sections: Iterable[str] = SECTIONS,
    seed: int = 0,
    report: Report = _ignore,
    workers: Sequence[int] = (),
    profile: str | None = None,
    train_baseline: Path | None = None,
) -> dict[str, Any]:
    """Run ``sections`` (see :data:`SECTIONS`); ``report(section, row)`` after every row.

    The reference (MPE) runs in turns with the env rows (``benchmark_env.bench_env_turns``),
    or alone before the later rows when ``env`` is not wanted; the env rows carry
    ``ratio_to_mpe`` (the vectorised
    rows run the same 2 envs in one process, then in 2 worker processes; the second carries
    ``ratio_to_one_process`` and ``ratio_to_env``, over full SLAM in one plain env); a ratio is
    None when either figure was not measured. ``workers`` (e.g. ``(1, 2, 4)``) adds a row of env
    steps/s per process count; ``profile`` adds the env step's profile (section ``profile``):
    ``"env"`` of the 3-robot env, ``"team"`` of the largest team size's env, ``"noslam"`` of
    the 3-robot env with ``slam_enabled=False``. ``train_baseline`` (a source tree) runs the
    training row from that tree too and gives the ratio of the two (issue 41's "× today").
    """
    wanted = set(sections)
    if any(n < 1 for n in workers):
        raise ValueError(f"workers: process counts must be >= 1, got {list(workers)}")
    if profile not in (None, "env", "team", "noslam"):
        raise ValueError(f"profile: expected 'env', 'team' or 'noslam', got {profile!r}")
    unknown = wanted - set(SECTIONS)
    if unknown:
        raise ValueError(f"sections: unknown {sorted(unknown)}; choose from {SECTIONS}")
    out: dict[str, Any] = {"plan": asdict(plan), "seed": seed, "machine": machine_info()}
    if "slam" in wanted:
        out["slam"] = [_emit(report, "slam", r) for r in bench_slam(plan.slam_sizes, plan, seed)]
    if "world" in wanted:
        rows = [_emit(report, "world", bench_world(n, plan)) for n in plan.robot_counts]
        out["world"] = {
            "rows": rows,
            "scaling_exponent": scaling_exponent(
                [r["robots"] for r in rows], [r["step_us"]["median"] for r in rows]
            ),
        }
    mpe = None
    if wanted & {"floor", "train"}:  # their figures in MPE steps need the reference
        wanted.add("reference")
    if "env" in wanted:  # the env rows and the reference in turns (bench_env_turns)
        turns = bench_env_turns(plan, seed)
        out["reference"] = _emit(
            report, "env", {"label": "MPE simple_spread", **turns["reference"]}
        )
        mpe = rate(out["reference"])
        full = {"label": "full SLAM", **turns["full_slam"]}
        nos = {"label": "slam_enabled=False", **turns["no_slam"]}
        out["env"] = {"full_slam": _emit(report, "env", full), "no_slam": _emit(report, "env", nos)}
    elif "reference" in wanted:  # first, so that every later row carries its ratio when printed
        out["reference"] = _emit(report, "env", {"label": "MPE simple_spread", **bench_mpe(plan)})
        mpe = rate(out["reference"])
    if "vec" in wanted:
        one = {"label": "SB3 vec, 1 proc", **bench_vec(plan, seed, num_cpus=0)}
        one["ratio_to_mpe"] = ratio(rate(one), mpe)
        out["vec_one_process"] = _emit(report, "env", one)
        vec = {"label": "SB3 vec, 2 procs", **bench_vec(plan, seed, num_cpus=2)}
        vec["ratio_to_mpe"] = ratio(rate(vec), mpe)
        vec["ratio_to_env"] = ratio(rate(vec), rate(out.get("env", {}).get("full_slam")))
        vec["ratio_to_one_process"] = ratio(rate(vec), rate(one))
        out["vec"] = _emit(report, "env", vec)
    if "backends" in wanted:
        out["backends"] = [_emit(report, "backends", r) for r in bench_backends(plan, seed)]
    if "floor" in wanted:
        from polyslam_env.apps.benchmark_floor import bench_floor

        out["floor"] = _emit(report, "floor", bench_floor(plan.floor_steps, mpe))
    _system_sections(out, plan, wanted, seed, report, workers, profile)
    _command_sections(out, plan, wanted, report, mpe, train_baseline)
    out["targets"] = targets(out)
    out["machine"]["load_after"] = load_average()
    return out


def _emit(report: Report, section: str, row: dict[str, Any]) -> dict[str, Any]:
    report(section, row)
    return row


def _system_sections(
    out: dict[str, Any],
    plan: Plan,
    wanted: set[str],
    seed: int,
    report: Report,
    workers: Sequence[int],
    profile: str | None,
) -> None:
    """The figures of :mod:`polyslam_env.apps.benchmark_scaling`, into ``out``."""
    from polyslam_env.apps import benchmark_scaling as system

    if "team" in wanted:
        rows = system.bench_team(plan.team_sizes, plan.team_steps, seed)
        out["team"] = [_emit(report, "team", r) for r in rows]
    if "memory" in wanted:
        mem = system.bench_memory(plan.memory_episodes, plan.memory_steps, seed)
        out["memory"] = mem
        for row in mem["episodes"]:
            _emit(report, "memory", row)
    if "compile" in wanted:
        out["compile"] = _emit(report, "compile", system.bench_compile(slam=plan.compile_slam))
    if workers:
        rows = system.bench_workers(workers, plan.env_steps, plan.repeats, seed)
        out["workers"] = [_emit(report, "workers", r) for r in rows]
    if profile is not None:
        team = max(plan.team_sizes) if profile == "team" else None
        steps = plan.profile_steps if team is None else plan.team_steps
        row = system.profile_env(steps, 20, seed, team, slam=profile != "noslam")
        out["profile"] = _emit(report, "profile", row)


def _command_sections(
    out: dict[str, Any],
    plan: Plan,
    wanted: set[str],
    report: Report,
    mpe: float | None,
    train_baseline: Path | None = None,
) -> None:
    """The figures of :mod:`polyslam_env.apps.benchmark_system`, into ``out`` (a plan's 0
    runs or timesteps leave its section out)."""
    from polyslam_env.apps import benchmark_system as command

    if "reproduce" in wanted and plan.reproduce_runs:
        out["reproduce"] = _emit(report, "reproduce", command.bench_reproduce(plan.reproduce_runs))
    if "train" in wanted and plan.train_timesteps:
        row = command.bench_train(
            plan.train_timesteps, baseline=train_baseline, repeats=plan.train_repeats
        )
        row["ratio_to_mpe"] = ratio(row["env_steps_per_s"], mpe)
        row.setdefault("ratio_to_today", None)  # measured only against a --train-baseline tree
        out["train"] = _emit(report, "train", row)


def targets(out: dict[str, Any]) -> list[dict[str, Any]]:
    """Issue 15's and issue 41's targets (:data:`TARGETS`) with the measured figure and whether
    it is met (None: not measured in this run)."""
    env = out.get("env", {})
    by_size = {r["landmarks"]: r["step_us"]["median"] for r in out.get("slam", [])}
    world = {r["robots"]: r["ratio_to_pymunk"] for r in out.get("world", {}).get("rows", [])}
    team = {r["robots"]: r["mean_ms"] for r in out.get("team", [])}
    floor = out.get("floor") or {}
    reproduce = out.get("reproduce") or {}
    measured = [
        (env.get("full_slam") or {}).get("ratio_to_mpe"),
        (env.get("no_slam") or {}).get("ratio_to_mpe"),
        by_size.get(30),
        by_size.get(300),
        by_size.get(300),
        world.get(3),
        (out.get("vec") or {}).get("ratio_to_one_process"),
        ratio(team.get(20), team.get(3)),
        (floor.get("env_step") or {}).get("mpe_steps"),
        (floor.get("team_act") or {}).get("mpe_steps"),
        floor.get("env_calls"),
        floor.get("act_calls"),
        reproduce.get("seconds") if reproduce.get("runs") == 100 else None,
        (out.get("train") or {}).get("ratio_to_today"),
    ]
    rows: list[dict[str, Any]] = []
    for (issue, name, goal, at_most), value in zip(TARGETS, measured, strict=True):
        met = None if value is None else (value <= goal if at_most else value >= goal)
        rows.append(
            {
                "issue": issue,
                "target": name,
                "measured": value,
                "goal": goal,
                "at_most": at_most,
                "met": met,
            }
        )
    return rows

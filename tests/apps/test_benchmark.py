"""The benchmark harness's statistics, and ``polyslam benchmark`` end to end (no timing checks:
performance figures live in the benchmark itself, not in unit tests)."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env.apps import benchmark, benchmark_harness
from polyslam_env.apps.benchmark import targets
from polyslam_env.apps.benchmark_components import scaling_exponent
from polyslam_env.apps.benchmark_harness import (
    Stats,
    interleaved_calls,
    rate_rounds,
    rate_samples,
    time_calls,
)
from polyslam_env.cli.main import main


class FakeClock:
    """A ``time`` stand-in whose ``perf_counter`` advances only when ``tick`` is called."""

    def __init__(self) -> None:
        self.now = 0.0

    def perf_counter(self) -> float:
        return self.now

    def tick(self, seconds: float) -> None:
        self.now += seconds


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeClock]:
    fake = FakeClock()
    monkeypatch.setattr(benchmark_harness, "time", fake)
    yield fake


def test_stats__known_samples() -> None:
    s = Stats.of([5.0, 1.0, 4.0, 2.0, 3.0])
    assert (s.median, s.q25, s.q75, s.min, s.max, s.n) == (3.0, 2.0, 4.0, 1.0, 5.0, 5)
    assert s.iqr == 2.0
    assert s.scaled(1e6).median == 3e6 and s.scaled(1e6).n == 5
    assert s.to_dict()["iqr"] == 2.0


def test_stats__no_samples_raises() -> None:
    with pytest.raises(ValueError, match="no samples"):
        Stats.of([])


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.0, 1e6, allow_nan=False), min_size=1, max_size=30))
def test_stats__order_of_quantiles(samples: list[float]) -> None:
    s = Stats.of(samples)
    # 1e-9 relative: np.percentile interpolates, which may round past an end by an ulp or so.
    tol = 1e-9 * max(1.0, s.max)
    assert s.min - tol <= s.q25 <= s.median + tol
    assert s.median - tol <= s.q75 <= s.max + tol
    assert s.median == pytest.approx(float(np.median(samples)), rel=1e-12, abs=1e-12)


def test_time_calls__per_call_time_with_warmup_and_number(clock: FakeClock) -> None:
    durations = iter([100.0, 100.0] + [1.0, 3.0] * 3 + [2.0, 2.0] * 3 + [5.0, 7.0] * 3)
    calls = []

    def fn() -> None:
        calls.append(1)
        clock.tick(next(durations))

    # Two warm-up calls (100 s each, not timed), then 3 samples of 6 calls each.
    s = time_calls(fn, repeats=3, number=6, warmup=2)
    assert len(calls) == 2 + 3 * 6
    assert (s.min, s.median, s.max, s.n) == (2.0, 2.0, 6.0, 3)


def test_interleaved_calls__turns_shares_and_one_sample_per_call(clock: FakeClock) -> None:
    order: list[str] = []

    def make(name: str, seconds: float) -> Callable[[], None]:
        def fn() -> None:
            order.append(name)
            clock.tick(seconds)

        return fn

    # 7 calls in 3 windows: shares 2, 2, 3 (they differ by at most one and sum to 7)
    a, b = interleaved_calls([make("a", 1.0), make("b", 3.0)], calls=7, windows=3, warmup=1)
    assert (
        order == ["a", "b"] + ["a"] * 2 + ["b"] * 2 + ["a"] * 2 + ["b"] * 2 + ["a"] * 3 + ["b"] * 3
    )
    assert (a, b) == ([1.0] * 7, [3.0] * 7)
    with pytest.raises(ValueError, match="windows"):
        interleaved_calls([make("a", 1.0)], calls=3, windows=0)


def test_rate_rounds__one_block_each_per_round_in_order(clock: FakeClock) -> None:
    order: list[str] = []
    per_call = {"a": 0.5, "b": 0.25}

    def make(name: str) -> Callable[[], None]:
        def step() -> None:
            order.append(name)
            clock.tick(per_call[name])

        return step

    a, b = rate_rounds([make("a"), make("b")], steps=[2, 4], repeats=2, warmups=[1, 0])
    assert order == ["a"] + (["a"] * 2 + ["b"] * 4) * 2
    assert (a, b) == ([2.0, 2.0], [4.0, 4.0])  # calls per second, one sample per round
    with pytest.raises(ValueError, match="one of each per stepper"):
        rate_rounds([make("a")], steps=[1, 2], repeats=1, warmups=[0])


def test_timed_calls__leave_out_kernel_loads(
    clock: FakeClock, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a call that spends 0.75 of its 1 s making a kernel ready (the compile clock advances by
    # that much while it runs) counts 0.25 s, in the per-call and the per-block timings alike
    loaded = [0.0]
    monkeypatch.setattr(benchmark_harness, "compile_seconds", lambda: loaded[0])

    def step() -> None:
        clock.tick(1.0)
        loaded[0] += 0.75

    assert interleaved_calls([step], calls=2, windows=1) == [[0.25, 0.25]]
    assert rate_rounds([step], steps=[2], repeats=1, warmups=[0]) == [[2 / 0.5]]


def test_rate_samples__calls_per_second(clock: FakeClock) -> None:
    per_call = [0.5]  # seconds each call takes; changed between blocks

    def step() -> None:
        clock.tick(per_call[0])

    rates = []
    for seconds in (0.5, 0.25, 1.0, 0.5):
        per_call[0] = seconds
        rates.append(rate_samples(step, steps=4, repeats=1).median)
    assert rates == [2.0, 4.0, 1.0, 2.0]
    assert rate_samples(step, steps=10, repeats=3, warmup=1).n == 3


class _RecordingEnv:
    """Two agents with the env's (v, ω) Box; records the actions it is stepped with."""

    def __init__(self) -> None:
        from gymnasium import spaces

        self.possible_agents = ["robot_0", "robot_1"]
        self.agents: list[str] = []
        self.space = spaces.Box(
            np.array([-0.5, -1.2], np.float32), np.array([0.7, 1.2], np.float32)
        )
        self.actions: list[np.ndarray] = []

    def action_space(self, agent: str) -> Any:
        return self.space

    def reset(self, seed: int | None = None) -> None:
        self.agents = list(self.possible_agents)

    def step(self, actions: dict[str, np.ndarray]) -> None:
        self.actions += [actions[a] for a in self.agents]


def test_random_stepper__draws_what_uniform_draws_bit_for_bit() -> None:
    env = _RecordingEnv()
    step = benchmark_harness.random_stepper(env, 7)
    for _ in range(500):
        step()
    rng = np.random.default_rng(7)
    expected = [rng.uniform(env.space.low, env.space.high) for _ in env.actions]
    got = np.array(env.actions)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, np.array(expected))


def test_scaling_exponent__linear_and_constant() -> None:
    counts = [1, 3, 8, 16, 32]
    linear = [5.0 * n for n in counts]
    # 1e-9: an exact power law; only floating-point rounding in the log-log fit remains.
    assert scaling_exponent(counts, linear) == pytest.approx(1.0, abs=1e-9)
    assert scaling_exponent(counts, [7.0] * 5) == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(scaling_exponent([3], [1.0]))


def test_targets__met_flags_and_missing_figures() -> None:
    results = {
        "env": {"full_slam": {"ratio_to_mpe": 0.6}, "no_slam": {"ratio_to_mpe": 0.9}},
        "slam": [
            {"landmarks": 30, "step_us": {"median": 59.0}},
            {"landmarks": 300, "step_us": {"median": 250.0}},
        ],
        "world": {"rows": [{"robots": 3, "ratio_to_pymunk": 3.5}]},
        "team": [{"robots": 3, "mean_ms": 4.0}, {"robots": 20, "mean_ms": 44.0}],
    }
    results["floor"] = {
        "env_step": {"mpe_steps": 4.5},
        "team_act": {"mpe_steps": 9.0},
        "env_calls": 1400.0,
        "act_calls": 700.0,
    }
    results["reproduce"] = {"runs": 100, "seconds": 14.0}
    rows = targets(results)
    assert [(r["issue"], r["target"]) for r in rows] == [
        (issue, name) for issue, name, _, _ in benchmark.TARGETS
    ]
    met = [(r["issue"], r["target"], r["met"]) for r in rows]
    assert met == [
        ("15, 41", "full-SLAM env / MPE simple_spread", True),
        ("15", "slam_enabled=False env / MPE", False),
        ("15, 41", "SLAM step µs, 30 landmarks", True),
        ("15", "SLAM step µs, 300 landmarks", False),
        ("41", "SLAM step µs, 300 landmarks", True),  # 250 ≤ 250
        ("15", "world step, 3 robots / pymunk", True),
        ("15", "SB3 vec 2 procs / one process", None),  # not measured
        ("15, 41", "step cost 20 / 3 robots", False),  # 11×
        ("41", "floor env step, MPE steps", True),
        ("41", "floor team act, MPE steps", False),
        ("41", "floor Python calls per env step", True),
        ("41", "floor Python calls per team act", False),
        ("41", "reproduce --runs 100, s", True),
        ("41", "train env steps/s, × today (--train-baseline)", None),  # not measured
    ]
    assert rows[7]["measured"] == pytest.approx(11.0, rel=1e-12)


def test_train_row__median_of_interleaved_pairs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Against a baseline tree (``--train-baseline``), the row runs pairs of ``polyslam train``
    processes, baseline first then this tree first, and gives the median over the pairs of the
    learning loops' ratios (and over this tree's runs, its env steps/s over MPE's)."""
    from polyslam_env.apps import benchmark_system

    # per tree, the loop's env steps/s and CPU ms per env step of each successive run
    rates = {"base": [10.0, 12.0, 8.0], "here": [30.0, 24.0, 40.0]}
    cpus = {"base": [4.0, 5.0, 4.4], "here": [1.6, 2.0, 1.1]}
    order: list[str] = []

    def fake_run(tree: Path, timesteps: int, config: str) -> dict[str, Any]:
        name = "base" if Path(tree).name == "base" else "here"
        k = order.count(name)
        order.append(name)
        rate, cpu = rates[name][k], cpus[name][k]
        loop = {"env_steps": 512.0, "seconds": 512.0 / rate, "env_steps_per_s": rate,
                "cpu_ms_per_env_step": cpu, "rollouts": 2, "before_s": 9.0}  # fmt: skip
        whole = rate / 2.0 if name == "here" else rate
        return {"timesteps": timesteps, "env_steps": 768.0, "seconds": 768.0 / whole,
                "env_steps_per_s": whole, "cpu_ms_per_env_step": cpu, "steady": loop}  # fmt: skip

    monkeypatch.setattr(benchmark_system, "train_in_tree", fake_run)
    out: dict[str, Any] = {}
    plan = benchmark.PLANS["full"]
    assert plan.train_repeats == 3
    benchmark._command_sections(out, plan, {"train"}, lambda s, r: None, 5000.0, Path("base"))
    assert order == ["base", "here", "here", "base", "base", "here"]
    row = out["train"]
    assert row["ratios_to_today"] == pytest.approx([3.0, 2.0, 5.0], rel=1e-12)
    assert row["ratio_to_today"] == pytest.approx(3.0, rel=1e-12)  # not the mean, 10/3
    assert row["cpu_ratios_to_today"] == pytest.approx([2.5, 2.5, 4.0], rel=1e-12)
    assert row["cpu_ratio_to_today"] == pytest.approx(2.5, rel=1e-12)
    assert row["whole_ratios_to_today"] == pytest.approx([1.5, 1.0, 2.5], rel=1e-12)
    assert row["env_steps_per_s"] == 30.0 and row["baseline"]["env_steps_per_s"] == 10.0
    assert row["ratio_to_mpe"] == pytest.approx(30.0 / 5000.0, rel=1e-12)
    assert len(row["runs"]) == 3 and len(row["baseline"]["runs"]) == 3


def test_train_marks__time_the_loop_after_the_first_rollout(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``train_marks`` wraps SB3's rollout collection and PPO's update (here stand-ins that
    count timesteps and burn CPU, under the names ``learn`` calls) to mark each rollout's start
    and each update's end; ``steady`` is the loop from the second rollout on."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    from polyslam_env.apps import train_marks

    def collect(self: Any, *args: Any) -> bool:
        self.num_timesteps += 32
        sum(range(20_000))  # CPU time to see
        return True

    monkeypatch.setattr(OnPolicyAlgorithm, "collect_rollouts", collect)
    monkeypatch.setattr(PPO, "train", lambda self: None)
    got = train_marks.install()
    model = type("Model", (), {"num_timesteps": 0, "env": None})()
    for _ in range(3):
        assert OnPolicyAlgorithm.collect_rollouts(model, None, None, None, 32)  # type: ignore[arg-type]
        PPO.train(model)  # type: ignore[arg-type]
    assert [m["what"] for m in got] == ["rollout", "updated"] * 3
    assert [m["timesteps"] for m in got] == [0, 32, 32, 64, 64, 96]
    times, cpu = [m["t"] for m in got], [m["cpu"] for m in got]
    assert times == sorted(times) and cpu == sorted(cpu) and cpu[-1] > cpu[0]
    loop = train_marks.steady(got)
    assert loop["timesteps"] == 64 and loop["rollouts"] == 2
    assert loop["seconds"] == pytest.approx(times[-1] - times[2], rel=1e-12)
    assert loop["cpu_s"] == pytest.approx(cpu[-1] - cpu[2], rel=1e-12)
    with pytest.raises(ValueError, match="at least two"):
        train_marks.steady(got[:2])


def test_train_in_tree__a_tree_without_the_config_is_a_one_line_error(tmp_path: Path) -> None:
    from polyslam_env.apps.benchmark_system import train_in_tree

    with pytest.raises(FileNotFoundError, match="train_goals.yaml"):
        train_in_tree(tmp_path, 8)


def test_targets__reproduce_counts_only_with_100_runs() -> None:
    """The target is about ``--runs 100``: a shorter reproduction's seconds are no figure."""
    rows = targets({"reproduce": {"runs": 20, "seconds": 3.0}})
    row = next(r for r in rows if r["target"].startswith("reproduce"))
    assert row["measured"] is None and row["met"] is None


def test_run_benchmark__rejects_unknown_section() -> None:
    with pytest.raises(ValueError, match="gpu"):
        benchmark.run_benchmark(benchmark.PLANS["tiny"], ["slam", "gpu"])


def test_benchmark_command__quick_json_has_every_section(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench.json"
    assert main(["benchmark", "--quick", "--tiny", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {"slam", "world", "env", "vec", "reference", "targets"} <= set(data)
    assert {"vec_one_process", "team", "memory", "compile", "floor"} <= set(data)
    assert data["reproduce"]["runs"] == benchmark.PLANS["tiny"].reproduce_runs
    assert data["reproduce"]["seconds"] > 0
    assert "train" not in data  # a plan's 0 timesteps leave it out
    floor, mpe = data["floor"], data["reference"]
    assert floor["steps"] == [3, 5] and floor["robots"] == 3
    assert floor["env_calls"] == pytest.approx(
        floor["env_calls_slam"] + floor["env_calls_exchange"] + floor["env_calls_rest"]
    )
    assert floor["env_calls_slam"] > 0 and floor["act_calls"] > 0
    for part in ("env_step", "team_act"):
        figure = floor[part]
        assert figure["mean_ms"] > 0
        if mpe["installed"]:  # ms over the same run's ms per MPE step
            ms_per_mpe_step = 1e3 / mpe["steps_per_s"]["median"]
            # 1e-9 relative: the same floats divided, JSON keeps 17 digits.
            assert figure["mpe_steps"] == pytest.approx(
                figure["mean_ms"] / ms_per_mpe_step, rel=1e-9
            )
    assert [r["landmarks"] for r in data["slam"]] == list(benchmark.PLANS["tiny"].slam_sizes)
    for row in data["slam"]:
        assert {"step_us", "reference_solve3_us", "ratio_to_solve3", "stages_us"} <= set(row)
        assert row["ratio_to_solve3"] > 0
    assert [r["robots"] for r in data["world"]["rows"]] == [1, 3]
    assert all(r["ratio_to_pymunk"] > 0 for r in data["world"]["rows"])
    assert "scaling_exponent" in data["world"]
    env_rows = [data["env"]["full_slam"], data["env"]["no_slam"], data["vec"]]
    mpe = data["reference"]
    # CI installs the bench extra: there the MPE branch must run, not be skipped for lack of it
    assert mpe["installed"] or not os.environ.get("CI"), "CI without mpe2 (the bench extra)"
    for row in env_rows:
        assert "ratio_to_mpe" in row
        if mpe["installed"] and row["installed"]:
            expected = row["steps_per_s"]["median"] / mpe["steps_per_s"]["median"]
            # 1e-9 relative: the ratio is computed from the same floats, JSON keeps 17 digits.
            assert row["ratio_to_mpe"] == pytest.approx(expected, rel=1e-9)
        else:
            assert row["ratio_to_mpe"] is None
    assert "ratio_to_env" in data["vec"]
    if data["vec"]["installed"]:
        assert data["vec"]["machine_speedup"] > 0  # side by side / one after another
        assert data["vec"]["processes"] == 2 and data["vec_one_process"]["processes"] == 1
        for row in (data["vec"], data["vec_one_process"]):  # CPU ticks: a few steps may be 0
            assert row["cpu_ms_per_env_step"] is None or row["cpu_ms_per_env_step"] >= 0
        expected = (
            data["vec"]["steps_per_s"]["median"] / data["vec_one_process"]["steps_per_s"]["median"]
        )
        # 1e-9 relative: the ratio is computed from the same floats, JSON keeps 17 digits.
        assert data["vec"]["ratio_to_one_process"] == pytest.approx(expected, rel=1e-9)
    team = data["team"]
    assert [r["robots"] for r in team] == list(benchmark.PLANS["tiny"].team_sizes)
    assert team[0]["ratio_to_first"] == 1.0 and all(r["mean_ms"] > 0 for r in team)
    memory = data["memory"]
    assert [r["episode"] for r in memory["episodes"]] == [1, 2]
    assert memory["total_steps"] == 2 * benchmark.PLANS["tiny"].memory_steps
    assert all(r["peak_mb"] > 0 for r in memory["episodes"])
    assert {"cold_s", "warm_s", "compile_s", "cached_files"} <= set(data["compile"])
    assert data["compile"]["cold_s"] > 0 and data["compile"]["warm_s"] > 0
    assert data["compile"]["slam_enabled"] is False  # tiny: the no-SLAM env's kernels only
    assert len(data["targets"]) == len(benchmark.TARGETS)
    machine = data["machine"]
    assert machine["cpus"] >= 1 and machine["numpy"] and machine["blas"]
    assert "load_before" in machine and "load_after" in machine
    printed = capsys.readouterr().out
    for heading in ("SLAM step", "world step", "env steps per second", "team size", "RSS",
                    "numba cache", "target", "machine:"):  # fmt: skip
        assert heading in printed
    assert "profile" not in data and "workers" not in data  # only on request


def test_benchmark_command__workers_and_profile_alone_run_only_their_rows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "bench.json"
    assert main(["benchmark", "--tiny", "--workers", "1,2", "--profile", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert not {"slam", "world", "env", "vec", "team", "memory", "compile"} & set(data)
    rows = data["workers"]
    assert [r["processes"] for r in rows] == [1, 2]
    assert rows[0]["ratio_to_one"] == 1.0
    for r in rows:
        assert r["total"] > 0 and r["per_process"] > 0
        # 1e-9 relative: the same floats divided, JSON keeps 17 digits.
        assert r["ratio_to_one"] == pytest.approx(r["total"] / rows[0]["total"], rel=1e-9)
    profile = data["profile"]
    assert profile["steps"] == benchmark.PLANS["tiny"].profile_steps
    assert (profile["robots"], profile["env"]) == (3, "paper")
    for key in ("tottime", "cumtime"):
        assert 0 < len(profile[key]) <= 20
        values = [e[key] for e in profile[key]]
        assert values == sorted(values, reverse=True)
        # The base is the wall time around the profiled calls, which holds their cumtime;
        # 1 % slack for the profiler's and perf_counter's clocks being read at other instants.
        assert all(0.0 <= e[key + "_pct"] <= 101.0 for e in profile[key])
    assert "parallel.py" in profile["cumtime"][0]["function"]  # the env step holds it all
    printed = capsys.readouterr().out
    for heading in ("N processes", "top by own time (tottime)", "top by cumulative time"):
        assert heading in printed


def test_benchmark_command__profile_team_profiles_the_largest_team(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["benchmark", "--tiny", "--profile", "team", "--json", str(out)]) == 0
    profile = json.loads(out.read_text())["profile"]
    tiny = benchmark.PLANS["tiny"]
    assert profile["robots"] == max(tiny.team_sizes) and profile["env"] == "generator:rooms"
    assert profile["steps"] == tiny.team_steps and profile["tottime"]


@pytest.mark.parametrize("value", ["0", "1,x", "", "2,-1"])
def test_benchmark_command__bad_workers_is_a_one_line_error(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["benchmark", "--tiny", "--workers", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--workers" in err and repr(value) in err


def test_benchmark_command__mpe_missing_says_not_installed(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "mpe2", None)  # makes ``import mpe2`` raise ImportError
    out = tmp_path / "ref.json"
    assert main(["benchmark", "--tiny", "--only", "reference", "--json", str(out)]) == 0
    assert "MPE simple_spread    not installed" in capsys.readouterr().out
    assert json.loads(out.read_text())["reference"]["installed"] is False


def _stats(median: float, low: float, high: float) -> dict[str, float]:
    return {"median": median, "iqr": high - low, "min": low, "max": high}


@pytest.mark.parametrize(
    ("section", "row"),
    [
        (
            "slam",
            {
                "landmarks": 300,
                "step_us": _stats(1234.5, 980.1, 23456.7),
                "reference_solve3_us": _stats(4.5, 4.0, 5.0),
                "ratio_to_solve3": 274.3,
                "beams_used_per_step": 5.0,
                "heading_step_us": _stats(1234.5, 980.1, 23456.7),
                "stages_us": {"predict": 40.0},
            },
        ),
        (
            "world",
            {
                "robots": 32,
                "step_us": _stats(12345.6, 2500.0, 150000.2),
                "per_robot_us": 385.8,
                "reference_pymunk_us": _stats(19.0, 18.0, 20.0),
                "ratio_to_pymunk": 649.8,
            },
        ),
        (
            "env",
            {
                "label": "MPE simple_spread",
                "installed": True,
                "steps_per_s": _stats(1862.0, 504.5, 13219.4),
                "ratio_to_mpe": None,
            },
        ),
        (
            "team",
            {
                "robots": 20,
                "steps": 150,
                "mean_ms": 1357.2,
                "median_ms": 999.1,
                "max_ms": 98765.4,
                "ratio_to_first": 199.6,
                "messages": 1290,
                "polynomials": 16170,
                "skipped": 12345,
                "covered": 12345,
                "refits": 99999,
            },
        ),
        ("memory", {"episode": 5, "steps": 200, "peak_mb": 1234.5, "rss_mb": 1200.1}),
        ("compile", {"cold_s": 12.34, "warm_s": 1.5, "compile_s": 10.84, "cached_files": 42}),
        ("workers", {"processes": 16, "per_process": 222.2, "total": 3205.1, "ratio_to_one": 14.4}),
    ],
)
def test_benchmark_tables__header_and_rows_share_column_edges(
    section: str, row: dict[str, Any]
) -> None:
    """Every column's right edge (left edge for the env label) is the same in the heading
    and in a row with a loaded machine's wide figures."""
    from polyslam_env.cli.benchmark import COLUMNS, FORMATTERS, HEADERS

    header, line = HEADERS[section], FORMATTERS[section](row)
    edge = -1
    for k, (_, width) in enumerate(COLUMNS[section]):
        edge += width + (1 if k else 0)
        if section == "env" and k == 0:
            continue
        for text in (header, line):
            assert text[edge] != " " and text[edge + 1 : edge + 2] in (" ", ""), (text, edge)


def test_benchmark_command__profile_noslam_profiles_the_env_without_slam(tmp_path: Path) -> None:
    out = tmp_path / "b.json"
    assert main(["benchmark", "--tiny", "--profile", "noslam", "--json", str(out)]) == 0
    profile = json.loads(out.read_text())["profile"]
    assert profile["slam_enabled"] is False and profile["env"] == "paper"
    names = [e["function"] for e in profile["cumtime"]]
    assert not any("slam/robot.py" in n for n in names)


def test_benchmark_command__backends_rows_time_every_backend_against_no_slam(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """One row per ``slam.backend`` after the no-SLAM reference, each with its ratio to it."""
    from polyslam_env.slam.config import BACKENDS

    out = tmp_path / "backends.json"
    assert main(["benchmark", "--tiny", "--only", "backends", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["backends"]
    assert [r["backend"] for r in rows] == ["none (slam_enabled=False)", *BACKENDS]
    reference = rows[0]["steps_per_s"]["median"]
    for r in rows[1:]:
        assert r["ratio_to_no_slam"] == pytest.approx(r["steps_per_s"]["median"] / reference)
    printed = capsys.readouterr().out
    assert all(b in printed for b in BACKENDS)


def test_benchmark_command__train_repeats_below_one_is_a_one_line_error(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["benchmark", "--only", "train", "--train-repeats", "0"]) == 2
    assert capsys.readouterr().err.strip() == (
        "polyslam: error: --train-repeats: must be >= 1, got 0"
    )

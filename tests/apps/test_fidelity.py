"""``polyslam fidelity``: structure of the summary, checks computed from the table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from polyslam_env.apps.fidelity import (
    REFERENCE_AREA,
    ROBOT_KEYS,
    SETTINGS,
    TARGETS,
    FidelityConfig,
    area_steps,
    checks_from_table,
    episode_config,
    map_label,
    markdown,
    misses,
    nees_checks,
    nees_excess,
    nees_means_text,
    picture,
    precision_checks,
    precision_expected_text,
    run_fidelity,
    summarise,
    worst_robots,
)
from polyslam_env.apps.rollout import EpisodeResult
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError
from polyslam_env.environment.config import EnvConfig
from polyslam_env.world.generators import make_generator
from polyslam_env.world.grid import free_space_grid
from polyslam_env.world.maps import load_map, save_map

TINY = FidelityConfig(maps=("loop",), seeds=1, robots=2, steps=6)


@pytest.fixture(scope="module")
def summary() -> dict:
    return run_fidelity(TINY)


def test_fidelity__table_per_map_and_setting_with_spread(summary: dict) -> None:
    assert set(summary["table"]) == {"loop"}
    for setting in SETTINGS:
        stats = summary["table"]["loop"][setting]
        assert set(stats) == {*ROBOT_KEYS, "coverage"}
        for s in stats.values():
            assert set(s) == {"mean", "min", "max"}
            assert s["min"] <= s["mean"] <= s["max"]
        episodes = summary["episodes"]["loop"][setting]
        assert [e["steps"] for e in episodes] == [TINY.steps]  # full length: no coverage target
        values = [m["nu_mean"] for e in episodes for m in e["robots"].values()]
        assert len(values) == TINY.robots and stats["nu_mean"]["max"] == max(values)


def test_fidelity__checks_are_booleans_computed_from_the_table(summary: dict) -> None:
    checks = summary["checks"]["loop"]
    assert all(isinstance(v, bool) for v in checks.values())
    on, off = summary["table"]["loop"]["exchange_on"], summary["table"]["loop"]["exchange_off"]
    # The rules written out again, from the targets.
    assert checks["nu_mean_le_0.05"] == (on["nu_mean"]["max"] <= 0.05)
    assert checks["map_precision_ge_0.9"] == (on["map_precision"]["min"] >= 0.9)
    assert checks["completeness_seen_ge_0.8"] == (on["completeness_seen"]["min"] >= 0.8)
    episodes = [r["robots"] for r in summary["episodes"]["loop"]["exchange_on"]]
    per_robot = [[m["nees"] for m in e.values()] for e in episodes]
    means = [sum(col) / len(col) for col in zip(*per_robot, strict=True)]
    assert checks["nees_mean_le_6"] == all(v <= 6.0 for v in means)
    assert checks["duplicates_le_0.05"] == (on["duplicates"]["max"] <= 0.05)
    assert checks["coverage_ge_0.85"] == (on["coverage"]["min"] >= 0.85)
    assert checks["exchange_completeness_higher"] == (
        on["completeness"]["mean"] > off["completeness"]["mean"]
    )
    assert checks["exchange_nu_mean_within_5mm"] == (
        on["nu_mean"]["mean"] <= off["nu_mean"]["mean"] + 0.005
    )
    assert "own_map_uncertainty_honest" in checks  # the polynomial EKF assesses itself
    assert summary["passed"] == all(checks.values())
    assert TARGETS["nu_mean_max"] == 0.05


def test_checks_from_table__each_target_flips_its_own_check() -> None:
    good = {
        "has_map": 1.0,
        "nu_mean": 0.02,
        "map_precision": 0.95,
        "completeness_seen": 0.9,
        "nees": 3.0,
        "duplicates": 0.01,
        "coverage": 0.9,
        "completeness": 0.6,
    }

    def table(**bad: float) -> dict:
        on = {k: dict.fromkeys(("mean", "min", "max"), bad.get(k, v)) for k, v in good.items()}
        off = {k: dict.fromkeys(("mean", "min", "max"), v) for k, v in good.items()}
        off["completeness"] = dict.fromkeys(("mean", "min", "max"), 0.5)
        return {"exchange_on": on, "exchange_off": off}

    assert all(checks_from_table(table()).values())
    for key, value, failing in [
        ("nu_mean", 0.051, ["nu_mean_le_0.05", "exchange_nu_mean_within_5mm"]),
        ("nu_mean", 0.026, ["exchange_nu_mean_within_5mm"]),  # 6 mm worse than off
        ("map_precision", 0.89, ["map_precision_ge_0.9"]),
        ("completeness_seen", 0.79, ["completeness_seen_ge_0.8"]),
        ("duplicates", 0.06, ["duplicates_le_0.05"]),
        ("coverage", 0.84, ["coverage_ge_0.85"]),
        ("completeness", 0.5, ["exchange_completeness_higher"]),
        ("has_map", 0.0, ["every_robot_has_map"]),
    ]:
        checks = checks_from_table(table(**{key: value}))
        assert [k for k, ok in checks.items() if not ok] == failing, (key, value)


def test_episode_config__exchange_off_has_no_channel_and_no_coverage_end() -> None:
    on = EnvConfig.from_dict(episode_config(TINY, "loop", exchange=True))
    off = EnvConfig.from_dict(episode_config(TINY, "loop", exchange=False))
    assert on.channel is not None and off.channel is None
    assert on.coverage_target is None and on.map == "generator:loop"
    assert on.replace(channel=None) == off
    if "initial_error" in EnvConfig.__dataclass_fields__:
        assert on.initial_error is True  # type: ignore[attr-defined]


def test_episode_config__env_set_reaches_every_episode_and_bad_pairs_are_named() -> None:
    """``--set`` (``env_set``) sets dotted env fields with YAML values on both settings; a
    malformed pair, an unknown field or a bad value is a one-line ConfigError naming it."""
    config = FidelityConfig(maps=("loop",), env_set=("slam.merge_turn=weights", "slam.eps_z=12"))
    for exchange in (True, False):
        env = EnvConfig.from_dict(episode_config(config, "loop", exchange))
        assert env.slam.merge_turn == "weights" and env.slam.eps_z == 12
        assert env.replace(slam__merge_turn="fit", slam__eps_z=15) == EnvConfig.from_dict(
            episode_config(TINY, "loop", exchange)
        ).replace(num_robots=env.num_robots, max_steps=env.max_steps)
    config = FidelityConfig(maps=("loop",), env_set=("channel.align_restarts=true",))
    on = EnvConfig.from_dict(episode_config(config, "loop", True))
    assert on.channel is not None and on.channel.align_restarts
    assert EnvConfig.from_dict(episode_config(config, "loop", False)).channel is None
    for pair, message in (
        ("slam.merge_turn", "expected KEY=VALUE"),
        ("slam.merge_turnx=fit", "unknown key 'slam.merge_turnx'"),
        ("slam.merge_turn=mean", "slam.merge_turn: must be one of"),
    ):
        with pytest.raises(ConfigError, match=message):
            FidelityConfig(env_set=(pair,))


def test_fidelity_cli__bad_set_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["fidelity", "--maps", "loop", "--seeds", "1", "--steps", "2", "--quiet"]
    assert main([*args, "--out", str(tmp_path), "--set", "slam.merge_turn=mean"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "slam.merge_turn: must be one of" in err
    assert "Traceback" not in err and not (tmp_path / "summary.json").exists()


def test_fidelity__policy_set_reaches_the_policy_and_bad_keywords_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--policy-set gain=visible`` gives every robot that policy argument (recorded in the
    settings); a keyword the policy does not take, or a bad value, is a one-line error before
    any episode runs, and nothing is written."""
    config = FidelityConfig(
        maps=("loop",), seeds=1, robots=1, steps=3, policy_set=("gain=visible",)
    )
    assert config.policy_kwargs() == {"gain": "visible"}
    summary = run_fidelity(config)
    assert summary["settings"]["policy_set"] == ["gain=visible"]
    for bad, says in (("gain=seen", "gain must be one of"), ("nothing=1", "unexpected keyword")):
        with pytest.raises(ConfigError, match=f"policy_set \\(--policy-set\\): .*{says}"):
            FidelityConfig(maps=("loop",), seeds=1, steps=3, policy_set=(bad,)).check_policy()
    out = tmp_path / "out"
    code = main(["fidelity", "--maps", "loop", "--seeds", "1", "--steps", "3", "--policy-set",
                 "gain=seen", "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "gain must be one of" in err
    assert not (out / "summary.json").exists()


def test_fidelity_config__bad_map_named() -> None:
    with pytest.raises(ConfigError, match="maps: 'maze'"):
        FidelityConfig(maps=("maze",))


def test_fidelity_cli__writes_summary_and_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["fidelity", "--maps", "loop", "--seeds", "1", "--steps", "4", "--robots", "2"]
    assert main([*args, "--out", str(tmp_path), "--quiet"]) == 0
    data = json.loads((tmp_path / "summary.json").read_text())
    assert set(data) >= {"table", "checks", "passed", "targets", "settings", "elapsed_s"}
    assert data["settings"]["maps"] == ["loop"]
    table = (tmp_path / "table.md").read_text()
    assert "### loop" in table and "| nu_mean |" in table
    assert "### loop" in capsys.readouterr().out
    assert {p.name for p in tmp_path.glob("worst_*.png")} == {
        "worst_loop_exchange_on.png",
        "worst_loop_exchange_off.png",
    }
    assert main([*args, "--out", str(tmp_path / "bare"), "--quiet", "--no-pictures"]) == 0
    assert not list((tmp_path / "bare").glob("*.png"))


def _result(seed: int, coverage: float, **robots: dict[str, float]) -> EpisodeResult:
    """An episode whose robots pass every target but what ``robots`` overrides."""
    passing = dict.fromkeys(ROBOT_KEYS, 0.0) | {
        "has_map": 1.0, "nu_mean": 0.01, "map_precision": 0.99, "completeness_seen": 0.9,
        "nees": 3.0,
    }  # fmt: skip
    full = {agent: passing | m for agent, m in robots.items()}
    return EpisodeResult(seed, 10, full, {"coverage": coverage})


def test_misses__names_every_robot_beyond_a_target_worst_first() -> None:
    """Floors and ceilings on their right side, equality passes (the checks use ≥ / ≤), the
    team's coverage per seed; the markdown names them under the map's checks."""
    results = [
        _result(0, 0.90, robot_0={"map_precision": 0.7}, robot_1={"completeness_seen": 0.8}),
        _result(1, 0.84, robot_0={"map_precision": 0.85, "duplicates": 0.07}, robot_1={}),
    ]
    got = misses(results)
    assert got == {
        "map_precision_ge_0.9": [
            {"seed": 0, "robot": "robot_0", "value": 0.7},
            {"seed": 1, "robot": "robot_0", "value": 0.85},
        ],
        "duplicates_le_0.05": [{"seed": 1, "robot": "robot_0", "value": 0.07}],
        "coverage_ge_0.85": [{"seed": 1, "robot": "team", "value": 0.84}],
    }
    text = markdown(summarise({"loop": {"exchange_on": results, "exchange_off": results[:1]}}))
    assert (
        "- exchange on, map_precision_ge_0.9 missed by seed 0 robot_0 0.7, seed 1 robot_0 0.85"
        in text
    )
    assert "- exchange off, map_precision_ge_0.9 missed by seed 0 robot_0 0.7\n" in text


def test_nees_excess__counts_robots_above_the_target_against_the_start_draws_binomial() -> None:
    """Robots above the NEES target (equality passes) with their start draws, and the count a
    consistent filter gives from the start draws alone: n · P(χ²(3) > 6) and its binomial
    95 % interval (n = 4 here: 4 · 0.112 = 0.4, interval 0–2)."""
    results = [
        _result(0, 0.9, robot_0={"nees": 9.5, "start_nees": 8.75}, robot_1={"nees": 6.0}),
        _result(1, 0.9, robot_0={}, robot_1={"nees": 7.0, "start_nees": 6.5}),
    ]
    text = nees_excess([r.to_dict() for r in results])
    assert text.startswith("`nees` above 6 for 2 of 4 robots")
    assert "gives 0.4 (95 %: 0–2)" in text
    assert text.endswith("their start draws e₀ᵀP0⁻¹e₀: 8.8, 6.5")  # worst NEES first
    assert "for 0 of 4 robots" in nees_excess([_result(0, 0.9, a={}, b={}).to_dict()] * 2)


def test_fidelity__every_robot_carries_its_filters_expected_precision(summary: dict) -> None:
    """The self-assessment (``self_assessment``, no ground truth) is in each robot's metrics
    and in the markdown, one line per setting."""
    for setting in SETTINGS:
        for episode in summary["episodes"]["loop"][setting]:
            for m in episode["robots"].values():
                assert 0.0 <= m["map_precision_expected"] <= 1.0
                assert 0.0 <= m["map_precision_risk"] <= 1.0
    text = markdown(summary)
    assert text.count("robots; their own filters expected") == len(SETTINGS)


def test_precision_expected_text__counts_against_the_filters_own_risks() -> None:
    """Robots below 0.9 (equality passes) against Σ P(below) = 0.1 + 0.5 + 0.5 + 0.9 = 2.0,
    whose exact 95 % interval is 1–3 (P(0) = P(4) = 0.9 · 0.5² · 0.1 = 0.0225, below 2.5 %);
    without self-assessments, no line."""
    risks = {"robot_0": 0.1, "robot_1": 0.5}
    results = [
        _result(0, 0.9, robot_0={"map_precision": 0.95}, robot_1={"map_precision": 0.9}),
        _result(1, 0.9, robot_0={"map_precision": 0.85}, robot_1={"map_precision": 0.7}),
    ]
    for r, extra in zip(results, ({}, {"robot_0": 0.5, "robot_1": 0.9}), strict=True):
        for agent, m in r.robots.items():
            m["map_precision_risk"] = extra.get(agent, risks[agent])
            m["map_precision_expected"] = 0.9
    text = precision_expected_text([r.to_dict() for r in results])
    assert text.startswith("`map_precision` below 0.9 for 2 of 4 robots")
    assert "their own filters expected 2.0 (95 %: 1–3)" in text
    assert text.endswith("mean `map_precision` 0.850, expected by the filters 0.900")
    assert precision_expected_text([_result(0, 0.9, a={}).to_dict()]) == ""


def test_precision_checks__the_count_below_the_target_within_the_filters_interval() -> None:
    """``own_map_uncertainty_honest``: with risks 0.1, 0.5, 0.5, 0.9 the exact 95 % interval
    of the count below 0.9 is 1–3 (above); 2 below passes, none below fails (the filters
    claimed too much uncertainty), all 4 below fails (too little); no self-assessment, no
    check."""

    def run(*precisions: float) -> list:
        results = [
            _result(0, 0.9, robot_0={"map_precision": precisions[0]}, robot_1={}),
            _result(1, 0.9, robot_0={"map_precision": precisions[1]}, robot_1={}),
        ]
        results[1].robots["robot_1"]["map_precision"] = precisions[3]
        results[0].robots["robot_1"]["map_precision"] = precisions[2]
        for r, risks in zip(results, ((0.1, 0.5), (0.5, 0.9)), strict=True):
            for m, risk in zip(r.robots.values(), risks, strict=True):
                m["map_precision_risk"] = risk
                m["map_precision_expected"] = 0.95
        return results

    assert precision_checks(run(0.95, 0.85, 0.99, 0.7)) == {"own_map_uncertainty_honest": True}
    assert precision_checks(run(0.95, 0.9, 0.99, 0.91)) == {"own_map_uncertainty_honest": False}
    assert precision_checks(run(0.8, 0.8, 0.8, 0.8)) == {"own_map_uncertainty_honest": False}
    assert precision_checks([_result(0, 0.9, a={})]) == {}


def test_nees_checks__monte_carlo_mean_per_robot_and_count_above_the_target() -> None:
    """``nees_mean_le_6``: each robot's mean ``nees`` over the seeds (robot_0 here: (9 + 3)/2
    = 6 passes, 6.2 fails); ``nees_above_6_consistent``: robots above 6 at most the top of
    the binomial 95 % interval of n · P(χ²(3) > 6) (n = 4: 0–2)."""

    def run(a: float, b: float, c: float = 3.0) -> list:
        return [
            _result(0, 0.9, robot_0={"nees": a}, robot_1={"nees": c}),
            _result(1, 0.9, robot_0={"nees": b}, robot_1={"nees": c}),
        ]

    assert nees_checks(run(9.0, 3.0)) == {"nees_mean_le_6": True, "nees_above_6_consistent": True}
    assert not nees_checks(run(9.4, 3.0))["nees_mean_le_6"]
    assert nees_checks(run(6.5, 6.5)) == {"nees_mean_le_6": False, "nees_above_6_consistent": True}
    assert not nees_checks(run(6.5, 6.5, c=6.5))["nees_above_6_consistent"]  # 4 above, top 2
    text = nees_means_text([r.to_dict() for r in run(9.0, 3.0)])
    assert text.startswith("mean `nees` over the 2 seeds: robot_0 6.00, robot_1 3.00")
    assert "95 % band of a mean of 2 χ²(3): 0.62–7.22" in text  # χ²(6) quantiles / 2


def test_fidelity_config__policy_must_be_a_scripted_policy() -> None:
    with pytest.raises(ConfigError, match="policy: 'nope' is not a policy; valid: frontier"):
        FidelityConfig(policy="nope")
    with pytest.raises(ConfigError, match="policy: 'ppo' needs a checkpoint"):
        FidelityConfig(policy="ppo")
    assert FidelityConfig(policy="frontier_closing").policy == "frontier_closing"


def test_worst_robots__lowest_map_precision_per_map_and_setting() -> None:
    on = [
        _result(0, 0.9, robot_0={"map_precision": 0.95}, robot_1={"map_precision": 0.8}),
        _result(1, 0.9, robot_0={"map_precision": 0.8}, robot_1={}),
    ]
    off = [_result(0, 0.9, robot_0={}, robot_1={"map_precision": 0.97})]
    summary = summarise({"loop": {"exchange_on": on, "exchange_off": off}})
    assert worst_robots(summary) == [
        {"map": "loop", "setting": "exchange_on", "seed": 0, "robot": "robot_1", "value": 0.8},
        {"map": "loop", "setting": "exchange_off", "seed": 0, "robot": "robot_1", "value": 0.97},
    ]


def test_picture__replays_the_worst_robots_episode(summary: dict, tmp_path: Path) -> None:
    """The picture's episode is the summary's (same seed, same episode, bit for bit): its
    map_precision is the summary's value exactly; the PNG is written."""
    for worst in worst_robots(summary):
        path = tmp_path / f"{worst['setting']}.png"
        assert picture(TINY, worst, path) == worst["value"]
        assert path.stat().st_size > 0


def test_area_steps__steps_per_reference_area_rounded_up_to_a_hundred_never_fewer() -> None:
    assert area_steps(1000, 0.5 * REFERENCE_AREA) == 1000  # never fewer than --steps
    assert area_steps(1000, REFERENCE_AREA) == 1000
    assert area_steps(1000, REFERENCE_AREA + 1.0) == 1100  # 1003.3 rounded up
    assert area_steps(1000, 3 * REFERENCE_AREA) == 3000


def test_fidelity__a_map_file_runs_labelled_by_its_stem_with_its_areas_budget(
    tmp_path: Path,
) -> None:
    layout = make_generator("loop")(np.random.default_rng(0))
    path = tmp_path / "my_floor.yaml"
    save_map(layout, path)
    config = FidelityConfig(maps=("loop", str(path)), seeds=1, robots=2, steps=100)
    assert map_label(str(path)) == "my_floor" and config.entry("my_floor") == str(path)
    area = free_space_grid(layout, 0.1).free_area
    assert config.steps_for(str(path)) == area_steps(100, area)
    assert config.steps_for("loop") == 100  # generators: --steps
    assert config.replace(area_budget=False).steps_for(str(path)) == 100
    fields = episode_config(config, str(path), exchange=True)
    assert np.array_equal(load_map(fields["map"]).segments, layout.segments)
    with pytest.raises(ConfigError, match="two maps are labelled 'my_floor'"):
        other = tmp_path / "b"
        other.mkdir()
        save_map(layout, other / "my_floor.yaml")
        FidelityConfig(maps=(str(path), str(other / "my_floor.yaml")))
    tiny = config.replace(maps=(str(path),), steps=4, area_budget=False)
    summary = run_fidelity(tiny)
    assert set(summary["table"]) == {"my_floor"}
    assert summary["settings"]["steps_per_map"] == {"my_floor": 4}

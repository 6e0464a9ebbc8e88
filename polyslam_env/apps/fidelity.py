"""The SLAM-fidelity protocol of issue 14 as one run: large generated maps, a frontier team,
initial error on, the exchange on and off on the same seeds, and the issue's targets checked.

For each map (a layout generator) and seed, two episodes run through the evaluation machinery
of :mod:`polyslam_env.apps.rollout` (:func:`~polyslam_env.apps.rollout.evaluate_episode`):
one with the rendezvous exchange on (the default channel) and one with it off, otherwise
identical (same layout, starts and noise streams). Episodes run the full ``steps`` (no
coverage target), so every episode is measured at the same horizon. ``initial_error`` is set
when :class:`~polyslam_env.environment.config.EnvConfig` has that field (else the robots start
at their frame origins, which the summary records).

:func:`summarise` turns the episodes into a ``table`` per map — mean, min and max over
robots × seeds of each per-robot metric in :data:`ROBOT_KEYS`, and over seeds of the team
coverage — and named boolean ``checks`` per map, each computed from the table alone
(:func:`checks_from_table`) against :data:`TARGETS`, the issue's "done when" targets.
:func:`markdown` adds who misses each target and, per setting, the robots above the NEES target
against what their start draws alone give (:func:`nees_excess`); :func:`picture` runs the
episode of a setting's lowest ``map_precision`` (:func:`worst_robots`) again and draws it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from policies.base import PolicyError, make_team, policy_factory, policy_names
from polyslam_env.apps.jobs import Runner, run_jobs, runner_of
from polyslam_env.apps.rollout import EpisodeResult, evaluate_episode, run_episode
from polyslam_env.core.config import Config, check_range, parse_overrides
from polyslam_env.core.errors import ConfigError, MapFileError
from polyslam_env.environment.config import GENERATOR_PREFIX, EnvConfig
from polyslam_env.environment.parallel import PolySlamParallelEnv, parallel_env
from polyslam_env.metrics.mapping import count_interval, expected_precision
from polyslam_env.metrics.pose import nees_band
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.generators import GENERATORS
from polyslam_env.world.grid import free_space_grid
from polyslam_env.world.maps import load_map, resolve_map_path

__all__ = [
    "DEFAULT_MAPS",
    "REFERENCE_AREA",
    "ROBOT_KEYS",
    "TARGETS",
    "FidelityConfig",
    "area_steps",
    "checks_from_table",
    "episode_config",
    "map_label",
    "markdown",
    "misses",
    "nees_excess",
    "picture",
    "precision_checks",
    "precision_count",
    "precision_expected_text",
    "run_fidelity",
    "self_assessment",
    "summarise",
    "worst_robots",
]

DEFAULT_MAPS = ("office_floor", "warehouse", "loop")
#: Per-robot metrics of the table (``infos[agent]["metrics"]`` keys), in order.
ROBOT_KEYS = (
    "nu_mean",
    "nu_mean_abs",
    "map_precision",
    "completeness",
    "completeness_seen",
    "duplicates",
    "nees",
    "nees_rel",
    "start_nees",
    "has_map",
    "rendezvous",
)
#: Issue 14's "done when" targets: every robot (the max or min over robots × seeds with the
#: exchange on) and the team coverage of every seed; exchange on against off compares means.
TARGETS: dict[str, float] = {
    "nu_mean_max": 0.05,  # m
    "map_precision_min": 0.9,
    "completeness_seen_min": 0.8,
    "nees_max": 6.0,  # mean standard NEES of each robot over the seeds (nees_checks)
    "duplicates_max": 0.05,
    "coverage_min": 0.85,  # team coverage at the episode end
    "exchange_nu_mean_slack": 0.005,  # m, on may be worse than off by at most this
}
#: The two settings of each seed: the exchange on, then off.
SETTINGS = ("exchange_on", "exchange_off")
#: The checks that every robot (or every seed's team) must pass: the metric, whether the
#: target is a floor (True) or a ceiling (False), and the target. :func:`checks_from_table`
#: tests them on the table's min / max, :func:`misses` lists who misses each.
PER_ROBOT_CHECKS: dict[str, tuple[str, bool, float]] = {
    "every_robot_has_map": ("has_map", True, 1.0),
    "nu_mean_le_0.05": ("nu_mean", False, TARGETS["nu_mean_max"]),
    "map_precision_ge_0.9": ("map_precision", True, TARGETS["map_precision_min"]),
    "completeness_seen_ge_0.8": ("completeness_seen", True, TARGETS["completeness_seen_min"]),
    "duplicates_le_0.05": ("duplicates", False, TARGETS["duplicates_max"]),
    "coverage_ge_0.85": ("coverage", True, TARGETS["coverage_min"]),
}


@dataclass(frozen=True)
class FidelityConfig(Config):
    """What :func:`run_fidelity` runs (the CLI's flags)."""

    #: layout generator names, built-in map names or map files (an imported building)
    maps: tuple[str, ...] = DEFAULT_MAPS
    seeds: int = 10  # seeds first_seed … first_seed + seeds − 1 per map
    first_seed: int = 0
    robots: int = 3
    steps: int = 600
    policy: str = "frontier"
    #: env config fields set on every episode, ``KEY=VALUE`` with dotted keys and YAML values
    #: (``slam.merge_turn=weights``): a variant of the filter or the world under the same protocol
    env_set: tuple[str, ...] = ()
    #: the policy's keyword arguments, ``KEY=VALUE`` with YAML values (``gain=visible``)
    policy_set: tuple[str, ...] = ()
    #: a fixed map (built-in or file) runs :func:`area_steps` steps, generators ``steps``
    area_budget: bool = True

    def validate(self) -> None:
        if not self.maps:
            raise ConfigError("maps: at least one map is needed")
        labels = [map_label(name) for name in self.maps]  # a bad name: its ConfigError
        for label in labels:
            if labels.count(label) > 1:
                raise ConfigError(f"maps: two maps are labelled {label!r}; rename one file")
        check_range("seeds", self.seeds, 1, 100_000)
        check_range("first_seed", self.first_seed, 0, 2**31)
        check_range("robots", self.robots, 1, 64)
        check_range("steps", self.steps, 1, 1_000_000)
        if self.policy not in policy_names():
            raise ConfigError(
                f"policy: {self.policy!r} is not a policy; valid: {', '.join(policy_names())}"
            )
        if getattr(policy_factory(self.policy), "takes_checkpoint", False):
            raise ConfigError(
                f"policy: {self.policy!r} needs a checkpoint; fidelity runs scripted policies"
            )
        EnvConfig().replace(**self.env_overrides())  # a bad field or value: its ConfigError

    def entry(self, label: str) -> str:
        """The ``maps`` entry whose table label is ``label``."""
        return next(name for name in self.maps if map_label(name) == label)

    def steps_for(self, name: str) -> int:
        """Steps of an episode on map ``name``: ``steps`` for a generator (and with
        ``area_budget`` off), else :func:`area_steps` of its free area."""
        if name in GENERATORS or not self.area_budget:
            return self.steps
        return area_steps(self.steps, free_space_grid(load_map(name), AREA_RESOLUTION).free_area)

    def env_overrides(self) -> dict[str, Any]:
        """``env_set`` as ``Config.replace`` keywords (``slam__merge_turn="weights"``)."""
        return parse_overrides(self.env_set, "env_set (--set)")

    def policy_kwargs(self) -> dict[str, Any]:
        """``policy_set`` as the policy's keyword arguments (``{"gain": "visible"}``)."""
        return parse_overrides(self.policy_set, "policy_set (--policy-set)")

    def check_policy(self) -> None:
        """Build the team once on the first map's env: a keyword the policy does not take, or
        a bad value, is a one-line ConfigError now rather than in every worker."""
        env = parallel_env(EnvConfig.from_dict(episode_config(self, self.maps[0], True)))
        try:
            make_team(self.policy, env, **self.policy_kwargs())
        except (TypeError, PolicyError) as err:
            raise ConfigError(f"policy_set (--policy-set): {err}") from None
        finally:
            env.close()


#: m², the free area ``steps`` are meant for on a fixed map: about the office floor's (the
#: default generator's free area is 302–312 m² on seeds 0–5, and a frontier team of 3 covers
#: it fully within 1,000 steps).
REFERENCE_AREA = 300.0
#: m, the raster the free area is measured on (the coverage grid's default resolution).
AREA_RESOLUTION = 0.1


def area_steps(steps: int, free_area: float) -> int:
    """The step budget of a fixed map of ``free_area`` m²: ``steps`` per
    :data:`REFERENCE_AREA` m², never fewer than ``steps``, rounded up to a hundred. A team
    sweeps about the same area per step anywhere, so a floor twice the size gets twice the
    steps."""
    return max(steps, math.ceil(steps * free_area / REFERENCE_AREA / 100) * 100)


def map_label(name: str) -> str:
    """The table label of a ``maps`` entry: a generator's name, a built-in map's name, or a
    map file's stem; ConfigError when ``name`` is none of them."""
    if name in GENERATORS:
        return name
    try:
        path = resolve_map_path(name)
    except MapFileError:
        raise ConfigError(
            f"maps: {name!r} is neither a layout generator ({', '.join(GENERATORS)}) nor a"
            " built-in map or map file"
        ) from None
    return path.stem


def has_initial_error() -> bool:
    """Whether this version's EnvConfig has ``initial_error`` (added by issue 14)."""
    return "initial_error" in EnvConfig.__dataclass_fields__


def episode_config(config: FidelityConfig, name: str, exchange: bool) -> dict[str, Any]:
    """The EnvConfig (as a dict) of one map and setting: full-length episodes, initial error
    on where supported, the default channel or none; ``env_set``'s ``channel.*`` fields set
    the exchange-on setting's channel (the other has none)."""
    fields: dict[str, Any] = {
        "map": GENERATOR_PREFIX + name if name in GENERATORS else str(resolve_map_path(name)),
        "num_robots": config.robots,
        "max_steps": config.steps_for(name),
        "coverage_target": None,
    }
    if not exchange:
        fields["channel"] = None
    if has_initial_error():
        fields["initial_error"] = True
    overrides = {
        key: value
        for key, value in config.env_overrides().items()
        if exchange or not key.startswith("channel__")
    }
    return EnvConfig.from_dict(fields).replace(**overrides).to_dict()


def _run_job(job: tuple[dict[str, Any], str, dict[str, Any], int]) -> EpisodeResult:
    config, policy, kwargs, seed = job
    return evaluate_episode(config, policy, kwargs, seed, after=self_assessment)


def self_assessment(env: PolySlamParallelEnv, result: EpisodeResult) -> None:
    """Add to each robot's metrics in ``result`` the map precision its own filter expects at
    the episode's end, ``map_precision_expected``, and the probability it gives to a
    precision below the target, ``map_precision_risk``
    (:func:`~polyslam_env.metrics.mapping.expected_precision`: no ground truth goes in).
    Other back-ends than the polynomial EKF get neither."""
    state = env.episode
    assert state is not None  # an episode ran
    for agent, slam in zip(env.possible_agents, state.slams, strict=True):
        if agent not in result.robots or not isinstance(slam, PolySlam):
            continue
        lengths, jacobian = slam.map_error_jacobian()
        mean, risk = expected_precision(
            lengths,
            jacobian,
            slam.cov,
            floor=TARGETS["map_precision_min"],
            frozen=slam.map_frozen_variance(),
        )
        result.robots[agent]["map_precision_expected"] = mean
        result.robots[agent]["map_precision_risk"] = risk


def run_fidelity(
    config: FidelityConfig,
    workers: int | Runner = 1,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run every map × seed × setting (in ``workers`` processes, or as its :class:`Runner`
    says) and :func:`summarise` them; ``progress(k)`` is called after each finished
    episode. Adds the settings and wall time; an episode that failed is left out."""
    seeds = [config.first_seed + k for k in range(config.seeds)]
    keys = [(name, setting, seed) for name in config.maps for setting in SETTINGS for seed in seeds]
    configs = {
        (name, setting): episode_config(config, name, setting == "exchange_on")
        for name in config.maps
        for setting in SETTINGS
    }
    labels = {name: map_label(name) for name in config.maps}
    config.check_policy()
    kwargs = config.policy_kwargs()
    jobs = [(configs[name, setting], config.policy, kwargs, seed) for name, setting, seed in keys]
    start = time.perf_counter()
    results = run_jobs(_run_job, jobs, workers, progress, seed_of=lambda job: job[3])
    grouped: dict[str, dict[str, list[EpisodeResult]]] = {
        labels[name]: {s: [] for s in SETTINGS} for name in config.maps
    }
    for (name, setting, _), result in zip(keys, results, strict=True):
        if result is not None:
            grouped[labels[name]][setting].append(result)
    summary = summarise(grouped)
    summary["settings"] = {
        **config.to_dict(),
        "steps_per_map": {
            labels[name]: configs[name, SETTINGS[0]]["max_steps"] for name in config.maps
        },
        "seed_list": seeds,
        "initial_error": has_initial_error(),
        "coverage_target": None,
        **runner_of(workers).settings(),
    }
    summary["elapsed_s"] = time.perf_counter() - start
    return summary


def worst_robots(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per map and setting, the robot of lowest ``map_precision`` over its seeds:
    ``{"map", "setting", "seed", "robot", "value"}`` (the first in seed order among ties)."""
    out = []
    for name, by_setting in summary["episodes"].items():
        for setting, episodes in by_setting.items():
            seed, robot, value = min(
                ((e["seed"], agent, m["map_precision"]) for e in episodes
                 for agent, m in e["robots"].items()),
                key=lambda t: t[2],
            )  # fmt: skip
            out.append(
                {"map": name, "setting": setting, "seed": seed, "robot": robot, "value": value}
            )
    return out


def picture(config: FidelityConfig, worst: Mapping[str, Any], path: str | Path) -> float:
    """Run ``worst``'s episode again (same seed, same episode) and draw that robot's map with
    the stretches farther than 5 cm from a true wall marked (:func:`plot_map_errors`); returns
    its ``map_precision`` in this run, which equals ``worst["value"]``."""
    from polyslam_env.render.plots import plot_map_errors  # matplotlib: only when drawing

    fields = episode_config(config, config.entry(worst["map"]), worst["setting"] == "exchange_on")
    env = parallel_env(EnvConfig.from_dict(fields))
    try:
        result = run_episode(
            env, make_team(config.policy, env, **config.policy_kwargs()), worst["seed"]
        )
        state = env.episode
        assert state is not None
        i = env.possible_agents.index(worst["robot"])
        run = state.histories[i].run(state.slams[i].polynomials())
        value = float(result.robots[worst["robot"]]["map_precision"])
    finally:
        env.close()
    setting = worst["setting"].replace("_", " ")
    plot_map_errors(
        state.world.layout,
        run,
        path,
        f"{worst['map']}, {setting}: seed {worst['seed']} {worst['robot']}, the lowest"
        f" map_precision ({value:.3f}); orange: farther than 5 cm from a true wall",
    )
    return value


def _spread(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {"mean": float(a.mean()), "min": float(a.min()), "max": float(a.max())}


def setting_table(results: Sequence[EpisodeResult]) -> dict[str, dict[str, float]]:
    """Mean, min, max over robots × episodes of each of :data:`ROBOT_KEYS`, and over episodes
    of the team ``coverage``."""
    table = {
        key: _spread([m[key] for r in results for m in r.robots.values()]) for key in ROBOT_KEYS
    }
    table["coverage"] = _spread([r.team["coverage"] for r in results])
    return table


def checks_from_table(table: Mapping[str, Mapping[str, Mapping[str, float]]]) -> dict[str, bool]:
    """The issue's targets for one map, from its table alone (``table[setting][metric]``)."""
    on, off = table["exchange_on"], table["exchange_off"]
    checks = {
        name: on[key]["min"] >= target if floor else on[key]["max"] <= target
        for name, (key, floor, target) in PER_ROBOT_CHECKS.items()
    }
    checks["exchange_completeness_higher"] = (
        on["completeness"]["mean"] > off["completeness"]["mean"]
    )
    checks["exchange_nu_mean_within_5mm"] = (
        on["nu_mean"]["mean"] <= off["nu_mean"]["mean"] + TARGETS["exchange_nu_mean_slack"]
    )
    return checks


def nees_checks(results: Sequence[EpisodeResult]) -> dict[str, bool]:
    """The NEES target on one setting's episodes, as a Monte Carlo test (Bar-Shalom's average
    NEES): ``nees_mean_le_6``, the mean ``nees`` of each robot (robot_0, robot_1, …) over the
    seeds is at most :data:`TARGETS` ``nees_max``; ``nees_above_6_consistent``, the number of
    single robots above it is at most what a consistent filter gives in 95 % of runs
    (:func:`nees_excess`). One episode's ``nees`` carries the robot's start draw
    e₀ᵀP0⁻¹e₀ ~ χ²(3), which nothing can observe, so "every robot's ``nees`` ≤ 6" fails for
    11 % of robots whatever the filter."""
    target = TARGETS["nees_max"]
    means = robot_nees_means([r.robots for r in results])
    robots = [m for r in results for m in r.robots.values()]
    above = sum(m["nees"] > target for m in robots)
    _, _, hi = start_draw_count(len(robots))
    return {
        "nees_mean_le_6": all(v <= target for v in means.values()),
        "nees_above_6_consistent": above <= hi,
    }


def robot_nees_means(episodes: Sequence[Mapping[str, Mapping[str, float]]]) -> dict[str, float]:
    """Each robot's mean ``nees`` over the episodes it ran in (each episode: agent →
    metrics)."""
    agents = sorted({a for robots in episodes for a in robots}, key=lambda a: (len(a), a))
    return {
        a: float(np.mean([robots[a]["nees"] for robots in episodes if a in robots])) for a in agents
    }


def misses(results: Sequence[EpisodeResult]) -> dict[str, list[dict[str, Any]]]:
    """Who misses each of :data:`PER_ROBOT_CHECKS` in one setting's episodes: per check, the
    ``{"seed", "robot", "value"}`` of every robot (``robot`` "team" for the coverage) beyond
    the target, worst first; checks nobody misses are left out."""
    out: dict[str, list[dict[str, Any]]] = {}
    for check, (key, floor, target) in PER_ROBOT_CHECKS.items():
        found = []
        for r in results:
            values = {"team": r.team[key]} if key == "coverage" else {
                agent: m[key] for agent, m in r.robots.items()
            }  # fmt: skip
            for who, value in values.items():
                if (value < target) if floor else (value > target):
                    found.append({"seed": r.seed, "robot": who, "value": float(value)})
        if found:
            out[check] = sorted(found, key=lambda f: f["value"], reverse=not floor)
    return out


def summarise(grouped: Mapping[str, Mapping[str, Sequence[EpisodeResult]]]) -> dict[str, Any]:
    """``table[map][setting][metric]`` (mean/min/max), ``checks[map][name]`` (bool),
    ``passed`` (all checks of all maps), ``misses[map][setting][check]`` (who misses a
    per-robot target, :func:`misses`) and the episodes (``episodes[map][setting]``)."""
    table = {
        name: {setting: setting_table(results) for setting, results in by_setting.items()}
        for name, by_setting in grouped.items()
    }
    checks = {
        name: {
            **checks_from_table(t),
            **nees_checks(grouped[name]["exchange_on"]),
            **precision_checks(grouped[name]["exchange_off"]),
        }
        for name, t in table.items()
    }
    return {
        "targets": dict(TARGETS),
        "table": table,
        "checks": checks,
        "passed": all(ok for c in checks.values() for ok in c.values()),
        "misses": {
            name: {setting: misses(results) for setting, results in by_setting.items()}
            for name, by_setting in grouped.items()
        },
        "episodes": {
            name: {s: [r.to_dict() for r in rs] for s, rs in by_setting.items()}
            for name, by_setting in grouped.items()
        },
    }


def markdown(summary: Mapping[str, Any]) -> str:
    """One markdown table per map (metric × setting: mean [min, max]) and its checks."""
    lines: list[str] = []
    settings = summary.get("settings", {})
    if settings:
        lines.append(
            f"{settings['policy']} team of {settings['robots']}, {settings['steps']} steps,"
            f" {settings['seeds']} seeds from {settings['first_seed']}, initial_error"
            f" {'on' if settings['initial_error'] else 'off (not in this EnvConfig)'};"
            " per-robot metrics over robots × seeds, coverage (team) over seeds."
        )
        lines.append("")
    per_map = settings.get("steps_per_map", {})
    for name, by_setting in summary["table"].items():
        steps = per_map.get(name, settings.get("steps"))
        if steps is not None and steps != settings.get("steps"):
            lines += [f"### {name} ({steps} steps: the budget of its free area)"]
        else:
            lines += [f"### {name}"]
        lines += ["", "| metric | exchange on | exchange off |", "|---|---|---|"]
        for key in (*ROBOT_KEYS, "coverage"):
            cells = [_cell(by_setting[s][key]) for s in SETTINGS]
            lines.append(f"| {key} | {cells[0]} | {cells[1]} |")
        lines.append("")
        checks = summary["checks"][name]
        lines.append(
            "checks (the exchange on; own_map_uncertainty_honest: off): "
            + ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in checks.items())
        )
        lines.append("")
        for setting in SETTINGS:
            for check, found in summary.get("misses", {}).get(name, {}).get(setting, {}).items():
                shown = ", ".join(
                    f"seed {f['seed']} {f['robot']} {f['value']:.3g}" for f in found[:MISSES_SHOWN]
                )
                more = f" and {len(found) - MISSES_SHOWN} more" if len(found) > MISSES_SHOWN else ""
                lines.append(f"- {setting.replace('_', ' ')}, {check} missed by {shown}{more}")
        for setting in SETTINGS:
            episodes = summary.get("episodes", {}).get(name, {}).get(setting, [])
            if episodes:
                lines.append(f"- {setting.replace('_', ' ')}: {nees_means_text(episodes)}")
                lines.append(f"- {setting.replace('_', ' ')}: {nees_excess(episodes)}")
                expected = precision_expected_text(episodes)
                if expected:
                    lines.append(f"- {setting.replace('_', ' ')}: {expected}")
        lines.append("")
    return "\n".join(lines)


def nees_excess(episodes: Sequence[Mapping[str, Any]]) -> str:
    """How many robots of ``episodes`` (``EpisodeResult.to_dict()``) have a mean ``nees``
    above :data:`TARGETS` ``nees_max``, against the count a consistent filter gives: each
    robot's unobservable start draw e₀ᵀP0⁻¹e₀ ~ χ²(3) (``start_nees``) stays in its NEES for
    the whole episode, so about P(χ²(3) > 6) = 11 % of robots exceed 6 from it alone; the
    binomial 95 % interval of that count, and the start draws of the robots above."""
    target = TARGETS["nees_max"]
    robots = [m for e in episodes for m in e["robots"].values()]
    above = sorted((m for m in robots if m["nees"] > target), key=lambda m: -m["nees"])
    expected, lo, hi = start_draw_count(len(robots))
    draws = ", ".join(f"{m['start_nees']:.1f}" for m in above)
    return (
        f"`nees` above {target:g} for {len(above)} of {len(robots)} robots; from the start"
        f" draws alone a consistent filter gives {expected:.1f} (95 %: {lo:.0f}–{hi:.0f})"
        + (f"; their start draws e₀ᵀP0⁻¹e₀: {draws}" if above else "")
    )


def precision_count(
    robots: Sequence[Mapping[str, float]],
) -> tuple[int, float, int, int] | None:
    """Of ``robots`` (metrics with :func:`self_assessment`'s keys), how many are below the
    ``map_precision`` target, the count their own filters expected (Σ P(below)) and its exact
    95 % interval (lo, hi) (:func:`~polyslam_env.metrics.mapping.count_interval`, the robots'
    filters being independent); None when any robot carries no self-assessment."""
    if not robots or any("map_precision_risk" not in m for m in robots):
        return None
    below = sum(m["map_precision"] < TARGETS["map_precision_min"] for m in robots)
    expected, lo, hi = count_interval([m["map_precision_risk"] for m in robots])
    return below, expected, lo, hi


def precision_checks(results: Sequence[EpisodeResult]) -> dict[str, bool]:
    """``own_map_uncertainty_honest`` on one setting's episodes (the exchange off, so every
    wall is the robot's own): the robots below the ``map_precision`` target are within the
    95 % interval of the count their own filters expected (:func:`precision_count`), on
    both sides, since a filter that claims too much uncertainty is as wrong as one that
    claims too little. Empty when the back-end gives no self-assessment. Received walls are
    left out: they carry the camera transform's noise, which their refinement on shared
    walls does not reduce (docs/design/consistency.md, "The maps' own uncertainty")."""
    counted = precision_count([m for r in results for m in r.robots.values()])
    if counted is None:
        return {}
    below, _, lo, hi = counted
    return {"own_map_uncertainty_honest": lo <= below <= hi}


def precision_expected_text(episodes: Sequence[Mapping[str, Any]]) -> str:
    """The robots of ``episodes`` below the ``map_precision`` target against what their own
    filters expected (:func:`precision_count`), and the mean precision observed and
    expected; "" when the episodes carry no self-assessment."""
    robots = [m for e in episodes for m in e["robots"].values()]
    counted = precision_count(robots)
    if counted is None:
        return ""
    target = TARGETS["map_precision_min"]
    below, expected, lo, hi = counted
    observed_mean = float(np.mean([m["map_precision"] for m in robots]))
    expected_mean = float(np.mean([m["map_precision_expected"] for m in robots]))
    return (
        f"`map_precision` below {target:g} for {below} of {len(robots)} robots; their own"
        f" filters expected {expected:.1f} (95 %: {lo}–{hi}); mean `map_precision`"
        f" {observed_mean:.3f}, expected by the filters {expected_mean:.3f}"
    )


def start_draw_count(robots: int) -> tuple[float, float, float]:
    """Of ``robots`` robots, how many a consistent filter has above :data:`TARGETS`
    ``nees_max`` from their start draws alone (χ²(3) each): the expected count and the
    binomial 95 % interval (lo, hi)."""
    p = float(stats.chi2.sf(TARGETS["nees_max"], 3))
    lo, hi = stats.binom.interval(0.95, robots, p)
    return p * robots, float(lo), float(hi)


def nees_means_text(episodes: Sequence[Mapping[str, Any]]) -> str:
    """Each robot's mean ``nees`` over ``episodes`` (``EpisodeResult.to_dict()``) against the
    target and the two-sided 95 % χ² band of a mean of that many χ²(3) values (a consistent
    filter's start draws alone; :func:`~polyslam_env.metrics.pose.nees_band`)."""
    means = robot_nees_means([e["robots"] for e in episodes])
    lo, hi = nees_band(3, len(episodes))
    shown = ", ".join(f"{a} {v:.2f}" for a, v in means.items())
    return (
        f"mean `nees` over the {len(episodes)} seeds: {shown} (target ≤ {TARGETS['nees_max']:g};"
        f" 95 % band of a mean of {len(episodes)} χ²(3): {lo:.2f}–{hi:.2f})"
    )


#: How many of a check's misses the markdown names (worst first; summary.json has them all).
MISSES_SHOWN = 6


def _cell(s: Mapping[str, float]) -> str:
    return f"{s['mean']:.3g} [{s['min']:.3g}, {s['max']:.3g}]"

"""The PettingZoo parallel env: PettingZoo's API battery, determinism, actions, rewards, ends."""

from __future__ import annotations

import types
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    seed_test,
)

import polyslam_env
from polyslam_env.environment.parallel import REWARD_TERMS, PolySlamParallelEnv, parallel_env
from polyslam_env.metrics.episode import ROBOT_METRIC_KEYS
from polyslam_env.render.state import RenderState

_PILLARS = {"map": "generator:pillar_hall", "num_robots": 3, "world__pillar_sensor__enabled": True}
VARIANTS = [
    pytest.param({"map": "two_rooms", "num_robots": 1}, id="two_rooms-1-vector-continuous"),
    pytest.param(
        {"map": "paper", "num_robots": 3, "observation__mode": "grid", "action__mode": "discrete"},
        id="paper-3-grid-discrete",
    ),
    pytest.param(
        {"map": "generator:rooms", "num_robots": 3, "action__mode": "discrete"},
        id="rooms-3-vector-discrete",
    ),
    pytest.param(
        {"map": "generator:cave", "num_robots": 1, "observation__mode": "grid"},
        id="cave-1-grid-continuous",
    ),
    # slam.backend: the point back-ends over the pillars (issues 17, 18)
    *(
        pytest.param(
            {**_PILLARS, "slam__backend": backend, **extra},
            id=f"pillar_hall-3-{name}",
        )
        for name, backend, extra in (
            ("fastslam2", "fastslam2", {}),
            ("em_fastslam", "em_fastslam", {}),
            ("seif", "seif", {}),
            ("seif-anonymous", "seif", {"world__pillar_sensor__identities": False}),
            ("mblcc", "mblcc", {"initial_error": False, "channel__range": 25.0}),
            ("shared", "multirobot_known_start", {"initial_error": False}),
        )
    ),
    # the map exchange with the pillar sensor on: by alignment, camera off (issue 18), and at
    # camera rendezvous (whose messages then carry no features)
    pytest.param(
        {**_PILLARS, "world__camera__enabled": False, "channel__mode": "alignment"},
        id="pillar_hall-3-alignment",
    ),
    pytest.param({**_PILLARS, "channel__range": 3.0}, id="pillar_hall-3-rendezvous"),
]


def _random_actions(env: PolySlamParallelEnv, rng: np.random.Generator) -> dict[str, Any]:
    """Seeded random actions over the full range (and beyond it, to exercise clipping)."""
    out: dict[str, Any] = {}
    for agent in env.agents:
        space = env.action_space(agent)
        if env.config.action.mode == "discrete":
            out[agent] = int(rng.integers(space.n))  # type: ignore[attr-defined]
        else:
            out[agent] = rng.uniform(-1.2, 1.2, 2) * space.high  # type: ignore[attr-defined]
    return out


def _tiny_map(tmp_path: Path, starts: list[list[float]]) -> str:
    """A 2 m × 1.5 m box with the given start poses."""
    path = tmp_path / "tiny.yaml"
    box = [[0, 0], [2, 0], [2, 1.5], [0, 1.5], [0, 0]]
    path.write_text(yaml.safe_dump({"name": "tiny", "walls": [box], "start_poses": starts}))
    return str(path)


# -- PettingZoo's test battery ----------------------------------------------------------------
@pytest.mark.parametrize("overrides", VARIANTS)
def test_env__passes_parallel_api_test(overrides: dict[str, Any]) -> None:
    env = parallel_env(max_steps=50, **overrides)
    parallel_api_test(env, num_cycles=50)


@pytest.mark.parametrize("overrides", VARIANTS[1:3])
def test_env__aec_version_passes_api_test(overrides: dict[str, Any]) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # PettingZoo reports soft API problems as warnings
        api_test(polyslam_env.env(max_steps=50, **overrides), num_cycles=50)
    # Dict observations (grid mode) legitimately draw these two; nothing else may warn.
    dict_obs = {
        "Observation is not a NumPy array",
        "Observation space for each agent probably should be gymnasium.spaces.box or"
        " gymnasium.spaces.discrete",
    }
    assert not {str(w.message) for w in caught} - dict_obs


@pytest.mark.parametrize("overrides", [VARIANTS[0], VARIANTS[2]])
def test_env__passes_parallel_seed_test(overrides: dict[str, Any]) -> None:
    parallel_seed_test(lambda: parallel_env(max_steps=50, **overrides), num_cycles=50)


@pytest.mark.parametrize("overrides", [VARIANTS[0], VARIANTS[2]])
def test_env__aec_version_passes_seed_test(overrides: dict[str, Any]) -> None:
    """PettingZoo's AEC ``seed_test(env_constructor, num_cycles)``: two envs reset with the
    same seed, stepped with the same seeded actions, agree on every agent, observation,
    reward, end and info."""
    seed_test(lambda: polyslam_env.env(max_steps=50, **overrides), num_cycles=50)


def test_env__passes_max_cycles_test() -> None:
    def par(max_cycles: int) -> PolySlamParallelEnv:
        return parallel_env(map="two_rooms", num_robots=2, max_steps=max_cycles)

    def aec(max_cycles: int) -> Any:
        return polyslam_env.env(map="two_rooms", num_robots=2, max_steps=max_cycles)

    max_cycles_test(types.SimpleNamespace(parallel_env=par, env=aec))


def test_package__exports_the_constructors() -> None:
    assert polyslam_env.parallel_env is parallel_env
    assert callable(polyslam_env.env) and not isinstance(polyslam_env.env, types.ModuleType)
    assert polyslam_env.EnvConfig().num_robots == 3


# -- determinism ------------------------------------------------------------------------------
def _rollout(seed: int, steps: int, before: int = 0) -> list[tuple[Any, ...]]:
    """The episode of ``seed``; ``before`` > 0: after an episode of another seed that long."""
    env = parallel_env(
        map="two_rooms",
        num_robots=2,
        max_steps=steps,
        coverage_target=None,
        channel__loss_prob=0.3,
    )
    if before:
        env.reset(seed=seed + 1)
        crowd = np.random.default_rng(9)
        for _ in range(before):
            env.step(_random_actions(env, crowd))
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(123)
    out: list[tuple[Any, ...]] = [({a: o.copy() for a, o in obs.items()},)]
    while env.agents:
        obs, rew, term, trunc, info = env.step(_random_actions(env, rng))
        terms = {a: i["reward_terms"] for a, i in info.items()}
        out.append((obs, rew, term, trunc, terms))
    return out


@pytest.mark.parametrize("before", [0, 60])
def test_env__same_seed_gives_bit_identical_200_step_rollouts(before: int) -> None:
    # before > 0: the second episode starts on an env that played another one on the same map
    # (a reset reuses the last world's walls: World._take_space)
    a, b = _rollout(7, 200), _rollout(7, 200, before)
    assert len(a) == len(b) == 201
    for sa, sb in zip(a, b, strict=True):
        for da, db in zip(sa, sb, strict=True):
            assert da.keys() == db.keys()
            for key in da:
                if isinstance(da[key], np.ndarray):
                    assert np.array_equal(da[key], db[key])
                else:
                    assert da[key] == db[key]
    first_obs_other_seed = _rollout(8, 1)[1][0]
    assert any(
        not np.array_equal(first_obs_other_seed[k], a[1][0][k]) for k in first_obs_other_seed
    )


def test_env__reset_without_seed_continues_a_seeded_sequence() -> None:
    e1, e2 = (parallel_env(map="generator:rooms", num_robots=1) for _ in range(2))
    e1.reset(seed=3)
    e2.reset(seed=3)
    o1, _ = e1.reset()
    o2, _ = e2.reset()
    assert np.array_equal(o1["robot_0"], o2["robot_0"])
    assert e1.episode.world.layout.segments.tolist() == e2.episode.world.layout.segments.tolist()


# -- actions ----------------------------------------------------------------------------------
def test_step__nan_or_inf_action_raises_naming_the_agent() -> None:
    env = parallel_env(map="two_rooms", num_robots=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="robot_1"):
        env.step({"robot_0": np.zeros(2), "robot_1": np.array([np.nan, 0.0])})
    with pytest.raises(ValueError, match="robot_0"):
        env.step({"robot_0": np.array([0.0, np.inf]), "robot_1": np.zeros(2)})


def test_step__unknown_or_missing_agent_raises_naming_it() -> None:
    env = parallel_env(map="two_rooms", num_robots=2)
    env.reset(seed=0)
    with pytest.raises(KeyError, match="robot_7"):
        env.step({"robot_0": np.zeros(2), "robot_1": np.zeros(2), "robot_7": np.zeros(2)})
    with pytest.raises(KeyError, match="robot_1"):
        env.step({"robot_0": np.zeros(2)})
    with pytest.raises(KeyError, match="robot_9"):
        env.action_space("robot_9")


def test_step__bad_shape_or_discrete_index_raises() -> None:
    env = parallel_env(map="two_rooms", num_robots=1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="robot_0"):
        env.step({"robot_0": np.zeros(3)})
    denv = parallel_env(map="two_rooms", num_robots=1, action__mode="discrete")
    denv.reset(seed=0)
    for bad in (7, -1, 1.5):
        with pytest.raises(ValueError, match="robot_0"):
            denv.step({"robot_0": bad})


def test_step__out_of_range_actions_are_clipped_to_the_robot_limits() -> None:
    env = parallel_env(map="two_rooms", num_robots=1)
    env.reset(seed=0)
    start = env.episode.world.poses[0].copy()
    env.step({"robot_0": np.array([50.0, 0.0])})
    moved = float(np.hypot(*(env.episode.world.poses[0, :2] - start[:2])))
    v_max, dt = env.config.world.robot.v_max, env.config.world.dt
    # The robot starts 0.5 m from the walls ahead, so one free step at v_max is exact up to
    # the physics' sub-step integration (1e-6 m is far below one sub-step's travel).
    assert moved == pytest.approx(v_max * dt, abs=1e-6)


# -- observations -----------------------------------------------------------------------------
@pytest.mark.parametrize("overrides", VARIANTS)
def test_observations__are_in_their_space_and_start_at_the_own_frame_origin(
    overrides: dict[str, Any],
) -> None:
    env = parallel_env(**overrides)
    obs, infos = env.reset(seed=1)
    layout = env._encoder.vector_layout
    for agent, o in obs.items():
        assert env.observation_space(agent).contains(o)
        vec = o["vector"] if isinstance(o, dict) else o
        # Each robot knows only its own frame: it starts at (0, 0) heading 0 whatever its true
        # start pose is (float32 of exact zeros and ones, so exact comparison).
        assert vec[layout["pose"]].tolist() == [0.0, 0.0, 1.0, 0.0]
        assert infos[agent] == {}


def test_observations__local_map_shows_own_polynomials_and_swept_space() -> None:
    env = parallel_env(map="two_rooms", num_robots=1, observation__mode="grid")
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(40):
        obs, *_ = env.step({"robot_0": rng.uniform([0.0, -0.5], [0.2, 0.5])})
    grid = obs["robot_0"]["grid"]
    assert np.all(grid.sum(axis=0) == 1.0)  # every cell is exactly one of the three classes
    assert grid[1].any()  # swept free space around the robot
    if env.episode.slams[0].n_landmarks:
        assert grid[0].any() or env.episode.slam.map_points(0).size > 0


# -- rewards ----------------------------------------------------------------------------------
def test_rewards__terms_are_in_infos_and_weighted_sum_gives_the_reward() -> None:
    env = parallel_env(map="two_rooms", num_robots=2, reward__time=0.5, reward__coverage=3.0)
    env.reset(seed=4)
    rng = np.random.default_rng(1)
    total_coverage = 0.0
    for _ in range(10):
        _, rew, _, _, info = env.step(_random_actions(env, rng))
        for agent, r in rew.items():
            terms = info[agent]["reward_terms"]
            assert tuple(terms) == REWARD_TERMS
            assert terms["time"] == -1.0
            expected = sum(getattr(env.config.reward, k) * v for k, v in terms.items())
            assert r == pytest.approx(expected, rel=1e-12)  # same sum, float rounding only
            total_coverage += terms["coverage"]
    assert total_coverage > 0.0  # moving robots sweep new free space


def test_rewards__shared_mode_gives_everyone_the_team_mean() -> None:
    env = parallel_env(map="two_rooms", num_robots=3, reward__shared=True)
    env.reset(seed=4)
    rng = np.random.default_rng(2)
    for _ in range(5):
        _, rew, _, _, _ = env.step(_random_actions(env, rng))
        assert len(set(rew.values())) == 1


def test_rewards__rendezvous_costs_bytes(tmp_path: Path) -> None:
    starts = [[0.6, 0.75, 0.0], [1.4, 0.75, np.pi]]  # 0.8 m apart, facing each other
    env = parallel_env(map=_tiny_map(tmp_path, starts), num_robots=2, coverage_target=1.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step({a: np.zeros(2) for a in env.agents})
    for agent in env.agents:
        assert info[agent]["reward_terms"]["bytes"] < 0.0
        assert (
            env.episode.exchange is not None
            and env.episode.exchange.counters(env._index[agent])["rendezvous"] == 1
        )
    obs, *_ = env.step({a: np.zeros(2) for a in env.agents})
    channel = obs["robot_0"][env._encoder.vector_layout["channel"]]
    assert channel[0] < 1.0 and channel[1] > 0.0  # met recently, once


# -- episode end ------------------------------------------------------------------------------
def _check_final_info(info: dict[str, Any]) -> None:
    assert set(info["metrics"]) == set(ROBOT_METRIC_KEYS)
    assert set(info["team"]) == {"coverage", "steps_to_50", "steps_to_90", "overlap"}


def test_episode__truncates_at_max_steps_with_metrics() -> None:
    env = parallel_env(map="two_rooms", num_robots=2, max_steps=5)
    env.reset(seed=0)
    rng = np.random.default_rng(3)
    for k in range(1, 6):
        _, _, term, trunc, info = env.step(_random_actions(env, rng))
        assert all(trunc.values()) == (k == 5)
        assert not any(term.values())
    assert env.agents == []
    for agent in env.possible_agents:
        _check_final_info(info[agent])
        assert info[agent]["metrics"]["path_length"] > 0.0
        assert np.isfinite(info[agent]["metrics"]["nees"])


def test_episode__terminates_when_team_coverage_reaches_target(tmp_path: Path) -> None:
    starts = [[0.5, 0.5, 0.0], [1.5, 1.0, np.pi]]
    env = parallel_env(map=_tiny_map(tmp_path, starts), num_robots=2, coverage_target=0.3)
    env.reset(seed=0)
    rng = np.random.default_rng(4)
    for _ in range(50):
        _, _, term, trunc, info = env.step(_random_actions(env, rng))
        if any(term.values()):
            break
    assert all(term.values()) and not any(trunc.values())
    assert env.agents == []
    team = info["robot_0"]["team"]
    assert team["coverage"] >= 0.3
    assert team["steps_to_50"] is None or team["steps_to_50"] <= env.episode.step_count


def test_faults__failed_robot_leaves_and_the_others_continue() -> None:
    env = parallel_env(map="two_rooms", num_robots=3, faults=((1, 3),), max_steps=6)
    env.reset(seed=0)
    rng = np.random.default_rng(5)
    for k in range(1, 7):
        actions = _random_actions(env, rng)
        if k > 3:
            actions["robot_1"] = np.zeros(2)  # a dead agent's action is ignored
        obs, _, term, trunc, info = env.step(actions)
        if k == 3:
            assert term["robot_1"] and not term["robot_0"] and not term["robot_2"]
            _check_final_info(info["robot_1"])
            pose_at_failure = env.episode.world.poses[1].copy()
        if k > 3:
            assert "robot_1" not in obs and "robot_1" not in info
    assert np.array_equal(env.episode.world.poses[1], pose_at_failure)
    assert not env.episode.world.active[1]
    assert all(trunc[a] for a in ("robot_0", "robot_2"))


def test_ground_truth_mode__runs_without_slam() -> None:
    env = parallel_env(map="two_rooms", num_robots=2, slam_enabled=False, max_steps=5)
    env.reset(seed=0)
    rng = np.random.default_rng(6)
    while env.agents:
        obs, _, _, _, info = env.step(_random_actions(env, rng))
        for agent, o in obs.items():
            assert env.observation_space(agent).contains(o)
    assert env.episode.slams == [] and env.episode.exchange is None
    metrics = info["robot_0"]["metrics"]
    # No SLAM: stated values and flags instead of NaN (metrics.episode.final_robot_metrics).
    assert metrics["slam"] == 0.0 and metrics["has_map"] == 0.0 and metrics["nees"] == 0.0
    assert all(np.isfinite(v) for v in metrics.values()) and metrics["coverage"] > 0.0


def test_render_state__is_built_without_a_renderer() -> None:
    env = parallel_env(map="two_rooms", num_robots=2, initial_error=False)
    env.reset(seed=0)
    env.step({a: np.array([0.2, 0.1]) for a in env.agents})
    state = env.render_state()
    assert isinstance(state, RenderState)
    assert state.true_poses.shape == state.est_poses_abs.shape == (2, 3)
    assert state.est_covs_abs.shape == (2, 3, 3)
    assert len(state.true_paths) == len(state.est_paths) == 2
    assert state.true_paths[0].shape == (2, 2)
    # estimates start at the true start pose (exact frame), so after one step they are close
    # (0.01 m: a few odometry noise sigmas of 1 mm plus one SLAM update)
    assert np.allclose(state.est_poses_abs[:, :2], state.true_poses[:, :2], atol=0.01)
    assert state.coverage.dtype == bool and state.coverage.any()
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None  # no render_mode: nothing drawn


# -- PettingZoo / Gymnasium conventions ----------------------------------------------------------
def test_env__max_cycles_is_an_alias_of_max_steps() -> None:
    assert parallel_env(map="two_rooms", num_robots=1, max_cycles=7).config.max_steps == 7
    same = parallel_env(map="two_rooms", num_robots=1, max_cycles=7, max_steps=7)
    assert same.config.max_steps == 7
    with pytest.raises(polyslam_env.ConfigError, match="max_cycles"):
        parallel_env(map="two_rooms", num_robots=1, max_cycles=7, max_steps=8)


def test_package__passes_pettingzoo_max_cycles_test_as_a_module() -> None:
    """PettingZoo's own call: ``mod.parallel_env(max_cycles=4)`` and ``mod.env(max_cycles=4)``."""
    max_cycles_test(polyslam_env)


@pytest.mark.parametrize(
    ("seed", "error"), [(-1, ValueError), ("abc", TypeError), (1.5, TypeError), (True, TypeError)]
)
def test_reset__bad_seed_raises_naming_seed(seed: Any, error: type[Exception]) -> None:
    env = parallel_env(map="two_rooms", num_robots=1)
    with pytest.raises(error, match="seed"):
        env.reset(seed=seed)


def test_reset__numpy_integer_seed_is_the_same_episode_as_int() -> None:
    a, b = (parallel_env(map="two_rooms", num_robots=1) for _ in range(2))
    np.testing.assert_array_equal(
        a.reset(seed=5)[0]["robot_0"], b.reset(seed=np.int64(5))[0]["robot_0"]
    )


def test_step__complex_action_raises_naming_the_agent() -> None:
    env = parallel_env(map="two_rooms", num_robots=2)
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning: the value is refused, not cast
        with pytest.raises(ValueError, match="robot_1.*real"):
            env.step({"robot_0": np.zeros(2), "robot_1": np.array([0.1 + 1j, 0.0])})


def test_config__fault_beyond_max_steps_is_a_named_error() -> None:
    with pytest.raises(polyslam_env.ConfigError, match=r"faults\[0\].*max_steps"):
        parallel_env(map="two_rooms", num_robots=2, max_steps=10, faults=[[1, 11]])
    parallel_env(map="two_rooms", num_robots=2, max_steps=10, faults=[[1, 10]])  # the last step


def test_gymnasium_make__module_prefixed_id_works_in_a_fresh_interpreter() -> None:
    """``gymnasium.make("polyslam_env:polyslam/Team-v0")`` imports the package itself."""
    import subprocess
    import sys

    code = (
        "import sys, gymnasium\n"
        "assert 'polyslam_env' not in sys.modules\n"
        "env = gymnasium.make('polyslam_env:polyslam/Team-v0', map='two_rooms', num_robots=1)\n"
        "obs, _ = env.reset(seed=0)\n"
        "print(type(env.unwrapped).__name__, obs.shape == env.observation_space.shape)\n"
    )
    root = str(Path(__file__).resolve().parents[2])
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["TeamEnv", "True"]


def test_episode__quick_frontier_run_raises_no_runtime_warning() -> None:
    """No-return beams (inf) must never reach arithmetic: an episode with beams into the open
    and the frontier policy's own map, with RuntimeWarning as an error."""
    from policies.base import make_team

    env = parallel_env(map="two_rooms", num_robots=2, max_steps=30)
    team = make_team("frontier", env)
    rng = np.random.default_rng(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        obs, _ = env.reset(seed=0)
        team.reset(0)
        while env.agents:
            obs, *_ = env.step(team.act(obs, rng))

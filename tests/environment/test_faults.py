"""Initial pose error and injected faults (kidnap, wheel slip, failure) of the env."""

from __future__ import annotations

import functools

import numpy as np
import pytest

import polyslam_env
from polyslam_env import parallel_env
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment.config import EnvConfig, FaultConfig
from polyslam_env.environment.parallel import PolySlamParallelEnv
from polyslam_env.slam.config import SlamConfig
from tests.stats import standard_normal_failures

SMALL = {"map": "two_rooms", "num_robots": 2, "coverage_target": None, "channel": None}


def _offsets(env: PolySlamParallelEnv) -> np.ndarray:  # (N, 3)
    """Each robot's true start in its own frame: the drawn offset e_i."""
    state = env.episode
    assert state is not None
    return between(state.start_poses, state.world.poses, wrap_remainder)


@functools.cache  # shared by the test and its mutants (read only)
def _whitened_offsets(seeds: int) -> np.ndarray:  # (2 · seeds, 3)
    """The two robots' drawn offsets over ``seeds`` resets, whitened with P0's Cholesky factor:
    z = L⁻¹e, N(0, I) if the draw is right."""
    env = parallel_env(**SMALL)
    e = np.concatenate([(env.reset(seed=s), _offsets(env))[1] for s in range(seeds)])  # (n, 3)
    return np.linalg.solve(np.linalg.cholesky(SlamConfig().p0), e.T).T


def test_initial_error__offsets_are_distributed_as_p0() -> None:
    """n = 2 × 150 whitened offsets: their mean, each axis's variance and their correlations
    (the Wishart scatter's Bartlett pieces, ``tests.stats.standard_normal_failures``), each at
    the 0.1 % tails: a correct draw fails one of the 8 checks with probability < 1 %. (The
    redraws near walls would bias this; two_rooms' starts are ≥ 0.3 m from walls, 6 σ of P0's
    5 cm.)"""
    assert standard_normal_failures(_whitened_offsets(150)) == []


def test_initial_error__correlated_offsets_fail_the_p0_checks() -> None:
    """Mutants of the same 300 draws: x and y fully correlated (y := x, each axis still N(0, 1):
    the mean and per-axis checks alone, the test before, pass it), and correlated by ρ = 0.5
    (y := ρx + √(1 − ρ²)y). The correlation check rejects a ρ of 0.5 at n = 300 with probability
    > 0.999 and of 0.3 with 0.92 (Bartlett's R₀₁ = ρ‖z₀‖ + √(1 − ρ²) N(0, 1) ≈ ρ√n against
    χ²(3)'s 0.1 % tail, 16.3; 2·10⁴ Wishart draws)."""
    z = _whitened_offsets(150)
    full = z.copy()
    full[:, 1] = full[:, 0]
    failures = standard_normal_failures(full)
    # only the correlation check fails it: the mean and per-axis checks (the test before) pass
    assert failures and all(f.startswith("correlation") for f in failures), failures
    half = z.copy()
    half[:, 1] = 0.5 * z[:, 0] + np.sqrt(0.75) * z[:, 1]
    assert any(f.startswith("correlation") for f in standard_normal_failures(half))


def test_initial_error__off_starts_exactly_at_the_frame_origin() -> None:
    env = parallel_env(**SMALL, initial_error=False)
    env.reset(seed=3)
    np.testing.assert_array_equal(_offsets(env), np.zeros((2, 3)))
    state = env.episode
    assert state is not None
    np.testing.assert_array_equal(state.histories[0].true[0], state.start_poses[0])


def test_initial_error__no_effect_without_slam() -> None:
    env = parallel_env(**SMALL, slam_enabled=False)
    env.reset(seed=3)
    np.testing.assert_array_equal(_offsets(env), np.zeros((2, 3)))


def test_initial_error__history_starts_at_the_true_pose_and_slam_at_zero() -> None:
    env = parallel_env(**SMALL)
    env.reset(seed=5)
    state = env.episode
    assert state is not None
    np.testing.assert_array_equal(state.histories[1].true[0], state.world.poses[1])
    np.testing.assert_array_equal(state.slams[1].pose, np.zeros(3))
    np.testing.assert_array_equal(state.slams[1].pose_cov, SlamConfig().p0)


def test_faults__pairs_are_fail_faults() -> None:
    cfg = EnvConfig(faults=((1, 3),))
    assert cfg.faults == (FaultConfig(kind="fail", robot=1, step=3),)
    assert EnvConfig.from_dict(cfg.to_dict()) == cfg


@pytest.mark.parametrize(
    ("fault", "match"),
    [
        ({"kind": "kidnap", "robot": 0, "step": 4}, r"faults\[1\]\.distance"),
        ({"kind": "slip", "robot": 0, "step": 4, "scale": 1.5}, r"faults\[1\]\.scale"),
        ({"kind": "slip", "robot": 0, "step": 4, "steps": 0, "scale": 0.5}, r"faults\[1\]\.steps"),
        ({"kind": "slip", "robot": 0, "step": 8, "steps": 5, "scale": 0.5}, r"faults\[1\]\.step.*"),
        ({"kind": "fail", "robot": 0, "step": 4, "scale": 0.5}, r"faults\[1\]\.scale"),
        ({"kind": "kidnap", "robot": 1, "step": 6, "distance": 1.0}, r"faults\[1\]\.step.*failed"),
        ({"kind": "jump", "robot": 0, "step": 4}, r"faults\[1\]\.kind"),
        ({"kind": "kidnap", "robot": 2, "step": 4, "distance": 1.0}, r"faults\[1\]\.robot"),
    ],
)
def test_faults__bad_entries_name_the_field(fault: dict[str, object], match: str) -> None:
    with pytest.raises(polyslam_env.ConfigError, match=match):
        EnvConfig.from_dict({"num_robots": 2, "max_steps": 10, "faults": [[1, 5], fault]})


def test_faults__overlapping_slips_of_one_robot_are_refused() -> None:
    slip = {"kind": "slip", "robot": 0, "scale": 0.5, "steps": 5}
    with pytest.raises(polyslam_env.ConfigError, match=r"faults\[1\]\.step.*overlaps"):
        EnvConfig.from_dict({"faults": [{**slip, "step": 3}, {**slip, "step": 7}]})
    EnvConfig.from_dict({"faults": [{**slip, "step": 3}, {**slip, "step": 8}]})


def _run(env: PolySlamParallelEnv, steps: int, v: float = 0.1, w: float = 0.0):
    """Step every live robot with (v, ω); yield (step, infos, world poses before, after)."""
    state = env.episode
    assert state is not None
    for k in range(1, steps + 1):
        before = state.world.poses
        _, _, _, _, infos = env.step({a: np.array([v, w]) for a in env.agents})
        yield k, infos, before, state.world.poses


def test_kidnap__true_pose_jumps_by_the_distance_and_odometry_does_not_see_it() -> None:
    kidnap = {"kind": "kidnap", "robot": 0, "step": 3, "distance": 0.5, "angle": 0.3}
    env = parallel_env(**SMALL, faults=[kidnap], max_steps=4)
    env.reset(seed=2)
    state = env.episode
    assert state is not None
    for k, infos, before, after in _run(env, 4, v=0.0):  # standing still: any move is the jump
        jump = after[0] - before[0]
        if k == 3:
            assert np.hypot(jump[0], jump[1]) == pytest.approx(0.5, abs=1e-9)
            assert wrap_remainder(jump[2]) == pytest.approx(0.3, abs=1e-9)
            (event,) = infos["robot_0"]["faults"]
            assert event["kind"] == "kidnap" and event["done"] and event["step"] == 3
        else:
            np.testing.assert_allclose(jump, 0.0, atol=1e-12)
            assert "faults" not in infos["robot_0"]
        assert "faults" not in infos["robot_1"]


def test_slip__robot_moves_scale_times_what_odometry_reports() -> None:
    """With odometry noise off, the reported displacement is exactly the true one / scale
    (straight driving, so no arc approximation is involved)."""
    slip = {"kind": "slip", "robot": 1, "step": 2, "scale": 0.5, "steps": 2}
    env = parallel_env(
        **SMALL,
        faults=[slip],
        max_steps=4,
        world__odometry__sigma_xy=0.0,
        world__odometry__sigma_theta_deg=0.0,
    )
    env.reset(seed=1)
    state = env.episode
    assert state is not None
    world = state.world
    for k in range(1, 5):
        start = world.poses
        result = world.step(np.array([[0.05, 0.0], [0.05, 0.0]]), env._faults.slip(k))
        true = between(start, world.poses)
        scale = 0.5 if k in (2, 3) else 1.0
        np.testing.assert_allclose(result.odometry[1] * scale, true[1], atol=1e-12)
        np.testing.assert_allclose(result.odometry[0], true[0], atol=1e-12)
        assert np.hypot(*true[1, :2]) == pytest.approx(0.05 * scale, rel=1e-6)


def test_slip__reported_in_infos_at_its_first_step() -> None:
    slip = {"kind": "slip", "robot": 1, "step": 2, "scale": 0.5, "steps": 2}
    env = parallel_env(**SMALL, faults=[slip, [0, 3]], max_steps=4)
    env.reset(seed=1)
    seen = {k: infos for k, infos, _, _ in _run(env, 3)}
    assert seen[2]["robot_1"]["faults"] == [
        {"kind": "slip", "robot": 1, "step": 2, "last_step": 3, "scale": 0.5}
    ]
    assert seen[3]["robot_0"]["faults"] == [{"kind": "fail", "robot": 0, "step": 3}]
    assert all("faults" not in i for k in (1, 3) for a, i in seen[k].items() if a == "robot_1")


def test_kidnap__lands_in_free_space_clear_of_walls() -> None:
    """Seeded 1 m kidnaps on generated caves (rocks inside): the new true pose is a free cell
    of the coverage grid (never inside a rock) with the clearance a start pose needs."""
    kidnap = {"kind": "kidnap", "robot": 0, "step": 1, "distance": 1.0}
    env = parallel_env(map="generator:cave", num_robots=1, faults=[kidnap], max_steps=1)
    for seed in range(10):
        env.reset(seed=seed)
        _, _, _, _, infos = env.step({"robot_0": np.zeros(2)})
        state = env.episode
        assert state is not None
        world, cov = state.world, state.coverage
        xy = world.poses[:, :2]
        (event,) = infos["robot_0"]["faults"]
        if not event["done"]:
            continue
        row, col, inside = cov.cells_of(xy)
        assert inside[0] and cov.free[row[0], col[0]]
        need = world.config.robot.radius + world.config.wall_radius
        assert world.layout.clearance(xy)[0] >= need

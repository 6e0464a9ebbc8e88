"""The episode state and the step's stages, and that ``simulate`` runs the same stages."""

from __future__ import annotations

import types

import numpy as np
import pytest

from polyslam_env.apps.simulate import simulate
from polyslam_env.core.seeding import make_rngs
from polyslam_env.environment import stages
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.scenarios.paths import load_paths
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import point_segment_distance
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World


def test_env__has_no_episode_before_reset_and_render_raises() -> None:
    env = parallel_env(map="two_rooms", num_robots=1, render_mode="rgb_array")
    assert env.episode is None
    with pytest.raises(RuntimeError, match="before reset"):
        env.render()
    with pytest.raises(RuntimeError, match="before reset"):
        env.render_state()
    with pytest.raises(RuntimeError, match="reset"):
        env.step({"robot_0": np.zeros(2)})
    env.reset(seed=0)
    assert env.episode is not None and env.episode.step_count == 0
    env.close()


def test_env__pettingzoo_global_state_method_is_not_shadowed() -> None:
    env = parallel_env(map="two_rooms", num_robots=1)
    env.reset(seed=0)
    with pytest.raises(NotImplementedError):
        env.state()


def test_reset__makes_a_new_episode_state_each_time() -> None:
    env = parallel_env(map="two_rooms", num_robots=2)
    env.reset(seed=0)
    first = env.episode
    env.step({a: np.array([0.1, 0.0]) for a in env.agents})
    env.reset(seed=0)
    assert env.episode is not first
    assert env.episode is not None and env.episode.step_count == 0
    assert len(env.episode.coverage_series) == 1
    assert all(len(h.true) == 1 for h in env.episode.histories)


def test_sense__noisy_ranges_are_exactly_those_of_scan_and_truth_of_true_scan() -> None:
    layout, cfg = load_map("two_rooms"), WorldConfig()
    a, b = (World(layout, cfg, 2, make_rngs(3)) for _ in range(2))
    for _ in range(3):
        got = stages.sense(a)
        np.testing.assert_array_equal(got.true_ranges, b.true_scan())
        np.testing.assert_array_equal(got.ranges, b.scan())
        assert got.detections == b.camera()
        commands = np.array([[0.1, 0.2], [0.05, -0.1]])
        a.step(commands)
        b.step(commands)


def test_sense__without_camera_draws_nothing_from_the_camera_stream() -> None:
    layout, cfg = load_map("two_rooms"), WorldConfig()
    a, b = (World(layout, cfg, 2, make_rngs(4)) for _ in range(2))
    assert stages.sense(a, camera=False).detections == [[], []]
    stages.sense(b, camera=False)
    assert stages.sense(a).detections == b.camera()


def test_record__hit_points_are_the_true_points_the_beams_hit() -> None:
    result = simulate("two_rooms", num_robots=1, steps=30, seed=2)
    hits = result.runs[0].hit_points
    assert len(hits) > 0
    layout = result.layout
    walls = point_segment_distance(hits, layout.segments).min(axis=1)
    centres, radii = layout.pillars[:, :2], layout.pillars[:, 2]
    pillars = np.abs(np.linalg.norm(hits[:, None] - centres, axis=-1) - radii).min(axis=1)
    assert np.minimum(walls, pillars).max() < 1e-9


def test_record__hits_read_later_are_the_step_by_step_placement_bit_for_bit() -> None:
    """The history keeps the true ranges and places them when read: the same floats as
    placing every step's hits with that step's true poses (the record's former form)."""
    from polyslam_env.core.geometry import beam_endpoints

    env = parallel_env(map="two_rooms", num_robots=2, slam_enabled=False, max_steps=60)
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    expected: list[list[np.ndarray]] = [[], []]
    while env.agents:
        env.step({a: rng.uniform(-1.0, 1.0, 2) for a in env.agents})
        state = env.episode
        assert state is not None
        poses, true = state.world.poses, state.sensing.true_ranges
        ok = np.isfinite(true)
        phi = poses[:, 2:3] + state.world.range_sensor.angles
        ends = beam_endpoints(poses[:, None, :2], phi, np.where(ok, true, 0.0))
        for i in range(2):
            expected[i].append(ends[i][ok[i]])
    state = env.episode
    assert state is not None
    for i in range(2):
        want = np.concatenate(expected[i])
        assert len(want) > 100  # the beams hit walls on most steps
        np.testing.assert_array_equal(state.history.hits(i), want, strict=True)


def test_simulate_and_env__same_seed_and_commands_give_identical_histories() -> None:
    """simulate and the env run the same stages (exchange off: the env's reset also takes a
    camera frame for the first observation, which simulate does not)."""
    steps = 40
    env = parallel_env(
        map="paper", channel=None, max_steps=steps, coverage_target=1.0, initial_error=False
    )
    commands = load_paths("paper").commands
    env.reset(seed=5)
    for k in range(steps):
        env.step({f"robot_{i}": commands[i, k] for i in range(3)})
    episode = env.episode
    assert episode is not None
    result = simulate(
        "paper",
        seed=5,
        steps=steps,
        world_config=env.config.world,
        slam_config=env.config.slam,
    )
    for history, slam, run in zip(episode.histories, episode.slams, result.runs, strict=True):
        mine = history.run(slam.polynomials())
        for name in ("true_poses", "est_poses", "est_covs", "hit_points"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(run, name), err_msg=name)
        assert mine.collisions == run.collisions
        assert len(mine.polynomials) == len(run.polynomials)


def test_simulate__step_numbers_are_one_based_like_the_env() -> None:
    done: list[int] = []
    result = simulate("paper", seed=0, exchange=True, progress=done.append)
    assert done == list(range(1, result.steps + 1))
    messages = result.meta["exchange"]
    assert messages
    assert all(1 <= m["sent_step"] <= m["delivered_step"] <= result.steps for m in messages)


def _se2(pose: np.ndarray) -> np.ndarray:  # (3, 3)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array([[c, -s, pose[0]], [s, c, pose[1]], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("seed", range(5))
def test_true_transform__is_the_senders_true_start_seen_from_the_receivers(seed: int) -> None:
    """``stages._true_transform``, the truth of every ``alignments_wrong`` count, against an
    independent computation: with M(x) the homogeneous matrix of pose x and s_i robot i's true
    start (where its SLAM's frame is), the transform of the sender's frame into the receiver's
    is M(s_r)⁻¹ M(s_s), and it carries a world point's coordinates in the sender's frame to its
    coordinates in the receiver's. Real episode states with the start offset on, so the true
    starts are not the nominal frames (a transform between the nominal frames, or the inverse
    one, misses by the 5 cm / 1° offsets, far beyond rounding)."""
    env = parallel_env(map="generator:rooms", num_robots=3, initial_error=True)
    env.reset(seed=seed)
    state = env.episode
    assert state is not None
    starts = state.world.poses  # (3, 3): the true starts, before any step
    point = np.array([1.3, -0.4, 1.0])  # a world point, homogeneous
    for sender, receiver in ((0, 1), (2, 0), (1, 2)):
        attempt = types.SimpleNamespace(sender=sender, receiver=receiver)
        got = stages._true_transform(state, attempt)  # type: ignore[arg-type]
        m = np.linalg.solve(_se2(starts[receiver]), _se2(starts[sender]))
        want = np.array([m[0, 2], m[1, 2], np.arctan2(m[1, 0], m[0, 0])])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)  # rounding of unit-scale trig
        in_sender = np.linalg.solve(_se2(starts[sender]), point)
        in_receiver = np.linalg.solve(_se2(starts[receiver]), point)
        np.testing.assert_allclose(_se2(got) @ in_sender, in_receiver, rtol=0, atol=1e-12)
        # the mutants, nominal frames instead of true starts and the inverse transform, fail the
        # first check
        frames = state.start_poses
        nominal = np.linalg.solve(_se2(frames[receiver]), _se2(frames[sender]))
        assert np.abs(nominal[:2, 2] - want[:2]).max() > 1e-12
        swapped = types.SimpleNamespace(sender=receiver, receiver=sender)
        inverse = stages._true_transform(state, swapped)  # type: ignore[arg-type]
        assert np.abs(inverse - want).max() > 1e-12

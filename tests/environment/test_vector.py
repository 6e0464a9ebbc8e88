"""The SuperSuit/SB3 parameter-sharing path: the adapter, black death by design, PPO."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import pytest
import supersuit as ss
from stable_baselines3 import PPO

from polyslam_env.environment.parallel import parallel_env
from polyslam_env.environment.vector import FixedAgents, make_vec_env

SMALL: dict[str, Any] = {"map": "two_rooms", "num_robots": 2, "max_steps": 8}


def _adapter(num_envs: int = 2, num_cpus: int = 0, **overrides: Any) -> Any:
    return make_vec_env({**SMALL, **overrides}, num_envs, num_cpus=num_cpus, monitor=False)


def test_raw_supersuit__ppo_with_seed_fails_without_the_adapter() -> None:
    """Documents why the adapter exists; if this starts passing, SuperSuit fixed it."""
    markov = ss.pettingzoo_env_to_vec_env_v1(FixedAgents(parallel_env(SMALL)))
    venv = ss.concat_vec_envs_v1(markov, 1, base_class="stable_baselines3")
    with pytest.raises(AttributeError, match="seed"):
        PPO("MlpPolicy", venv, seed=0, n_steps=8, batch_size=8)


def test_adapter_seed__gives_per_slot_seeds_and_seeds_the_next_reset() -> None:
    venv = _adapter()
    assert list(venv.seed(7)) == [7, 8, 9, 10]  # SB3's convention: seed + slot index
    obs = venv.reset()
    assert venv._seeds == [None] * 4  # used once, as in SB3
    ref, _ = parallel_env(SMALL).reset(seed=7)  # sub-env 0 gets the seed itself
    np.testing.assert_array_equal(obs[0], ref["robot_0"])
    np.testing.assert_array_equal(obs[1], ref["robot_1"])
    other = _adapter()
    other.seed(7)
    np.testing.assert_array_equal(other.reset(), obs)
    venv.close()
    other.close()


def test_adapter__sb3_vecenv_queries_answer_per_slot() -> None:
    venv = _adapter()
    assert venv.get_attr("render_mode") == [None] * 4
    assert venv.render_mode is None
    assert venv.env_is_wrapped(gymnasium.Wrapper) == [False] * 4
    assert venv.env_is_wrapped(gymnasium.Wrapper, indices=[1]) == [False]
    venv.close()


def test_ppo__learns_a_few_hundred_steps_through_supersuit() -> None:
    venv = make_vec_env(SMALL, 2, seed=0)
    model = PPO("MlpPolicy", venv, seed=0, n_steps=32, batch_size=64, n_epochs=1)
    model.learn(256)
    assert model.num_timesteps >= 256
    assert len(model.ep_info_buffer) > 0  # VecMonitor saw whole (8-step) episodes
    venv.close()


def test_vec_path__fault_injection_keeps_slots_and_ends_episodes_cleanly() -> None:
    venv = _adapter(num_envs=1, faults=[[1, 3]])
    venv.seed(0)
    first = venv.reset()
    forward = np.array([[0.5, 0.0], [0.5, 0.0]], dtype=np.float32)
    for k in range(1, 9):
        obs, rewards, dones, infos = venv.step(forward)
        if k < 3:
            assert not dones.any()
        elif k == 3:  # robot_1 fails: its slot's episode ends (terminated, no bootstrap)
            assert dones.tolist() == [False, True]
            assert not infos[1]["TimeLimit.truncated"]
            assert infos[1]["terminal_observation"].shape == first[1].shape
            assert np.all(obs[1] == 0.0)
        elif k < 8:  # the dead slot is zeros, reward 0, not done
            assert dones.tolist() == [False, False]
            assert np.all(obs[1] == 0.0) and rewards[1] == 0.0
        else:  # max_steps: robot_0 truncated (bootstrap), everything auto-resets
            assert dones.tolist() == [True, True]
            assert infos[0]["TimeLimit.truncated"]
            assert "team" in infos[0]
            assert np.any(obs[1] != 0.0)  # the failed robot is back after the reset
    venv.close()


def test_vec_path__worker_processes_give_the_same_rollout() -> None:
    """Three copies on two workers (two on the first: SuperSuit's own split seeded the third
    like the second) play what they play in one process, although each worker first plays
    a step of its own to load its kernels."""
    actions = np.random.default_rng(0).uniform(-1, 1, (5, 6, 2)).astype(np.float32)
    results = []
    for cpus in (0, 2):
        venv = _adapter(num_envs=3, num_cpus=cpus)
        venv.seed(3)
        obs = [venv.reset()]
        assert len(venv.reset_infos) == 6 and all(isinstance(i, dict) for i in venv.reset_infos)
        venv.seed(3)
        obs = [venv.reset()]
        obs += [venv.step(a)[0] for a in actions]
        results.append(np.array(obs))
        venv.close()
    np.testing.assert_array_equal(results[0], results[1])
    assert not np.array_equal(results[0][:, 2:4], results[0][:, 4:6])  # copies 1, 2: own seeds


def test_fixed_agents__maps_the_unit_box_to_physical_limits() -> None:
    env = FixedAgents(parallel_env(SMALL))
    high = env.unwrapped.action_space("robot_0").high
    np.testing.assert_allclose(env.physical(np.array([1.0, -1.0])), [high[0], -high[1]])
    np.testing.assert_allclose(env.physical(np.array([0.0, 0.0])), [0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(env.physical(np.array([3.0, 0.0]))[0], high[0])  # clipped


def _run_past_one_episode_end(venv: Any, slots: int, action_dim: int) -> None:
    """Reset, step a vectorised env with zero actions past ``max_steps``, close: every slot
    ends exactly once (truncated at max_steps, then reset automatically)."""
    obs = venv.reset()
    assert obs.shape == (slots, *venv.observation_space.shape)
    ends = 0
    for _ in range(SMALL["max_steps"] + 2):
        obs, rewards, dones, infos = venv.step(np.zeros((slots, action_dim), dtype=np.float32))
        assert obs.shape[0] == rewards.shape[0] == len(infos) == slots
        ends += int(dones.all())
    assert ends == 1
    venv.close()


def test_vec_path__two_worker_processes_build_reset_step_and_close() -> None:
    """What ``polyslam train`` builds with ``num_cpus=2`` (VecMonitor on top), through an
    episode end and its automatic reset."""
    venv = make_vec_env(SMALL, 2, num_cpus=2, seed=1)
    _run_past_one_episode_end(venv, slots=4, action_dim=2)


def test_sb3_subproc_vec_env__two_workers_of_the_team_env() -> None:
    from stable_baselines3.common.vec_env import SubprocVecEnv

    from polyslam_env.environment.team import TeamEnv

    venv = SubprocVecEnv([lambda: TeamEnv(**SMALL) for _ in range(2)])
    venv.seed(3)
    _run_past_one_episode_end(venv, slots=2, action_dim=4)

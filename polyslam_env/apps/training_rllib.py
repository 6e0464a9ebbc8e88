"""PPO training with RLlib (``polyslam train --backend rllib``, the ``ray`` extra).

RLlib's new API stack: the PettingZoo parallel env is wrapped in
``ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv``, and one RLModule,
``"shared"``, drives every robot (``multi_agent(policies={"shared"}, policy_mapping_fn=...)``),
the same parameter sharing as the SB3 path. Sampling runs in ``cfg.num_cpus`` env runners
(Ray actors); learning runs in this process (one local learner).

Ray is either started here, sized for this machine (``num_cpus`` = the env runners, at
least 1; no dashboard; workers' logs not forwarded), or joined with ``address``
(``--address`` / ``RAY_ADDRESS``; then the cluster must reach this package: ``PYTHONPATH`` is
passed to the workers through the job's runtime env).

Checkpoints are directories ``OUT/checkpoints/rllib_<timesteps>_steps`` written by
``Algorithm.save_to_path`` into a temporary sibling that is then renamed (a kill mid-write
leaves no partial ``rllib_*`` directory). ``resume`` restores the newest one that loads (a
damaged newer one is skipped, and said so on stderr). On SIGTERM the current ``algo.train()``
iteration finishes, a checkpoint is saved and
:class:`~polyslam_env.apps.training.TrainingTerminated` is raised, as on the SB3 path.
TensorBoard (``OUT/tb``) gets the SB3 path's ``polyslam/`` scalars per iteration, averaged over
the episodes that ended in it (:func:`~polyslam_env.apps.training.episode_scalars`, collected
by an RLlib callback in the env runners). Timesteps count robot-steps (RLlib's agent steps),
as the SB3 path does.

The :class:`~polyslam_env.apps.training.TrainConfig` fields RLlib uses: ``timesteps``,
``num_envs`` (env copies, spread over the env runners), ``num_cpus`` (env runners; 0: sample
in this process), ``seed``, ``checkpoint_every``, ``eval_episodes``, ``torch_threads``,
``env``, and of ``ppo``: ``learning_rate`` (lr), ``n_steps`` (a train batch is ``n_steps ·
num_envs`` env steps, i.e. the SB3 rollout), ``batch_size`` (minibatch, in agent steps),
``n_epochs``, ``gamma``, ``gae_lambda``, ``clip_range``, ``ent_coef``, ``vf_coef``,
``max_grad_norm`` and ``net_arch`` (``fcnet_hiddens``). ``log_std_init`` is not used (RLlib
starts the Gaussian's log std at its default).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.cluster import init_ray, require_ray
from polyslam_env.apps.training import (
    EPISODE_TAGS,
    EVAL_SEED,
    TrainConfig,
    TrainingTerminated,
    checkpoints,
    episode_scalars,
    evaluate_coverage,
)
from polyslam_env.core.errors import PolyslamError
from polyslam_env.environment.config import EnvConfig

__all__ = [
    "ENV_NAME",
    "MODULE_ID",
    "RLlibTeam",
    "build_algorithm_config",
    "check_run_folder",
    "final_evaluation",
    "load_team",
    "require_ray",
    "rllib_checkpoints",
    "train",
]

#: The name the env is registered under with Ray Tune's registry.
ENV_NAME = "polyslam_parallel"
#: The one RLModule (policy) every robot maps to.
MODULE_ID = "shared"
CHECKPOINT_PREFIX = "rllib"
#: What a whole checkpoint directory holds (``Algorithm.save_to_path``), the network included.
CHECKPOINT_PARTS = (
    "rllib_checkpoint.json",
    "algorithm_state.pkl",
    f"learner_group/learner/rl_module/{MODULE_ID}",
)
_CHECKPOINT_RE = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps$")


# -- checkpoints -----------------------------------------------------------------------------
def rllib_checkpoints(folder: str | Path) -> list[tuple[int, Path]]:
    """``(timesteps, path)`` of the RLlib checkpoint directories in ``folder``, oldest first."""
    return checkpoints(folder, _CHECKPOINT_RE, dirs=True)


def check_run_folder(out: str | Path, resume: bool) -> None:
    """One run per output folder (as the SB3 path): ``resume`` needs an RLlib checkpoint
    there; a fresh run needs no checkpoint of either backend."""
    ckpt_dir = Path(out) / "checkpoints"
    found = rllib_checkpoints(ckpt_dir)
    if resume and not found:
        raise PolyslamError(f"--resume: no RLlib checkpoint (rllib_*_steps/) in {ckpt_dir}")
    if not resume and (found or checkpoints(ckpt_dir)):
        raise PolyslamError(
            f"{out}: already holds a training run (checkpoints in checkpoints/); continue it"
            " with --resume (same backend), or train into a new --out folder"
        )


def save_checkpoint(algo: Any, folder: Path, timesteps: int) -> Path:
    """``algo.save_to_path`` into a temporary directory next to the final name, then rename
    it (the rename is atomic on one file system; an existing name is replaced)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{CHECKPOINT_PREFIX}_{timesteps}_steps"
    tmp = folder / f".{path.name}.{os.getpid()}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        algo.save_to_path(str(tmp))
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


# -- the env and the algorithm ---------------------------------------------------------------
def _make_env(env_config: dict[str, Any]) -> Any:
    """The RLlib env: :func:`parallel_env` of an :class:`EnvConfig` dict, wrapped."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from polyslam_env.environment.parallel import parallel_env

    return ParallelPettingZooEnv(parallel_env(EnvConfig.from_dict(dict(env_config))))


def _map_to_shared(agent_id: Any, *args: Any, **kwargs: Any) -> str:
    return MODULE_ID


def _callbacks() -> type:
    """The RLlib callback that logs :func:`episode_scalars` of every finished episode: per
    tag its sum and count (``reduce="sum"``: summed over the env runners and the episodes of
    one iteration), read back by :func:`_log_episodes`."""
    from ray.rllib.callbacks.callbacks import RLlibCallback

    class EpisodeMetrics(RLlibCallback):
        def on_episode_end(self, *, episode: Any, metrics_logger: Any = None, **_: Any) -> None:
            robots, team = [], None
            for agent_episode in episode.agent_episodes.values():
                info = agent_episode.get_infos(-1) if len(agent_episode) else {}
                if "metrics" in info:
                    robots.append(info["metrics"])
                team = team or info.get("team")
            if team is None or metrics_logger is None:
                return
            for tag, value in episode_scalars(team, robots).items():
                metrics_logger.log_value(("polyslam", tag), value, reduce="sum")
                metrics_logger.log_value(("polyslam", f"{tag}_n"), 1, reduce="sum")

    return EpisodeMetrics


def _log_episodes(writer: Any, result: dict[str, Any], step: int, episodes: int) -> int:
    """Write this iteration's ``polyslam/`` means to TensorBoard at ``step``; the running
    count of episodes after it."""
    sums = result.get("env_runners", {}).get("polyslam", {})

    def count(key: str) -> int:  # an iteration that logged nothing reports NaN (or nothing)
        value = float(sums.get(key, 0.0) or 0.0)
        return int(value) if math.isfinite(value) else 0

    ended = count("team_coverage_n")
    if ended == 0:
        return episodes
    for tag in EPISODE_TAGS:
        n = count(f"{tag}_n")
        if tag != "episodes" and n > 0:
            writer.add_scalar(f"polyslam/{tag}", float(sums[tag]) / n, step)
    episodes += ended
    writer.add_scalar("polyslam/episodes", episodes, step)
    writer.flush()
    return episodes


def build_algorithm_config(cfg: TrainConfig) -> Any:
    """RLlib's ``PPOConfig`` for ``cfg`` (see the module docstring for the fields used)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    runners = cfg.num_cpus
    envs_per_runner = max(1, math.ceil(cfg.num_envs / max(1, runners)))
    env_steps_per_batch = cfg.ppo.n_steps * envs_per_runner * max(1, runners)
    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=cfg.env.to_dict())
        .multi_agent(policies={MODULE_ID}, policy_mapping_fn=_map_to_shared)
        .env_runners(
            num_env_runners=runners,
            num_envs_per_env_runner=envs_per_runner,
            num_cpus_per_env_runner=1,
            rollout_fragment_length="auto",
        )
        .learners(num_learners=0)
        .training(
            lr=cfg.ppo.learning_rate,
            gamma=cfg.ppo.gamma,
            lambda_=cfg.ppo.gae_lambda,
            clip_param=cfg.ppo.clip_range,
            entropy_coeff=cfg.ppo.ent_coef,
            vf_loss_coeff=cfg.ppo.vf_coef,
            grad_clip=cfg.ppo.max_grad_norm,
            num_epochs=cfg.ppo.n_epochs,
            minibatch_size=cfg.ppo.batch_size,
            train_batch_size_per_learner=env_steps_per_batch,
        )
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=list(cfg.ppo.net_arch)))
        .callbacks(_callbacks())
        .debugging(seed=cfg.seed, log_level="ERROR")
    )


def _lifetime(result: dict[str, Any], key: str) -> int:
    value = result.get("env_runners", {}).get(key, 0)
    if isinstance(value, dict):
        value = sum(value.values())
    return int(value or 0)


def _sampled(result: dict[str, Any]) -> int:
    """Env steps sampled in this iteration."""
    return _lifetime(result, "num_env_steps_sampled")


def _train_loop(
    algo: Any,
    cfg: TrainConfig,
    ckpt_dir: Path,
    progress: bool,
    say: Callable[[str], None],
    stop: threading.Event,
    writer: Any,
) -> tuple[int, Path, dict[str, Any]]:
    """``algo.train()`` until ``cfg.timesteps`` agent steps, checkpointing on the way and
    logging each iteration's episodes to ``writer`` (TensorBoard); after ``stop`` is set,
    checkpoint and raise :class:`TrainingTerminated`."""
    start = time.perf_counter()
    episodes = 0
    agent_steps = env_steps = iterations = 0
    sample_s = 0.0  # RLlib's sampling timer (the wall time of the env runners' sample step)
    env_steps_before: int | None = None
    next_ckpt: int | None = None
    while True:
        result = algo.train()
        iterations += 1
        agent_steps = _lifetime(result, "num_agent_steps_sampled_lifetime")
        env_steps = _lifetime(result, "num_env_steps_sampled_lifetime")
        sample_s += float(result.get("timers", {}).get("env_runner_sampling_timer", 0.0))
        episodes = _log_episodes(writer, result, agent_steps, episodes)
        if env_steps_before is None:  # a resumed run counts from its checkpoint
            env_steps_before = env_steps - _sampled(result)
        if next_ckpt is None:  # the first multiple above the steps before this iteration
            before = agent_steps - _lifetime(result, "num_agent_steps_sampled")
            next_ckpt = (before // cfg.checkpoint_every + 1) * cfg.checkpoint_every
        if progress:
            ret = result.get("env_runners", {}).get("episode_return_mean", float("nan"))
            say(
                f"iteration {iterations}: {agent_steps}/{cfg.timesteps} timesteps"
                f" ({env_steps} env steps), episode return mean {ret:.3f},"
                f" {time.perf_counter() - start:.1f} s"
            )
        if agent_steps >= cfg.timesteps:
            break
        if stop.is_set():
            raise TrainingTerminated(save_checkpoint(algo, ckpt_dir, agent_steps), agent_steps)
        if agent_steps >= next_ckpt:
            save_checkpoint(algo, ckpt_dir, agent_steps)
            next_ckpt = (agent_steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
    seconds = time.perf_counter() - start
    last = save_checkpoint(algo, ckpt_dir, agent_steps)
    stats = {
        "iterations": iterations,
        "agent_steps": agent_steps,
        "env_steps": env_steps - (env_steps_before or 0),
        "train_s": seconds,
        "sample_s": sample_s,
    }
    return agent_steps, last, stats


def train(
    cfg: TrainConfig,
    out: str | Path,
    resume: bool = False,
    address: str | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple[int, Path, dict[str, Any]]:
    """Train until ``cfg.timesteps`` robot-steps; return them, the last checkpoint and
    throughput figures: ``env_steps`` sampled by this call, ``agent_steps`` (lifetime),
    ``train_s`` (wall time of the ``algo.train()`` loop: sampling and learning),
    ``sample_s`` (RLlib's sampling timer summed over the iterations) and ``iterations``.

    Ray is shut down on return (and on errors) if this call started or joined it.
    """
    import ray
    import torch
    from ray.tune.registry import register_env
    from torch.utils.tensorboard import SummaryWriter

    out = Path(out)
    ckpt_dir = out / "checkpoints"
    check_run_folder(out, resume)
    say = log or (lambda line: print(line, flush=True))
    torch.set_num_threads(cfg.torch_threads)
    if resume:
        steps, path = rllib_checkpoints(ckpt_dir)[-1]
        if steps >= cfg.timesteps:  # as the SB3 path: nothing left to learn, Ray not needed
            say(f"--resume: {path} already has {steps} >= {cfg.timesteps} timesteps")
            return steps, path, {"iterations": 0, "agent_steps": steps, "env_steps": 0}
    started = not ray.is_initialized()
    stop = threading.Event()
    installed, previous = False, None
    try:
        if started:
            init_ray(address, max(1, cfg.num_cpus))
        if threading.current_thread() is threading.main_thread():
            # after ray.init, which installs a C-level SIGTERM handler of its own that exits
            previous = signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
            installed = True
        register_env(ENV_NAME, _make_env)
        if resume:  # the checkpoint's algorithm config is kept; the YAML's PPO part is not used
            algo = _restore_newest(ckpt_dir, say)
        else:
            algo = build_algorithm_config(cfg).build_algo()
        try:
            with SummaryWriter(str(out / "tb" / f"rllib_{os.getpid()}_{time.time_ns()}")) as tb:
                return _train_loop(algo, cfg, ckpt_dir, progress, say, stop, tb)
        finally:
            algo.stop()
    finally:
        if started:
            ray.shutdown()
        if installed:
            signal.signal(signal.SIGTERM, previous)


def _restore_newest(ckpt_dir: Path, say: Callable[[str], None]) -> Any:
    """The algorithm of the newest checkpoint in ``ckpt_dir`` that loads; damaged newer ones
    are skipped, and the skips reported on stderr (as the SB3 path's ``--resume``)."""
    from ray.rllib.algorithms.algorithm import Algorithm

    skipped = []
    for steps, path in reversed(rllib_checkpoints(ckpt_dir)):
        missing = [part for part in CHECKPOINT_PARTS if not (path / part).exists()]
        if missing:  # RLlib restores without a missing part, silently
            skipped.append(f"checkpoint {str(path)!r}: {missing[0]} is missing")
            continue
        try:
            algo = Algorithm.from_checkpoint(str(path))
        except Exception as err:  # RLlib raises many kinds on a damaged directory
            skipped.append(f"checkpoint {str(path)!r}: cannot load ({type(err).__name__})")
            continue
        for reason in skipped:
            print(f"--resume: skipped {reason}", file=sys.stderr)
        say(f"--resume: restoring {path} ({steps} timesteps)")
        return algo
    raise PolyslamError(
        f"--resume: no readable RLlib checkpoint in {ckpt_dir} ({len(skipped)} damaged:"
        f" {skipped[0] if skipped else 'none'})"
    )


# -- evaluation ------------------------------------------------------------------------------
class RLlibTeam:
    """Acts for every robot with the trained RLModule, deterministically: the mean of its
    Gaussian, mapped from RLlib's normalised [-1, 1] box to the action space (as RLlib's
    ``normalize_actions`` does) and clipped. Duck-types :class:`policies.base.TeamPolicy`."""

    def __init__(self, module: Any, action_space: Any) -> None:
        self.module = module
        self.action_space = action_space

    def reset(self, seed: int | None = None) -> None:
        """Stateless (an MLP)."""

    def act(self, observations: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        import torch
        from ray.rllib.utils.spaces.space_utils import unsquash_action

        agents = list(observations)
        if not agents:
            return {}
        obs = torch.as_tensor(np.stack([observations[a] for a in agents]), dtype=torch.float32)
        with torch.no_grad():
            out = self.module.forward_inference({"obs": obs})
        inputs = out["action_dist_inputs"].numpy()
        mean = inputs[:, : inputs.shape[1] // 2]
        low, high = self.action_space.low, self.action_space.high
        actions = {}
        for agent, m in zip(agents, mean, strict=True):
            a = np.clip(unsquash_action(m, self.action_space), low, high)
            actions[agent] = a.astype(self.action_space.dtype)
        return actions


def load_team(checkpoint: str | Path, env_cfg: EnvConfig) -> RLlibTeam:
    """The shared RLModule of an RLlib checkpoint, without Ray running (it is plain torch)."""
    from ray.rllib.core.rl_module.rl_module import RLModule

    from polyslam_env.environment.parallel import parallel_env

    path = Path(checkpoint) / "learner_group" / "learner" / "rl_module" / MODULE_ID
    if not path.is_dir():
        raise PolyslamError(f"{checkpoint}: not an RLlib checkpoint with module {MODULE_ID!r}")
    module = RLModule.from_checkpoint(str(path))
    env = parallel_env(env_cfg)
    space = env.action_space(env.possible_agents[0])
    env.close()
    return RLlibTeam(module, space)


def final_evaluation(cfg: TrainConfig, checkpoint: Path, timesteps: int) -> dict[str, Any]:
    """The trained shared module vs the registered ``random`` policy on the same seeds
    (the SB3 path's :func:`polyslam_env.apps.training.final_evaluation`, key ``rllib``)."""
    start = time.perf_counter()
    team = load_team(checkpoint, cfg.env)
    report: dict[str, Any] = {
        "backend": "rllib",
        "checkpoint": str(checkpoint),
        "timesteps": timesteps,
        "episodes": cfg.eval_episodes,
        "seeds": [EVAL_SEED + k for k in range(cfg.eval_episodes)],
        "rllib": evaluate_coverage(cfg.env, team, cfg.eval_episodes),
        "random": evaluate_coverage(cfg.env, "random", cfg.eval_episodes),
    }
    report["eval_time_s"] = time.perf_counter() - start
    return report

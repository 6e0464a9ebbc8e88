"""PPO training with parameter sharing (``polyslam train``), and its final evaluation.

:class:`TrainConfig` is the YAML file (``configs/train_ppo.yaml``): the env config, PPO's
hyperparameters and the run settings. :func:`train` learns through
:func:`polyslam_env.environment.vector.make_vec_env`, logs to ``OUT/tb``, writes checkpoints
``OUT/checkpoints/ppo_<timesteps>_steps.zip`` (periodically, at the end, and on Ctrl-C),
resumes from the newest one, and compares the policy with the ``random`` policy on a few
seeded episodes (``OUT/final_eval.json``). Timesteps count robot-steps (one per robot slot
per env step), as SB3 counts them.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.core.config import Config, check_positive, check_range
from polyslam_env.core.errors import ConfigError, PolyslamError
from polyslam_env.environment.config import EnvConfig

__all__ = [
    "PPOConfig",
    "TrainConfig",
    "checkpoints",
    "evaluate_coverage",
    "final_evaluation",
    "train",
]

#: Checkpoint file names; SB3's CheckpointCallback writes the same pattern.
CHECKPOINT_PREFIX = "ppo"
_CHECKPOINT_RE = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps\.zip$")
#: Evaluation episodes use seeds from here on, away from the training seeds.
EVAL_SEED = 10_000


@dataclass(frozen=True)
class PPOConfig(Config):
    """Stable-Baselines3 PPO hyperparameters (the same names as ``PPO(...)``)."""

    learning_rate: float = 3e-4
    n_steps: int = 128  # per slot and rollout; a rollout is n_steps · slots timesteps
    batch_size: int = 256
    n_epochs: int = 5
    gamma: float = 0.98
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    net_arch: tuple[int, ...] = (64, 64)  # hidden layers of both the policy and value MLPs
    log_std_init: float = -0.5  # initial log std of the Gaussian over the unit action box

    def validate(self) -> None:
        check_positive("ppo.learning_rate", self.learning_rate)
        for name in ("n_steps", "batch_size", "n_epochs"):
            if getattr(self, name) < 1:
                raise ConfigError(f"ppo.{name}: must be >= 1, got {getattr(self, name)!r}")
        for name in ("gamma", "gae_lambda"):
            check_range(f"ppo.{name}", getattr(self, name), 0.0, 1.0)
        check_positive("ppo.clip_range", self.clip_range)
        check_range("ppo.ent_coef", self.ent_coef, 0.0, 1.0)
        check_positive("ppo.vf_coef", self.vf_coef)
        check_positive("ppo.max_grad_norm", self.max_grad_norm)
        if not self.net_arch or min(self.net_arch) < 1:
            raise ConfigError(f"ppo.net_arch: must be layer sizes >= 1, got {self.net_arch!r}")
        check_range("ppo.log_std_init", self.log_std_init, -5.0, 2.0)

    def sb3_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for ``PPO(...)``."""
        out = self.to_dict()
        arch = list(out.pop("net_arch"))
        out["policy_kwargs"] = {"net_arch": arch, "log_std_init": out.pop("log_std_init")}
        return out


@dataclass(frozen=True)
class TrainConfig(Config):
    """A training run: env, PPO, and how long, how parallel, how often to save."""

    env: EnvConfig = field(default_factory=EnvConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    timesteps: int = 50_000  # total robot-steps (SB3 timesteps)
    num_envs: int = 4  # env copies; slots = num_envs · num_robots
    num_cpus: int = 0  # 0: all envs in this process; k: k worker processes
    seed: int = 0
    checkpoint_every: int = 10_000  # timesteps between checkpoints
    eval_episodes: int = 3  # final evaluation episodes (trained policy and random)
    torch_threads: int = 1  # torch intra-op threads (small MLPs: more threads only add overhead)

    def validate(self) -> None:
        for name in ("timesteps", "num_envs", "checkpoint_every", "torch_threads"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}: must be >= 1, got {getattr(self, name)!r}")
        for name in ("num_cpus", "eval_episodes"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}: must be >= 0, got {getattr(self, name)!r}")
        if self.env.observation.mode != "vector":
            raise ConfigError(
                f"env.observation.mode: must be 'vector' for PPO training, got"
                f" {self.env.observation.mode!r}"
            )
        if self.env.action.mode != "continuous":
            raise ConfigError(
                f"env.action.mode: must be 'continuous' for PPO training, got"
                f" {self.env.action.mode!r}"
            )

    @property
    def slots(self) -> int:
        """Robot slots of the vectorised env (timesteps per vectorised step)."""
        return self.num_envs * self.env.num_robots


# -- checkpoints -----------------------------------------------------------------------------
def checkpoints(folder: str | Path) -> list[tuple[int, Path]]:
    """``(timesteps, path)`` of the checkpoints in ``folder``, oldest first."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = []
    for path in folder.iterdir():
        m = _CHECKPOINT_RE.match(path.name)
        if m:
            found.append((int(m.group(1)), path))
    return sorted(found)


def save_checkpoint(model: Any, folder: Path) -> Path:
    """Save ``model`` as ``ppo_<timesteps>_steps.zip`` (atomically: temp file + rename)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{CHECKPOINT_PREFIX}_{model.num_timesteps}_steps.zip"
    tmp = folder / f".{path.name}.tmp.zip"
    model.save(tmp)
    tmp.replace(path)
    return path


# -- training --------------------------------------------------------------------------------
def _progress_callback(total: int, start: int, enabled: bool) -> Any:
    """A plain-tqdm progress bar (SB3's own needs ``rich``, which we do not depend on)."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class _Bar(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(
                total=total,
                initial=start,
                unit="step",
                desc="train",
                disable=not enabled,
                leave=False,
            )

        def _on_step(self) -> bool:
            self.bar.update(self.model.num_timesteps - self.bar.n)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return _Bar()


def _make_model(cfg: TrainConfig, venv: Any, out: Path, resume: bool) -> Any:
    """A new PPO, or the newest checkpoint under ``out`` when resuming."""
    from stable_baselines3 import PPO

    tb = str(out / "tb")
    if not resume:
        return PPO(
            "MlpPolicy", venv, seed=cfg.seed, tensorboard_log=tb, verbose=0, **cfg.ppo.sb3_kwargs()
        )
    found = checkpoints(out / "checkpoints")
    from policies.ppo import load_checkpoint

    load_checkpoint(found[-1][1])  # clear errors for a damaged file
    model = PPO.load(found[-1][1], env=venv, device="cpu", tensorboard_log=tb)
    if model.observation_space.shape != venv.observation_space.shape:
        raise PolyslamError(
            f"--resume: {found[-1][1]} expects observations of shape"
            f" {model.observation_space.shape}, the configured env gives"
            f" {venv.observation_space.shape}"
        )
    return model


def train(
    cfg: TrainConfig, out: str | Path, resume: bool = False, progress: bool = False
) -> tuple[Any, Path]:
    """Learn until ``cfg.timesteps`` in total; return the model and its last checkpoint.

    On Ctrl-C a checkpoint is saved before ``KeyboardInterrupt`` propagates.
    """
    out = Path(out)
    ckpt_dir = out / "checkpoints"
    if resume and not checkpoints(ckpt_dir):
        raise PolyslamError(f"--resume: no checkpoint in {ckpt_dir}")
    import torch
    from stable_baselines3.common.callbacks import CheckpointCallback

    from polyslam_env.environment.vector import make_vec_env

    torch.set_num_threads(cfg.torch_threads)
    venv = make_vec_env(cfg.env, cfg.num_envs, num_cpus=cfg.num_cpus, seed=cfg.seed)
    try:
        model = _make_model(cfg, venv, out, resume)
        remaining = cfg.timesteps - model.num_timesteps
        if remaining > 0:
            callbacks = [
                CheckpointCallback(
                    max(cfg.checkpoint_every // cfg.slots, 1),
                    str(ckpt_dir),
                    name_prefix=CHECKPOINT_PREFIX,
                ),
                _progress_callback(cfg.timesteps, model.num_timesteps, progress),
            ]
            try:
                model.learn(
                    remaining, callback=callbacks, reset_num_timesteps=not resume, tb_log_name="ppo"
                )
            except KeyboardInterrupt:
                path = save_checkpoint(model, ckpt_dir)
                print(f"interrupted: saved {path} at {model.num_timesteps} timesteps")
                raise
        return model, save_checkpoint(model, ckpt_dir)
    finally:
        venv.close()


# -- evaluation ------------------------------------------------------------------------------
def evaluate_coverage(
    env_cfg: EnvConfig, policy: str, episodes: int, seed: int = EVAL_SEED, **kwargs: Any
) -> dict[str, Any]:
    """Team coverage and team return at the end of ``episodes`` seeded episodes of the
    registered ``policy`` (the same for every robot; ``kwargs`` go to its factory)."""
    from policies.base import make_team
    from polyslam_env.environment.parallel import parallel_env

    env = parallel_env(env_cfg)
    team = make_team(policy, env, **kwargs)
    coverage, returns = [], []
    for k in range(episodes):
        rng = np.random.default_rng(seed + k)
        obs, _ = env.reset(seed=seed + k)
        team.reset(seed + k)
        total = 0.0
        while env.agents:
            obs, rewards, _, _, _ = env.step(team.act(obs, rng))
            total += float(sum(rewards.values()))
        assert env.episode is not None  # made by reset
        coverage.append(float(env.episode.coverage.coverage))
        returns.append(total)
    env.close()
    return {
        "coverage_mean": float(np.mean(coverage)) if coverage else float("nan"),
        "coverage": coverage,
        "return_mean": float(np.mean(returns)) if returns else float("nan"),
    }


def final_evaluation(cfg: TrainConfig, checkpoint: Path, timesteps: int) -> dict[str, Any]:
    """The trained policy vs the registered ``random`` policy on the same seeded episodes."""
    start = time.perf_counter()
    report = {
        "checkpoint": str(checkpoint),
        "timesteps": timesteps,
        "episodes": cfg.eval_episodes,
        "seeds": [EVAL_SEED + k for k in range(cfg.eval_episodes)],
        "ppo": evaluate_coverage(cfg.env, "ppo", cfg.eval_episodes, checkpoint=checkpoint),
        "random": evaluate_coverage(cfg.env, "random", cfg.eval_episodes),
    }
    report["eval_time_s"] = time.perf_counter() - start
    return report

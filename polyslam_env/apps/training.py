"""PPO training with parameter sharing (``polyslam train``), and its final evaluation.

:class:`TrainConfig` is the YAML file (``configs/train_ppo.yaml``): the env config, PPO's
hyperparameters and the run settings. :func:`train` learns through
:func:`polyslam_env.environment.vector.make_vec_env`, logs to ``OUT/tb`` (SB3's scalars plus the
env's episode metrics under ``polyslam/``), writes checkpoints
``OUT/checkpoints/ppo_<timesteps>_steps.zip`` atomically (periodically, at the end, on Ctrl-C
and on SIGTERM), resumes from the newest readable one, and compares the policy with the
``random`` policy on a few seeded episodes (``OUT/final_eval.json``). One ``OUT`` holds one
run: a fresh run into a folder with checkpoints is refused. Timesteps count robot-steps (one
per robot slot per env step), as SB3 counts them.
"""

from __future__ import annotations

import math
import os
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from polyslam_env.core.config import Config, check_positive, check_range
from polyslam_env.core.errors import ConfigError, PolyslamError
from polyslam_env.environment.config import EnvConfig
from polyslam_env.metrics.episode import meaningful

__all__ = [
    "PPOConfig",
    "TrainConfig",
    "TrainingTerminated",
    "check_run_folder",
    "checkpoints",
    "episode_scalars",
    "evaluate_coverage",
    "final_evaluation",
    "learning_curve",
    "train",
]

#: Checkpoint file names (the pattern SB3's CheckpointCallback uses).
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
    # what the network controls: "velocity", the (v, ω) of every step from the env's own
    # observation; "goals", which of the frontier planner's candidate goals to drive to every
    # decide_every steps (policies.goals); "drive", the (v, ω) of every step from the features
    # of its own map's planner (policies.drive, apps.drive_env)
    control: Literal["velocity", "goals", "drive"] = "velocity"
    decide_every: int = 8  # steps per decision (control: goals)
    repeat: int = 1  # env steps per action (control: drive; action repeat)
    progress: float = 1.0  # weight of the shaping term progress, per metre (control: drive)
    # control: drive: the guide is frontier_team's (goals announced over mutual sightings
    # discount the planner's utility; policies.drive.TeamDriveGuide), as behind --policy ppo
    team: bool = False
    # control: goals or drive: every episode picks one of these maps (env.map when empty); its
    # layout seed lies below EVAL_SEED, so evaluation seeds are layouts never trained on
    maps: tuple[str, ...] = ()
    # a checkpoint to start from instead of a new network (fine-tuning, e.g. with other reward
    # weights); its network and PPO settings are kept (the ppo section is not used), its step
    # count is not: timesteps counts this run's steps only
    init: str = ""

    def validate(self) -> None:
        for name in (
            "timesteps",
            "num_envs",
            "checkpoint_every",
            "torch_threads",
            "decide_every",
            "repeat",
        ):
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
        if self.control not in ("velocity", "goals", "drive"):
            raise ConfigError(
                f"control: must be 'velocity', 'goals' or 'drive', got {self.control!r}"
            )
        if self.maps and self.control == "velocity":
            raise ConfigError(
                "maps: only with control: goals or drive (velocity training uses env.map)"
            )
        check_range("progress", self.progress, 0.0, 1e6)
        if self.team and self.control != "drive":
            raise ConfigError(f"team: only with control: drive, got control: {self.control}")

    @property
    def slots(self) -> int:
        """Robot slots of the vectorised env (timesteps per vectorised step)."""
        return self.num_envs * self.env.num_robots

    def env_configs(self) -> list[EnvConfig]:
        """The env config of every training map (``maps``, or ``env.map`` alone)."""
        return [self.env.replace(map=m) for m in self.maps] if self.maps else [self.env]


# -- checkpoints -----------------------------------------------------------------------------
def checkpoints(
    folder: str | Path, pattern: re.Pattern[str] = _CHECKPOINT_RE, dirs: bool = False
) -> list[tuple[int, Path]]:
    """``(timesteps, path)`` of the checkpoints in ``folder`` whose names match ``pattern``
    (its group 1 the timesteps; files, or directories with ``dirs``), oldest first."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = []
    for path in folder.iterdir():
        m = pattern.match(path.name)
        if m and path.is_dir() == dirs:
            found.append((int(m.group(1)), path))
    return sorted(found)


def save_checkpoint(model: Any, folder: Path) -> Path:
    """Save ``model`` as ``ppo_<timesteps>_steps.zip`` atomically: SB3 writes a temporary file
    in the same folder, which is flushed to disk and then renamed over the name (a kill or a
    full disk mid-write leaves the previous checkpoints intact and no partial ``ppo_*.zip``)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{CHECKPOINT_PREFIX}_{model.num_timesteps}_steps.zip"
    tmp = folder / f".{path.name}.{os.getpid()}.tmp.zip"
    try:
        model.save(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def check_run_folder(out: str | Path, resume: bool) -> None:
    """One run per output folder: ``--resume`` needs a checkpoint there, a fresh run needs
    none (it would mix two runs' checkpoints, and ``--resume`` would pick the wrong one)."""
    ckpt_dir = Path(out) / "checkpoints"
    found = checkpoints(ckpt_dir)
    if resume and not found:
        raise PolyslamError(f"--resume: no checkpoint in {ckpt_dir}")
    if not resume and found:
        raise PolyslamError(
            f"{out}: already holds a training run (checkpoints up to {found[-1][0]} timesteps"
            " in checkpoints/); continue it with --resume, or train into a new --out folder"
        )


def newest_good_checkpoint(folder: Path) -> tuple[int, Path]:
    """The newest checkpoint in ``folder`` that loads; damaged newer ones are skipped, and
    the skip is reported (stderr)."""
    from policies.base import CheckpointError
    from policies.ppo import load_checkpoint

    found = checkpoints(folder)
    skipped = []
    for steps, path in reversed(found):
        try:
            load_checkpoint(path)
        except CheckpointError as err:
            skipped.append(str(err))
            continue
        for reason in skipped:
            print(f"--resume: skipped {reason}", file=sys.stderr)
        if skipped:
            print(f"--resume: resuming from {path} ({steps} timesteps)", file=sys.stderr)
        return steps, path
    raise PolyslamError(
        f"--resume: no readable checkpoint in {folder} ({len(found)} damaged: {skipped[0]})"
    )


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


class TrainingTerminated(Exception):
    """Training was stopped by SIGTERM; a checkpoint was saved (``path``)."""

    def __init__(self, path: Path, timesteps: int) -> None:
        super().__init__(f"terminated (SIGTERM): saved {path} at {timesteps} timesteps")
        self.path, self.timesteps = path, timesteps


def _stop_callback(flag: threading.Event) -> Any:
    """Stops ``learn`` at the next env step once ``flag`` is set (by the SIGTERM handler)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Stop(BaseCallback):
        def _on_step(self) -> bool:
            return not flag.is_set()

    return _Stop()


def _checkpoint_callback(every: int, folder: Path) -> Any:
    """Saves with :func:`save_checkpoint` (atomic) whenever the timesteps pass a multiple of
    ``every`` (counted from zero, so a resumed run keeps the same cadence)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Checkpoints(BaseCallback):
        def _on_training_start(self) -> None:
            self.next = (self.model.num_timesteps // every + 1) * every

        def _on_step(self) -> bool:
            if self.model.num_timesteps >= self.next:
                save_checkpoint(self.model, folder)
                self.next = (self.model.num_timesteps // every + 1) * every
            return True

    return _Checkpoints()


#: TensorBoard tags of :func:`_metrics_callback` (under ``polyslam/``).
EPISODE_TAGS = (
    "team_coverage",
    "robot_coverage_mean",
    "robot_coverage_min",
    "robot_coverage_max",
    "nu_mean",
    "completeness",
    "bytes_sent",
    "rendezvous",
    "episodes",
)


def episode_scalars(team: dict[str, Any], robots: list[dict[str, Any]]) -> dict[str, float]:
    """The ``polyslam/`` scalars of one finished team episode (tag → value, without
    ``episodes``), from its ``infos["team"]`` and its robots' ``infos["metrics"]``:
    coverage of the team and its robots' mean/min/max, ``nu_mean`` only over robots with a map
    and ``completeness`` over robots with SLAM (``metrics.episode.meaningful``), and the team's
    totals of ``bytes_sent`` and ``rendezvous``. A tag with no meaningful value is left out."""

    def finite(values: list[Any]) -> list[float]:
        return [float(v) for v in values if v is not None and math.isfinite(float(v))]

    out = {"team_coverage": float(team["coverage"])}
    coverage = finite([m.get("coverage") for m in robots])
    if coverage:
        out["robot_coverage_mean"] = float(np.mean(coverage))
        out["robot_coverage_min"] = min(coverage)
        out["robot_coverage_max"] = max(coverage)
    for key in ("nu_mean", "completeness"):  # only robots with a map / with SLAM
        values = finite(list(meaningful(robots, key)))
        if values:
            out[key] = float(np.mean(values))
    for key in ("bytes_sent", "rendezvous"):  # team totals
        out[key] = float(sum(finite([m.get(key) for m in robots])))
    return out


def _metrics_callback(num_robots: int) -> Any:
    """Logs the env's end-of-episode metrics to TensorBoard, per finished team episode.

    Slots ``k·R … k·R+R−1`` are env copy ``k``. A robot's ``infos["metrics"]`` arrive at its
    last step (a failed robot's earlier); the team episode has ended when all its slots are
    done, and then ``infos["team"]`` is read from one of them. Values (:func:`episode_scalars`)
    are averaged over the episodes that ended between two log dumps (SB3's ``record_mean``).
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class _EpisodeMetrics(BaseCallback):
        def _on_training_start(self) -> None:
            self.pending: dict[int, list[dict[str, float]]] = {}
            self.episodes = 0

        def _on_step(self) -> bool:
            infos, dones = self.locals["infos"], self.locals["dones"]
            for k in range(len(infos) // num_robots):
                slots = range(k * num_robots, (k + 1) * num_robots)
                pending = self.pending.setdefault(k, [])
                pending.extend(infos[s]["metrics"] for s in slots if "metrics" in infos[s])
                if not all(dones[s] for s in slots):
                    continue
                team = next((infos[s]["team"] for s in slots if "team" in infos[s]), None)
                if team is not None:
                    self.episodes += 1
                    for tag, value in episode_scalars(team, pending).items():
                        self.logger.record_mean(f"polyslam/{tag}", value)
                    self.logger.record("polyslam/episodes", self.episodes)
                self.pending[k] = []
            return True

    return _EpisodeMetrics()


def _make_venv(cfg: TrainConfig) -> Any:
    """The SB3 vectorised env of ``cfg``: robot slots of the env itself (``control:
    velocity``), of the goal-choice env (``control: goals``) or of the driving env
    (``control: drive``)."""
    from polyslam_env.environment.vector import make_vec_env, vectorise

    if cfg.control == "goals":
        from polyslam_env.apps.goal_env import GoalChoiceEnv

        team = GoalChoiceEnv(cfg.env_configs(), cfg.decide_every, seed_limit=EVAL_SEED)
        return vectorise(team, cfg.num_envs, num_cpus=cfg.num_cpus, seed=cfg.seed)
    if cfg.control == "drive":
        from polyslam_env.apps.drive_env import DriveEnv

        drive = DriveEnv(
            cfg.env_configs(), cfg.repeat, cfg.progress, seed_limit=EVAL_SEED, team=cfg.team
        )
        return vectorise(drive, cfg.num_envs, num_cpus=cfg.num_cpus, seed=cfg.seed)
    return make_vec_env(cfg.env, cfg.num_envs, num_cpus=cfg.num_cpus, seed=cfg.seed)


def _make_model(cfg: TrainConfig, venv: Any, out: Path, resume: bool) -> Any:
    """A new PPO, the checkpoint ``cfg.init`` (its step count reset to 0), or the newest
    readable checkpoint under ``out`` when resuming."""
    from stable_baselines3 import PPO

    tb = str(out / "tb")
    if resume:
        _, path = newest_good_checkpoint(out / "checkpoints")
        return _load_model(path, venv, tb, "--resume")
    if cfg.init:
        if not Path(cfg.init).is_file():
            raise PolyslamError(f"init: no checkpoint file {cfg.init}")
        model = _load_model(Path(cfg.init), venv, tb, "init")
        model.num_timesteps = 0
        model.set_random_seed(cfg.seed)
        return model
    return PPO(
        "MlpPolicy", venv, seed=cfg.seed, tensorboard_log=tb, verbose=0, **cfg.ppo.sb3_kwargs()
    )


def _load_model(path: Path, venv: Any, tb: str, what: str) -> Any:
    """The PPO checkpoint at ``path`` on ``venv``; one line if its observations do not fit."""
    from stable_baselines3 import PPO

    model = PPO.load(path, env=venv, device="cpu", tensorboard_log=tb)
    if model.observation_space.shape != venv.observation_space.shape:
        raise PolyslamError(
            f"{what}: {path} expects observations of shape"
            f" {model.observation_space.shape}, the configured env gives"
            f" {venv.observation_space.shape}"
        )
    return model


def train(
    cfg: TrainConfig, out: str | Path, resume: bool = False, progress: bool = False
) -> tuple[Any, Path]:
    """Learn until ``cfg.timesteps`` in total; return the model and its last checkpoint.

    On Ctrl-C a checkpoint is saved before ``KeyboardInterrupt`` propagates. On SIGTERM (a
    cluster scheduler's stop; handled while this runs in the main thread) learning stops at
    the next env step, a checkpoint is saved and :class:`TrainingTerminated` is raised.
    """
    out = Path(out)
    ckpt_dir = out / "checkpoints"
    check_run_folder(out, resume)
    import torch

    torch.set_num_threads(cfg.torch_threads)
    terminated = threading.Event()
    installed, previous = False, None
    if threading.current_thread() is threading.main_thread():
        # before the workers are forked (num_cpus > 0), so that a SIGTERM sent to the whole
        # process group only sets their copy of the flag instead of killing them mid-step
        previous = signal.signal(signal.SIGTERM, lambda signum, frame: terminated.set())
        installed = True
    try:
        venv = _make_venv(cfg)
        try:
            model = _make_model(cfg, venv, out, resume)
            remaining = cfg.timesteps - model.num_timesteps
            if remaining > 0:
                callbacks = [
                    _stop_callback(terminated),
                    _checkpoint_callback(cfg.checkpoint_every, ckpt_dir),
                    _metrics_callback(cfg.env.num_robots),
                    _progress_callback(cfg.timesteps, model.num_timesteps, progress),
                ]
                try:
                    model.learn(
                        remaining,
                        callback=callbacks,
                        reset_num_timesteps=not resume,
                        tb_log_name="ppo",
                    )
                except KeyboardInterrupt:
                    path = save_checkpoint(model, ckpt_dir)
                    print(f"interrupted: saved {path} at {model.num_timesteps} timesteps")
                    raise
                if terminated.is_set():
                    path = save_checkpoint(model, ckpt_dir)
                    raise TrainingTerminated(path, model.num_timesteps)
            return model, save_checkpoint(model, ckpt_dir)
        finally:
            venv.close()
    finally:
        if installed:
            signal.signal(signal.SIGTERM, previous)


# -- evaluation ------------------------------------------------------------------------------
def evaluate_coverage(
    env_cfg: EnvConfig, policy: Any, episodes: int, seed: int = EVAL_SEED, **kwargs: Any
) -> dict[str, Any]:
    """Team coverage and team return at the end of ``episodes`` seeded episodes of the
    registered ``policy`` (a name: the same for every robot; ``kwargs`` go to its factory),
    or of a ready team (an object with ``reset(seed)`` and ``act(observations, rng)``)."""
    from policies.base import make_team
    from polyslam_env.environment.parallel import parallel_env

    env = parallel_env(env_cfg)
    team = make_team(policy, env, **kwargs) if isinstance(policy, str) else policy
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
    """The trained policy (``ppo``, or ``ppo_drive`` for ``control: drive``) vs the registered
    ``random`` policy (and ``frontier``, whose goals a ``control: goals`` network chooses among
    and whose planner guides a ``control: drive`` one) on the same seeded episodes of
    ``cfg.env``."""
    start = time.perf_counter()
    name = "ppo_drive" if cfg.control == "drive" and not cfg.team else "ppo"
    report = {
        "checkpoint": str(checkpoint),
        "timesteps": timesteps,
        "episodes": cfg.eval_episodes,
        "seeds": [EVAL_SEED + k for k in range(cfg.eval_episodes)],
        "ppo": evaluate_coverage(cfg.env, name, cfg.eval_episodes, checkpoint=checkpoint),
        "random": evaluate_coverage(cfg.env, "random", cfg.eval_episodes),
    }
    if cfg.control in ("goals", "drive"):
        report["frontier"] = evaluate_coverage(cfg.env, "frontier", cfg.eval_episodes)
    report["eval_time_s"] = time.perf_counter() - start
    return report


#: The TensorBoard tag of the learning curve.
CURVE_TAG = "polyslam/team_coverage"


def learning_curve(out: str | Path) -> tuple[Path, Path] | None:
    """Write ``OUT/learning_curve.csv`` (timesteps, team coverage at the end of the episodes
    that ended in each logging interval) and ``OUT/learning_curve.png`` from the run's
    TensorBoard logs (every event file under ``OUT/tb``, so a resumed run's too), with a
    running mean over 10 intervals; None when no episode has ended yet."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = Path(out)
    points: dict[int, float] = {}
    for events in sorted((out / "tb").rglob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        if CURVE_TAG in acc.Tags().get("scalars", []):
            points.update({int(e.step): float(e.value) for e in acc.Scalars(CURVE_TAG)})
    if not points:
        return None
    steps = np.array(sorted(points))
    values = np.array([points[s] for s in steps])
    csv = out / "learning_curve.csv"
    np.savetxt(
        csv,
        np.column_stack([steps, values]),
        delimiter=",",
        header="timesteps,team_coverage",
        comments="",
        fmt=["%d", "%.6f"],
    )
    from polyslam_env.render.plots import plot_learning_curve

    png = plot_learning_curve(steps, values, out / "learning_curve.png")
    return csv, png

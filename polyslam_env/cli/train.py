"""``polyslam train``: PPO with parameter sharing, checkpoints, resume, final evaluation.

``--backend sb3`` (default): Stable-Baselines3, the ``rl`` extra. ``--backend rllib``: RLlib
on a local Ray instance or the cluster at ``--address``, the ``ray`` extra.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from polyslam_env.cli.common import show_progress


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "train",
        help="train a shared PPO policy for all robots (needs the [rl] extra)",
        description="Train one PPO network that drives every robot on its own observation"
        " (Stable-Baselines3 through SuperSuit, or RLlib): its (v, ω) every step (control:"
        " velocity, configs/train_ppo.yaml) or which of the frontier planner's candidate goals"
        " to drive to every decide_every steps (control: goals, configs/train_goals.yaml, the"
        " shipped ppo's training) or its (v, ω) every step from its beams and its own map's"
        " planned path (control: drive, configs/train_drive.yaml, the shipped ppo_drive's"
        " training). Writes TensorBoard logs to OUT/tb (the backend's"
        " scalars and, per finished episode, polyslam/team_coverage, robot_coverage_mean/min/"
        "max, nu_mean, completeness, bytes_sent, rendezvous), the learning curve to"
        " OUT/learning_curve.png and .csv, checkpoints to OUT/checkpoints (atomically:"
        " periodic, final, on SIGTERM (exit 143) and, with SB3, on Ctrl-C (exit 130)), and"
        " compares the trained policy with random actions (and frontier, for goals and drive) in"
        " OUT/final_eval.json. One OUT folder holds one run: a fresh run into a folder with"
        " checkpoints is refused (exit 2); --resume continues it from its newest readable"
        " checkpoint.",
    )
    parser.add_argument("--config", default=None, help="training YAML (default: train_ppo.yaml)")
    parser.add_argument("--timesteps", type=int, default=None, help="total timesteps (robot-steps)")
    parser.add_argument("--out", default="out/train", help="output folder (default: out/train)")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out from its newest readable checkpoint (a damaged"
        " newer one is skipped, and said so)",
    )
    parser.add_argument("--seed", type=int, default=None, help="seed (default: from the config)")
    parser.add_argument(
        "--backend",
        choices=("sb3", "rllib"),
        default="sb3",
        help="sb3: Stable-Baselines3 (default, the [rl] extra); rllib: RLlib PPO on Ray"
        " (the [ray] extra), checkpoints OUT/checkpoints/rllib_<timesteps>_steps/",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="rllib: join the Ray cluster at this address (host:port of `ray start --head`;"
        " default: $RAY_ADDRESS, else a local Ray instance with num_cpus env runners)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from polyslam_env.apps.training import (
        TrainConfig,
        TrainingTerminated,
        check_run_folder,
        final_evaluation,
        learning_curve,
        train,
    )
    from polyslam_env.core.errors import PolyslamError
    from polyslam_env.core.io import write_json
    from polyslam_env.core.resources import configs_dir

    path = Path(args.config) if args.config else configs_dir() / "train_ppo.yaml"
    overrides: dict[str, Any] = {}
    if args.timesteps is not None:
        overrides["timesteps"] = args.timesteps
    if args.seed is not None:
        overrides["seed"] = args.seed
    cfg = TrainConfig.from_yaml(path, **overrides)
    out = Path(args.out)
    if args.backend == "rllib":
        if cfg.control != "velocity":
            raise PolyslamError(f"control: {cfg.control!r} trains with --backend sb3 only")
        return _run_rllib(args, cfg, out)
    if args.address is not None:
        raise PolyslamError("--address: only with --backend rllib")
    check_run_folder(out, args.resume)  # before train_config.json: never touch another run
    write_json(out / "train_config.json", cfg.to_dict())
    start = time.perf_counter()
    try:
        model, checkpoint = train(cfg, out, resume=args.resume, progress=show_progress(args.quiet))
    except TrainingTerminated as stop:
        print(f"{stop}; continue with --resume", flush=True)
        return 143  # 128 + SIGTERM, as a shell reports a process that SIGTERM ended
    seconds = time.perf_counter() - start
    print(f"trained to {model.num_timesteps} timesteps in {seconds:.0f} s; saved {checkpoint}")
    curve = learning_curve(out)
    if curve is not None:
        print(f"learning curve: {curve[1]} ({curve[0]})")
    if cfg.eval_episodes == 0:
        return 0
    report = final_evaluation(cfg, checkpoint, model.num_timesteps)
    report["train_time_s"] = seconds
    _print_evaluation(report, "ppo", cfg.eval_episodes, write_json(out / "final_eval.json", report))
    return 0


def _run_rllib(args: argparse.Namespace, cfg: Any, out: Path) -> int:
    from polyslam_env.apps import training_rllib as rl
    from polyslam_env.core.io import write_json

    rl.require_ray()  # the one-line "needs ray" error before anything is written
    rl.check_run_folder(out, args.resume)
    write_json(out / "train_config.json", {**cfg.to_dict(), "backend": "rllib"})
    from polyslam_env.apps.training import TrainingTerminated, learning_curve

    try:
        timesteps, checkpoint, stats = rl.train(
            cfg, out, resume=args.resume, address=args.address, progress=not args.quiet
        )
    except TrainingTerminated as stop:
        print(f"{stop}; continue with --resume", flush=True)
        return 143  # 128 + SIGTERM, as on the SB3 backend

    def rate(seconds: float) -> float:
        return stats["env_steps"] / seconds if seconds > 0 else float("nan")

    if not stats["iterations"]:
        print(f"nothing to train: {checkpoint} has {timesteps} timesteps", flush=True)
    else:
        print(
            f"trained to {timesteps} timesteps in {stats['train_s']:.0f} s"
            f" ({stats['iterations']} iterations; {stats['env_steps']} env steps:"
            f" {rate(stats['train_s']):.0f}/s overall, {rate(stats['sample_s']):.0f}/s while"
            f" sampling); saved {checkpoint}",
            flush=True,
        )
    curve = learning_curve(out)
    if curve is not None:
        print(f"learning curve: {curve[1]} ({curve[0]})")
    if cfg.eval_episodes == 0:
        return 0
    report = rl.final_evaluation(cfg, checkpoint, timesteps)
    report["train"] = stats
    _print_evaluation(
        report, "rllib", cfg.eval_episodes, write_json(out / "final_eval.json", report)
    )
    return 0


def _print_evaluation(report: dict[str, Any], learned: str, episodes: int, path: Path) -> None:
    """One line: the learned policy's team coverage and return next to ``random``'s (and
    ``frontier``'s when the report has it)."""
    ours, rnd = report[learned], report["random"]
    frontier = report.get("frontier")
    also = "" if frontier is None else f", frontier {100 * frontier['coverage_mean']:.1f} %"
    print(
        f"final evaluation, {episodes} episodes: team coverage"
        f" {learned} {100 * ours['coverage_mean']:.1f} %, random {100 * rnd['coverage_mean']:.1f} %"
        f"{also} (return {ours['return_mean']:.2f} vs {rnd['return_mean']:.2f}); wrote {path}"
    )

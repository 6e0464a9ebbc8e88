"""``polyslam run``: one episode of ``polyslam_v0`` with a policy team; metrics + picture."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from polyslam_env.cli.common import (
    check_output_file,
    check_output_folder,
    fmt,
    progress_bar,
)
from polyslam_env.core.errors import DisplayError

#: With no --map and no --config: the map of each policy's default run (``paper`` replays the
#: paper paths on the paper map, and says so; the others explore the office, which frontier
#: covers to 95 % in about 100–140 steps with 3 robots).
DEFAULT_MAP = {"paper": "paper"}
FALLBACK_MAP = "office"
#: With no --steps and no --config: the paper paths are 200 steps long.
DEFAULT_STEPS = {"paper": 200}
FALLBACK_STEPS = 400
#: Policies that replay fixed paths: their episodes must not end early at the coverage target
#: (the paper's paths cover the whole paper map before r2 and r3 meet), so ``run`` and
#: ``evaluate`` set ``coverage_target=None`` for them (and say so).
REPLAYS_PATHS = ("paper",)
#: Steps of the untimed warm-up before the timed episode (the same seeded episode's first
#: steps): the numba kernels compile (first run) or load from their disk cache on first use,
#: which would otherwise land in the ``slam_time_ms`` of the robot that used them first (in
#: the default run every kernel is in use by step 7).
WARMUP_STEPS = 20


def add_env_arguments(parser: argparse.ArgumentParser) -> None:
    """The options ``run`` and ``evaluate`` share: policy, env config and seed."""
    parser.add_argument("--policy", default="frontier", help="policy name (default: frontier)")
    parser.add_argument("--checkpoint", help="policy checkpoint file (learned policies only)")
    parser.add_argument("--map", help="built-in map, map file or generator:<name>")
    parser.add_argument("--robots", type=int, help="number of robots (default: 3)")
    parser.add_argument("--steps", type=int, help="max steps per episode (default: 400)")
    parser.add_argument("--seed", type=int, default=0, help="episode seed (default: 0)")
    parser.add_argument("--config", help="YAML file with EnvConfig fields")


def env_config(args: argparse.Namespace) -> Any:
    """The EnvConfig of ``args``: --config (or defaults) with --map/--robots/--steps on top."""
    from polyslam_env.environment.config import EnvConfig

    base = EnvConfig.from_yaml(args.config) if args.config else EnvConfig()
    overrides: dict[str, Any] = {}
    if args.map is not None:
        overrides["map"] = args.map
    elif not args.config:
        overrides["map"] = DEFAULT_MAP.get(args.policy, FALLBACK_MAP)
    if args.robots is not None:
        overrides["num_robots"] = args.robots
    if args.steps is not None:
        overrides["max_steps"] = args.steps
    elif not args.config:
        overrides["max_steps"] = DEFAULT_STEPS.get(args.policy, FALLBACK_STEPS)
    if args.policy in REPLAYS_PATHS:
        overrides["coverage_target"] = None
    return base.replace(**overrides)


def explain_choices(args: argparse.Namespace, cfg: Any) -> None:
    """Say what the policy chose that the user did not ask for (stderr, one line)."""
    if args.policy not in REPLAYS_PATHS:
        return
    chosen = "" if args.map or args.config else f"map {cfg.map!r} (its paths' map), "
    print(
        f"policy {args.policy!r} replays fixed paths: {chosen}{cfg.max_steps} steps,"
        " no end at a coverage target (the paths play to their end)",
        file=sys.stderr,
    )


def policy_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Factory keyword arguments; a missing checkpoint file is reported before any work."""
    from policies.base import CheckpointError, policy_factory

    policy_factory(args.policy)  # an unknown name fails here, before the env is built
    if args.checkpoint is None:
        return {}
    if not Path(args.checkpoint).is_file():
        raise CheckpointError(f"--checkpoint: file not found: {args.checkpoint}")
    return {"checkpoint": args.checkpoint}


def register(sub: Any) -> None:
    parser = sub.add_parser(
        "run",
        help="one episode with a policy: metrics table, metrics.json and a picture",
        description="Run one seeded episode of polyslam_v0 with the same policy for every"
        " robot; print per-robot metrics and the team block, write metrics.json and"
        " final.png (the robots' maps over the true walls). Default: a frontier team on the"
        " office map.",
    )
    add_env_arguments(parser)
    parser.add_argument("--render", action="store_true", help="show the episode in a window")
    parser.add_argument("--video", help="save the episode as a video (.gif, or .mp4 with imageio)")
    parser.add_argument("--out", default="out/run", help="output folder (default: out/run)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def print_results(result: Any, env: Any, title: str, kernels: dict[str, float]) -> None:
    """The per-robot table of the metrics that apply to ``env``'s set-up (grouped, with
    units), what ``nees`` and ``slam_time_ms`` hold, and the team block."""
    from polyslam_env.apps.run_table import describe_setup, format_run_table, shown_metrics

    print(f"{title} {describe_setup(env)}:")
    print(format_run_table(result.robots, shown_metrics(env), fmt))
    if env.config.slam_enabled and env.config.initial_error:
        print(
            "nees carries each robot's start draw (start_nees = e0' P0^-1 e0 ~ chi2(3), which no"
            " filter can observe)\nfor the whole episode; nees_rel leaves it out (3 for a"
            " consistent filter)"
        )
    if env.config.slam_enabled:
        print(
            f"slam_time_ms: mean SLAM step of the episode, after a {kernels['warmup_steps']}-step"
            f" warm-up that compiled or loaded\nthe numba kernels ({kernels['warmup_s']:.1f} s,"
            f" not timed); kernels first used later in the episode: {kernels['episode_s']:.2f} s"
            " (timed)"
        )
    print("team: " + ", ".join(f"{k} {_team_value(v)}" for k, v in result.team.items()))


def _team_value(v: Any) -> str:
    return "not reached" if v is None else fmt(float(v))


def run(args: argparse.Namespace) -> int:

    from policies.base import make_team
    from polyslam_env.apps.rollout import run_episode, warm_up
    from polyslam_env.core.io import write_json
    from polyslam_env.core.jit import compile_seconds
    from polyslam_env.environment.parallel import parallel_env
    from polyslam_env.render.renderer import Renderer, check_video_path, save_video

    out = check_output_folder(args.out, "--out")
    if args.video:
        check_video_path(args.video)
        check_output_file(args.video, "--video")
    if args.render:
        check_display()
    cfg = env_config(args)
    kwargs = policy_kwargs(args)
    env = parallel_env(cfg, render_mode="human" if args.render else None)
    team = make_team(args.policy, env, **kwargs)
    explain_choices(args, cfg)
    frames: list[Any] = []
    pictures: list[Renderer] = []

    def on_step(e: Any) -> None:
        bar.update(0 if e.episode.step_count == 0 else 1)
        if args.render:
            e.render()
        if args.video:
            frames.append(_picture(e, pictures))

    warmup = min(WARMUP_STEPS, cfg.max_steps)
    try:
        with progress_bar(warmup, "warm-up", "step", args.quiet) as bar:
            kernels = {"warmup_steps": warmup, "warmup_s": 0.0, "episode_s": 0.0}
            kernels["warmup_s"] = warm_up(env, team, args.seed, warmup, lambda: bar.update(1))
        before = compile_seconds()
        with progress_bar(cfg.max_steps, "run", "step", args.quiet) as bar:
            result = run_episode(env, team, args.seed, on_step)
        kernels["episode_s"] = compile_seconds() - before
    finally:
        env.close()
    title = f"policy {args.policy!r}, map {cfg.map!r}, seed {args.seed},"
    print_results(result, env, title, kernels)
    data = {
        "policy": args.policy,
        "map": cfg.map,
        "config": cfg.to_dict(),
        **result.to_dict(),
        "kernels": kernels,
    }
    write_json(out / "metrics.json", data)
    picture = _save_png(_picture(env, pictures), out / "final.png")
    written = [str(out / "metrics.json"), str(picture)]
    if args.video:
        written.append(str(save_video(frames, args.video, fps=env.metadata["render_fps"])))
    for renderer in pictures:
        renderer.close()
    print("wrote " + ", ".join(written))
    return 0


def check_display() -> None:
    """--render needs a display: on a machine without one (no DISPLAY or WAYLAND_DISPLAY on
    Linux, and no SDL_VIDEODRIVER chosen) say how to get the frames instead."""
    if not sys.platform.startswith("linux") or os.environ.get("SDL_VIDEODRIVER"):
        return
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise DisplayError(
            "--render: no display here (DISPLAY is not set); save the frames instead with"
            " --video out.gif (or set SDL_VIDEODRIVER to draw to another video driver)"
        )


def _picture(env: Any, cache: list[Any]) -> Any:  # (H, W, 3) uint8
    """The env's current state drawn off-screen (one renderer, kept in ``cache``)."""
    from polyslam_env.render.renderer import Renderer

    if not cache:
        cache.append(
            Renderer(env.episode.world.layout, env.config.num_robots, "rgb_array", env.config.world)
        )
    return cache[0].render(env.render_state())


def _save_png(image: Any, path: Path) -> Path:
    """An RGB array as a PNG, written atomically."""
    import io

    from PIL import Image

    from polyslam_env.core.io import write_atomic

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return write_atomic(path, buf.getvalue())

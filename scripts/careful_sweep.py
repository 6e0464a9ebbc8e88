"""The ``map_error`` / ``bytes`` weight sweep of issue 44 item 3: one training config per point,
its training and evaluation commands, and the Pareto figure drawn from the evaluation JSON.

Every point is ``configs/train_careful.yaml`` (the shipped driver ``ppo_drive`` fine-tuned with
SLAM on) with its two reward weights replaced; the points ``drive`` and ``careful`` are the
shipped checkpoints themselves (weights 0 / 0 and 100 / 0: nothing to train). For each point
the sweep writes ``OUT/configs/POINT.yaml``, trains into ``OUT/POINT`` (``polyslam train``; its
learning curve is ``OUT/POINT/learning_curve.png``), evaluates the newest checkpoint on the
held-out layouts (``polyslam evaluate --policy ppo_careful --checkpoint ...``, seeds from
``--seed``, both large generators) into ``OUT/eval/POINT_MAP.json``, and finally draws
``scripts/pareto.py``'s figure over the points that have both files. A step whose output
exists is skipped and a training run that stopped is resumed, so a stopped sweep goes on where
it stopped. Run it from the repository's root (the base config's ``init`` path is relative).

    python scripts/careful_sweep.py --out out/sweep                 # print the commands
    python scripts/careful_sweep.py --out out/sweep --run           # run them all
    python scripts/careful_sweep.py --out out/sweep --run --only b20 --episodes 10
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

BASE = Path(__file__).resolve().parent.parent / "configs" / "train_careful.yaml"
MAPS = ("office_floor", "warehouse")


@dataclass(frozen=True)
class Point:
    """One point of the sweep: its reward weights and, for a shipped network, its policy."""

    name: str
    map_error: float
    bytes: float
    shipped: str | None = None  # a registered policy playing a shipped checkpoint

    @property
    def label(self) -> str:
        return f"{self.name} (map_error {self.map_error:g}, bytes {self.bytes:g})"


POINTS = (
    Point("drive", 0.0, 0.0, shipped="ppo_drive"),
    Point("careful", 100.0, 0.0, shipped="ppo_careful"),
    Point("me1000", 1000.0, 0.0),
    Point("me100_b20", 100.0, 20.0),
    Point("b20", 0.0, 20.0),
    Point("b100", 0.0, 100.0),
)


def config(point: Point) -> dict[str, object]:
    """The training config of ``point``: the base with its two weights."""
    data = yaml.safe_load(BASE.read_text())
    data["env"]["reward"]["map_error"] = point.map_error
    data["env"]["reward"]["bytes"] = point.bytes
    data["eval_episodes"] = 0  # the sweep evaluates on the held-out layouts itself
    return data


def checkpoint(out: Path, point: Point) -> Path | None:
    """The newest checkpoint of ``point``'s training run (None before one exists)."""
    found = sorted(
        (out / point.name / "checkpoints").glob("ppo_*_steps.zip"),
        key=lambda p: int(p.stem.split("_")[1]),
    )
    return found[-1] if found else None


def commands(
    out: Path, point: Point, seed: int, episodes: int, workers: int
) -> list[tuple[Path, list[str]]]:
    """(the output that marks it done, the command) for each step of ``point``."""
    steps: list[tuple[Path, list[str]]] = []
    run = out / point.name
    if point.shipped is None:
        done = run / "learning_curve.csv"  # written when the training ends
        config_file = out / "configs" / f"{point.name}.yaml"
        train = ["polyslam", "train", "--config", str(config_file), "--out", str(run)]
        if (run / "train_config.json").is_file():
            train.append("--resume")  # a run that stopped: go on from its newest checkpoint
        steps.append((done, train))
    for name in MAPS:
        policy = ["--policy", point.shipped or "ppo_careful"]
        if point.shipped is None:
            ckpt = checkpoint(out, point)
            policy += ["--checkpoint", str(ckpt or run / "checkpoints" / "NEWEST.zip")]
        steps.append(
            (
                out / "eval" / f"{point.name}_{name}.json",
                [
                    "polyslam",
                    "evaluate",
                    *policy,
                    "--map",
                    f"generator:{name}",
                    "--seed",
                    str(seed),
                    "--episodes",
                    str(episodes),
                    "--workers",
                    str(workers),
                    "--quiet",
                    "--json",
                    str(out / "eval" / f"{point.name}_{name}.json"),
                ],
            )
        )
    return steps


def pareto(out: Path, points: list[Point]) -> list[str]:
    """``scripts/pareto.py`` over the points whose evaluations are all there."""
    args = ["python", str(Path(__file__).with_name("pareto.py")), "--out", str(out / "pareto.png")]
    for p in points:
        files = [out / "eval" / f"{p.name}_{m}.json" for m in MAPS]
        if all(f.is_file() for f in files):
            args += ["--point", p.label, p.shipped or "ppo_careful", *map(str, files)]
    return args


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="the sweep's folder")
    parser.add_argument("--run", action="store_true", help="run the steps (else print them)")
    parser.add_argument("--only", default="", help="comma list of point names (default: all)")
    parser.add_argument("--seed", type=int, default=10000, help="first held-out layout seed")
    parser.add_argument("--episodes", type=int, default=20, help="layouts per map")
    parser.add_argument("--workers", type=int, default=2, help="evaluate's processes")
    args = parser.parse_args(argv)
    names = [n for n in args.only.split(",") if n]
    unknown = sorted(set(names) - {p.name for p in POINTS})
    if unknown:
        parser.error(
            f"--only: unknown point(s) {', '.join(unknown)}; points are"
            f" {', '.join(p.name for p in POINTS)}"
        )
    points = [p for p in POINTS if not names or p.name in names]
    (args.out / "configs").mkdir(parents=True, exist_ok=True)
    (args.out / "eval").mkdir(exist_ok=True)
    for p in points:
        if p.shipped is None:
            path = args.out / "configs" / f"{p.name}.yaml"
            path.write_text(yaml.safe_dump(config(p), sort_keys=False))
    for p in points:
        for done, command in commands(args.out, p, args.seed, args.episodes, args.workers):
            if done.exists():
                print(f"# done: {shlex.join(command)}")
                continue
            if args.run and "NEWEST.zip" in " ".join(command):  # trained just now: look again
                command = dict(commands(args.out, p, args.seed, args.episodes, args.workers))[done]
            print(shlex.join(command), flush=True)
            if args.run:
                if subprocess.call(command) != 0:
                    print(f"careful_sweep: failed: {shlex.join(command)}", file=sys.stderr)
                    return 1
    figure = pareto(args.out, points)
    print(shlex.join(figure))
    if args.run and "--point" in figure:
        return subprocess.call(figure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Where a robot's filter grows overconfident: its pose NEES step by step, and the map events.

One robot of one seeded ``polyslam fidelity`` episode (frontier team, ``initial_error`` on,
the map exchange off, so each robot's SLAM depends on its own readings only). The episode
runs once and every robot's odometry and range readings are recorded (``--cache`` keeps
them); the chosen robot's SLAM is then played again alone on them (the same numbers: checked
when recorded), with every map event logged: landmarks created, refit, merged (lineage),
links and square ties (the wall graph), divergence alarms. At every step the filter's pose
error relative to the true start is compared with its own covariance P_S (the NEES behind
``nees_rel``). Printed: a row every ``--every`` steps, then the steps where the NEES jumps
or a pose σ shrinks sharply (where a filter takes information it may not have), each with
the events of that step and the two before, and every landmark an event touched with its
true error (the largest distance of its curve to the true walls, placed by the true start
as ``map_precision`` places it; a new landmark carries the pose's error of its time).

To tell the estimator's own errors from the inputs' noise, ``--ideal-ranges`` replays noise-free
ranges (cast from the true poses) and ``--ideal-odometry`` the true motion: with both, every
pose error comes from the filter's model (its shapes, merges, ties), and a NEES far above 3
there is a modelling error, not bad luck. ``--set KEY=VALUE`` changes the SLAM config of the
replay only (``order=1``, ``square_walls=false``; the recording is the fidelity config's), so
a variant is tried on the very same readings in seconds.

``--info FROM:TO`` says where the heading's information comes from over steps FROM … TO − 1:
the change of the filter's heading variance summed by stage of the step (prediction, map
changes, update) and the update's share split by the landmarks in it (lines only, or curves
among them; each landmark's age since it was fitted). In ground the robot has not seen
before the heading variance can only grow (no landmark there holds information from before
the robot's own poses there); a stage that shrinks it there takes information the readings
do not hold (docs/notes/floors.md, Round 9).

Usage::

    python scripts/nees_trace.py --map /work/real/willow.yaml --seed 0 --robot 2 --steps 1000 \
        --fixed-steps --cache willow0.pkl
    python scripts/nees_trace.py --map /work/real/willow.yaml --robot 2 --cache willow0.pkl \
        --ideal-ranges --ideal-odometry --set order=1 --plot trace.png
    python scripts/nees_trace.py --map /work/real/willow.yaml --robot 2 --cache willow0.pkl \
        --info 740:900
"""

from __future__ import annotations

import argparse
import pickle
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from policies.base import make_team
from polyslam_env.apps.fidelity import FidelityConfig, episode_config
from polyslam_env.apps.rollout import run_episode
from polyslam_env.core.config import parse_overrides
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.metrics.boundary import distance_to_boundary
from polyslam_env.metrics.mapping import map_points
from polyslam_env.slam import robot as slam_robot
from polyslam_env.slam.columns import G_ROW
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.lineage import LineageEvent
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.layout import Layout
from polyslam_env.world.sensors import cast_rays


@dataclass
class Recording:
    """One robot's readings over an episode, and the truth to judge its filter by."""

    odometry: np.ndarray  # (T, 3)
    ranges: np.ndarray  # (T, B)
    true: np.ndarray  # (T + 1, 3) true poses, absolute frame (row 0: the true start)
    angles: np.ndarray  # (B,)
    max_range: float
    slam: dict[str, Any]  # the episode's SLAM config
    layout: Layout


def record(config: dict[str, Any], seed: int) -> list[Recording]:
    """Run the episode ``config`` (a team under the frontier policy) and keep every robot's
    SLAM inputs and true poses; each robot's SLAM is played again alone on them and must
    end where the episode's did (else the robots' filters were not independent)."""
    env = parallel_env(EnvConfig.from_dict(config))
    n = env.config.num_robots
    odometry: list[list[np.ndarray]] = [[] for _ in range(n)]
    ranges: list[list[np.ndarray]] = [[] for _ in range(n)]

    def recording(robot: int, step: Any) -> Any:
        def recorded(odo: np.ndarray, z: np.ndarray) -> Any:
            odometry[robot].append(np.array(odo, dtype=float))
            ranges[robot].append(np.array(z, dtype=float))
            return step(odo, z)

        return recorded

    def watch(env: Any) -> None:
        state = env.episode
        if state.step_count == 0:
            for robot, slam in enumerate(state.slams):
                slam.step = recording(robot, slam.step)

    run_episode(env, make_team("frontier", env), seed, on_step=watch)
    state = env.episode
    assert state is not None
    recordings = [
        Recording(
            np.array(odometry[i]),
            np.array(ranges[i]),
            np.array(state.histories[i].true),
            np.array(state.angles),
            env.config.world.range_sensor.max_range,
            env.config.slam.to_dict(),
            state.world.layout,
        )
        for i in range(n)
    ]
    finals = [slam.mean[:3].copy() for slam in state.slams]
    env.close()
    for rec, final in zip(recordings, finals, strict=True):
        replayed = PolySlam(SlamConfig.from_dict(rec.slam), rec.angles, rec.max_range)
        for odo, z in zip(rec.odometry, rec.ranges, strict=True):
            replayed.step(odo, z)
        if not np.array_equal(replayed.mean[:3], final):
            raise RuntimeError("a replayed SLAM differs from the episode's: not its robot's alone")
    return recordings


@dataclass
class Trace:
    """Per step (rows 0 … T − 1 for steps 1 … T): the NEES of the pose relative to the true
    start, the error (x, y, θ) and the filter's σ, and the events of the step."""

    nees: np.ndarray  # (T,)
    error: np.ndarray  # (T, 3)
    sigma: np.ndarray  # (T, 3)
    events: list[list[str]]  # per step


def landmark_error(slam: PolySlam, landmark_id: int, true_start: np.ndarray, layout: Layout) -> str:
    """A landmark's length and its true error: the largest distance of its curve (current
    c0) to the true walls, in cm."""
    if landmark_id not in slam.table:
        return f"#{landmark_id}"
    i = slam.table.index_of(landmark_id)
    poly = slam.polynomials()[i]
    points = map_points([poly], true_start, 0.02)[0]
    d = distance_to_boundary(points, layout)
    return (
        f"#{landmark_id}(o{int(slam.table.order[i])} {poly.hi - poly.lo:.2f} m,"
        f" err {100 * d.max():.1f} cm)"
    )


def replay(rec: Recording, config: SlamConfig) -> Trace:
    """The SLAM played on ``rec``'s readings with every map event logged."""
    slam = PolySlam(config, rec.angles, rec.max_range)
    true_start = rec.true[0]
    events: list[list[str]] = []
    now: list[str] = []
    touched: list[int] = []

    def logged_event(event: LineageEvent) -> None:
        parents = f" from {list(event.parents)}" if event.parents else ""
        now.append(f"{event.kind} #{event.landmark_id}{parents}")
        touched.append(event.landmark_id)

    slam.lineage.listen(logged_event)
    walls = slam.walls
    link_pair, square_wall = walls.link_pair, walls.square_wall

    def logged_link(first: int, second: int) -> bool:
        done = link_pair(first, second)
        if done:
            now.append(f"linked #{first}–#{second}")
            touched.extend((first, second))
        return done

    def logged_square(landmark_id: int) -> int:
        done = square_wall(landmark_id)
        if done:
            now.append(f"tied square #{landmark_id}")
            touched.append(landmark_id)
        return done

    walls.link_pair = logged_link  # type: ignore[method-assign]
    walls.square_wall = logged_square  # type: ignore[method-assign]
    T = len(rec.odometry)
    nees, error, sigma = np.zeros(T), np.zeros((T, 3)), np.zeros((T, 3))
    for k, (odo, z) in enumerate(zip(rec.odometry, rec.ranges, strict=True)):
        now.clear()
        touched.clear()
        info = slam.step(odo, z)
        true_rel = between(true_start, rec.true[k + 1], wrap_remainder)
        e = slam.mean[:3] - true_rel
        e[2] = wrap_remainder(e[2])
        P = slam.cov[:3, :3]
        nees[k] = float(e @ np.linalg.solve(P, e))
        error[k], sigma[k] = e, np.sqrt(np.diag(P))
        if info.diverging:
            now.append("divergence alarm")
        described = sorted(set(touched))
        if described:
            now.append(
                "; ".join(landmark_error(slam, j, true_start, rec.layout) for j in described)
            )
        events.append(list(now))
    return Trace(nees, error, sigma, events)


@dataclass
class HeadingInfo:
    """Where the heading variance changed over a stretch of steps (rad², summed)."""

    predict: float = 0.0
    map_changes: float = 0.0
    update_lines: float = 0.0  # steps whose update used straight landmarks only
    update_curves: float = 0.0  # steps whose update used a curved landmark
    steps_lines: int = 0
    steps_curves: int = 0
    steps_none: int = 0
    ages: dict[str, int] = field(default_factory=dict)  # landmark uses by kind and age fitted
    first: float = float("nan")  # the heading variance before step FROM
    last: float = float("nan")  # … and after step TO − 1


def heading_info(rec: Recording, config: SlamConfig, start: int, stop: int) -> HeadingInfo:
    """The SLAM played on ``rec``'s readings to step ``stop``; over steps ``start`` …
    ``stop`` − 1 the heading variance's change by stage (module docstring). The stages are
    told apart by wrapping the step's two compiled calls (``step_kernels.begin_step``: the
    prediction and the association, which leaves the covariance as the prediction made it;
    ``finish_step``: the update); what lies between them is the map changes."""
    slam = PolySlam(config, rec.angles, rec.max_range)
    kernels = slam_robot.step_kernels
    begin, finish = kernels.begin_step, kernels.finish_step
    seen: dict[str, float] = {}

    def begin_logged(mean: np.ndarray, cov: np.ndarray, *args: Any) -> None:
        seen["before"] = float(cov[2, 2])
        begin(mean, cov, *args)
        seen["predicted"] = float(cov[2, 2])

    def finish_logged(mean: np.ndarray, cov: np.ndarray, *args: Any) -> None:
        seen["mapped"] = float(cov[2, 2])
        finish(mean, cov, *args)
        seen["updated"] = float(cov[2, 2])

    info = HeadingInfo()
    kernels.begin_step = begin_logged  # type: ignore[assignment]
    kernels.finish_step = finish_logged  # type: ignore[assignment]
    try:
        steps = zip(rec.odometry[: stop - 1], rec.ranges[: stop - 1], strict=True)
        for k, (odo, z) in enumerate(steps):
            seen.clear()
            slam.step(odo, z)
            step = k + 1
            if step < start:
                continue
            if step == start:
                info.first = seen["before"]
            info.last = seen["updated"]
            info.predict += seen["predicted"] - seen["before"]
            info.map_changes += seen["mapped"] - seen["predicted"]
            rows = slam._outcome[0][G_ROW]
            used = np.unique(rows[rows >= 0])
            change = seen["updated"] - seen["mapped"]
            if not used.size:
                info.steps_none += 1
                continue
            orders = slam.table.order[used]
            if (orders >= 2).any():
                info.update_curves += change
                info.steps_curves += 1
            else:
                info.update_lines += change
                info.steps_lines += 1
            made_at = slam.table.changed_at[used].tolist()
            for order, made in zip(orders.tolist(), made_at, strict=True):
                kind = "curve" if order >= 2 else "line"
                key = f"{kind}, {'< 20' if step - made < 20 else '≥ 20'} steps"
                info.ages[key] = info.ages.get(key, 0) + 1
    finally:
        kernels.begin_step, kernels.finish_step = begin, finish
    return info


def print_heading_info(info: HeadingInfo, start: int, stop: int) -> None:
    deg2 = (180.0 / np.pi) ** 2
    print(
        f"heading variance (deg²) over steps {start}–{stop - 1}: {info.first * deg2:.5f} →"
        f" {info.last * deg2:.5f}; its change summed by stage:"
    )
    print(f"  prediction        {info.predict * deg2:+.5f}")
    print(f"  map changes       {info.map_changes * deg2:+.5f}")
    print(f"  update, lines     {info.update_lines * deg2:+.5f}  ({info.steps_lines} steps)")
    print(f"  update, curves    {info.update_curves * deg2:+.5f}  ({info.steps_curves} steps)")
    print(f"  no update         {info.steps_none} steps")
    print("  landmark uses: " + ", ".join(f"{k}: {v}" for k, v in sorted(info.ages.items())))


def ideal_ranges(rec: Recording) -> np.ndarray:  # (T, B)
    """The ranges without noise: every beam cast from its step's true pose onto the true
    walls (no other robots: a beam that met one reads the wall behind it)."""
    poses = rec.true[1:]
    steps, beams = rec.ranges.shape
    origins = np.repeat(poses[:, :2], beams, axis=0)
    angles = (poses[:, 2][:, None] + rec.angles[None, :]).reshape(-1)
    ranges = cast_rays(origins, angles, rec.layout.segments, np.zeros((0, 3)), rec.max_range)
    return ranges.reshape(steps, beams)


def ideal_odometry(rec: Recording) -> np.ndarray:  # (T, 3)
    """The true motion of every step, in the robot's frame of the step before."""
    return between(rec.true[:-1], rec.true[1:], wrap_remainder)


def jumps(trace: Trace, factor: float, floor: float, shrink: float) -> list[int]:
    """Rows where the NEES rose by ``factor`` over the step before and is above ``floor``, or
    where a pose σ fell below ``shrink`` times its value the step before."""
    n, sigma = trace.nees, trace.sigma
    return [
        k
        for k in range(1, n.size)
        if (n[k] > floor and n[k] > factor * max(n[k - 1], 1e-9))
        or bool((sigma[k] < shrink * sigma[k - 1]).any())
    ]


def plot(trace: Trace, title: str, path: str) -> None:
    """NEES (log scale, with χ²₃'s 95 % line) and the heading error against ±σ, per step."""
    import matplotlib.pyplot as plt

    steps = np.arange(1, trace.nees.size + 1)
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(9, 5.5))
    top.semilogy(steps, np.maximum(trace.nees, 1e-3), lw=0.8)
    top.axhline(7.81, color="k", ls="--", lw=0.8, label="χ²₃ 95 %")
    top.set_ylabel("pose NEES (relative)")
    top.legend(loc="upper left")
    top.set_title(title)
    bottom.plot(steps, np.degrees(trace.error[:, 2]), lw=0.8, label="heading error")
    bottom.fill_between(steps, -np.degrees(trace.sigma[:, 2]), np.degrees(trace.sigma[:, 2]),
                        alpha=0.3, label="±σ")  # fmt: skip
    bottom.set_ylabel("degrees")
    bottom.set_xlabel("step")
    bottom.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", required=True, help="layout generator or map file")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", type=int, default=0)
    parser.add_argument("--steps", type=int, default=1000, help="as polyslam fidelity's --steps")
    parser.add_argument(
        "--fixed-steps", action="store_true", help="a map file runs --steps, not its area's budget"
    )
    parser.add_argument("--set", nargs="*", default=[], help="SLAM overrides of the replay")
    parser.add_argument("--factor", type=float, default=1.5, help="a jump: NEES × this")
    parser.add_argument("--floor", type=float, default=7.81, help="… and above this (χ²₃ 95 %%)")
    parser.add_argument("--shrink", type=float, default=0.8, help="or a pose σ × less than this")
    parser.add_argument("--ideal-ranges", action="store_true", help="replay noise-free ranges")
    parser.add_argument("--ideal-odometry", action="store_true", help="replay the true motion")
    parser.add_argument("--every", type=int, default=50, help="print a row every N steps")
    parser.add_argument("--cache", default=None, help="keep the recording in this file")
    parser.add_argument("--plot", default=None, help="draw NEES and heading error here")
    parser.add_argument(
        "--info", default=None, metavar="FROM:TO", help="where the heading's information came from"
    )
    args = parser.parse_args()
    try:
        fidelity = FidelityConfig(steps=args.steps, area_budget=not args.fixed_steps)
        config = episode_config(fidelity, args.map, exchange=False)
        if not 0 <= args.robot < config["num_robots"]:
            raise ConfigError(f"--robot {args.robot}: the team has {config['num_robots']} robots")
        overrides = parse_overrides(args.set)
    except ConfigError as err:
        sys.exit(f"nees_trace: {err}")
    cache = Path(args.cache) if args.cache else None
    if cache is not None and cache.exists():
        with cache.open("rb") as f:
            recordings = [Recording(**fields) for fields in pickle.load(f)]
    else:
        recordings = record(config, args.seed)
        if cache is not None:
            with cache.open("wb") as f:
                pickle.dump([vars(rec) for rec in recordings], f)
    rec = recordings[args.robot]
    if args.ideal_ranges:
        rec.ranges = ideal_ranges(rec)
    if args.ideal_odometry:
        rec.odometry = ideal_odometry(rec)
    try:
        slam_config = SlamConfig.from_dict(rec.slam).replace(**overrides)
    except ConfigError as err:
        sys.exit(f"nees_trace: --set: {err}")
    if args.info:
        try:
            start, stop = (int(x) for x in args.info.split(":"))
            if not 1 <= start < stop <= len(rec.odometry) + 1:
                raise ValueError
        except ValueError:
            sys.exit(f"nees_trace: --info {args.info!r}: FROM:TO with 1 ≤ FROM < TO ≤ steps + 1")
        print_heading_info(heading_info(rec, slam_config, start, stop), start, stop)
        return
    trace = replay(rec, slam_config)
    inputs = [name for name, on in (("ideal ranges", args.ideal_ranges),
                                    ("ideal odometry", args.ideal_odometry)) if on]  # fmt: skip
    title = (
        f"{args.map} seed {args.seed} robot {args.robot}, exchange off, {len(trace.nees)} steps"
        + "".join(f", {x}" for x in inputs + list(args.set))
    )
    print(f"{title}; mean NEES {trace.nees.mean():.1f}, median {np.median(trace.nees):.1f}")
    for k in range(0, len(trace.nees), args.every):
        e, s = trace.error[k], trace.sigma[k]
        e_cm, s_cm = 100 * e[:2], 100 * s[:2]
        print(
            f"step {k + 1:5d}  NEES {trace.nees[k]:7.1f}"
            f"  err {e_cm[0]:6.1f} {e_cm[1]:6.1f} cm {np.degrees(e[2]):6.2f}°"
            f"  σ {s_cm[0]:5.1f} {s_cm[1]:5.1f} cm {np.degrees(s[2]):5.2f}°"
        )
    print("jumps (NEES up, or a pose σ down):")
    for k in jumps(trace, args.factor, args.floor, args.shrink):
        ratio = trace.sigma[k] / trace.sigma[k - 1]
        print(
            f"step {k + 1:5d}  NEES {trace.nees[k - 1]:7.1f} → {trace.nees[k]:7.1f}"
            f"  σ × {ratio[0]:.2f} {ratio[1]:.2f} {ratio[2]:.2f} (x y θ)"
        )
        for j in range(max(0, k - 2), k + 1):
            for event in trace.events[j]:
                print(f"    [{j + 1}] {event}")
    if args.plot:
        plot(trace, title, args.plot)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()

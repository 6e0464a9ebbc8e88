"""Design the paper's three robot paths on the ``paper`` map and write ``configs/paths/paper.yaml``.

Usage: ``python scripts/design_paper_paths.py [--out configs/paths/paper.yaml]
[--png /tmp/paper_paths.png] [--check-only]``

Each robot follows hand-placed waypoints (legs, each with its own speed) with a
pure-pursuit unicycle controller, run in the real :class:`World`; the clipped commands the world
applied are recorded, rounded to 4 decimals, written, then **replayed open loop** and checked
(the file is what the tests and the ``paper`` policy use, so the checks run on it):

* r1 (west room) is never in camera view (1.5 m, line of sight) of r2 or r3;
* r2 (central hall, then the west of the south strip) and r3 (north-east room, then the east
  of the south strip) see each other in exactly one contiguous window of at most 12 steps,
  not at step 0;
* no collision, no guard revert, robots ≥ 0.3 m apart and ≥ 0.25 m from every wall;
* speeds ≤ 0.1 m/s, |ω| ≤ 0.5 rad/s, 200 steps;
* each robot's true beam hits cover ≥ 30 % of the boundary, none covers 90 % or more, and the
  union covers ≥ 75 % (``metrics.hit_fraction``).

True motion does not depend on the seed (noise is in odometry and sensors only); the replay is
checked with three seeds all the same. The figure shows the map, the three paths, the start
poses and the r2–r3 meeting window.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polyslam_env.core.seeding import make_rngs
from polyslam_env.metrics import hit_fraction
from polyslam_env.scenarios.paths import Paths, load_paths, paths_dir, save_paths
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World
from polyslam_env.world.replay import Replay, contiguous_runs, replay_paths
from polyslam_env.world.sensors import wrap_angle

STEPS = 200  # k_f
V_MAX = 0.1  # m/s, design limit (the robot could do 0.3)
W_MAX = 0.5  # rad/s, design limit
LOOKAHEAD = 0.25  # m, pure-pursuit look-ahead distance
TURN_IN_PLACE = 1.0  # rad: heading errors beyond this turn on the spot
ARRIVED = 0.03  # m: a leg is done when its end is this close
MIN_WALL = 0.25  # m, required clearance of robot centres from walls
MIN_GAP = 0.3  # m, required distance between robot centres
MAX_MEETING = 12  # samples: the r2-r3 rendezvous is "a handful of steps", not a joint patrol
MIN_SHARE, MAX_SHARE, MIN_UNION = 0.30, 0.9, 0.75  # boundary-hit fractions aimed at


@dataclass(frozen=True)
class Leg:
    """Drive through ``points`` (m) at ``speed`` (m/s); the next leg starts where this ends."""

    points: tuple[tuple[float, float], ...]
    speed: float


# Waypoints (m), ~0.5 m from the walls. r1 circles the west room twice, at ~0.8 m then ~0.5 m
# from its walls; its inner loop stays low (y <= 2.95) while r2 passes the gap (x = 2, y > 3.1).
# r2 sweeps the central hall (x = 2 wall, bulge, hanging wall, hook), goes down into the west
# of the south strip and comes back up to where it started. r3 circles the north-east room
# slowly (its speed times the meeting), sweeps the east of the south strip, where it meets r2
# once at the south-west corner of its loop, and returns into the north-east room.
# fmt: off
ROUTES: dict[str, tuple[Leg, ...]] = {
    "r1": (
        Leg(((1.0, 1.5), (0.8, 1.9), (0.8, 2.95), (1.2, 2.95), (1.2, 0.9), (0.9, 0.85),  # inner
             (0.55, 1.3), (0.55, 3.3), (0.8, 3.45), (1.3, 3.4), (1.5, 2.9), (1.5, 0.8),  # outer
             (1.2, 0.5), (0.8, 0.5), (0.6, 0.7)), 0.06),
    ),
    "r2": (
        Leg(((3.0, 2.4), (2.55, 2.3), (2.5, 2.6), (2.5, 3.1), (3.8, 3.1),  # hall
             (3.8, 0.5), (2.5, 0.5), (2.5, 1.7), (3.3, 1.7),  # south strip, west
             (3.3, 2.3), (3.0, 2.6)), 0.05),  # back into the hall
    ),
    "r3": (
        Leg(((5.35, 2.4), (5.0, 2.55), (4.85, 2.9), (4.85, 3.35), (5.2, 3.25), (5.45, 2.9),
             (5.45, 2.5)), 0.038),  # north-east room
        Leg(((5.45, 0.5), (4.8, 0.5), (4.8, 1.4), (5.45, 1.4)), 0.07),  # south strip, east
        Leg(((5.45, 2.9), (5.2, 3.25), (4.85, 3.35), (4.85, 2.9)), 0.05),  # north-east room
    ),
}
# fmt: on


class PurePursuit:
    """Follows a robot's legs: look-ahead point on the current leg, turn on the spot if needed."""

    def __init__(self, legs: tuple[Leg, ...], start: np.ndarray) -> None:
        self.legs = legs
        self.leg = -1  # index of the current leg; len(legs) when done
        self._next_leg(start)

    def _next_leg(self, pose: np.ndarray) -> None:
        """Start the next leg from the current position."""
        self.leg += 1
        if self.leg < len(self.legs):
            pts = np.asarray(self.legs[self.leg].points, dtype=float)
            self.poly = np.vstack([pose[:2], pts])  # (P, 2) polyline of the leg
            seg = np.diff(self.poly, axis=0)  # (P-1, 2)
            self.seg_len = np.hypot(seg[:, 0], seg[:, 1])  # (P-1,)
            self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])  # (P,)
            self.progress = 0.0  # m along the polyline

    @property
    def done(self) -> bool:
        return self.leg >= len(self.legs)

    def _point_at(self, s: float) -> np.ndarray:  # (2,)
        s = float(np.clip(s, 0.0, self.cum[-1]))
        i = min(int(np.searchsorted(self.cum, s, side="right")) - 1, len(self.seg_len) - 1)
        frac = (s - self.cum[i]) / max(self.seg_len[i], 1e-12)
        return np.asarray(self.poly[i] + frac * (self.poly[i + 1] - self.poly[i]))

    def _project(self, xy: np.ndarray) -> float:
        """Arc length of the point of the leg nearest ``xy``, searched just ahead of progress."""
        s = np.linspace(self.progress, min(self.progress + 0.5, self.cum[-1]), 51)
        pts = np.array([self._point_at(v) for v in s])  # (51, 2)
        return float(s[int(np.argmin(np.hypot(*(pts - xy).T)))])

    def _arrived(self, pose: np.ndarray) -> bool:
        """Near the end of the polyline (not merely passing its end point) and close to it."""
        near_end = self.progress > self.cum[-1] - 2 * LOOKAHEAD
        return near_end and math.hypot(*(self.poly[-1] - pose[:2])) < ARRIVED

    def command(self, pose: np.ndarray) -> tuple[float, float]:
        """(v, ω) for the current true pose; (0, 0) once the last leg is done."""
        while not self.done and self._arrived(pose):
            self._next_leg(pose)
        if self.done:
            return 0.0, 0.0
        speed = self.legs[self.leg].speed
        self.progress = self._project(pose[:2])
        dx, dy = self._point_at(self.progress + LOOKAHEAD) - pose[:2]
        alpha = float(wrap_angle(np.array(math.atan2(dy, dx) - pose[2])))
        if abs(alpha) > TURN_IN_PLACE:
            return 0.0, float(np.clip(alpha, -W_MAX, W_MAX))
        to_go = max(self.cum[-1] - self.progress, math.hypot(*(self.poly[-1] - pose[:2])))
        v = min(speed * math.cos(alpha), to_go)  # stop on the leg's end, do not overshoot it
        w = 2.0 * speed * math.sin(alpha) / LOOKAHEAD  # pure-pursuit curvature 2 sin(α) / L
        return v, float(np.clip(w, -W_MAX, W_MAX))


def drive(layout: Layout) -> np.ndarray:  # (N, K, 2)
    """Run the controllers in the world for STEPS steps; the clipped commands applied."""
    world = World(layout, WorldConfig(), 3, make_rngs(0))
    ctrl = [PurePursuit(ROUTES[r], world.poses[i]) for i, r in enumerate(ROUTES)]
    applied, done = [], [STEPS] * 3
    for k in range(STEPS):
        done = [k if d == STEPS and c.done else d for d, c in zip(done, ctrl, strict=True)]
        pose = world.poses
        cmd = np.array([c.command(pose[i]) for i, c in enumerate(ctrl)])  # (3, 2)
        applied.append(world.step(cmd).commands)
    print("routes end at steps " + ", ".join(f"{r} {d}" for r, d in zip(ROUTES, done, strict=True)))
    return np.stack(applied, axis=1)


# -- checks ------------------------------------------------------------------------------------
def check(replay: Replay, paths: Paths) -> list[str]:
    """The promises of the paper paths; returns the failures (empty when all hold)."""
    fails = []
    if paths.num_steps != STEPS or paths.num_robots != 3:
        fails.append(f"shape {paths.commands.shape}, expected (3, {STEPS}, 2)")
    if np.abs(paths.commands[..., 0]).max() > V_MAX + 1e-9:
        fails.append(f"speed {np.abs(paths.commands[..., 0]).max():.4f} > {V_MAX}")
    if np.abs(paths.commands[..., 1]).max() > W_MAX + 1e-9:
        fails.append(f"turn rate {np.abs(paths.commands[..., 1]).max():.4f} > {W_MAX}")
    for j in (1, 2):
        seen = replay.visible[:, 0, j] | replay.visible[:, j, 0]  # (K+1,) either way
        if seen.any():
            fails.append(f"r1 and r{j + 1} in view at samples {contiguous_runs(seen)}")
    meet = replay.meetings(1, 2)
    if len(meet) != 1 or meet[0][0] == 0 or meet[0][1] - meet[0][0] + 1 > MAX_MEETING:
        fails.append(f"r2-r3 meetings {meet}: expected one window of <= {MAX_MEETING} after 0")
    if replay.collided.any() or replay.guard_reverts:
        fails.append(f"collisions at steps {np.argwhere(replay.collided).tolist()[:5]}")
    gaps = replay.pair_distances() + np.eye(3) * 1e9
    if gaps.min() < MIN_GAP:
        fails.append(f"robots {gaps.min():.3f} m apart < {MIN_GAP}")
    clear = replay.layout.clearance(replay.poses[..., :2].reshape(-1, 2)).reshape(-1, 3)
    if clear.min() < MIN_WALL:
        worst = np.unravel_index(int(np.argmin(clear)), clear.shape)
        fails.append(f"r{worst[1] + 1} {clear.min():.3f} m from a wall at sample {worst[0]}")
    share, union = coverage(replay)
    if min(share) < MIN_SHARE or max(share) >= MAX_SHARE or union < MIN_UNION:
        fails.append(f"boundary hits {[round(s, 3) for s in share]}, union {union:.3f}")
    return fails


def coverage(replay: Replay) -> tuple[list[float], float]:
    """Per-robot and union fractions of the boundary within 5 cm of a true beam hit."""
    per = [replay.robot_hits(i) for i in range(3)]
    union = hit_fraction(np.vstack(per), replay.layout)
    return [hit_fraction(h, replay.layout) for h in per], union


# -- figure ------------------------------------------------------------------------------------
def plot(replay: Replay, path: Path) -> None:
    """The map, the three true paths with start poses, and the r2–r3 meeting window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6.4))
    for wall in replay.layout.walls:
        ax.plot(wall[:, 0], wall[:, 1], "k-", lw=1.5)
    colours = ("tab:blue", "tab:orange", "tab:green")
    for i, c in enumerate(colours):
        xy = replay.poses[:, i, :2]
        ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=1.2, label=f"r{i + 1}")
        ax.plot(xy[::20, 0], xy[::20, 1], ".", color=c, ms=4)
        x, y, th = replay.poses[0, i]
        ax.annotate(
            "",
            (x + 0.25 * math.cos(th), y + 0.25 * math.sin(th)),
            (x, y),
            arrowprops={"arrowstyle": "->", "color": c, "lw": 2},
        )
        hits = replay.robot_hits(i)
        ax.plot(hits[:, 0], hits[:, 1], ",", color=c, alpha=0.5)
    for a, b in replay.meetings(1, 2):
        for k in range(a, b + 1):
            p, q = replay.poses[k, 1, :2], replay.poses[k, 2, :2]
            ax.plot([p[0], q[0]], [p[1], q[1]], "r-", lw=0.8, alpha=0.6)
        ax.plot([], [], "r-", label=f"r2-r3 meet, steps {a}-{b}")
    share, union = coverage(replay)
    ax.set_title(
        "paper paths: boundary hit "
        + ", ".join(f"r{i + 1} {s:.0%}" for i, s in enumerate(share))
        + f", union {union:.0%}"
    )
    ax.set_aspect("equal")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


HEADER = """The paper's three precomputed paths (§4) on the `paper` map: k_f = 200 steps of T = 1 s,
one [v (m/s), omega (rad/s)] per step, robot i starting at the map's start_poses[i].
r1 never meets anyone; r2 and r3 see each other in exactly one window; no robot alone sees the
whole boundary. Generated by scripts/design_paper_paths.py (do not edit by hand; rerun it)."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=paths_dir() / "paper.yaml")
    parser.add_argument("--png", type=Path, default=Path("/tmp/paper_paths.png"))
    parser.add_argument("--check-only", action="store_true", help="replay --out, write nothing")
    args = parser.parse_args(argv)
    layout = load_map("paper")
    if not args.check_only:
        designed = Paths("paper", "paper", 1.0, np.round(drive(layout), 4))
        save_paths(designed, args.out, HEADER)
    paths = load_paths(args.out)
    replays = [replay_paths(paths, layout, seed=s) for s in (0, 1, 2)]
    same = all(np.array_equal(r.poses, replays[0].poses) for r in replays[1:])
    replay = replays[0]
    share, union = coverage(replay)
    print(
        "boundary hit fraction: "
        + ", ".join(f"r{i + 1} {s:.3f}" for i, s in enumerate(share))
        + f", union {union:.3f}"
    )
    print(f"r2-r3 meeting windows (samples): {replay.meetings(1, 2)}")
    d = replay.pair_distances()
    pairs = ((0, 1), (0, 2), (1, 2))
    print(
        "closest approach "
        + ", ".join(f"r{i + 1}-r{j + 1} {d[:, i, j].min():.2f} m" for i, j in pairs)
    )
    clear = replay.layout.clearance(replay.poses[..., :2].reshape(-1, 2)).reshape(-1, 3)
    print(
        "min wall clearance "
        + ", ".join(f"r{i + 1} {c:.3f}" for i, c in enumerate(clear.min(axis=0)))
        + " m"
    )
    print(f"true paths identical for seeds 0, 1, 2: {same}")
    plot(replay, args.png)
    print(f"figure: {args.png}")
    fails = check(replay, paths) + ([] if same else ["true paths depend on the seed"])
    for f in fails:
        print("FAIL:", f)
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())

"""Cheap whole episodes of the SLAM alone on small fixed maps of the new floor families.

An episode of the generated families in the env costs ~30 s (docs/notes/floors.md, R3.3), far
beyond what a test over ≥ 20 seeds per family may take. Here one :class:`PolySlam` runs
alone along a scripted path on a small map of each family — an arc corridor for the curved
floors, walls at 30° and −30° for the angled ones, an irregular chamber with a rock island for
the caves, and a wide chamber for the open spaces — a few hundred steps, ~0.1 s an episode.

The world is the SLAM's own model, exactly: the true pose moves by the scripted increments
(v·T, 0, Δθ) (:func:`~polyslam_env.core.geometry.compose`), the odometry is that increment
plus N(0, ``odom_cov``), and the ranges are the default sensor's beams
(:class:`~polyslam_env.world.sensors.RangeSensor`, the env's ray casting on the map's
polylines) plus N(0, ``range_sigma``²). So a consistent filter's errors are exactly as large
as its covariance says, up to linearisation and its map model (cubics for curved walls).
With ``initial_error`` the true start is the nominal start ⊕ e₀, e₀ ~ N(0, P0) (as the env
draws it), so the robot sees its map shifted by e₀ while its estimate starts at 0.

``python -m tests.slam.floor_families --seeds 70`` runs every family and prints the figures
the tests check (final relative NEES per family, the slope of ``nees_rel`` on
``start_nees`` over all robots).
"""

from __future__ import annotations

import argparse
import functools
import math
from dataclasses import dataclass

import numpy as np

from polyslam_env.core.geometry import between, compose, wrap_remainder
from polyslam_env.core.seeding import make_rngs
from polyslam_env.metrics.episode import RobotRun, nees_relative, start_nees
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.robot import PolySlam
from polyslam_env.world.config import RangeSensorConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.nearby import WallIndex
from polyslam_env.world.sensors import RangeSensor

#: m per step: 0.08 m/s at the env's 1 s control period (v_max 0.3 m/s), as the wall follower.
SPEED = 0.08
#: m, spacing of the polylines of curved walls (the cave generator's).
SPACING = 0.03

Move = tuple[float, float]  # (v·T, Δθ) of one step


def line(length: float, speed: float = SPEED) -> list[Move]:
    return [(speed, 0.0)] * round(length / speed)


def turn(angle: float, steps: int = 12) -> list[Move]:
    """In place by ``angle`` (rad) over ``steps`` steps (180° in 12: 15° a step)."""
    return [(0.0, angle / steps)] * steps


def circle(radius: float, angle: float) -> list[Move]:
    """Along a circle of ``radius`` through ``angle`` (rad; > 0 turns left)."""
    n = round(abs(angle) * radius / SPEED)
    return [(abs(angle) * radius / n, angle / n)] * n


def arc(centre: tuple[float, float], radius: float, a0: float, a1: float) -> np.ndarray:
    """A circular wall (k, 2) from angle ``a0`` to ``a1`` about ``centre``."""
    n = max(2, math.ceil(abs(a1 - a0) * radius / SPACING))
    a = np.linspace(a0, a1, n + 1)
    return np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)])


def outline(
    centre: tuple[float, float], radius: float, amplitudes: list[float], phases: list[float]
) -> np.ndarray:
    """A closed star-shaped wall (k, 2): radius R (1 + Σ_k a_k cos(kφ + φ_k)), k = 2, 3, …
    (the cave generator's chambers and islands)."""
    phi = np.linspace(0.0, 2.0 * math.pi, math.ceil(2.0 * math.pi * radius / SPACING) + 1)
    k = np.arange(2, 2 + len(amplitudes))
    waves = np.asarray(amplitudes) * np.cos(np.outer(phi, k) + np.asarray(phases))
    rho = radius * (1.0 + waves.sum(axis=1))
    points = np.column_stack([centre[0] + rho * np.cos(phi), centre[1] + rho * np.sin(phi)])
    points[-1] = points[0]
    return points


def corridor(centre_line: np.ndarray, half: float) -> list[np.ndarray]:
    """The two walls (left, right) of a corridor ``half`` either side of the polyline
    ``centre_line`` (k, 2), mitred at its bends, and the two walls closing its ends."""
    d = np.diff(centre_line, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    normals = np.column_stack([-d[:, 1], d[:, 0]])
    sides = []
    for sign in (1.0, -1.0):
        wall = [centre_line[0] + sign * half * normals[0]]
        for i in range(1, len(centre_line) - 1):
            mitre = normals[i - 1] + normals[i]
            mitre /= np.linalg.norm(mitre)
            wall.append(centre_line[i] + sign * half * mitre / float(mitre @ normals[i]))
        wall.append(centre_line[-1] + sign * half * normals[-1])
        sides.append(np.array(wall))
    left, right = sides
    return [left, right, np.array([left[0], right[0]]), np.array([left[-1], right[-1]])]


@dataclass(frozen=True)
class Floor:
    """A small map (wall polylines), the nominal start (3,) and the scripted path."""

    name: str
    walls: tuple[np.ndarray, ...]
    start: np.ndarray
    moves: tuple[Move, ...]

    @functools.cached_property
    def index(self) -> WallIndex:
        return WallIndex.build(Layout(self.name, self.walls).segments)


def _curved() -> Floor:
    """Half a ring corridor 1.4 m wide (inner wall radius 2.6 m, convex; outer 4.0 m,
    concave), closed at its ends; the path follows its centre through 144°, turns round and
    comes back 81° over the walls it mapped."""
    walls = (
        arc((0.0, 0.0), 2.6, -0.5 * math.pi, 0.5 * math.pi),
        arc((0.0, 0.0), 4.0, -0.5 * math.pi, 0.5 * math.pi),
        np.array([[0.0, -2.6], [0.0, -4.0]]),
        np.array([[0.0, 2.6], [0.0, 4.0]]),
    )
    moves = circle(3.3, 0.8 * math.pi) + turn(math.pi) + circle(3.3, -0.45 * math.pi)
    return Floor("curved", walls, np.array([0.3, -3.3, 0.0]), tuple(moves))


def _angled() -> Floor:
    """A corridor 1.4 m wide running at 30°, bending by 60° to run at −30° (no wall square
    to another), closed at its ends; the path follows it, turns round and comes back 3 m."""
    a = math.radians(30.0)
    bend = 4.0 * np.array([math.cos(a), math.sin(a)])
    centre_line = np.array(
        [
            -0.6 * np.array([math.cos(a), math.sin(a)]),
            bend,
            bend + 4.0 * np.array([math.cos(a), -math.sin(a)]),
        ]
    )
    moves = line(4.0) + turn(-2.0 * a, 8) + line(3.4) + turn(math.pi) + line(3.0)
    return Floor("angled", tuple(corridor(centre_line, 0.7)), np.array([0.0, 0.0, a]), tuple(moves))


def _cave() -> Floor:
    """An irregular chamber (mean radius 2.6 m, three harmonics) with a rock island (0.5 m)
    off its centre; the path circles the island 1.3 times (its first walls seen again)."""
    walls = (
        outline((0.0, 0.0), 2.6, [0.08, 0.05, 0.03], [0.5, 1.3, 2.0]),
        outline((0.2, -0.1), 0.5, [0.1, 0.05], [0.3, 2.0]),
    )
    moves = circle(1.45, 2.6 * math.pi)
    return Floor("cave", walls, np.array([1.45, 0.0, 0.5 * math.pi]), tuple(moves))


FAMILIES = {f.name: f for f in (_curved(), _angled(), _cave())}

#: The open chamber's first wall (y = 0.7, along the first stretch, on the left) and the far
#: wall (y = −9.3), both of direction 0 in the robot's frame, the start's.
OPEN_WALLS = {"first": 0.7, "far": -9.3}
#: m per step across the chamber: the robot's top speed, 0.3 m/s, less a margin.
CROSSING = 0.2


def _open() -> Floor:
    """A wide chamber (8 × 10 m): the path maps 1.5 m of the first wall, crosses 8.6 m to
    the far wall (blind for ~7 m: the N/S walls are 3 m away, beyond the 2 m range, and the
    first wall is behind), maps 1.5 m of it, and crosses back onto the first wall, which it
    re-acquires head-on and then follows back over the stretch it mapped first."""
    first, far = OPEN_WALLS["first"], OPEN_WALLS["far"]
    walls = (
        np.array([[-3.0, first], [5.0, first]]),
        np.array([[-3.0, far], [5.0, far]]),
        np.array([[-3.0, first], [-3.0, far]]),
        np.array([[5.0, first], [5.0, far]]),
    )
    cross = line(8.6, CROSSING)
    moves = (
        line(1.5) + turn(-0.5 * math.pi, 6) + cross + turn(0.5 * math.pi, 6) + line(1.5)
        + turn(math.pi) + line(1.5) + turn(-0.5 * math.pi, 6) + cross
        + turn(0.5 * math.pi, 6) + line(1.5)
    )  # fmt: skip
    return Floor("open", walls, np.zeros(3), tuple(moves))


OPEN = _open()


@dataclass
class Episode:
    """One robot's episode: what the metrics take (:class:`RobotRun`), its SLAM at the end,
    and its final pose error relative to the true start with the filter's own P_S."""

    run: RobotRun
    slam: PolySlam
    odometry: np.ndarray  # (K, 3) what the filter was given
    beams_used: np.ndarray  # (K,) beams in each step's update
    cov_relative: np.ndarray  # (K+1, 3, 3) the filter's own P_S after each step

    @property
    def final_nees(self) -> float:
        """eᵀP_S⁻¹e at the last step, e the error relative to the true start."""
        true = between(self.run.true_poses[0], self.run.true_poses[-1], wrap_remainder)
        e = true - self.slam.pose
        e[2] = wrap_remainder(float(e[2]))
        return float(e @ np.linalg.solve(self.slam.pose_cov_relative, e))


def episode(
    floor: Floor,
    seed: int,
    config: SlamConfig | None = None,
    world_sigma: float | None = None,
    initial_error: bool = True,
    odometry_scale: float = 1.0,
) -> Episode:
    """The SLAM alone along ``floor``'s path, with ``initial_error`` its true start drawn
    from P0 about the nominal one (stream ``anchor``), odometry and range noise from
    ``config``'s model (to force a filter that is wrong about its sensors: ranges with σ
    ``world_sigma``, odometry with ``odometry_scale`` times its σ)."""
    cfg = config or SlamConfig()
    rngs = make_rngs(seed, ["anchor", "noise"])
    sensor = RangeSensor(
        RangeSensorConfig(sigma=cfg.range_sigma if world_sigma is None else world_sigma)
    )
    slam = PolySlam(cfg, sensor.angles, sensor.config.max_range)
    e0 = rngs["anchor"].multivariate_normal(np.zeros(3), cfg.p0)
    pose = compose(floor.start, e0) if initial_error else floor.start.copy()
    odometry_sigma = odometry_scale * np.sqrt(np.diag(cfg.odom_cov))
    true, est, covs, own = [pose], [slam.pose], [slam.pose_cov], [slam.pose_cov_relative]
    odometry, used = [], []
    no_circles = np.zeros((0, 3))
    for dist, dtheta in floor.moves:
        u = np.array([dist, 0.0, dtheta])
        pose = compose(pose, u)
        ranges = sensor.measure(pose[None], floor.index, no_circles, rngs["noise"])[0]
        odometry.append(u + rngs["noise"].normal(0.0, odometry_sigma))
        used.append(slam.step(odometry[-1], ranges).beams_used)
        true.append(pose)
        est.append(slam.pose)
        covs.append(slam.pose_cov)
        own.append(slam.pose_cov_relative)
    k = len(floor.moves)
    run = RobotRun(
        floor.start, np.array(true), np.array(est), np.array(covs), slam.polynomials(),
        np.zeros((0, 2)), np.zeros(k), False, 0, p0=cfg.p0 if initial_error else None,
    )  # fmt: skip
    return Episode(run, slam, np.array(odometry), np.array(used), np.array(own))


@functools.cache
def episodes(name: str, seeds: int) -> tuple[Episode, ...]:
    """Seeds 0 … ``seeds`` − 1 of family ``name`` with the default config (cached: the NEES
    test and the start-draw test share them)."""
    return tuple(episode(FAMILIES[name], seed) for seed in range(seeds))


def start_draw_rows(runs: list[RobotRun]) -> list[dict[str, float]]:
    """Each robot's ``nees_rel`` and ``start_nees`` (the metrics' own functions) as the rows
    ``scripts/nees_start_draw.py``'s ``analyse`` takes; every robot its own episode."""
    return [
        {"seed": i, "draw": -1, "nees_rel": nees_relative(r), "start_nees": start_nees(r)}
        for i, r in enumerate(runs)
    ]


def main() -> None:
    from tests.scripts_module import load_script
    from tests.stats import log_chi2_mean_band, log_mean

    parser = argparse.ArgumentParser(description="The floor families' NEES and start draws")
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    lo, hi = log_chi2_mean_band(3, args.seeds, 0.01)
    runs = []
    for name in FAMILIES:
        eps = episodes(name, args.seeds)
        final = [e.final_nees for e in eps]
        print(f"{name}: final relative NEES log-mean {log_mean(final):.3f} in [{lo:.3f}, {hi:.3f}]"
              f" (median {np.median(final):.2f})")  # fmt: skip
        runs += [e.run for e in eps]
    study = load_script("nees_start_draw")
    result = study.analyse(start_draw_rows(runs), False, np.random.default_rng(0))
    print(
        {
            k: result[k]
            for k in ("robots", "slope", "slope_ci_t", "slope_ci_bootstrap", "tercile_mean")
        }
    )


if __name__ == "__main__":
    main()

"""The pymunk world: real collisions, differential drive, clipping, odometry, failures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polyslam_env.core.errors import MapFileError
from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.generators import GENERATORS
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map
from polyslam_env.world.physics import World
from tests.scripts_module import load_script

CFG = WorldConfig()
R = CFG.robot.radius
# Overlap allowed by the checks below: the skin rules out first-impact overlap, what is left is
# the iterative solver's residual when a robot is wedged, measured at < 0.1 mm; 1 mm is 10× that.
TOL = 1e-3
physics_substeps = load_script("physics_substeps")


def box_layout(w: float, h: float, interior: list[np.ndarray] | None = None) -> Layout:
    box = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h], [0.0, 0.0]])
    return Layout("box", (box, *(interior or [])))


def random_layout(rng: np.random.Generator) -> Layout:
    """A box of random size with up to three random interior wall segments."""
    w, h = rng.uniform(0.6, 2.0, size=2)
    n_seg = int(rng.integers(0, 4))
    return box_layout(w, h, [rng.uniform([0, 0], [w, h], size=(2, 2)) for _ in range(n_seg)])


def random_poses(rng: np.random.Generator, layout: Layout, n: int) -> np.ndarray | None:
    """n start poses clear of walls and of each other (None if rejection sampling fails)."""
    x0, y0, x1, y1 = layout.bounds
    poses: list[np.ndarray] = []
    for _ in range(500):
        p = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1), rng.uniform(-np.pi, np.pi)])
        ok = layout.contains(p[None, :2])[0] and layout.clearance(p[None, :2])[0] > R + 0.01
        if ok and all(math.hypot(*(p[:2] - q[:2])) > 2 * R + 0.01 for q in poses):
            poses.append(p)
            if len(poses) == n:
                return np.array(poses)
    return None


def crosses(p: np.ndarray, q: np.ndarray, seg: np.ndarray) -> bool:
    """Plain orientation test: does the path p→q properly cross segment seg (x0, y0, x1, y1)?"""

    def orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
        return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    a, b = seg[:2], seg[2:]
    return orient(p, q, a) * orient(p, q, b) < 0 and orient(a, b, p) * orient(a, b, q) < 0


def point_segment(p: np.ndarray, seg: np.ndarray) -> float:
    a, b = seg[:2], seg[2:]
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * (b - a))))


def check_invariants(layout: Layout, old: np.ndarray, new: np.ndarray) -> None:
    """No centre crossed a wall, no robot overlaps a wall or another robot, all inside."""
    for i in range(len(new)):
        for seg in layout.segments:
            assert not crosses(old[i, :2], new[i, :2], seg), f"robot {i} crossed {seg}"
            assert point_segment(new[i, :2], seg) >= R - TOL, f"robot {i} in wall {seg}"
        for j in range(i):
            assert math.dist(new[i, :2], new[j, :2]) >= 2 * R - TOL, f"robots {i}, {j} overlap"
    assert layout.contains(new[:, :2]).all()


def commands_for(pattern: str, rng: np.random.Generator, world: World) -> np.ndarray:
    """Commands that stress the contacts: full-speed pushes, converging robots, random."""
    n = world.num_robots
    if pattern == "push":  # full speed ahead, slight turns: ends up ramming walls and corners
        return np.column_stack([np.full(n, 1.0), rng.uniform(-0.2, 0.2, n)])
    if pattern == "converge":  # every robot turns towards the team's centroid, at full speed
        p = world.poses
        to = p[:, :2].mean(axis=0) - p[:, :2]
        err = np.arctan2(to[:, 1], to[:, 0]) - p[:, 2]
        return np.column_stack([np.full(n, 1.0), 3.0 * np.arctan2(np.sin(err), np.cos(err))])
    return rng.uniform(-2.0, 2.0, size=(n, 2))  # beyond the limits on purpose: clipped


# a seeded random map, team and command sequence: the seed is the input (a plain parameter)
@pytest.mark.parametrize("seed", range(40))
def test_world__robots_never_pass_through_walls_or_each_other(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_robots = int(rng.integers(1, 6))
    patterns = list(rng.choice(["push", "converge", "random"], size=int(rng.integers(1, 4))))
    layout = random_layout(rng)
    poses = random_poses(rng, layout, n_robots)
    if poses is None:
        return  # the random map is too cramped for this team; other examples cover it
    world = World(layout, CFG, n_robots, make_rngs(seed), start_poses=poses)
    old = world.poses
    for pattern in patterns:
        for _ in range(12):
            world.step(commands_for(pattern, rng, world))
            new = world.poses
            check_invariants(layout, old, new)
            old = new
    # world.guard_reverts may be > 0 here: a robot rammed by another into a gap narrower than
    # itself can settle ~2 mm into a wall, and the guard undoes that step (physics module doc).


def test_step__head_on_robots_stop_at_contact() -> None:
    layout = box_layout(3.0, 1.0)
    poses = np.array([[1.0, 0.5, 0.0], [2.0, 0.5, math.pi]])
    world = World(layout, CFG, 2, make_rngs(0), start_poses=poses)
    hit = np.zeros(2, dtype=bool)
    for _ in range(5):
        hit |= world.step(np.array([[0.3, 0.0], [0.3, 0.0]])).collided
    p = world.poses
    gap = p[1, 0] - p[0, 0]
    # They meet in the middle; the skin (one sub-step each) stops them at most two skins early.
    assert 2 * R - TOL <= gap <= 2 * R + 2 * world.skin + TOL
    assert abs(p[0, 0] + p[1, 0] - 3.0) < 1e-9  # symmetric: equal and opposite to round-off
    assert hit.all()
    assert world.guard_reverts == 0  # the physics alone stopped them


def test_step__robot_pushing_a_wall_stops_and_reports_collision() -> None:
    layout = box_layout(1.0, 1.0)
    world = World(layout, CFG, 1, make_rngs(0), start_poses=np.array([[0.5, 0.5, 0.0]]))
    results = [world.step(np.array([[0.3, 0.0]])) for _ in range(6)]
    x = world.poses[0, 0]
    assert 1.0 - R - CFG.wall_radius - world.skin - TOL <= x <= 1.0 - R - CFG.wall_radius + TOL
    assert results[-1].collided[0] and not results[0].collided[0]
    assert abs(results[-1].true_odometry[0, 0]) < 1e-9  # pinned: no further motion
    assert world.guard_reverts == 0


def test_step__robot_slides_along_a_wall_it_hits_at_an_angle() -> None:
    layout = box_layout(2.0, 1.0)
    start = np.array([[0.5, 0.8, math.radians(30.0)]])
    world = World(layout, CFG, 1, make_rngs(0), start_poses=start)
    for _ in range(3):
        world.step(np.array([[0.3, 0.0]]))
    # Frictionless contact keeps the along-wall speed 0.3 cos 30° once pinned to the top wall.
    res = world.step(np.array([[0.3, 0.0]]))
    assert res.collided[0]
    assert res.true_odometry[0, 0] == pytest.approx(0.3 * math.cos(math.radians(30)) ** 2, 1e-6)


@pytest.mark.parametrize(("v", "w"), [(0.2, 0.5), (0.3, -1.5), (-0.1, 0.3), (0.25, 0.0)])
def test_step__free_motion_follows_the_unicycle_arc(v: float, w: float) -> None:
    world = World(box_layout(4.0, 4.0), CFG, 1, make_rngs(0), np.array([[2.0, 2.0, 0.3]]))
    odo = world.step(np.array([[v, w]])).true_odometry[0]
    dt = CFG.dt
    exact = (
        np.array([v * dt, 0.0, 0.0])
        if w == 0
        else np.array([v / w * math.sin(w * dt), v / w * (1 - math.cos(w * dt)), w * dt])
    )
    # Sub-steps follow the arc's chords exactly: only round-off over the sub-steps remains.
    np.testing.assert_allclose(odo, exact, atol=1e-12)


def test_clip_commands__limits_and_no_reverse() -> None:
    world = World(box_layout(4.0, 4.0), CFG, 2, make_rngs(0), np.array([[1, 1, 0], [3, 3, 0.0]]))
    res = world.step(np.array([[5.0, -9.0], [-5.0, 9.0]]))
    rc = CFG.robot
    np.testing.assert_array_equal(
        res.commands, [[rc.v_max, -rc.omega_max], [-rc.v_max, rc.omega_max]]
    )
    assert res.true_odometry[0, 2] == pytest.approx(-rc.omega_max * CFG.dt, abs=1e-12)
    fwd = CFG.replace(robot__allow_reverse=False)
    world = World(box_layout(4.0, 4.0), fwd, 1, make_rngs(0), np.array([[2.0, 2.0, 0.0]]))
    res = world.step(np.array([[-0.2, 0.0]]))
    assert res.commands[0, 0] == 0.0
    assert np.allclose(res.true_odometry, 0.0, atol=1e-12)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_step__non_finite_command_raises_naming_the_robot(bad: float) -> None:
    world = World(load_map("two_rooms"), CFG, 3, make_rngs(0))
    cmd = np.zeros((3, 2))
    cmd[2, 1] = bad
    with pytest.raises(ValueError, match="robot_2"):
        world.step(cmd)


def test_step__wrong_shape_raises() -> None:
    world = World(load_map("two_rooms"), CFG, 3, make_rngs(0))
    with pytest.raises(ValueError, match="shape"):
        world.step(np.zeros((2, 2)))


def test_world__too_few_start_poses_is_a_map_error() -> None:
    with pytest.raises(MapFileError, match="two_rooms"):
        World(load_map("two_rooms"), CFG, 4, make_rngs(0))


def test_world__start_pose_in_a_wall_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"start_poses\[0\]"):
        World(box_layout(1.0, 1.0), CFG, 1, make_rngs(0), np.array([[0.03, 0.5, 0.0]]))


def test_poses__heading_is_wrapped() -> None:
    world = World(box_layout(4.0, 4.0), CFG, 1, make_rngs(0), np.array([[2.0, 2.0, 3.0]]))
    for _ in range(5):
        world.step(np.array([[0.0, 1.5]]))
    th = world.poses[0, 2]
    assert -math.pi < th <= math.pi
    assert th == pytest.approx(math.remainder(3.0 + 7.5, 2 * math.pi), abs=1e-9)


def test_disable__failed_robot_is_an_immovable_obstacle() -> None:
    layout = box_layout(3.0, 1.0)
    poses = np.array([[1.0, 0.5, 0.0], [1.5, 0.5, math.pi]])
    world = World(layout, CFG, 2, make_rngs(0), start_poses=poses)
    world.disable(1)
    for _ in range(5):
        res = world.step(np.array([[0.3, 0.0], [0.3, 0.0]]))
    p = world.poses
    np.testing.assert_array_equal(p[1], poses[1])  # commanded, pushed, but never moved
    assert 2 * R - TOL <= p[1, 0] - p[0, 0] <= 2 * R + 2 * world.skin
    assert res.collided[0]
    np.testing.assert_array_equal(res.commands[1], [0.0, 0.0])
    assert world.camera()[0] == []  # 0.13 m apart, in range, but failed robots are not seen


def test_odometry__noise_has_the_configured_covariance() -> None:
    cfg = CFG.replace(odometry__sigma_xy=0.01, odometry__sigma_theta_deg=0.5)
    n_robots, steps = 4, 1500
    world = World(
        box_layout(4.0, 4.0),
        cfg,
        n_robots,
        make_rngs(3),
        np.array([[1, 1, 0], [3, 1, 1], [1, 3, 2], [3, 3, 3]], dtype=float),
    )
    rng = np.random.default_rng(3)
    resid = []
    for _ in range(steps):
        cmd = np.column_stack([rng.uniform(-0.05, 0.05, n_robots), rng.uniform(-1, 1, n_robots)])
        res = world.step(cmd)
        resid.append(res.odometry - res.true_odometry)
    e = np.concatenate(resid)  # (6000, 3)
    sig = np.array([0.01, 0.01, math.radians(0.5)])
    n = len(e)
    cov = np.cov(e.T) / np.outer(sig, sig)  # normalised: identity if correct
    # A sample variance of n Gaussians has relative std sqrt(2/n) ≈ 0.018, a correlation 1/sqrt(n)
    # ≈ 0.013: 5 standard errors keep a false failure below 1e-6.
    np.testing.assert_allclose(np.diag(cov), 1.0, atol=5 * math.sqrt(2 / n))
    off = cov[~np.eye(3, dtype=bool)]
    assert np.all(np.abs(off) < 5 / math.sqrt(n))
    assert np.all(np.abs(e.mean(axis=0) / sig) < 5 / math.sqrt(n))  # unbiased


#: Every generator but cave_system and curved_floor, whose layouts take seconds to build (their
#: chains of short segments are the cave's, which stays); all nine are in the 10^5-step study.
QUICK_GENERATORS = [name for name in GENERATORS if name not in ("cave_system", "curved_floor")]


@pytest.mark.parametrize("generator", QUICK_GENERATORS)
def test_default_substeps__no_robot_through_or_into_anything_on_the_generators(
    generator: str,
) -> None:
    # The default sub-step count on a layout of the generator, 4 robots driving seeded random
    # held commands, every step checked by brute force before the guard: the study of
    # scripts/physics_substeps.py (10^5 steps on every generator) cut to one short episode.
    row = physics_substeps.drive(generator, CFG.substeps, 100, 4, 100, seed=1)
    broken = {k: row[k] for k in ("through", "wall_overlap", "pillar_overlap", "robot_overlap")}
    assert broken == dict.fromkeys(broken, 0)
    assert row["after_guard"] == 0
    # A robot that moved less than half its commanded chord was blocked by a push: counted.
    assert row["pushes_counted"] in (None, 1.0)


def _run(world: World, rng: np.random.Generator, steps: int) -> list[tuple[np.ndarray, ...]]:
    """Each step's true poses, odometry and pushes under the contact-stressing commands."""
    out = []
    for k in range(steps):
        pattern = ("push", "converge", "random")[(k // 10) % 3]
        result = world.step(commands_for(pattern, rng, world))
        out.append((world.poses, result.odometry, result.collided))
    return out


# a seeded box with interior walls, a team of 2-5 and a command sequence; the seed is the input
@pytest.mark.parametrize("seed", range(12))
def test_recycled_space__same_episode_as_a_fresh_world_to_the_bit(seed: int) -> None:
    # The next episode's world takes the last one's space (its walls) instead of building one:
    # crowded robots pushing walls and each other give the contact solver many pairs at once,
    # whose order follows the shapes' hash ids (World._take_space resets their counter).
    rng = np.random.default_rng(seed)
    layout = random_layout(rng)
    n = int(rng.integers(2, 6))
    first, second = random_poses(rng, layout, n), random_poses(rng, layout, n)
    if first is None or second is None:
        return  # too cramped for this team; other seeds cover it
    old = World(layout, CFG, n, make_rngs(seed), start_poses=first)
    _run(old, np.random.default_rng(seed + 100), 40)  # contacts cached when it ends
    recycled = World(layout, CFG, n, make_rngs(seed + 1), start_poses=second, recycle=old)
    fresh = World(layout, CFG, n, make_rngs(seed + 1), start_poses=second)
    assert recycled.space is old.space and fresh.space is not old.space
    got = _run(recycled, np.random.default_rng(seed + 200), 60)
    want = _run(fresh, np.random.default_rng(seed + 200), 60)
    assert any(c.any() for _, _, c in want)  # the episode has contacts to get wrong
    for a, b in zip(got, want, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


def test_recycled_space__old_world_cannot_step_and_others_are_not_taken() -> None:
    layout = box_layout(2.0, 2.0)
    poses = np.array([[0.5, 0.5, 0.0], [1.5, 1.5, 1.0]])
    old = World(layout, CFG, 2, make_rngs(0), start_poses=poses)
    new = World(layout, CFG, 2, make_rngs(1), start_poses=poses, recycle=old)
    assert new.space is old.space
    with pytest.raises(RuntimeError, match="next episode"):
        old.step(np.zeros((2, 2)))
    # a spent world, another layout, another config or a failed robot: a space of its own
    again = World(layout, CFG, 2, make_rngs(2), start_poses=poses, recycle=old)
    assert again.space is not new.space
    other = World(box_layout(2.0, 2.0), CFG, 2, make_rngs(2), start_poses=poses, recycle=new)
    assert other.space is not new.space
    slow = WorldConfig(substeps=20)
    assert World(layout, slow, 2, make_rngs(2), poses, recycle=other).space is not other.space
    failed = World(layout, CFG, 2, make_rngs(3), start_poses=poses)
    failed.disable(0)
    assert World(layout, CFG, 2, make_rngs(2), poses, recycle=failed).space is not failed.space

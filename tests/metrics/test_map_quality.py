"""Map precision, completeness over the seen boundary, duplicates, the placing pose, and the
values of empty maps (issue 14), each against a brute-force oracle or a hand-computed value."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from polyslam_env import metrics as M
from polyslam_env.metrics.episode import (
    MAP_METRIC_KEYS,
    ROBOT_METRIC_KEYS,
    RobotHistory,
    RobotRun,
    final_robot_metrics,
    robot_metrics,
)
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.layout import Layout, point_segment_distance

SIDE = 4.0
#: The documented accuracy (m) of distance_to_boundary; samples nearer than this to a
#: tolerance may fall either side of it.
DIST_ACC = 1e-3


def square_room() -> Layout:
    wall = np.array([[0.0, 0.0], [SIDE, 0.0], [SIDE, SIDE], [0.0, SIDE], [0.0, 0.0]])
    return Layout("square", (wall,))


def _random_map(rng: np.random.Generator, count: int) -> list[Polynomial]:
    """Polynomials near the walls of the square room (some on them, some off), both variates."""
    polys = []
    for _ in range(count):
        variate = int(rng.integers(1, 3))
        c0 = rng.choice([0.0, SIDE]) + rng.normal(0.0, 0.08)
        coeffs = np.array([c0, rng.normal(0, 0.02), rng.normal(0, 0.01)])
        lo = rng.uniform(0.2, 2.5)
        polys.append(Polynomial(variate, coeffs, lo, lo + rng.uniform(0.3, 1.4)))
    return polys


def _brute_distances(points: np.ndarray, layout: Layout) -> np.ndarray:  # (n,)
    return np.array([point_segment_distance(p, layout.segments).min() for p in points])


# -- map precision ------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(4))
def test_map_precision__matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    layout, pose = square_room(), np.array([0.1, -0.05, 0.02])
    polys = _random_map(rng, 6)
    tol = 0.05
    pts = np.vstack(M.map_points(polys, pose, 0.01))
    d = _brute_distances(pts, layout)
    expected = np.count_nonzero(d <= tol) / len(d)
    undecided = np.count_nonzero(np.abs(d - tol) <= DIST_ACC) / len(d)
    assert abs(M.map_precision(polys, pose, layout, tol=tol) - expected) <= undecided


def test_map_precision__half_on_the_wall_half_off() -> None:
    layout = square_room()
    on = Polynomial(1, np.array([0.0, 0.0]), 1.0, 2.0)  # on y = 0
    off = Polynomial(1, np.array([0.5, 0.0]), 1.0, 2.0)  # 0.5 m inside
    # Equal lengths, so equal sample counts: exactly half the samples within 5 cm.
    assert M.map_precision([on, off], np.zeros(3), layout) == 0.5
    assert M.map_precision([], np.zeros(3), layout) == 1.0


# -- completeness over the seen boundary ----------------------------------------------------------
def _turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) between directions a and b."""
    return math.degrees(math.acos(np.clip(a @ b / np.hypot(*a) / np.hypot(*b), -1.0, 1.0)))


def _faces_by_hand(layout: Layout) -> list[int]:
    """The face of each of ``layout.segments``, readably: walk each polyline and start a new
    face where it turns by 45° or more; a closed polyline's last face joins its first when
    they meet at less than 45°."""
    faces: list[int] = []
    for wall in layout.walls:
        pts = [p for i, p in enumerate(wall) if i == 0 or not np.array_equal(p, wall[i - 1])]
        dirs = [np.subtract(b, a) for a, b in itertools.pairwise(pts)]
        ids = [len(set(faces))]
        for a, b in itertools.pairwise(dirs):
            ids.append(ids[-1] + 1 if _turn_deg(a, b) >= 45.0 else ids[-1])
        closed = np.array_equal(wall[0], wall[-1]) and len(dirs) > 1
        if closed and _turn_deg(dirs[-1], dirs[0]) < 45.0 and ids[-1] != ids[0]:
            ids = [ids[0] if i == ids[-1] else i for i in ids]
        faces.extend(ids)
    return faces


def _seen_by_brute_force(layout: Layout, hits: np.ndarray, radius: float) -> np.ndarray:
    """Per boundary sample: is a finite hit within ``radius`` whose nearest segment has the
    sample's face (each sample's segment found the same way, by the nearest segment)?"""
    segs, faces = layout.segments, _faces_by_hand(layout)
    bpts, _ = M.boundary_samples(layout, 0.01)

    def face_of(p: np.ndarray) -> int:
        return faces[int(np.argmin(point_segment_distance(p, segs)))]

    finite = hits[np.isfinite(hits).all(axis=1)]
    hit_faces = [face_of(h) for h in finite]
    seen = []
    for b in bpts:
        f, close = face_of(b), np.hypot(*(finite - b).T) < radius
        seen.append(any(c and hf == f for c, hf in zip(close, hit_faces, strict=True)))
    return np.array(seen)


def test_segment_faces__corners_split_jogs_and_small_turns_do_not() -> None:
    room = square_room()  # closed, four right angles: four faces
    assert M.segment_faces(room).tolist() == [0, 1, 2, 3] == _faces_by_hand(room)
    jagged = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.1], [3.0, 0.1], [3.0, 1.0], [3.0, 2.0]])
    hexagon = np.array(
        [[math.cos(a), 5 + math.sin(a)] for a in np.linspace(0, 2 * math.pi, 7)[:-1]]
    )
    hexagon = np.vstack([hexagon, hexagon[:1]])  # turns of 60°: each side a face
    fine = np.array([[math.cos(a), 9 + math.sin(a)] for a in np.linspace(0, 2 * math.pi, 33)])
    fine[-1] = fine[0]  # closed 32-gon: turns of 11.25°, one face, the last joining the first
    layout = Layout("faces", (jagged, hexagon, fine))
    got = M.segment_faces(layout).tolist()
    assert got == _faces_by_hand(layout)
    assert got[:5] == [0, 0, 0, 1, 1]
    assert got[5:11] == list(range(2, 8))
    assert set(got[11:]) == {8}


def test_completeness_seen__matches_brute_force() -> None:
    rng = np.random.default_rng(7)
    layout, pose = square_room(), np.zeros(3)
    polys = _random_map(rng, 5)
    # hits along the bottom wall up to 10 cm from the corner (the right wall's first 10 cm
    # are within the radius of the last one, but on another face), one on the right wall
    bottom = [[x, 0.0] for x in np.arange(0.5, 3.91, 0.2)]
    hits = np.vstack([bottom, [[SIDE, 1.0]], [[np.inf] * 2]])
    radius, tol = M.mapping.SEEN_RADIUS, 0.05
    bpts, weights = M.boundary_samples(layout, 0.01)
    map_pts = np.vstack(M.map_points(polys, pose, 0.01))
    seen = _seen_by_brute_force(layout, hits, radius)
    covered = np.array([np.hypot(*(map_pts - b).T).min() <= tol for b in bpts])
    expected = weights[seen & covered].sum() / weights[seen].sum()
    got = M.completeness_seen(polys, pose, layout, hits, radius=radius, tol=tol)
    assert got == pytest.approx(expected, abs=1e-12)
    assert np.array_equal(M.seen_samples(hits, layout, radius), seen)


def test_seen_samples__stop_at_a_corner_and_at_a_surface_behind() -> None:
    """The radius's sweep argument holds along the face a beam sweeps: hits on one face of a
    box do not make its side faces seen, nor a wall 10 cm behind it (both would be within the
    radius of the hits)."""
    box = np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 1.3], [1.0, 1.3], [1.0, 1.0]])
    wall = np.array([[0.0, 1.4], [3.0, 1.4]])  # 10 cm behind the box's far face
    layout = Layout("box", (box, wall))
    hits = np.column_stack([np.arange(1.025, 1.98, 0.05), np.full(20, 1.3)])  # the far face
    bpts, weights = M.boundary_samples(layout, 0.01)
    seen = M.seen_samples(hits, layout)
    assert np.array_equal(seen, _seen_by_brute_force(layout, hits, M.mapping.SEEN_RADIUS))
    far_face = (np.abs(bpts[:, 1] - 1.3) < 1e-9) & (bpts[:, 0] > 1.0) & (bpts[:, 0] < 2.0)
    assert seen[far_face].all()
    assert weights[seen].sum() == pytest.approx(1.0, abs=0.011)  # the far face, nothing else
    within = np.array([np.hypot(*(hits - b).T).min() < M.mapping.SEEN_RADIUS for b in bpts])
    assert weights[within & ~seen].sum() > 0.5  # sides' ends and the wall behind: not seen


def test_completeness_seen__full_on_the_seen_stretch_where_completeness_is_not() -> None:
    layout = square_room()
    wall = Polynomial(1, np.zeros(2), 1.0, 3.0)  # maps y = 0 between x = 1 and 3
    hits = np.column_stack([np.arange(1.2, 2.81, 0.1), np.zeros(17)])  # seen: x ∈ [1.05, 2.95]
    assert M.completeness_seen([wall], np.zeros(3), layout, hits) == 1.0
    assert M.completeness([wall], np.zeros(3), layout) < 0.2
    assert M.completeness_seen([], np.zeros(3), layout, hits) == 0.0
    assert M.completeness_seen([wall], np.zeros(3), layout, np.zeros((0, 2))) == 0.0


# -- duplicates -----------------------------------------------------------------------------------
def test_duplicates__two_overlapping_parallel_lines_and_a_crossing_one() -> None:
    a = Polynomial(1, np.array([0.0, 0.0]), 0.0, 2.0)
    b = Polynomial(1, np.array([0.05, 0.0]), 1.0, 3.0)  # 5 cm away, overlapping on x ∈ [1, 2]
    c = Polynomial(2, np.array([1.5, 0.0]), -0.5, 0.5)  # x = 1.5, crossing both at 90°
    # A point of a is within 10 cm of b from x = 1 − √(0.1² − 0.05²) on, and b likewise up to
    # 2 + that; c is perpendicular to both and counts nowhere.
    reach = 1.0 + math.sqrt(0.1**2 - 0.05**2)
    n = [len(p.sample_arclength(0.01)) for p in (a, b, c)]
    expected = (reach / 2.0 * n[0] + reach / 2.0 * n[1]) / sum(n)
    # Each of the two band ends is decided per sample: off by at most one sample each.
    got = M.duplicates([a, b, c])
    assert abs(got - expected) <= 2 / sum(n)


def test_duplicates__matches_brute_force_with_analytic_tangents() -> None:
    rng = np.random.default_rng(3)
    polys = _random_map(rng, 8)
    tol, angle = M.mapping.DUPLICATE_TOL, M.mapping.DUPLICATE_ANGLE
    own = [p.sample_arclength(0.01) for p in polys]
    tangents = []
    for p, pts in zip(polys, own, strict=True):
        xi, _ = p.from_xy(pts)
        d = np.column_stack([np.ones_like(xi), p.slope(xi)])  # (dξ, dη)
        t = d if p.variate == 1 else d[:, ::-1]
        tangents.append(t / np.linalg.norm(t, axis=1, keepdims=True))
    marked = 0
    near_threshold = 0
    for i, (pi, ti) in enumerate(zip(own, tangents, strict=True)):
        for k in range(len(pi)):
            hit = edge = False
            for j, (pj, tj) in enumerate(zip(own, tangents, strict=True)):
                if j == i:
                    continue
                dist = np.hypot(*(pj - pi[k]).T)
                sin = np.abs(ti[k, 0] * tj[:, 1] - ti[k, 1] * tj[:, 0])
                hit |= bool(((dist <= tol) & (sin <= math.sin(angle))).any())
                # Finite-difference tangents differ from analytic ones by ~1e-3 rad (the
                # curvature times the step): pairs that close to the angle cut are undecided.
                edge |= bool(((dist <= tol) & (np.abs(sin - math.sin(angle)) < 2e-3)).any())
            marked += hit
            near_threshold += edge
    total = sum(len(p) for p in own)
    assert 0 < marked < total  # the map has some duplicates and some not: a real comparison
    assert abs(M.duplicates(polys) - marked / total) <= near_threshold / total


def test_duplicates__a_wall_mapped_twice_is_all_duplicate_one_wall_none() -> None:
    a = Polynomial(1, np.array([0.0, 0.0]), 0.0, 2.0)
    assert M.duplicates([a]) == 0.0
    assert M.duplicates([a, a.with_c0(0.02)]) == 1.0
    assert M.duplicates([]) == 0.0
    assert M.duplicates([a, Polynomial(2, np.array([1.0, 0.0]), 0.5, 0.5)]) == 0.0  # a point


# -- placing pose, empty maps, no SLAM -----------------------------------------------------------
def _run(true_start: np.ndarray, frame: np.ndarray, polys: list[Polynomial]) -> RobotRun:
    history = RobotHistory(frame, np.zeros(3), np.diag([0.05**2, 0.05**2, 0.0175**2]), true_start)
    history.record(
        true_start, np.zeros(3), np.eye(3) * 1e-4, np.array([[0.0, 1.0]]), 0.0, False, False
    )
    return history.run(polys)


def test_robot_metrics__map_placed_by_true_start_abs_by_frame() -> None:
    layout = square_room()
    true_start = np.array([1.0, 1.0, 0.0])
    frame = np.array([1.05, 1.0, 0.0])  # the nominal start, 5 cm off along x
    wall = Polynomial(2, np.array([-1.0, 0.0]), -0.5, 0.5)  # x = 0 seen from the true start
    m = robot_metrics(_run(true_start, frame, [wall]), layout)
    assert m["nu_mean"] <= DIST_ACC
    assert m["nu_mean_abs"] == pytest.approx(0.05, abs=DIST_ACC)
    assert m["map_precision"] == 1.0 and m["has_map"] == 1.0
    same = robot_metrics(_run(true_start, true_start, [wall]), layout)
    assert same["nu_mean"] == same["nu_mean_abs"]


def test_final_robot_metrics__empty_map_and_no_slam_are_finite_and_flagged() -> None:
    layout = square_room()
    start = np.array([1.0, 1.0, 0.0])
    history = RobotHistory(start, np.zeros(3), np.eye(3) * 1e-3)
    history.record(start, np.zeros(3), np.eye(3) * 1e-3, np.zeros((0, 2)), 0.0, False, False)
    empty = final_robot_metrics(history, [], layout, 0.1, {})
    none = final_robot_metrics(history, None, layout, 0.1, {})
    for out in (empty, none):
        assert set(out) == set(ROBOT_METRIC_KEYS)
        assert all(math.isfinite(v) for v in out.values())
        assert out["has_map"] == 0.0 and out["map_precision"] == 1.0
        assert all(out[k] == 0.0 for k in MAP_METRIC_KEYS if k != "map_precision")
    assert empty["slam"] == 1.0 and none["slam"] == 0.0
    assert none["nees"] == 0.0


def test_meaningful__map_errors_only_from_robots_with_a_map_slam_metrics_only_with_slam() -> None:
    from polyslam_env.metrics.episode import meaningful

    no_map = {"nu_mean": 0.0, "completeness": 0.0, "has_map": 0.0, "slam": 1.0, "coverage": 0.1}
    mapped = {"nu_mean": 0.03, "completeness": 0.4, "has_map": 1.0, "slam": 1.0, "coverage": 0.2}
    no_slam = {"nu_mean": 0.0, "completeness": 0.0, "has_map": 0.0, "slam": 0.0, "coverage": 0.3}
    robots = [no_map, mapped, no_slam]
    assert meaningful(robots, "nu_mean") == [0.03]
    assert meaningful(robots, "completeness") == [0.0, 0.4]  # an empty map is 0 % complete
    assert meaningful(robots, "coverage") == [0.1, 0.2, 0.3]


def test_env_final_metrics__short_episode_without_map_is_finite_and_flagged() -> None:
    from polyslam_env.environment.parallel import parallel_env
    from polyslam_env.world.config import PAPER_BEAMS_DEG

    # five beams × 2 steps = 10 hits, fewer than the ε_Z + 1 = 16 a landmark needs
    env = parallel_env(
        map="generator:cave",
        num_robots=2,
        max_steps=2,
        world__range_sensor__angles_deg=PAPER_BEAMS_DEG,
    )
    env.reset(seed=0)
    info: dict = {}
    while env.agents:
        *_, info = env.step({a: np.zeros(2) for a in env.agents})
    for agent in env.possible_agents:
        m = info[agent]["metrics"]
        assert all(math.isfinite(v) for v in m.values()), agent
        assert m["has_map"] == 0.0 and m["slam"] == 1.0
        assert m["nu_mean"] == 0.0 and m["map_precision"] == 1.0


@pytest.mark.parametrize("count", [0, 1, 7])
def test_completeness_and_error__the_two_metrics_bit_for_bit(count: int) -> None:
    # one sampling serves both (the env's reward): the same numbers as the two functions
    rng = np.random.default_rng(count)
    layout, pose = square_room(), np.array([0.05, 0.1, -0.03])
    polys = _random_map(rng, count)
    both = M.completeness_and_error(polys, pose, layout, tol=0.05, step=0.05)
    assert both == (
        M.completeness(polys, pose, layout, tol=0.05, step=0.05),
        M.map_error_length(polys, pose, layout, step=0.05),
    )


@pytest.mark.parametrize("step", [0.01, 0.05])
@pytest.mark.parametrize("seed", range(3))
def test_completeness_and_error__compiled_sums_bit_for_bit_with_pillars(
    step: float, seed: int
) -> None:
    # the compiled call's placing, distances (walls and pillars) and sums against the numpy
    # path of the two functions, on a map that runs past the pillars and out of the room
    rng = np.random.default_rng(seed)
    wall = np.array([[0.0, 0.0], [SIDE, 0.0], [SIDE, SIDE], [0.0, SIDE], [0.0, 0.0]])
    pillars = np.array([[1.0, 1.2, 0.15], [2.6, 2.9, 0.3], [1.9, 3.2, 0.2]])
    layout = Layout("pillared", (wall,), pillars)
    polys = _random_map(rng, 9)
    polys.append(Polynomial(1, np.array([1.2, 0.4, -0.3]), -2.0, 5.5))
    pose = np.array([0.03, -0.02, rng.normal(0, 0.2)])
    for tol in (0.0, 0.05, 0.2):
        assert M.completeness_and_error(polys, pose, layout, tol=tol, step=step) == (
            M.completeness(polys, pose, layout, tol=tol, step=step),
            M.map_error_length(polys, pose, layout, step=step),
        )


@pytest.mark.parametrize(("count", "offset"), [(0, False), (1, False), (7, False), (7, True)])
def test_map_quality__every_metric_bit_for_bit_as_its_own_function(
    count: int, offset: bool
) -> None:
    # one sampling, placing and distance query for all: the same floats as each function
    rng = np.random.default_rng(count)
    layout, pose = square_room(), np.array([0.05, 0.1, -0.03])
    frame = pose + np.array([0.02, -0.01, 0.004]) if offset else pose.copy()
    polys = _random_map(rng, count)
    hits = rng.uniform(-0.1, SIDE + 0.1, (60, 2))
    hits[::7] = np.inf  # no return
    assert M.map_quality(polys, pose, frame, hits, layout) == {
        "nu": M.nu(polys, pose, layout),
        "nu_mean": M.nu_mean(polys, pose, layout),
        "nu_mean_abs": M.nu_mean(polys, frame, layout),
        "completeness": M.completeness(polys, pose, layout),
        "completeness_seen": M.completeness_seen(polys, pose, layout, hits),
        "map_precision": M.map_precision(polys, pose, layout),
        "duplicates": M.duplicates(polys),
        "has_map": M.has_map(polys),
    }


@pytest.mark.parametrize("seed", range(3))
def test_tangents__numpy_gradient_of_each_polynomial_bit_for_bit(seed: int) -> None:
    """``duplicates``' tangents of all polynomials at once are ``np.gradient`` of each (zeros for a
    single point), the same floats."""
    from polyslam_env.metrics.mapping import _tangents

    rng = np.random.default_rng(seed)
    for _ in range(50):
        counts = rng.integers(1, 7, size=rng.integers(1, 6))
        own = [rng.normal(size=(c, 2)) * 10 for c in counts]
        want = [np.gradient(p, axis=0) if len(p) > 1 else np.zeros((1, 2)) for p in own]
        assert np.array_equal(_tangents(np.vstack(own), counts), np.vstack(want))

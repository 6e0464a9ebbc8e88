"""``slam.backend``: the point-landmark back-ends in the env (issues 17 and 18).

The polynomial EKF is tested everywhere else; here the env runs FastSLAM 2.0, EM-FastSLAM,
MBLCC and SEIF over the pillars of ``generator:pillar_hall``: configuration errors, the
consensus messages (wire format, frames, bytes), ε = 0 against the independent filter, the
landmark metrics, the observations, and SEIF's consistency over whole seeded episodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.stats import chi2

from polyslam_env import metrics
from polyslam_env.comms.channel import ChannelConfig
from polyslam_env.comms.consensus import ConsensusExchange, decode, encode
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import between, compose, transform_points, wrap_remainder
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import PolySlamParallelEnv
from polyslam_env.metrics.episode import RobotHistory, final_robot_metrics, meaningful
from polyslam_env.slam.backends import PointSlamRobot
from polyslam_env.slam.points.interface import LandmarkMessage
from polyslam_env.world.layout import Layout

PILLARS: dict[str, Any] = {
    "map": "generator:pillar_hall",
    "num_robots": 3,
    "coverage_target": None,
    "world": {"pillar_sensor": {"enabled": True}},
}


def point_config(backend: str, **overrides: Any) -> EnvConfig:
    data: dict[str, Any] = {**PILLARS, "slam": {"backend": backend}}
    if backend == "mblcc":
        # a radio across the hall, so that robots that start apart exchange at all
        data.update(channel={"range": 25.0}, initial_error=False)
    if backend == "multirobot_known_start":
        data.update(initial_error=False)
    data.update(overrides)
    return EnvConfig.from_dict(data)


def run(config: EnvConfig, seed: int, steps: int) -> tuple[PolySlamParallelEnv, dict[str, Any]]:
    """``steps`` steps of seeded random driving (forward, any turn); the env and the last
    infos."""
    env = PolySlamParallelEnv(config.replace(max_steps=steps))
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    infos: dict[str, Any] = {}
    while env.agents:
        actions = {
            a: rng.uniform([0.2, -1.0], [1.0, 1.0]) * env.action_space(a).high  # type: ignore[attr-defined]
            for a in env.agents
        }
        infos = env.step(actions)[4]
    return env, infos


# -- configuration ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"slam": {"backend": "seif"}}, "world.pillar_sensor.enabled"),
        (
            {**PILLARS, "slam": {"backend": "mblcc"}, "initial_error": False, "channel": None},
            "set channel",
        ),
        (
            {**PILLARS, "slam": {"backend": "mblcc"}, "channel": {"range": 5.0}},
            "initial_error: false",
        ),
        ({**PILLARS, "slam": {"backend": "multirobot_known_start"}}, "initial_error: false"),
        (
            {
                **PILLARS,
                "slam": {"backend": "mblcc"},
                "initial_error": False,
                "channel": {"mode": "alignment"},
            },
            "channel.mode",
        ),
        ({**PILLARS, "slam": {"backend": "fastslam"}}, "slam.backend: must be one of"),
        ({**PILLARS, "slam": {"backend": "seif", "points": {"max_active": 0}}}, "max_active"),
        (
            {
                **PILLARS,
                "world": {"pillar_sensor": {"enabled": True, "identities": False}},
                "slam": {"backend": "mblcc"},
                "initial_error": False,
            },
            "identities: true",
        ),
        (
            {
                **PILLARS,
                "world": {"pillar_sensor": {"enabled": True, "identities": False}},
                "channel": {"mode": "alignment"},
            },
            "identities: true",
        ),
        (
            {**PILLARS, "slam": {"backend": "seif", "points": {"gate_prob": 1.0}}},
            "gate_prob",
        ),
    ],
)
def test_config__rejects_what_a_point_backend_cannot_run(data: dict[str, Any], needle: str) -> None:
    with pytest.raises(ConfigError) as err:
        EnvConfig.from_dict(data)
    assert needle in str(err.value)
    assert "\n" not in str(err.value)


# -- the consensus messages --------------------------------------------------------------------
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_consensus_wire_format__round_trips(precision: str) -> None:
    rng = np.random.default_rng(0)
    msg = LandmarkMessage(2, np.array([4, 17, 3], np.int64), rng.uniform(-9, 9, (3, 2)))
    payload = encode(msg, precision)
    width = 4 if precision == "float32" else 8
    assert len(payload) == 4 + 3 * 4 + 3 * 2 * width
    back = decode(payload, 2, precision)
    np.testing.assert_array_equal(back.ids, msg.ids)
    tol = 1e-6 * 9 if precision == "float32" else 0.0  # float32 keeps ~7 significant digits
    np.testing.assert_allclose(back.means, msg.means, rtol=0, atol=tol)


def test_consensus__maps_estimates_into_the_receivers_frame() -> None:
    """A landmark the sender places exactly (in its own frame) arrives where the receiver's
    frame has it: brute force through the absolute frame."""
    rng = np.random.default_rng(1)
    starts = rng.uniform([-5, -5, -3], [5, 5, 3], (3, 3))
    truth = rng.uniform(-8, 8, (4, 2))  # absolute
    own = transform_points(truth, between(starts[0], np.zeros(3), wrap_remainder))  # in 0's frame
    ex = ConsensusExchange(ChannelConfig(), starts, np.random.default_rng(0))
    out = ex._into_frame(LandmarkMessage(0, np.arange(4), own), receiver=2)
    want = transform_points(truth, compose(np.zeros(3), between(starts[2], np.zeros(3))))
    np.testing.assert_allclose(out.means, want, atol=1e-12)


def test_mblcc_with_zero_step__equals_em_fastslam_and_counts_its_bytes() -> None:
    """ε = 0 makes eq. 12's term exactly zero: the same poses and maps as EM-FastSLAM, step
    for step, while the messages still travel (and are counted)."""
    seed, steps = 1, 150  # seed 1: robots that see common pillars within the episode
    zero = {"backend": "mblcc", "points": {"consensus_step": 0.0}}
    mblcc, _ = run(point_config("mblcc", slam=zero), seed, steps)
    em, _ = run(point_config("em_fastslam", initial_error=False), seed, steps)
    for a, b in zip(mblcc.episode.histories, em.episode.histories, strict=True):
        np.testing.assert_array_equal(np.array(a.est), np.array(b.est))
    assert mblcc.episode.consensus is not None
    sent = [mblcc.episode.consensus.counters(i)["bytes_sent"] for i in range(3)]
    assert sum(sent) > 0


def test_mblcc__consensus_changes_the_estimates() -> None:
    """With ε = 0.1 the received estimates do act (else the exchange would be decoration)."""
    seed, steps = 1, 150  # seed 1: robots that see common pillars within the episode
    mblcc, _ = run(point_config("mblcc"), seed, steps)
    em, _ = run(point_config("em_fastslam", initial_error=False), seed, steps)
    diffs = [
        np.abs(np.array(a.est) - np.array(b.est)).max()
        for a, b in zip(mblcc.episode.histories, em.episode.histories, strict=True)
    ]
    assert max(diffs) > 0.0


# -- metrics and observations -------------------------------------------------------------------
def test_landmark_error__is_zero_for_the_true_pillars_and_gated_by_its_flag() -> None:
    pillars = np.array([[1.0, 2.0, 0.1], [3.0, -1.0, 0.1], [-2.0, 0.5, 0.1]])
    box = np.array([[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0], [-5.0, -5.0]])
    layout = Layout("box", (box,), pillars, np.array([[0.5, 0.5, 0.3]]))
    start = np.array([0.5, 0.5, 0.3])
    history = RobotHistory(start, np.zeros(3), np.eye(3) * 1e-4)
    ids = np.array([2, 0])
    own = transform_points(pillars[ids, :2], between(start, np.zeros(3), wrap_remainder))
    perfect = final_robot_metrics(history, [], layout, 0.0, {}, (ids, own))
    assert perfect["landmark_error"] == pytest.approx(0.0, abs=1e-12)
    assert perfect["has_landmarks"] == 1.0 and perfect["has_map"] == 0.0
    shifted = final_robot_metrics(history, [], layout, 0.0, {}, (ids, own + np.array([0.03, 0.04])))
    assert shifted["landmark_error"] == pytest.approx(0.05, abs=1e-12)
    polynomial = final_robot_metrics(history, [], layout, 0.0, {})
    assert polynomial["has_landmarks"] == 0.0
    assert meaningful([perfect, polynomial], "landmark_error") == [perfect["landmark_error"]]


@pytest.mark.parametrize("backend", ["fastslam2", "seif", "multirobot_known_start"])
def test_point_backend__observes_its_landmarks_and_reports_landmark_metrics(backend: str) -> None:
    env, infos = run(point_config(backend), seed=0, steps=60)
    slam = env.episode.slams[0]
    assert isinstance(slam, PointSlamRobot)
    lm = slam.landmarks()
    assert len(lm.ids) > 0
    np.testing.assert_array_equal(env.episode.slam.map_points(0), lm.means)
    m = infos["robot_0"]["metrics"]
    assert m["has_landmarks"] == 1.0 and m["has_map"] == 0.0 and m["slam"] == 1.0
    # a pillar sensor with σ_r = 3 cm and 1° places pillars within a few cm; 0.5 m would
    # mean landmarks in the wrong frame or under the wrong ids
    assert 0.0 < m["landmark_error"] < 0.5
    # the same for the pose: its estimate is in the robot's own frame
    assert m["pose_error"] < 0.5


#: SEIF's consistency: NEES of the filter's own pose covariance (relative to the true start) at
#: the end of each episode, over 20 seeded episodes × 3 robots.
NEES_RUNS = 20


def test_seif__is_consistent_at_the_end_of_whole_episodes() -> None:
    """At the last step of each of 20 seeded 150-step episodes, every robot's pose error
    (relative to its true start) against ``pose_cov_relative``: the mean of the 60 NEES values
    must lie in the two-sided 95 % χ² band of a consistent filter, χ²(3·60)/60. SEIF's
    sparsification is an approximation, but with ``max_active`` = 20 ≥ the pillars one sweep
    sees here it drops no links a sweep makes."""
    values = []
    for seed in range(NEES_RUNS):
        env, _ = run(point_config("seif"), seed=seed, steps=150)
        for i, slam in enumerate(env.episode.slams):
            history = env.episode.histories[i]
            truth = between(history.true[0], history.true[-1], wrap_remainder)
            err = truth - slam.pose
            err[2] = wrap_remainder(err[2])
            values.append(float(err @ np.linalg.solve(slam.pose_cov_relative, err)))
    n = len(values)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * n) / n
    assert lo <= np.mean(values) <= hi, (np.mean(values), lo, hi)


ANONYMOUS = {"pillar_sensor": {"enabled": True, "identities": False}}


@pytest.mark.parametrize("backend", ["fastslam2", "seif"])
def test_anonymous_readings__one_landmark_per_pillar_and_no_wrong_pairing(backend: str) -> None:
    """Without identities the robots associate by χ² gating. Pillars stand ≥ 2 m apart and
    the sensor's σ is 3 cm / 1°, so a wrong pairing would put a landmark metres from every
    pillar and a duplicate would put two on one: every landmark lies within 0.1 m (over 3σ of
    a landmark's error here) of its nearest true pillar, no two share one, and they are
    pillars the same episode with identities maps."""
    for seed in range(3):
        named, _ = run(point_config(backend), seed, 200)
        env, infos = run(point_config(backend, world=ANONYMOUS), seed, 200)
        centres = env.episode.world.pillars[:, :2]
        for i, slam in enumerate(env.episode.slams):
            assert isinstance(slam, PointSlamRobot) and slam.anonymous
            start = env.episode.histories[i].true[0]
            means = slam.landmarks().means
            nearest = metrics.nearest_points(means, start, centres)
            d = metrics.landmark_distances(means, start, centres[nearest])
            assert d.max() < 0.1, (seed, i, d.max())
            assert len(set(nearest.tolist())) == len(nearest), (seed, i, "duplicate")
            assert set(nearest.tolist()) <= set(named.episode.slams[i].landmarks().ids.tolist())
            m = infos[f"robot_{i}"]["metrics"]
            assert m["landmark_error"] == pytest.approx(float(d.mean()))


def test_multirobot_known_start__one_shared_map_seen_from_each_robots_frame() -> None:
    """The joint filter holds one map: each robot reports it in its own frame, so the same
    landmark placed by each robot's true start lands on the same point."""
    env, _ = run(point_config("multirobot_known_start"), seed=1, steps=100)
    maps = [s.landmarks() for s in env.episode.slams]
    ids = maps[0].ids
    assert len(ids) > 0 and all(np.array_equal(m.ids, ids) for m in maps)
    starts = [h.true[0] for h in env.episode.histories]
    placed = [transform_points(m.means, start) for m, start in zip(maps, starts, strict=True)]
    for other in placed[1:]:
        np.testing.assert_allclose(other, placed[0], atol=1e-9)
    # and each robot's pose is the team filter's estimate of it seen from its own frame, from
    # the first step on
    for steps in (1, 100):
        env, _ = run(point_config("multirobot_known_start"), seed=1, steps=steps)
        for slam, start in zip(env.episode.slams, env.episode.start_poses, strict=True):
            assert isinstance(slam, PointSlamRobot)
            shared = slam.backend.pose()[0]
            np.testing.assert_allclose(compose(start, slam.pose), shared, atol=1e-9)


def test_consensus__travels_only_within_range_and_is_lost_like_any_message() -> None:
    """A 0.1 m radio links no pair (robots are ≥ 2 radii apart): nothing is sent. A channel
    that loses every attempt sends bytes (counted) but delivers nothing, so the filters equal
    EM-FastSLAM's step for step; undelivered messages expire the next step instead of piling
    up."""
    seed, steps = 1, 80
    em, _ = run(point_config("em_fastslam", initial_error=False), seed, steps)
    short, _ = run(point_config("mblcc", channel={"range": 0.1}), seed, steps)
    assert short.episode.consensus is not None
    assert short.episode.consensus.channel.totals().messages_sent == 0
    lossy, _ = run(point_config("mblcc", channel={"range": 25.0, "loss_prob": 1.0}), seed, steps)
    consensus = lossy.episode.consensus
    assert consensus is not None
    totals = consensus.channel.totals()
    assert totals.bytes_sent > 0 and totals.messages_delivered == 0
    assert totals.messages_expired > 0
    assert consensus.channel.pending() <= 3 * 2  # at most the last step's, one per pair
    for a, b in zip(lossy.episode.histories, em.episode.histories, strict=True):
        np.testing.assert_array_equal(np.array(a.est), np.array(b.est))


@pytest.mark.parametrize(
    "name",
    ["alignment", "alignment_none", "alignment_rendezvous", "pillar_backends"],
)
def test_shipped_env_configs__load_and_reset(name: str) -> None:
    """The env configs of the pillar hall README names load, validate and start an episode
    (``paper.yaml`` is the reproduction's config, tested with it)."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "configs" / f"{name}.yaml"
    env = PolySlamParallelEnv(EnvConfig.from_yaml(path).replace(max_steps=2))
    env.reset(seed=0)
    env.close()

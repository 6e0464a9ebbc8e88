"""Honest uncertainty over whole episodes on a large generated map (issue 14).

A frontier robot explores a generated office floor, a warehouse or a pillar hall for a whole
episode with
``initial_error`` on: its true start is drawn from P0 around its frame origin. Over 60 seeded
runs the standard pose NEES *at the last step* must lie in the two-sided 95 % band of the mean
of 60 χ²(3) variables, χ²(180)/60, both for the pose in the robot's frame (error includes the
start offset, covariance :attr:`PolySlam.pose_cov`) and for the filter's own estimate relative
to the true start (:attr:`PolySlam.pose_cov_relative`, where P0 plays no part, the stricter
test). And at every step of every run the pose covariance stays above the propagated P0
(J P0 Jᵀ): the start offset is unobservable, so no measurement may shrink it.

One robot and no exchange keep the runs independent (the band assumes independent runs).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from policies.base import make_team
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.slam.ekf import start_error_cov

#: 60, not the issue's minimum of 20: one run's final NEES has a heavy tail (a wall group's
#: direction 2σ off, a run of 16), so the mean of 20 swings by more than its χ² band allows
#: (the lone pillar-hall robot: 4.21 over seeds 0–19 with walls tied square, above the band's
#: 4.16, and 3.28 over seeds 0–59, inside the 60-run band 2.41–3.65, which is the stricter test
#: of the mean; README "Walls tied square")
RUNS = 60
#: (map, steps): rooms off a corridor; shelf rows, whose many short faces and corners are where
#: beams pass a wall's end (slam.end_sigma: the lone warehouse robot was above the band without
#: it); round pillars, short strongly curved landmarks whose beams may miss them within the
#: state's uncertainty while the linearised end test keeps them (kernels.steady_beams: without
#: it the final relative NEES was 3.44 after 300 steps, in the band, and 5.25 after 600)
EPISODES = (
    ("generator:office_floor", 300),
    ("generator:warehouse", 300),
    ("generator:pillar_hall", 600),
)


def _nees(err: np.ndarray, cov: np.ndarray) -> float:
    return float(err @ np.linalg.solve(cov, err))


def _run(map_name: str, steps: int, seed: int) -> tuple[float, float, float]:
    """One episode: (final NEES in the frame, final NEES relative to the true start, the
    smallest eigenvalue of P − J P0 Jᵀ over the episode relative to ‖P‖)."""
    env = parallel_env(
        map=map_name,
        num_robots=1,
        max_steps=steps,
        coverage_target=None,
        channel=None,
        initial_error=True,
    )
    team = make_team("frontier", env)
    obs, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = np.random.default_rng([seed, 1])
    state = env.unwrapped.episode
    slam, history = state.slams[0], state.histories[0]
    worst = np.inf
    while env.agents:
        obs, *_ = env.step(team.act(obs, rng))
        p = slam.pose_cov
        gap = p - start_error_cov(slam.mean, slam.config.p0)
        worst = min(worst, float(np.linalg.eigvalsh(0.5 * (gap + gap.T))[0]) / np.abs(p).max())
    pose = slam.pose
    in_frame = between(state.start_poses[0], state.world.poses[0], wrap_remainder)
    from_true_start = between(history.true[0], state.world.poses[0], wrap_remainder)
    e_frame, e_rel = in_frame - pose, from_true_start - pose
    e_frame[2], e_rel[2] = wrap_remainder(e_frame[2]), wrap_remainder(e_rel[2])
    env.close()
    return _nees(e_frame, slam.pose_cov), _nees(e_rel, slam.pose_cov_relative), worst


@pytest.mark.slow
@pytest.mark.parametrize(("map_name", "steps"), EPISODES)
def test_nees__whole_episodes_with_initial_error_on_a_large_map__inside_the_95_band(
    map_name: str, steps: int
) -> None:
    results = np.array([_run(map_name, steps, seed) for seed in range(RUNS)])  # (RUNS, 3)
    lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 3 * RUNS) / RUNS
    frame, relative = results[:, 0].mean(), results[:, 1].mean()
    assert lo <= frame <= hi, f"final NEES in the frame {frame:.2f} outside [{lo:.2f}, {hi:.2f}]"
    assert lo <= relative <= hi, (
        f"final NEES relative to the true start {relative:.2f} outside [{lo:.2f}, {hi:.2f}]"
    )
    # P − J P0 Jᵀ is the filter's own covariance: PSD up to rounding relative to ‖P‖
    assert results[:, 2].min() >= -1e-12

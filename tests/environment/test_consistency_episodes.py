"""Honest uncertainty over whole episodes on a large generated map (issue 14).

A frontier robot explores a generated office floor, a warehouse or a pillar hall for a whole
episode with
``initial_error`` on: its true start is drawn from P0 around its frame origin. Over RUNS seeded
runs the standard pose NEES *at the last step* must be χ²(3)-like, both for the pose in the
robot's frame (error includes the start offset, covariance :attr:`PolySlam.pose_cov`) and for
the filter's own estimate relative to the true start (:attr:`PolySlam.pose_cov_relative`, where
P0 plays no part, the stricter test). The final NEES is heavy-tailed (a wall group's direction
2σ off gives a run of 16), so the test is on the mean of log NEES, whose distribution for a
consistent filter is exact and which one such run barely moves (``tests/stats.py``). And at
every step of every run the pose covariance stays above the propagated P0 (J P0 Jᵀ): the start
offset is unobservable, so no measurement may shrink it.

One robot and no exchange keep the runs independent (the band assumes independent runs).
"""

from __future__ import annotations

import numpy as np
import pytest

from policies.base import make_team
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.slam.ekf import start_error_cov
from tests.stats import log_chi2_mean_band, log_mean

#: Fixed before looking, from the power: with 30 runs the log-mean band at α = 1 % (six checks,
#: a consistent filter fails one with probability ≤ 6 %) rejects a filter whose covariance is
#: halved (every NEES doubled) with probability 0.93 and one whose covariance is doubled with
#: 0.89 (``tests.stats.log_chi2_mean_power``). (60 runs of a χ²-mean band before: 20 runs had
#: been raised to 60 after a 20-run mean fell outside its band.)
RUNS = 30
ALPHA = 0.01
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


#: Known misses of the check in the frame (issue 45): the final NEES in the frame sits low on
#: every map — the covariance with the start offset's share J P0 Jᵀ is too large for the
#: errors, while the relative NEES is χ²(3)-like. Seeds 0–29 on merged main at stop 51
#: (10 physics sub-steps, compiled cluster fit, reuse bound): frame log-means 0.35 office,
#: 0.43 warehouse, 0.39 pillar hall against χ²(3)'s 0.73 (band 0.25–1.16); relative 0.80,
#: 1.05, 1.06. The office's, 0.22 before, now falls inside the band: its entry went. A map
#: whose frame NEES is known to miss goes here and must keep failing until the filter is fixed.
FRAME_MISSES: dict[str, str] = {}


@pytest.mark.slow
@pytest.mark.parametrize(("map_name", "steps"), EPISODES)
def test_nees__whole_episodes_with_initial_error_on_a_large_map__inside_the_log_nees_band(
    map_name: str, steps: int
) -> None:
    results = np.array([_run(map_name, steps, seed) for seed in range(RUNS)])  # (RUNS, 3)
    lo, hi = log_chi2_mean_band(3, RUNS, ALPHA)
    relative, frame = log_mean(results[:, 1]), log_mean(results[:, 0])
    assert lo <= relative <= hi, (
        f"final NEES relative to the true start: mean log {relative:.3f} outside"
        f" [{lo:.3f}, {hi:.3f}] (median {np.median(results[:, 1]):.2f}, χ²(3)'s 2.37)"
    )
    # the mutant, a filter reporting half its covariance (every NEES doubled), is caught
    assert not lo <= log_mean(2.0 * results[:, 1]) <= hi, "no power on these runs"
    # P − J P0 Jᵀ is the filter's own covariance: PSD up to rounding relative to ‖P‖
    assert results[:, 2].min() >= -1e-12
    in_band = lo <= frame <= hi
    if map_name in FRAME_MISSES:
        assert not in_band, f"{map_name} now passes in the frame: drop it from FRAME_MISSES"
        pytest.xfail(f"{FRAME_MISSES[map_name]}: {frame:.3f} outside [{lo:.3f}, {hi:.3f}]")
    assert in_band, (
        f"final NEES in the frame: mean log {frame:.3f} outside [{lo:.3f}, {hi:.3f}]"
        f" (median {np.median(results[:, 0]):.2f}, χ²(3)'s 2.37)"
    )

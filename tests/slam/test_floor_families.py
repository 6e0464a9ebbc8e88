"""Honest uncertainty on the new floor families (issue 42, "Tests that must exist"): whole
episodes of the SLAM alone on small fixed maps of each family (``tests/slam/floor_families.py``:
an arc corridor, a corridor at 30° and −30°, an irregular chamber with a rock island, a wide
open chamber), the world exactly the filter's model, so what the tests find is the filter's.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.stats

from polyslam_env import metrics
from polyslam_env.core.geometry import compose, compose_inverse, wrap_remainder
from polyslam_env.metrics.episode import nees_relative, start_nees
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.world.layout import Layout, point_segment_distance
from tests.scripts_module import load_script
from tests.slam.floor_families import (
    FAMILIES,
    OPEN,
    OPEN_WALLS,
    Episode,
    episode,
    episodes,
    start_draw_rows,
)
from tests.slam.reference import motion_jacobians
from tests.slam.test_links import _wall_errors
from tests.stats import log_chi2_mean_band, log_mean

#: Runs per family, fixed from the power (as ``tests/environment/test_consistency_episodes.py``):
#: the log-mean band of 30 final NEES at α = 1 % rejects a filter reporting half its covariance
#: with probability 0.93 and one reporting twice it with 0.89 (``tests.stats.log_chi2_mean_power``).
RUNS = 30
ALPHA = 0.01


@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_nees__whole_episodes_of_each_family__inside_the_log_nees_band(name: str) -> None:
    """RUNS seeded episodes of one family, initial error drawn from P0: the final pose NEES
    relative to the true start against the filter's own P_S is χ²(3) for a consistent filter,
    so the mean of its log over the runs lies in the exact two-sided 99 % band of the mean of
    RUNS log χ²(3) values (``tests.stats.log_chi2_mean_band``: log χ²(3) = log 2 + log G with
    G ~ Gamma(3/2), the mean of n independent ones has the characteristic function φ(t/n)ⁿ,
    inverted exactly; the final NEES is heavy-tailed, its log is not, so one bad run moves the
    statistic little). The mutant reporting half the covariance (every NEES doubled) falls out.
    A filter whose odometry is 2× noisier than it believes fails on every family; over 140
    seeds the curved corridor's log-mean is 1.195, above its 140-run band [0.513, 0.934]: the
    filter is ~1.5× overconfident once it drives back over the curved walls it mapped, which
    30 runs catch with probability ~0.46 only (docs/notes/floortests.md)."""
    final = np.array([e.final_nees for e in episodes(name, RUNS)])
    lo, hi = log_chi2_mean_band(3, RUNS, ALPHA)
    got = log_mean(final)
    assert lo <= got <= hi, (
        f"{name}: final relative NEES mean log {got:.3f} outside [{lo:.3f}, {hi:.3f}]"
        f" (median {np.median(final):.2f}, χ²(3)'s 2.37)"
    )
    assert not lo <= log_mean(2.0 * final) <= hi, "no power on these runs"


#: Found by the test below (reported to the lead): landmarks on curved walls lie further from
#: the wall than the map's own variance (the state's and each landmark's frozen error) says.
#: Seeds 0–29, χ²/dof with the frozen terms (state only): curved 4.07 (5.58) over 449
#: landmarks, cave 2.35 (4.74) over 489; the angled corridor's straight walls 0.93 (1.13). The
#: curved landmarks are nearly honest once their frozen shape error counts (1.63 curved, 0.99
#: cave); what is left is mostly *lines* on curved walls (406 and 325 of them: 4.32, 3.04):
#: a short piece of arc passes the order test as a line, and its sagitta is an error no state
#: and no fit misfit holds (docs/notes/floors.md, Round 6; ``slam.curvature_test`` about halves
#: the excess on this harness, 4.07 → 2.39 curved, 2.35 → 1.84 cave).
CURVED_MAP = "lines on curved walls: their sagitta is a frozen error the map does not state"


@pytest.mark.parametrize(
    "name",
    [
        "angled",
        pytest.param("curved", marks=pytest.mark.xfail(strict=True, reason=CURVED_MAP)),
        pytest.param("cave", marks=pytest.mark.xfail(strict=True, reason=CURVED_MAP)),
    ],
)
def test_map__each_landmark_lies_where_its_covariance_says(name: str) -> None:
    """The map's own uncertainty (issue 42: a curved wall's uncertainty covers its error): at
    the middle of each landmark's evidence, its distance to the true wall (placed by the true
    start, the filter's frame) against the filter's variance of its normal offset there: the
    state's (``PolySlam.map_error_jacobian``'s row, J P Jᵀ) and the landmark's frozen error
    (``PolySlam.map_frozen_variance``, the terms the update puts in R); summed over the RUNS
    runs of the family test (one point a landmark: points of one landmark share its c0 and
    α), χ² with one dof a landmark, two-sided 99 % band. Landmarks further than 0.2 m from
    every wall are left out (none in these runs; a wrong association is not what this
    checks)."""
    floor = FAMILIES[name]
    segments = Layout(name, floor.walls).segments
    total, dof = 0.0, 0
    for e in episodes(name, RUNS):
        slam, start = e.slam, e.run.true_poses[0]
        _, rows = slam.map_error_jacobian()
        frozen, landmark = slam.map_frozen_variance()
        first = 0
        for i, poly in enumerate(slam.polynomials()):
            n = max(2, math.ceil((poly.hi - poly.lo) / 0.02) + 1)  # map_error_jacobian's points
            xi = np.linspace(poly.lo, poly.hi, n)
            k = int(np.argmin(np.abs(xi - float(np.mean(slam.table.evidence[i])))))
            row, own = rows[first + k], frozen[first + k]
            assert landmark[first + k] == i
            first += n
            point = compose(start, np.r_[poly.points_at(xi[k : k + 1])[0], 0.0])[:2]
            distance = float(point_segment_distance(point, segments).min())
            if distance > 0.2:
                continue
            total += distance**2 / (float(row @ slam.cov @ row) + own)
            dof += 1
    assert first == len(rows)
    lo, hi = scipy.stats.chi2.ppf([0.005, 0.995], dof)
    assert lo <= total <= hi, (name, total, dof, lo, hi)


def _runs() -> list[Episode]:
    return [e for name in sorted(FAMILIES) for e in episodes(name, RUNS)]


def test_nees_rel__does_not_depend_on_the_start_draw_over_the_families_robots() -> None:
    """Over the 3 × RUNS robots of the test above (each its own episode, its true start drawn
    from P0 so it sees its map shifted by e₀), the least-squares slope of ``nees_rel`` on
    ``start_nees`` has a 95 % t interval holding 0 (``scripts/nees_start_draw.py``'s
    ``analyse``). On the same robots ``nees``, which carries e₀ᵀP0⁻¹e₀ on purpose, has a slope
    whose interval excludes 0: a ``nees_rel`` that kept the start offset would fail. (≥ 200
    robots do not fit in the suite: 420, seeds 0–139, are in docs/results/floors.md.)"""
    study = load_script("nees_start_draw")
    runs = [e.run for e in _runs()]
    rows = start_draw_rows(runs)
    result = study.analyse(rows, False, np.random.default_rng(0))
    lo, hi = result["slope_ci_t"]
    assert lo <= 0.0 <= hi, (result["slope"], lo, hi, result["tercile_mean"])
    frame = [
        {**row, "nees_rel": metrics.nees(r.true_poses, r.est_poses, r.est_covs, r.start_pose)}
        for row, r in zip(rows, runs, strict=True)
    ]
    lo, hi = study.analyse(frame, False, np.random.default_rng(0))["slope_ci_t"]
    assert lo > 0.0, ("nees in the frame should rise with the start draw", lo, hi)


def test_nees_rel__is_the_same_whatever_the_nominal_frame() -> None:
    """The start offset is unobservable: moving only the nominal frame (the same filter run,
    its true start read from another frame, e₀ redrawn) changes ``start_nees`` and ``nees``
    and leaves ``nees_rel`` as it was, to rounding of the subtraction (relative 1e-12)."""
    run = episodes("cave", RUNS)[0].run
    rng = np.random.default_rng(1)
    assert run.p0 is not None
    for _ in range(5):
        e0 = rng.multivariate_normal(np.zeros(3), run.p0 * 16.0)  # far draws: 4 σ
        moved = dataclasses.replace(run, start_pose=compose_inverse(run.true_poses[0], e0))
        assert abs(start_nees(moved) - start_nees(run)) > 1e-3
        assert abs(nees_relative(moved) - nees_relative(run)) <= 1e-12 * nees_relative(run)


# -- open spaces --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def open_runs() -> list[Episode]:
    """RUNS crossings of the wide chamber, no initial error: the robot's frame is the map's."""
    return [episode(OPEN, seed, initial_error=False) for seed in range(RUNS)]


def _blind_stretches(used: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) step (1-based, as the covariance series) of each run of steps whose
    update used no beam, at least 10 long."""
    out, start = [], None
    for k, n in enumerate(np.append(used, 1), start=1):
        if n == 0 and start is None:
            start = k
        elif n != 0 and start is not None:
            if k - start >= 10:
                out.append((start, k - 1))
            start = None
    return out


def test_open_space__pose_covariance_grows_as_the_odometry_model_says(
    open_runs: list[Episode],
) -> None:
    """Across the chamber nothing is in range (both crossings are blind for ≥ 30 steps): the
    filter's P_S there must be its P_S at the first blind step propagated by the odometry
    model alone, P ← F P Fᵀ + L W Lᵀ with F, L of the unicycle at the estimate and the given
    odometry (``tests/slam/reference.motion_jacobians``, the textbook Jacobians: after a
    step without an update the first-estimate Jacobians are these). Nothing else — no map
    maintenance, link or tie — may give the pose information or take it away (relative 1e-9:
    rounding of ~40 products)."""
    cfg = open_runs[0].slam.config
    for e in open_runs:
        stretches = _blind_stretches(e.beams_used)
        assert len(stretches) == 2, stretches
        for first, last in stretches:
            assert last - first >= 30, (first, last)
            p = e.cov_relative[first].copy()
            for k in range(first + 1, last + 1):
                F, L = motion_jacobians(e.run.est_poses[k - 1], e.odometry[k - 1])
                p = F @ p @ F.T + L @ cfg.odom_cov @ L.T
            np.testing.assert_allclose(e.cov_relative[last], p, rtol=1e-9, atol=0)


#: Found by the test below (reported to the lead, not fixed here: the estimator is another
#: branch's this round). At the start of the second crossing P_S is right axis by axis (z rms
#: 0.93, 0.91, 0.94 over the 30 runs) but its x–θ correlation is 0.41 where the errors' is
#: 0.70: the far wall's steps lost part of it. The heading error's share of the along-wall
#: error x, which the truth cancels on the way back, then adds in the filter: after 7 m blind
#: its x variance is 2.4× the errors' (z rms 0.65), log-mean NEES 0.10 below the band.
SECOND_CROSSING = "x–θ correlation lost at the far wall: underconfident after crossing back"


@pytest.mark.parametrize(
    "at",
    [
        "first crossing",
        pytest.param(
            "second crossing", marks=pytest.mark.xfail(strict=True, reason=SECOND_CROSSING)
        ),
        "end",
    ],
)
def test_open_space__errors_after_the_crossings_as_large_as_the_covariance_says(
    open_runs: list[Episode], at: str
) -> None:
    """At the end of each blind crossing (the pose error then is the odometry's, unchecked by
    any wall) and at the end of the episode (after the re-acquisition), the relative NEES over
    the RUNS runs lies in the log-mean band, as the families' final NEES."""
    lo, hi = log_chi2_mean_band(3, RUNS, ALPHA)
    nees = []
    for e in open_runs:
        stretches = _blind_stretches(e.beams_used)
        k = {"first crossing": stretches[0][1], "second crossing": stretches[1][1]}.get(
            at, len(e.beams_used)
        )
        err = e.run.true_poses[k] - e.run.est_poses[k]  # the frame is the true start's
        err[2] = wrap_remainder(float(err[2]))
        nees.append(float(err @ np.linalg.solve(e.cov_relative[k], err)))
    assert lo <= log_mean(nees) <= hi, (at, log_mean(nees), lo, hi)


def _open_truth(poly: Polynomial) -> tuple[float, float] | None:
    """(offset, direction) of the chamber's wall a landmark lies on: the first or the far
    wall (y = const, direction 0); None for the side walls (x = const)."""
    if poly.variate != 1:
        return None
    c0 = float(poly.coeffs[0])
    return min(((y, 0.0) for y in OPEN_WALLS.values()), key=lambda t: abs(t[0] - c0))


def test_open_space__re_acquired_wall_stays_where_its_covariance_says(
    open_runs: list[Episode],
) -> None:
    """After crossing back blind, the robot meets the first wall again head-on and follows
    it over the stretch it mapped first; the map must not bend there. Each straight landmark
    of the first and the far wall, at the middle of its evidence (offset) and in direction,
    against the filter's own covariance of them: summed over the RUNS runs, eᵀC⁻¹e lies in the
    two-sided 99 % band of a χ² with as many dof as rows. A re-acquisition that pulled the
    wall off (a kink, a second landmark beside the first) leaves the band."""
    total, dof = 0.0, 0
    for e in open_runs:
        errors, cov = _wall_errors(e.slam, _open_truth, directions=True)
        total += float(errors @ np.linalg.solve(cov, errors))
        dof += errors.size
    lo, hi = scipy.stats.chi2.ppf([0.005, 0.995], dof)
    assert lo <= total <= hi, (total, dof, lo, hi)

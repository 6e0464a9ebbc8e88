"""``scripts/nees_trace.py --info``: where a filter's heading information comes from."""

from __future__ import annotations

import math

import pytest

from polyslam_env.apps.fidelity import FidelityConfig, episode_config
from polyslam_env.slam.config import SlamConfig
from tests.scripts_module import load_script


@pytest.mark.slow
def test_heading_info__stages_add_up_and_the_prediction_adds_the_odometry_noise() -> None:
    """Over a stretch of a recorded episode the three stages' changes add up to the heading
    variance's whole change (nothing is left out or counted twice), and the prediction's share
    is the odometry's heading variance W_θθ once per step: the unicycle's prediction leaves the
    heading's row of F and G at (0, 0, 1), so it adds exactly W_θθ (to rounding)."""
    trace = load_script("nees_trace")
    config = episode_config(FidelityConfig(steps=120), "rooms", exchange=False)
    rec = trace.record(config, seed=3)[0]
    slam_config = trace.SlamConfig.from_dict(rec.slam)
    info = trace.heading_info(rec, slam_config, 10, 120)
    assert info.map_changes < 0 and info.update_lines < 0  # every stage takes part here
    stages = info.predict + info.map_changes + info.update_lines + info.update_curves
    assert math.isclose(info.last - info.first, stages, rel_tol=1e-9, abs_tol=1e-18)
    w = SlamConfig.from_dict(rec.slam).odom_cov[2, 2]
    assert math.isclose(info.predict, 110 * w, rel_tol=1e-9)
    assert info.steps_lines + info.steps_curves + info.steps_none == 110
    assert sum(info.ages.values()) > 0

"""``polyslam run``'s table: the metrics that apply to the set-up, grouped, with units."""

from __future__ import annotations

from typing import Any

import pytest

from polyslam_env.apps.run_table import GROUPS, LABELS, format_run_table, shown_metrics
from polyslam_env.cli.common import fmt
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.metrics.episode import FLAG_KEYS, METRIC_UNITS, ROBOT_METRIC_KEYS

#: Small maps, one robot pair: shown_metrics reads the config and the state ``reset`` made.
TWO = {"map": "two_rooms", "num_robots": 2, "max_steps": 5}
PILLARS = {
    "map": "generator:pillar_hall",
    "num_robots": 2,
    "max_steps": 5,
    "world": {"camera": {"enabled": False}, "pillar_sensor": {"enabled": True}},
}


def shown(**config: Any) -> dict[str, tuple[str, ...]]:
    env = parallel_env(**config)
    env.reset(seed=0)
    try:
        return shown_metrics(env)
    finally:
        env.close()


def test_every_metric_has_a_unit_or_is_a_flag() -> None:
    # a new metric must say its unit (or be a 0/1 flag the tables leave out)
    missing = set(ROBOT_METRIC_KEYS) - set(METRIC_UNITS) - set(FLAG_KEYS)
    assert not missing


def test_polynomial_with_rendezvous__wall_map_and_rendezvous_rows_only() -> None:
    groups = shown(**TWO)
    assert list(groups) == list(GROUPS)
    assert groups["pose"][:2] == ("nees", "nees_rel")  # nees_rel beside nees
    assert "start_nees" in groups["pose"]  # initial_error is on by default
    assert {"nu_mean", "map_precision", "completeness_seen"} <= set(groups["map"])
    assert groups["exchange"] == ("bytes_sent", "bytes_received", "rendezvous")
    every = {k for keys in groups.values() for k in keys}
    assert not every & {"landmark_error", "landmarks", "alignments_attempted", *FLAG_KEYS}
    assert "slam_time_ms" in groups["cost"]


def test_known_starts__no_start_draw_row() -> None:
    groups = shown(**TWO, initial_error=False)
    assert "start_nees" not in groups["pose"] and "nu_mean_abs" not in groups["map"]


def test_no_channel__no_exchange_rows() -> None:
    assert shown(**TWO, channel=None)["exchange"] == ()


def test_no_slam__no_pose_map_or_slam_time_rows() -> None:
    groups = shown(**TWO, slam_enabled=False)
    assert groups["pose"] == () and groups["map"] == ("coverage",)
    assert groups["exchange"] == () and "slam_time_ms" not in groups["cost"]


def test_alignment_mode__alignment_counters_not_rendezvous() -> None:
    groups = shown(**TWO, channel={"mode": "alignment", "features": "walls"})
    assert groups["exchange"] == (
        "bytes_sent",
        "bytes_received",
        "alignments_attempted",
        "alignments_accepted",
        "alignments_wrong",
    )


@pytest.mark.parametrize(
    ("backend", "exchange"),
    [("fastslam2", ()), ("seif", ("bytes_sent", "bytes_received", "alignments_attempted"))],
)
def test_point_backend__pillar_map_rows_not_wall_map_rows(
    backend: str, exchange: tuple[str, ...]
) -> None:
    channel = {"mode": "alignment", "range": 5.0} if backend == "seif" else None
    groups = shown(**PILLARS, slam={"backend": backend}, channel=channel)
    assert groups["map"] == ("landmark_error", "landmarks", "coverage")
    assert groups["exchange"][: len(exchange)] == exchange
    if not exchange:  # FastSLAM 2.0 leaves the channel unused
        assert groups["exchange"] == ()


def test_format__groups_in_order_with_units_and_whole_counts() -> None:
    robots = {
        "robot_0": dict.fromkeys(ROBOT_METRIC_KEYS, 0.5) | {"bytes_sent": 822.0},
        "robot_1": dict.fromkeys(ROBOT_METRIC_KEYS, 0.25) | {"bytes_sent": 0.0},
    }
    groups = {"pose": ("nees", "nees_rel"), "map": (), "exchange": ("bytes_sent",), "cost": ()}
    lines = format_run_table(robots, groups, fmt).splitlines()
    assert lines[0].split() == ["unit", "robot_0", "robot_1"]
    assert [ln for ln in lines if not ln.startswith((" ", "-"))] == ["pose", "exchange"]
    nees = next(ln for ln in lines if ln.strip().startswith(LABELS["nees"]))
    assert nees.split()[-2:] == ["0.500", "0.250"]
    sent = next(ln for ln in lines if "bytes_sent" in ln)
    assert sent.split() == ["bytes_sent", "B", "822", "0"]

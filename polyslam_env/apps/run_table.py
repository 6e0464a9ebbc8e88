"""What ``polyslam run`` prints of an episode: the metrics that apply to its set-up.

``infos[agent]["metrics"]`` (and ``metrics.json``) hold every metric of
:data:`~polyslam_env.metrics.episode.ROBOT_METRIC_KEYS` for every set-up, with stated values
where a metric does not apply (a point back-end has no wall map, a team without a channel
sends nothing). The table shows only the metrics that mean something for the episode's SLAM
back-end and exchange, in four groups with their units:

* **pose**: ``nees`` (which carries the robot's start draw, see below), ``nees_rel`` beside it,
  ``start_nees`` (the draw itself, with ``initial_error``) and ``pose_error``;
* **map**: the wall map's metrics (``polynomial`` back-end) or the pillar map's
  (``landmark_error``, ``landmarks``), and the area the robot swept (``coverage``);
* **exchange**: the counters of the exchange in use (camera rendezvous, alignment, MBLCC's
  consensus or SEIF map fusion), none without one;
* **cost**: the SLAM step's time, the path driven and the collisions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from polyslam_env.metrics.episode import COUNTER_KEYS, METRIC_UNITS

__all__ = ["GROUPS", "LABELS", "describe_setup", "format_run_table", "shown_metrics"]

#: The table's groups, in order.
GROUPS: tuple[str, ...] = ("pose", "map", "exchange", "cost")
#: Row labels that say more than the key.
LABELS: dict[str, str] = {
    "nees": "nees (with start draw)",
    "nees_rel": "nees_rel (without it)",
    "start_nees": "start_nees (the draw)",
}
#: Counts, printed as whole numbers.
COUNTS = frozenset({"landmarks", *COUNTER_KEYS, "collisions"})
_EXCHANGED = ("bytes_sent", "bytes_received")
_ALIGNED = (*_EXCHANGED, "alignments_attempted", "alignments_accepted", "alignments_wrong")


def shown_metrics(env: Any) -> dict[str, tuple[str, ...]]:
    """Group → the metric keys that apply to ``env``'s episode (a reset
    :class:`~polyslam_env.environment.parallel.PolySlamParallelEnv`): its config's back-end,
    ``initial_error`` and ``slam_enabled``, and the exchange its episode state holds."""
    cfg = env.config
    state = env.episode
    slam = cfg.slam_enabled
    drawn = ("start_nees",) if cfg.initial_error else ()
    pose = ("nees", "nees_rel", *drawn, "pose_error") if slam else ()
    if slam and cfg.slam.backend == "polynomial":
        offset = ("nu_mean_abs",) if cfg.initial_error else ()
        kept = ("map_precision", "completeness", "completeness_seen", "duplicates", "nu")
        walls: tuple[str, ...] = ("nu_mean", *offset, *kept)
    elif slam:
        walls = ("landmark_error", "landmarks")
    else:
        walls = ()
    exchange: tuple[str, ...] = ()
    if state.exchange is not None:
        meets = ("rendezvous",) if cfg.channel.mode == "rendezvous" else _ALIGNED[2:]
        exchange = (*_EXCHANGED, *meets)
    elif state.consensus is not None:
        exchange = _EXCHANGED
    elif state.seif_exchange is not None:
        exchange = _ALIGNED
    cost = (*(("slam_time_ms",) if slam else ()), "path_length", "collisions")
    return {"pose": pose, "map": (*walls, "coverage"), "exchange": exchange, "cost": cost}


def describe_setup(env: Any) -> str:
    """The episode's SLAM back-end and exchange in words, for the table's title."""
    cfg = env.config
    state = env.episode
    if not cfg.slam_enabled:
        return "no SLAM (true poses), no exchange"
    slam = f"{cfg.slam.backend} SLAM"
    if state.exchange is not None and cfg.channel.mode == "rendezvous":
        return f"{slam}, map exchange at camera rendezvous"
    if state.exchange is not None:
        return f"{slam}, map exchange by aligning {cfg.channel.features}"
    if state.consensus is not None:
        return f"{slam}, landmark consensus over the channel"
    if state.seif_exchange is not None:
        return f"{slam}, SEIF map fusion over the channel"
    return f"{slam}, no exchange"


def format_run_table(
    robots: Mapping[str, Mapping[str, float]],
    groups: Mapping[str, Sequence[str]],
    fmt: Any,
) -> str:
    """A plain-text table, one column per robot (``robots``: name → metrics), the rows of
    each non-empty group under its name, each with its unit; ``fmt`` formats a number."""
    names = list(robots)
    rows = [(LABELS.get(k, k), METRIC_UNITS[k], k) for g in GROUPS for k in groups.get(g, ())]
    width = max(len(label) for label, _, _ in rows) + 4
    units = max(len(unit) for _, unit, _ in rows) + 2
    head = " " * width + f"{'unit':<{units}}" + "".join(f"{n:>12}" for n in names)
    lines = [head, "-" * len(head)]
    for group in GROUPS:
        if not groups.get(group):
            continue
        lines.append(group)
        for key in groups[group]:
            label = f"  {LABELS.get(key, key)}"
            values = "".join(f"{_number(key, robots[n].get(key, 0.0), fmt):>12}" for n in names)
            lines.append(f"{label:<{width}}{METRIC_UNITS[key]:<{units}}{values}")
    return "\n".join(lines)


def _number(key: str, value: float, fmt: Any) -> str:
    return f"{round(value):d}" if key in COUNTS else str(fmt(float(value)))

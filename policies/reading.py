"""One step's observation read at once: pose, beams, local map and sightings.

:func:`read` gives what :class:`~policies.base.PolicyContext`'s ``pose``, ``ranges``,
``local_grid`` and ``detections`` give, value for value, in one compiled pass over the flat
observation vector instead of a dozen numpy calls (the frontier policy reads every step).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from policies.base import PolicyContext
from polyslam_env.core.jit import njit

__all__ = ["Reading", "read"]


class Reading(NamedTuple):
    """What a step's observation says (see :class:`~policies.base.PolicyContext`)."""

    pose: np.ndarray  # (3,) x, y, θ in the own start frame
    ranges: np.ndarray  # (B,) m, inf = no return
    occ: np.ndarray  # (G, G) bool: occupied cells of the egocentric local map
    free: np.ndarray  # (G, G) bool: free cells of it
    detections: np.ndarray  # (k, 2) distance m, bearing rad of the robots the camera sees


@njit
def _read(
    vec: np.ndarray,
    ranges_at: int,
    no_return_at: int,
    beams: int,
    pose_at: int,
    pose_scale: float,
    max_range: float,
    local_at: int,
    g: int,
    detections_at: int,
    slots: int,
    camera_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    pose = np.empty(3)
    pose[0] = vec[pose_at] * pose_scale
    pose[1] = vec[pose_at + 1] * pose_scale
    pose[2] = math.atan2(vec[pose_at + 3], vec[pose_at + 2])
    ranges = np.empty(beams)
    for b in range(beams):
        ranges[b] = math.inf if vec[no_return_at + b] > 0.5 else vec[ranges_at + b] * max_range
    occ = np.empty((g, g), dtype=np.bool_)
    free = np.empty((g, g), dtype=np.bool_)
    for i in range(g * g):
        v = vec[local_at + i]
        o, unknown = v > 0.75, abs(v - 0.5) < 0.25  # values are 0, 0.5 or 1
        occ[i // g, i % g] = o
        free[i // g, i % g] = not (o or unknown)
    seen = 0
    for k in range(slots):
        if vec[detections_at + 4 * k] > 0.5:
            seen += 1
    detections = np.empty((seen, 2))
    j = 0
    for k in range(slots):
        at = detections_at + 4 * k
        if vec[at] > 0.5:
            detections[j, 0] = vec[at + 1] * camera_range
            detections[j, 1] = math.atan2(vec[at + 3], vec[at + 2])
            j += 1
    return pose, ranges, occ, free, detections


def read(context: PolicyContext, observation: Any) -> Reading:
    """The :class:`Reading` of ``observation`` (either observation mode)."""
    ctx = context
    if isinstance(observation, Mapping):  # grid mode: the local map is its own array
        local = ctx.local_grid(observation)
        return Reading(
            ctx.pose(observation), ctx.ranges(observation), local[0], local[1],
            ctx.detections(observation),
        )  # fmt: skip
    layout = ctx.vector_layout
    det = layout["detections"]
    return Reading(
        *_read(
            np.asarray(observation, dtype=float),
            layout["ranges"].start,
            layout["no_return"].start,
            len(ctx.beam_angles),
            layout["pose"].start,
            ctx.pose_scale,
            ctx.max_range,
            layout["local_map"].start,
            ctx.grid_size,
            det.start,
            (det.stop - det.start) // 4,
            ctx.camera_range,
        )
    )

"""Readable numpy versions of the observation kernels (``polyslam_env/environment/kernels.py``):
the oracles of the kernel tests (same float operations in the same order: identical cells)."""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.geometry import rotation
from polyslam_env.environment.observations import (
    FREE,
    OCCUPIED,
    STD_CAPS,
    UNKNOWN,
    BeliefGrid,
    ObservationEncoder,
    RobotView,
)
from polyslam_env.metrics.mapping import MapShapes, sample_shapes
from polyslam_env.slam.robot import PolySlam
from tests.core.reference import point_cells


def local_cells(
    pose: np.ndarray,
    map_points: np.ndarray,
    belief: BeliefGrid,
    cell_centres: np.ndarray,
    g: int,
    res: float,
    use_hits: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Occupied and free cells (G²,) of the egocentric grid (``ObservationEncoder.local_cells``)."""
    rot = rotation(pose[2])  # ego → own frame; (own − xy) @ rot = ego
    occ = np.zeros(g * g, dtype=bool)  # (G²,)
    if len(map_points):
        ego = (map_points - pose[:2]) @ rot  # (M, 2)
        idx = np.floor(ego / res + (g // 2 + 0.5)).astype(np.intp)  # (M, 2)
        u = idx.view(np.uintp)  # negatives wrap to huge values
        ok = (u[:, 0] < g) & (u[:, 1] < g)
        occ[idx[ok, 1] * g + idx[ok, 0]] = True
    centres = cell_centres @ rot.T + pose[:2]
    flat, inside = point_cells(centres[:, 0], centres[:, 1], *belief._grid)
    flat = np.where(inside, flat, 0)
    free = belief.free.reshape(-1)[flat] & inside
    hit = belief.hit.reshape(-1)[flat] & inside
    if use_hits:
        occ |= hit
    free &= ~occ
    return occ, free


def detection_slots(encoder: ObservationEncoder, view: RobotView) -> list[float]:  # (4K,)
    """Camera slots nearest first (ties: the lower target), ``(seen, d/range, cos α, sin α)``,
    zeros for empty slots."""
    cam_range = encoder.config.world.camera.range
    out: list[float] = []
    for det in sorted(view.detections, key=lambda d: (d.distance, d.target))[: encoder.k]:
        out += (
            1.0,
            min(det.distance / cam_range, 1.0),
            math.cos(det.bearing),
            math.sin(det.bearing),
        )
    return out + [0.0] * (4 * encoder.k - len(out))


def vector(
    encoder: ObservationEncoder, view: RobotView, cells: tuple[np.ndarray, np.ndarray] | None
) -> np.ndarray:
    """The flat vector observation (``ObservationEncoder.vector``), written part by part."""
    oc = encoder.config.observation
    lay = encoder.vector_layout
    out = np.empty(encoder.vector_space.shape, dtype=np.float32)
    out[lay["ranges"]] = np.fmin(view.ranges / encoder.max_range, 1.0)  # no return (inf) → 1
    out[lay["no_return"]] = ~np.isfinite(view.ranges)
    x, y, theta = view.pose.tolist()
    scale = encoder.pose_scale
    out[lay["pose"]] = (
        min(max(x / scale, -1.0), 1.0),
        min(max(y / scale, -1.0), 1.0),
        math.cos(theta),
        math.sin(theta),
    )
    std = zip(view.pose_std.tolist(), STD_CAPS.tolist(), strict=True)
    out[lay["pose_std"]] = [min(max(sd / cap, 0.0), 1.0) for sd, cap in std]
    if cells is not None:
        occ, free = cells
        local = out[lay["local_map"]]
        local.fill(UNKNOWN)
        local[occ] = OCCUPIED
        local[free] = FREE
    since, t = view.steps_since_rendezvous, encoder.config.max_steps
    out[lay["detections"].start : lay["progress"].stop] = [
        *detection_slots(encoder, view),
        1.0 if since is None else min(since / t, 1.0),
        min(view.rendezvous, oc.rendezvous_cap) / oc.rendezvous_cap,
        min(view.step / t, 1.0),
    ]
    return out


class MapSamplerOracle:
    """The readable :class:`~polyslam_env.environment.observations.MapSampler`: a dict of
    landmark id → (stamp, c0 when sampled, points, dependent axis, count), resampled per stale
    landmark and concatenated in state order (the sampler's layout before it kept arrays)."""

    def __init__(self, step: float) -> None:
        self.step = float(step)
        self._version = -1
        self._entries: dict[int, tuple[int, float, np.ndarray, int, int]] = {}
        self._c0 = np.zeros(0)
        self._points = np.zeros((0, 2))
        self._owner = np.zeros(0, dtype=np.intp)
        self._axis = np.zeros(0, dtype=np.intp)

    def _rebuild(self, slam: PolySlam) -> None:
        table = slam.table
        ids, stamps = list(table.ids), table.stamp.tolist()
        c0s = slam.c0s
        entries = [self._entries.get(i) for i in ids]
        stale = [e is None or e[0] != stamp for e, stamp in zip(entries, stamps, strict=True)]
        rows = np.array(stale, dtype=bool).nonzero()[0]
        if len(rows):
            coeffs = table.shape.copy()
            coeffs[:, 0] = c0s
            fresh = MapShapes(table.variate, coeffs, table.lo, table.hi)
            points, starts = sample_shapes(fresh, self.step, rows)
            for q, r in enumerate(rows):
                a, b = starts[q], starts[q + 1]
                axis = 1 if table.variate[r] == 1 else 0
                entries[r] = (stamps[r], float(c0s[r]), points[a:b], axis, b - a)
        done: list[tuple[int, float, np.ndarray, int, int]] = entries  # type: ignore[assignment]
        self._entries = dict(zip(ids, done, strict=True))
        self._version = table.version
        counts = np.array([e[4] for e in done], dtype=np.intp)
        self._c0 = np.array([e[1] for e in done])
        self._points = np.concatenate([e[2] for e in done]) if done else np.zeros((0, 2))
        self._owner = np.arange(len(done)).repeat(counts)
        self._axis = np.array([e[3] for e in done], dtype=np.intp).repeat(counts)

    def points(self, slam: PolySlam) -> np.ndarray:  # (M, 2)
        if slam.table.version != self._version:
            self._rebuild(slam)
        out = self._points.copy()
        shift = (slam.c0s - self._c0)[self._owner]
        out[np.arange(len(out)), self._axis] += shift
        return out


def team_status(
    covs: np.ndarray, last: np.ndarray, step_count: int, never: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A team view's pose standard deviations (K, 3), steps since the last rendezvous (K,) and
    env step (K,), as ``stages.observe`` computed them with numpy."""
    stds = np.sqrt(np.maximum(covs.diagonal(axis1=1, axis2=2), 0.0))
    since = np.where(last == never, never, step_count - last)
    return stds, since, np.full(len(covs), step_count, dtype=np.int64)

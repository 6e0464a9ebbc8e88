"""What the renderer draws: a plain snapshot of one env step, built only when rendering.

The env fills a ``RenderState`` from ground truth and from each robot's on-board estimate (mapped
to the absolute frame with the robot's true start pose, which the robot itself never sees). The
renderer reads it and nothing flows back: rendering never feeds observations.

numpy only: no pymunk, no pygame, no PettingZoo.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["RenderState"]


@dataclass(frozen=True)
class RenderState:
    """One frame of the episode, all geometry in the absolute (world) frame, metres/radians."""

    true_poses: np.ndarray  # (N, 3) x, y, θ from the physics world
    est_poses_abs: np.ndarray  # (N, 3) each robot's SLAM estimate in the absolute frame
    est_covs_abs: np.ndarray  # (N, 3, 3) pose covariances rotated into the absolute frame
    maps_abs: list[list[np.ndarray]]  # per robot, its polynomials as (n, 2) polylines
    true_paths: list[np.ndarray]  # per robot, (k, 2) true positions so far
    est_paths: list[np.ndarray]  # per robot, (k, 2) estimated positions so far (absolute)
    links: list[tuple[int, int]]  # robot pairs (i < j) in mutual camera view this step
    coverage: np.ndarray  # (H, W) bool, team-swept free cells; row = y index, col = x index
    coverage_origin: tuple[float, float]  # (x, y) of the lower-left corner of cell [0, 0]
    coverage_resolution: float  # cell side, metres
    active: np.ndarray  # (N,) bool, False for failed robots
    step: int  # env steps taken in this episode
    info_text: str = ""  # free-form status line (coverage, bytes, ...)
    extra: dict[str, object] = field(default_factory=dict)  # room for later additions

    @property
    def num_robots(self) -> int:
        """N, the number of robots in the episode (failed ones included)."""
        return int(self.true_poses.shape[0])

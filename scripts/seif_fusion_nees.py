"""Consistency of SEIF maps fused between robots in the env (configs/seif_fusion.yaml).

For each seed, one episode of the frontier team with SEIF map fusion; at its end, for every
robot and every landmark of its map, the standard NEES of the estimate against the true pillar
centre (in the robot's frame, placed by its true start; 2 degrees of freedom), once for the
robot's own SEIF map and once for the map with the other robots' maps fused in. Prints both
means with the two-sided 95 % band of a mean of that many χ²(2) variables (landmarks of one map
are correlated, so the band is only a guide).

Usage::

    python scripts/seif_fusion_nees.py --episodes 6 --steps 200
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scipy.stats
import yaml

from policies.base import make_team
from polyslam_env.apps.rollout import run_episode
from polyslam_env.core.geometry import between, transform_points
from polyslam_env.environment.config import EnvConfig
from polyslam_env.environment.parallel import parallel_env
from polyslam_env.slam.backends import PointSlamRobot
from polyslam_env.slam.points.interface import LandmarkMap

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "seif_fusion.yaml"


def _nees(landmarks: LandmarkMap, centres: np.ndarray, start: np.ndarray) -> list[float]:
    """NEES (2 dof) per landmark of a map against the true centres of the pillars it names."""
    truth = transform_points(centres[landmarks.ids.astype(int)], between(start, np.zeros(3)))
    out = []
    for mean, cov, true in zip(landmarks.means, landmarks.covs, truth, strict=True):
        e = mean - true
        out.append(float(e @ np.linalg.solve(cov, e)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    data = yaml.safe_load(CONFIG.read_text()) | {"max_steps": args.steps}
    own: list[float] = []
    fused: list[float] = []
    for seed in range(args.episodes):
        env = parallel_env(EnvConfig.from_dict(data))
        run_episode(env, make_team("frontier", env), seed)
        state = env.episode
        assert state is not None
        centres = state.world.layout.pillars[:, :2]
        for i, robot in enumerate(state.slams):
            assert isinstance(robot, PointSlamRobot)
            start = state.histories[i].true[0]
            own += _nees(robot.backend.landmarks(), centres, start)
            fused += _nees(robot.landmarks(), centres, start)
    for name, values in (("own SEIF maps", own), ("fused maps", fused)):
        lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 2 * len(values)) / len(values)
        print(
            f"{name}: mean landmark NEES {np.mean(values):.2f} over {len(values)} landmarks"
            f" (95 % band of independent χ²(2): {lo:.2f}–{hi:.2f})"
        )


if __name__ == "__main__":
    main()

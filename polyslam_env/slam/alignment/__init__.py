"""Map alignment without a rendezvous (seed 004): aligners for landmark maps and the team
solver that makes the pairwise transforms of several robots consistent."""

from polyslam_env.slam.alignment.aligners import (
    ALIGNERS,
    AlignConfig,
    Alignment,
    FeatureMap,
    align,
    icp,
    imp_icp,
    ransac,
    refine,
    rigid_fit,
    svd,
)
from polyslam_env.slam.alignment.team import PairwiseAlignment, solve_team

__all__ = [
    "ALIGNERS",
    "AlignConfig",
    "Alignment",
    "FeatureMap",
    "PairwiseAlignment",
    "align",
    "icp",
    "imp_icp",
    "ransac",
    "refine",
    "rigid_fit",
    "solve_team",
    "svd",
]

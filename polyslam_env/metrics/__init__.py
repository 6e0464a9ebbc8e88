"""Evaluation metrics (SPEC §5), each computed against ground truth the robots never see
(except ``expected_precision``: the map precision a robot's own filter expects).

It owns: ``pose`` (frames, position and landmark errors, NEES in both forms, the χ² band),
``boundary`` (the true boundary and distances to it), ``mapping`` (ν in both forms,
completeness, hit fraction, precision, completeness over the seen boundary, duplicates),
``coverage`` (the team coverage grid, time to a coverage fraction) and ``episode`` (per-robot
histories and the end-of-episode metrics of the env and of ``simulate``). numpy/scipy,
``core``, the SLAM's polynomials and the world's layouts only: no pymunk, no PettingZoo. The
SLAM wall time τ is measured by its caller.
"""

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.metrics.boundary import (
    boundary_faces,
    boundary_points,
    boundary_samples,
    distance_to_boundary,
    segment_faces,
)
from polyslam_env.metrics.coverage import CoverageGrid, time_to_fraction
from polyslam_env.metrics.mapping import (
    completeness,
    completeness_and_error,
    completeness_seen,
    count_interval,
    duplicates,
    expected_precision,
    has_map,
    hit_fraction,
    map_distances,
    map_error_length,
    map_points,
    map_precision,
    map_quality,
    nu,
    nu_mean,
    sample_arclength_batch,
    seen_boundary,
    seen_samples,
)
from polyslam_env.metrics.pose import (
    cov_to_absolute,
    landmark_distances,
    nearest_points,
    nees,
    nees_and_paper,
    nees_band,
    nees_paper,
    nees_paper_series,
    nees_series,
    pose_to_absolute,
    position_error,
)

__all__ = [
    "CoverageGrid",
    "boundary_faces",
    "boundary_points",
    "boundary_samples",
    "completeness",
    "completeness_and_error",
    "completeness_seen",
    "count_interval",
    "cov_to_absolute",
    "distance_to_boundary",
    "duplicates",
    "expected_precision",
    "has_map",
    "hit_fraction",
    "landmark_distances",
    "map_distances",
    "map_error_length",
    "map_points",
    "map_precision",
    "map_quality",
    "nearest_points",
    "nees",
    "nees_and_paper",
    "nees_band",
    "nees_paper",
    "nees_paper_series",
    "nees_series",
    "nu",
    "nu_mean",
    "pose_to_absolute",
    "position_error",
    "sample_arclength_batch",
    "seen_boundary",
    "seen_samples",
    "segment_faces",
    "time_to_fraction",
    "wrap_angle",
]

"""Point-landmark particle-filter SLAM back-ends from seed 003 (Chen et al., MBLCC-FastSLAM).

numpy and ``core`` only. It owns: ``config`` (``PointSlamConfig``, the seed's settings, and
:func:`algorithm_config`), ``models`` (the filters' car and range-bearing models),
``particles`` (vectorised particle state and the pure prediction / proposal / weight /
landmark-EKF / resampling functions), ``em`` (EM-FastSLAM's attraction-repulsion move),
``fastslam`` (one robot's FastSLAM 2.0, EM-FastSLAM or MBLCC-FastSLAM) and ``shared_map``
(``multirobot_known_start``: one joint filter and one map for the team, ref. [10]).

The interface every back-end implements (:class:`PointSlamBackend`)::

    step(controls (K, 2) of measured (V, G), PointMeasurements(ids, z))   # one sweep
    pose() -> (mean (3,), cov (3, 3))
    landmarks() -> LandmarkMap(ids (M,), means (M, 2), covs (M, 2, 2))
    export_message() -> LandmarkMessage      # after a step: what the robot offers
    import_messages([LandmarkMessage, ...])  # before a step: what the others offered

A step takes the controls the robot applied since its last sweep (one per period ``dt``) and
one sensor sweep (maybe empty). MBLCC's message is its best particle's estimates of the
landmarks it observed in its last sweep (eq. 12's μ^{n,max}_{j,k−1}); a robot applies the
consensus term to the landmarks it re-observes that the messages carry. The other back-ends
send empty or unused messages, so a driver can treat all alike.
"""

from polyslam_env.slam.points.config import ALGORITHMS, PointSlamConfig, algorithm_config
from polyslam_env.slam.points.fastslam import PointFastSlam
from polyslam_env.slam.points.interface import (
    LandmarkMap,
    LandmarkMessage,
    PointMeasurements,
    PointSlamBackend,
)
from polyslam_env.slam.points.shared_map import SharedMapFastSlam, SharedMapRobot

__all__ = [
    "ALGORITHMS",
    "LandmarkMap",
    "LandmarkMessage",
    "PointFastSlam",
    "PointMeasurements",
    "PointSlamBackend",
    "PointSlamConfig",
    "SharedMapFastSlam",
    "SharedMapRobot",
    "algorithm_config",
]

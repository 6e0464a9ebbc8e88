"""The one name of a robot: ``robot_<i>``, as the env's agents are called.

Tables, metrics files, picture legends and labels all name robot ``i`` by :func:`robot_name`
(``polyslam reproduce`` keeps the paper's ``r1``–``r3`` where it sets its table beside the
paper's).
"""

from __future__ import annotations

__all__ = ["robot_name"]


def robot_name(index: int) -> str:
    """Robot ``index``'s name everywhere: ``robot_0``, ``robot_1``, …"""
    return f"robot_{index}"

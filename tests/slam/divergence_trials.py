"""Seeded episodes with an injected fault, reduced to when the divergence flag first fired.

Shared by ``tests/slam/test_divergence.py`` and ``scripts/divergence_rates.py``: one robot
follows the right-hand wall (``wall_follow`` policy) on a generated 6 × 4 m ``rooms`` map,
without map exchange and with ``initial_error`` on; the fault (if any) hits it at
``FAULT_STEP``, after it has mapped the walls around it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from policies.base import make_team
from polyslam_env import parallel_env

#: Step of the injected fault and the steps the flag has to fire in after it.
FAULT_STEP, DEADLINE = 60, 20

KIDNAP_05 = {"kind": "kidnap", "robot": 0, "step": FAULT_STEP, "distance": 0.5}
KIDNAP_10 = {"kind": "kidnap", "robot": 0, "step": FAULT_STEP, "distance": 1.0}
SLIP_05 = {"kind": "slip", "robot": 0, "step": FAULT_STEP, "scale": 0.5, "steps": DEADLINE}


def first_alarm(seed: int, fault: dict[str, Any] | None, steps: int) -> int | None:
    """The env step at which robot 0's divergence flag first fired, None if never."""
    env = parallel_env(
        map="generator:rooms",
        num_robots=1,
        max_steps=steps,
        coverage_target=None,
        channel=None,
        faults=[] if fault is None else [fault],
    )
    team = make_team("wall_follow", env)
    observations, _ = env.reset(seed=seed)
    team.reset(seed)
    rng = np.random.default_rng(seed)
    alarm = None
    while env.agents:
        observations, _, _, _, infos = env.step(team.act(observations, rng))
        alarm = infos["robot_0"]["diverged_at"]
    return alarm


def detection_delay(seed: int, fault: dict[str, Any]) -> int | None:
    """Steps from the fault to the first alarm at or after it, None if none within
    ``DEADLINE`` steps; -1 if the flag fired before the fault (a false alarm)."""
    alarm = first_alarm(seed, fault, FAULT_STEP + DEADLINE)
    if alarm is None:
        return None
    return alarm - FAULT_STEP if alarm >= FAULT_STEP else -1

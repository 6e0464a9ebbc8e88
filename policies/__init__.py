"""Policies for ``polyslam_v0``: the interface, the registry and the scripted policies.

Policies see their agent's observation and static facts only (:class:`PolicyContext`). The
registry :data:`POLICIES` maps names to factories; :func:`make_policy` builds one by name.
"""

from policies.base import (
    POLICIES,
    CheckpointError,
    Policy,
    PolicyContext,
    PolicyError,
    TeamPolicy,
    make_policy,
    make_team,
    policy_names,
)

__all__ = [
    "POLICIES",
    "CheckpointError",
    "Policy",
    "PolicyContext",
    "PolicyError",
    "TeamPolicy",
    "make_policy",
    "make_team",
    "policy_names",
]

"""Joining a Ray cluster (or starting a local Ray instance), for the work that runs on Ray:
RLlib training (:mod:`polyslam_env.apps.training_rllib`) and a study's jobs
(:mod:`polyslam_env.apps.jobs`). Ray is the ``ray`` extra, imported only here and there."""

from __future__ import annotations

import os
from pathlib import Path

from polyslam_env.core.errors import PolyslamError

__all__ = ["init_ray", "join_error", "require_ray"]


def require_ray() -> None:
    """Raise ``ModuleNotFoundError`` (name ``ray``) when the ``ray`` extra is missing."""
    import ray  # noqa: F401


def _package_root() -> str:
    import polyslam_env

    return str(Path(polyslam_env.__file__).resolve().parents[1])


def init_ray(address: str | None, num_cpus: int) -> None:
    """Join the cluster at ``address`` (or ``RAY_ADDRESS``), else start a local instance
    with ``num_cpus`` CPUs, no dashboard, workers' output not forwarded. Workers get this
    package's folder on ``PYTHONPATH`` so that they import the same code as this process."""
    import ray

    root = _package_root()
    path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
    runtime_env = {"env_vars": {"PYTHONPATH": path}}
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        try:
            ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
        except ConnectionError as err:
            raise PolyslamError(join_error(address, err)) from err
    else:
        ray.init(
            address="local",  # a new instance even if `ray start` runs on this machine
            num_cpus=num_cpus,
            include_dashboard=False,
            log_to_driver=False,
            runtime_env=runtime_env,
            configure_logging=False,
        )


def join_error(address: str, err: BaseException) -> str:
    """One line on why joining the cluster at ``address`` failed. Ray's own message spans
    tracebacks; a cluster that asks for a token is named with the fix: ``ray start`` turns
    token authentication on when the head has a token (``~/.ray/auth_token``), while a
    driver given an explicit address never turns it on by itself (Ray's rule, so that a token
    is not sent to any address one types)."""
    text = " ".join(str(e) for e in (err, err.__cause__, err.__context__) if e is not None)
    if "InvalidAuthToken" in text or "AuthenticationError" in text:
        return (
            f"--address {address}: the Ray cluster asks for token authentication; set"
            " RAY_AUTH_MODE=token and give its token (~/.ray/auth_token, RAY_AUTH_TOKEN or"
            " RAY_AUTH_TOKEN_PATH), or start the cluster with RAY_AUTH_MODE=disabled"
        )
    first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    return f"--address {address}: could not join the Ray cluster: {first}"

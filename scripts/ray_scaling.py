"""A study on 1 and 2 Ray workers (a local head started with ``--num-cpus 1``, then 2), and
on 1 and 2 local processes, in one run: wall times and their ratios (docs/guide/cluster.md).

    python scripts/ray_scaling.py [--seeds 6] [--steps 100] [--rounds 2]

Starts and stops its own Ray heads under the machine-wide lock the Ray tests take (``ray
stop --force`` stops every Ray process on the machine). Prints one line per run with the
load average beside it, and the ratios at the end.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def study(seeds: int, steps: int) -> list[str]:
    return [
        sys.executable, "-m", "polyslam_env.cli", "fidelity", "--maps", "loop",
        "--seeds", str(seeds), "--steps", str(steps), "--robots", "2", "--no-pictures", "--quiet",
    ]  # fmt: skip


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def timed(command: list[str], out: Path) -> tuple[float, float]:
    """Wall time of ``command`` (whole, Ray's join included) and the study's own."""
    start = time.perf_counter()
    subprocess.run([*command, "--out", str(out)], check=True, capture_output=True)
    wall = time.perf_counter() - start
    return wall, json.loads((out / "summary.json").read_text())["elapsed_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    ray = shutil.which("ray") or str(Path(sys.executable).with_name("ray"))
    env = {**os.environ, "RAY_AUTH_MODE": os.environ.get("RAY_AUTH_MODE", "disabled")}
    env.pop("RAY_ADDRESS", None)
    os.environ.update(env)
    command = study(args.seeds, args.steps)
    times: dict[str, list[float]] = {}
    lock = Path(tempfile.gettempdir()) / "polyslam-ray-tests.lock"
    with open(lock, "w") as held, tempfile.TemporaryDirectory() as tmp:
        fcntl.flock(held, fcntl.LOCK_EX)
        for _ in range(args.rounds):
            for cpus in (1, 2):
                port = free_port()
                head = [ray, "start", "--head", f"--port={port}", f"--num-cpus={cpus}"]
                flags = ["--disable-usage-stats", "--include-dashboard=false"]
                subprocess.run([*head, *flags], check=True, capture_output=True)
                try:
                    run = [*command, "--address", f"127.0.0.1:{port}"]
                    report(f"ray {cpus} worker(s)", run, Path(tmp) / f"ray{cpus}", times)
                finally:
                    subprocess.run([ray, "stop", "--force"], capture_output=True)
            for workers in (1, 2):
                run = [*command, "--workers", str(workers)]
                report(f"local {workers} process(es)", run, Path(tmp) / f"loc{workers}", times)
    for kind in ("ray", "local"):
        one, two = (min(v) for k, v in sorted(times.items()) if k.startswith(kind))
        print(f"{kind}: 1 → 2 workers, best study time {one:.1f} s → {two:.1f} s: ×{one / two:.2f}")


def report(name: str, command: list[str], out: Path, times: dict[str, list[float]]) -> None:
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3])
    wall, elapsed = timed(command, out)
    times.setdefault(name, []).append(elapsed)
    print(f"{name:<22} study {elapsed:6.1f} s, command {wall:6.1f} s (load {load})", flush=True)


if __name__ == "__main__":
    main()

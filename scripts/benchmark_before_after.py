"""Issue 15's target table, before and after, in one run on one machine.

Exports the ``--before`` commit's source tree (``git archive``) to a temporary folder and runs
``polyslam benchmark --quick --json`` and ``polyslam reproduce --runs N`` from that tree and
from this checkout in turn, ``--repeats`` times each, interleaved (before, after, before,
after, …) so that a change of machine load hits both sides alike. Each side runs in its own
process with its own source on ``PYTHONPATH``. The table gives, per target of
:data:`polyslam_env.apps.benchmark.TARGETS` and for the reproduction's wall time, the median
over repeats of each side (a row the older benchmark did not measure shows "—").

    python scripts/benchmark_before_after.py --before 5c72457 --repeats 2 --out out/before_after
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from polyslam_env.apps.benchmark import TARGETS, targets

ROOT = Path(__file__).resolve().parents[1]
#: Runs the CLI of whichever ``polyslam_env`` is first on ``PYTHONPATH``.
CLI = "import sys; from polyslam_env.cli.main import main; sys.exit(main(sys.argv[1:]))"


def export(rev: str, folder: Path) -> Path:
    """The source tree of commit ``rev`` under ``folder``."""
    archive = folder / "src.tar"
    with open(archive, "wb") as f:
        subprocess.run(["git", "-C", str(ROOT), "archive", rev], stdout=f, check=True)
    src = folder / "src"
    with tarfile.open(archive) as tar:
        tar.extractall(src, filter="data")
    return src


def polyslam(src: Path, args: list[str]) -> float:
    """Run ``polyslam ARGS`` from the tree ``src``; its wall time (s)."""
    env = {**os.environ, "PYTHONPATH": str(src), "PYTHONHASHSEED": "0"}
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", CLI, *args], cwd=src, env=env, check=True, stdout=subprocess.DEVNULL
    )
    return time.perf_counter() - start


def measure(src: Path, out: Path, name: str, runs: int) -> dict[str, Any]:
    """One benchmark and one reproduction from ``src``: the target figures and the seconds."""
    bench = out / f"{name}.json"
    polyslam(src, ["benchmark", "--quick", "--json", str(bench)])
    figures = {row["target"]: row["measured"] for row in targets(json.loads(bench.read_text()))}
    seconds = polyslam(src, ["reproduce", "--runs", str(runs), "--out", str(out / f"{name}_rep")])
    return {"targets": figures, "reproduce_s": seconds}


def _median(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return float(np.median(known)) if known else None


def _cell(value: float | None) -> str:
    if value is None:
        return "—"
    return f"{value:.3g}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="the commit to compare with")
    parser.add_argument("--repeats", type=int, default=2, help="runs per side (default 2)")
    parser.add_argument("--runs", type=int, default=100, help="polyslam reproduce --runs")
    parser.add_argument("--out", default="out/before_after", help="output folder")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        before = export(args.before, Path(tmp))
        for k in range(args.repeats):
            for side, src in (("before", before), ("after", ROOT)):
                print(f"repeat {k + 1}/{args.repeats}: {side}", file=sys.stderr, flush=True)
                results[side].append(measure(src, out, f"{side}_{k}", args.runs))
    rows: list[dict[str, Any]] = []
    for _issues, name, goal, at_most in TARGETS:
        b = _median([r["targets"].get(name) for r in results["before"]])
        a = _median([r["targets"].get(name) for r in results["after"]])
        met = None if a is None else (a <= goal if at_most else a >= goal)
        rows.append(
            {"figure": name, "before": b, "after": a, "goal": goal, "at_most": at_most, "met": met}
        )
    b = _median([r["reproduce_s"] for r in results["before"]])
    a = _median([r["reproduce_s"] for r in results["after"]])
    rows.append(
        {
            "figure": f"polyslam reproduce --runs {args.runs} (s)",
            "before": b,
            "after": a,
            "goal": 20.0,
            "at_most": True,
            "met": a is not None and a <= 20.0,
        }
    )
    summary = {"before": args.before, "repeats": args.repeats, "rows": rows, "raw": results}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"| figure | before ({args.before}) | after | target | met |")
    print("|---|---|---|---|---|")
    for r in rows:
        bound = ("≤ " if r["at_most"] else "≥ ") + _cell(r["goal"])
        verdict = {None: "—", True: "yes", False: "no"}[r["met"]]
        print(
            f"| {r['figure']} | {_cell(r['before'])} | {_cell(r['after'])} | {bound} | {verdict} |"
        )
    print(f"medians of {args.repeats} interleaved runs per side; wrote {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A tiny run of each script README takes figures from: it exits 0 and writes what it says.

Each runs as a user runs it (``python scripts/NAME.py …``, the checkout on ``PYTHONPATH``),
with arguments that make it quick; the figures themselves are README's, measured with the
full arguments. Not here: ``benchmark_before_after.py`` (it runs ``polyslam benchmark`` and
``polyslam reproduce`` twice each from two source trees, minutes even with its smallest
arguments; both commands have their own tests in ``tests/apps``), ``backends_table.py`` (one
episode of each of seven back-ends at the preset's full length, no option to shorten it:
over 10 minutes here; its episodes are ``evaluate_episode``'s, tested in ``tests/apps``), and
``check_slam_regression.py`` (compares with a reference it has no option to relocate; a
regression check, not a figure source).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str, cwd: Path = ROOT) -> str:
    env = os.environ | {"PYTHONPATH": str(ROOT), "SDL_VIDEODRIVER": "dummy", "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, f"{args[0]} exited {done.returncode}:\n{done.stderr[-2000:]}"
    return done.stdout


#: (script and tiny arguments, a line its output must contain)
PRINTING = [
    (["divergence_rates.py", "--seeds", "1"], "healthy (80 steps): flag fired in"),
    (["bench_team_act.py", "--steps", "2", "4", "--compare", "."], "this tree "),
    (["bench_reset.py", "--resets", "20"], "fresh/reuse"),
    (["env_stage_calls.py", "--env", "noslam", "--first", "2", "--last", "6"],
     "Python calls per env step"),
    (["exchange_bytes.py"], "polynomials"),
    (["floor_before_after.py", "--tree", ".", "--first", "2", "--last", "4"], "env calls"),
    (["landmark_consistency.py", "--seeds", "1", "--robots", "1", "--steps", "40"], "c0_nees"),
    (["nees_episodes.py", "--runs", "1", "--steps", "20"], "seed 0: final NEES frame"),
    (["nees_start_draw.py", "--seeds", "3", "--steps", "20", "--robots", "2"], '"slope_ci_t"'),
    (["physics_substeps.py", "--substeps", "20,10", "--steps", "40", "--generators", "rooms"],
     "calls per world step"),
    (["seif_fusion_nees.py", "--episodes", "1", "--steps", "20"], "NEES"),
    (["slam_table.py", "--seeds", "1", "--workers", "1"], "paper Table 1:"),
    (["slam_calls.py", "--first", "2", "--last", "6"], "calls per env step"),
    (["train_throughput.py", "--tree", ".", "--timesteps", "48", "--n-steps", "2", "--repeats",
      "1"],
     "CPU ms/env step"),
    (["vec_lockstep.py", "--steps", "10"], "2 processes / one:"),
]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize(("args", "expected"), PRINTING, ids=[a[0] for a, _ in PRINTING])
def test_script__tiny_run_prints_its_table(args: list[str], expected: str) -> None:
    out = _run(f"scripts/{args[0]}", *args[1:])
    assert expected in out, out[-2000:]


@pytest.mark.slow
def test_paired_slam__tiny_run_writes_its_json(tmp_path: Path) -> None:
    path = tmp_path / "paired.json"
    short = ["max_steps=20"]
    _run("scripts/paired_slam.py", "--seeds", "2", "--workers", "1", "--json", str(path),
         "--a", *short, "--b", *short)  # fmt: skip
    assert json.loads(path.read_text())


@pytest.mark.slow
def test_learned_policy_report__reads_an_evaluate_json(tmp_path: Path) -> None:
    path = tmp_path / "eval.json"
    tiny = ["--policy", "frontier,random,ppo", "--map", "two_rooms", "--robots", "2",
            "--steps", "10", "--episodes", "1"]  # fmt: skip
    _run("-m", "polyslam_env.cli.main", "evaluate", *tiny, "--workers", "1", "--quiet",
         "--json", str(path))  # fmt: skip
    assert path.exists()
    assert _run("scripts/learned_policy_report.py", str(path), "--workers", "1").strip()
    # a policy renamed from a file of its own pairs with the same policy of another file
    one = tmp_path / "one.json"
    report = json.loads(path.read_text())
    report["episodes"] = {"frontier": report["episodes"]["frontier"]}
    one.write_text(json.dumps(report))
    out = _run("scripts/learned_policy_report.py", "--phases", "--policies", "frontier,again",
               str(path), f"again={one}")  # fmt: skip
    assert "again − frontier steps to 30 %, paired by seed: +0.0000" in out, out
    # the Pareto figure of two of its policies, paired on the same episode
    figure = tmp_path / "pareto.png"
    out = _run("scripts/pareto.py", "--out", str(figure), "--point", "F", "frontier", str(path),
               "--point", "R", "random", str(path))  # fmt: skip
    assert figure.stat().st_size > 0 and "R − F, paired" in out


@pytest.mark.slow
def test_check_env_regression__records_then_matches_its_reference(tmp_path: Path) -> None:
    ref = tmp_path / "reference.pkl"
    assert "saved to" in _run("scripts/check_env_regression.py", "--steps", "3", "--record",
                              "--reference", str(ref))  # fmt: skip
    out = _run("scripts/check_env_regression.py", "--steps", "3", "--reference", str(ref))
    assert out.strip() and "BAD" not in out

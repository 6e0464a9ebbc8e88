"""A study on a real Ray cluster (`ray start --head` on this machine, shared by the tests of
this module): the same episodes as a local run, bit for bit; killed half-way by SIGTERM and
resumed, the table of a run straight through; a task that raises retried once and reported.

Skipped without the ``ray`` extra; holds the lock of :mod:`tests.apps.ray_cluster`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from polyslam_env.apps.jobs import Runner
from polyslam_env.cli.main import main
from tests.apps import ray_cluster as cluster
from tests.apps.test_jobs import retried_and_reported

#: 4 seeds × 2 settings of 30 steps on loop: long enough to be killed half-way on 2 CPUs
#: (about a second an episode), short enough for the suite.
STUDY = ["fidelity", "--maps", "loop", "--seeds", "4", "--steps", "30", "--robots", "2"]
EPISODES = 8
FLAGS = ["--quiet", "--no-pictures"]
#: Wall-clock metrics measure the machine, not the episode.
TIMINGS = ("slam_time_ms", "slam_time_ms_median")


@pytest.fixture(scope="module")
def head() -> Iterator[str]:
    """One Ray head (2 CPUs) for every test here: Ray's start-up is slow."""
    with cluster.ray_lock(), pytest.MonkeyPatch.context() as mp, cluster.ray_head(mp) as address:
        yield address


@pytest.fixture(scope="module")
def straight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The study run straight through, locally in this process: its output folder."""
    out = tmp_path_factory.mktemp("straight")
    assert main([*STUDY, *FLAGS, "--workers", "1", "--out", str(out)]) == 0
    return out


def _episodes(out: Path) -> dict[int, Any]:
    """Each episode of the results log in ``out`` by index, its timings left out."""
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    return {record["index"]: _untimed(record) for record in records}


def _untimed(data: Any) -> Any:
    """``data`` without the :data:`TIMINGS` keys of its dicts, at any depth."""
    if isinstance(data, dict):
        return {k: _untimed(v) for k, v in data.items() if k not in TIMINGS}
    if isinstance(data, list):
        return [_untimed(v) for v in data]
    return data


def test_cluster__same_episodes_as_a_local_run(
    head: str, straight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*STUDY, *FLAGS, "--address", head, "--out", str(tmp_path)]) == 0
    assert f"on the Ray cluster at {head}" in capsys.readouterr().out
    local, remote = _episodes(straight), _episodes(tmp_path)
    assert sorted(remote) == list(range(EPISODES))
    assert remote == local  # every metric, bit for bit (JSON floats round-trip exactly)
    assert (tmp_path / "table.md").read_text() == (straight / "table.md").read_text()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["settings"]["address"] == head and summary["failed"] == []


def test_cluster__killed_half_way_and_resumed_gives_the_straight_table(
    head: str, straight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a real SIGTERM to the CLI, as a scheduler sends, once the first episode is logged
    log = tmp_path / "episodes.jsonl"
    args = [*STUDY, *FLAGS, "--address", head, "--out", str(tmp_path)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "polyslam_env.cli", *args],
        env={k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 240
        while not (log.exists() and log.read_bytes().count(b"\n")) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 143, stderr
    assert "interrupted (SIGTERM)" in stderr and "--resume" in stderr
    kept = log.read_bytes().count(b"\n")
    assert 1 <= kept < EPISODES, "the study was not killed half-way"
    assert not (tmp_path / "table.md").exists()

    assert main([*args, "--resume"]) == 0
    assert f"--resume: {kept} of {EPISODES} episodes already in" in capsys.readouterr().err
    assert (tmp_path / "table.md").read_text() == (straight / "table.md").read_text()
    assert _episodes(tmp_path) == _episodes(straight)


def test_cluster__a_task_that_raises_is_retried_once_and_reported(
    head: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the test-only job of test_jobs.py, imported by the Ray workers from this checkout
    retried_and_reported(Runner(address=head), tmp_path, capsys)


def test_cluster__evaluate_and_reproduce_same_as_local(head: str, tmp_path: Path) -> None:
    config = tmp_path / "paper.yaml"
    config.write_text("steps: 20\nruns: 2\n")  # the paper's study, 2 runs of 20 steps
    commands = {
        "evaluate": ["evaluate", "--map", "two_rooms", "--episodes", "2", "--steps", "10"],
        "reproduce": ["reproduce", "--config", str(config)],
    }
    for name, command in commands.items():
        local, remote = tmp_path / f"{name}_local", tmp_path / f"{name}_ray"
        assert main([*command, "--quiet", "--workers", "1", "--out", str(local)]) == 0
        assert main([*command, "--quiet", "--address", head, "--out", str(remote)]) == 0
        assert len(_episodes(remote)) == 2, name
        assert _episodes(remote) == _episodes(local), name

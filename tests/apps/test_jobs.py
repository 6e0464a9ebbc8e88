"""A study's jobs without Ray: the results log (its codec, torn lines, another study's log),
resuming, a failing job retried once and reported, the progress bar, and the CLI's flags.
The Ray backend's tests are in :mod:`tests.apps.test_jobs_ray`."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from polyslam_env.apps import fidelity
from polyslam_env.apps.joblog import ResultsLog, decode, encode, study_hash
from polyslam_env.apps.jobs import Runner, run_jobs
from polyslam_env.apps.rollout import EpisodeResult
from polyslam_env.cli.main import main
from polyslam_env.core.errors import PolyslamError

#: A fidelity study small enough for a unit test: 2 seeds × 2 settings of 4 steps on loop.
FIDELITY = ["fidelity", "--maps", "loop", "--seeds", "2", "--steps", "4", "--robots", "2"]


def flaky(job: tuple[int, str, str]) -> dict[str, Any]:
    """A test-only job: ``(seed, mode, folder)``. ``once`` raises the first time it runs
    (a marker file in ``folder`` remembers, across processes), ``always`` every time."""
    seed, mode, folder = job
    marker = Path(folder) / f"tried_{seed}"
    if mode == "always" or (mode == "once" and not marker.exists()):
        marker.touch()
        raise ValueError(f"map file of seed {seed} does not load")
    return {"seed": seed, "value": seed * 0.1}


def retried_and_reported(runner: Runner, folder: Path, capsys: Any) -> str:
    """Run three :func:`flaky` jobs with ``runner`` (fine, failing once, failing always) and
    check the outcome: the second retried and done, the third reported and left out, the
    study going on. Returns what went to stderr."""
    jobs = [(10, "fine", ""), (11, "once", str(folder)), (12, "always", str(folder))]
    results = run_jobs(flaky, jobs, runner, seed_of=lambda job: job[0])
    assert results == [{"seed": 10, "value": 1.0}, {"seed": 11, "value": 1.1}, None]
    error = "ValueError: map file of seed 12 does not load"
    assert runner.failed == [{"index": 2, "seed": 12, "error": error}]
    err: str = capsys.readouterr().err
    assert "episode 1 (seed 11) failed: ValueError: map file of seed 11 does not load" in err
    assert err.count("trying it once more") == 2  # episodes 1 and 2, once each
    assert f"episode 2 (seed 12) failed again: {error}; going on without it" in err
    return err


def counted(job: tuple[int, str]) -> float:
    """A test-only job ``(seed, folder)`` that leaves a file per run, to count the runs."""
    seed, folder = job
    with open(Path(folder) / f"ran_{seed}", "a") as f:
        f.write("x")
    return seed / 3


def test_codec__round_trips_results_bit_for_bit_as_strict_json() -> None:
    value: dict[str, Any] = {
        "floats": [0.1, -0.0, 1e-300, math.pi, math.nan, math.inf, -math.inf],
        "numpy": [np.float32(0.1), np.int64(7), np.bool_(True), np.arange(6.0).reshape(2, 3)],
        "tuple": (1, "a", None),
        "by_int": {3: [1.5], 4: []},
        "episode": EpisodeResult(3, 10, {"robot_0": {"nu": 0.25}}, {"coverage": 0.5}, [0.1]),
    }
    back = decode(json.loads(json.dumps(encode(value), allow_nan=False)))
    assert json.dumps(encode(back), allow_nan=False) == json.dumps(encode(value))
    assert isinstance(back["episode"], EpisodeResult) and back["episode"] == value["episode"]
    assert type(back["numpy"][0]) is np.float32 and back["numpy"][0] == value["numpy"][0]
    assert back["numpy"][3].shape == (2, 3) and back["numpy"][3].dtype == np.float64
    assert back["tuple"] == (1, "a", None) and back["by_int"] == {3: [1.5], 4: []}
    floats = back["floats"]
    assert [x.hex() for x in floats[:4]] == [x.hex() for x in value["floats"][:4]]
    assert math.isnan(floats[4]) and floats[5:] == [math.inf, -math.inf]
    with pytest.raises(TypeError, match="set"):
        encode({1, 2})


def test_codec__rebuilds_only_this_packages_classes() -> None:
    planted = {"__type__": "dataclass", "class": "os:system", "fields": {}}
    with pytest.raises(ValueError, match="not a class of this package"):
        decode(planted)


def test_results_log__ignores_a_torn_last_line_and_cuts_it_before_appending(
    tmp_path: Path,
) -> None:
    log = ResultsLog(tmp_path / "episodes.jsonl", "abc")
    log.open(resume=False)
    log.append(0, 10, result=1.5)
    with open(log.path, "ab") as f:  # a kill in the middle of the second line's write
        f.write(b'{"study":"abc","index":1,"seed":11,"resu')
    assert [r["index"] for r in log.read()] == [0]
    log.open(resume=True)
    log.append(1, 11, result=2.5)
    assert [(r["index"], r["result"]) for r in log.read()] == [(0, 1.5), (1, 2.5)]
    assert log.path.read_bytes().count(b"\n") == 2


def test_run_jobs__resume_skips_the_logged_jobs_and_returns_the_log(tmp_path: Path) -> None:
    jobs = [(seed, str(tmp_path)) for seed in range(5)]
    log = tmp_path / "episodes.jsonl"
    straight = run_jobs(counted, jobs, Runner(log=log), seed_of=lambda job: job[0])
    assert straight == [seed / 3 for seed in range(5)]
    lines = log.read_bytes().splitlines(keepends=True)
    log.write_bytes(b"".join(lines[:2]) + lines[2][:20])  # killed during the third line
    for ran in tmp_path.glob("ran_*"):
        ran.unlink()
    resumed = run_jobs(counted, jobs, Runner(log=log, resume=True), seed_of=lambda j: j[0])
    assert resumed == straight
    assert sorted(p.name for p in tmp_path.glob("ran_*")) == ["ran_2", "ran_3", "ran_4"]
    assert [json.loads(line)["seed"] for line in log.read_text().splitlines()] == [0, 1, 2, 3, 4]


def test_run_jobs__refuses_a_log_of_another_study(tmp_path: Path) -> None:
    log = tmp_path / "episodes.jsonl"
    run_jobs(counted, [(0, str(tmp_path))], Runner(log=log))
    with pytest.raises(PolyslamError, match="another study configuration") as err:
        run_jobs(counted, [(1, str(tmp_path))], Runner(log=log, resume=True))
    assert "\n" not in str(err.value) and str(log) in str(err.value)
    assert study_hash(counted, [(0, "a")]) != study_hash(counted, [(0, "b")])
    assert study_hash(counted, [(0, "a")]) != study_hash(flaky, [(0, "a")])


@pytest.mark.parametrize("workers", [1, 2])
def test_run_jobs__a_failing_job_is_retried_once_reported_and_the_study_goes_on(
    tmp_path: Path, workers: int, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "episodes.jsonl"
    runner = Runner(workers=workers, log=log, bar=True, desc="study")
    err = retried_and_reported(runner, tmp_path, capsys)
    assert "3/3" in err and "failed 1" in err  # the progress bar
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert {r["index"]: "result" in r for r in logged} == {0: True, 1: True, 2: False}
    assert [r["failed"] for r in logged if r["index"] == 2] == [runner.failed[0]["error"]]


def test_run_jobs__every_job_failing_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(PolyslamError, match="every episode failed; the first, episode 0"):
        run_jobs(flaky, [(5, "always", str(tmp_path))], 1, seed_of=lambda job: job[0])


def test_fidelity_cli__a_failed_episode_is_listed_in_summary_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    run_job = fidelity._run_job

    def broken_on_seed_1(job: Any) -> Any:  # in this process: --workers 1
        if job[3] == 1 and job[0]["channel"] is None:
            raise OSError("out of memory")
        return run_job(job)

    monkeypatch.setattr(fidelity, "_run_job", broken_on_seed_1)
    args = [*FIDELITY, "--out", str(tmp_path), "--quiet", "--no-pictures", "--workers", "1"]
    assert main(args) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    # jobs: exchange_on seeds 0, 1, then exchange_off seeds 0, 1
    assert summary["failed"] == [{"index": 3, "seed": 1, "error": "OSError: out of memory"}]
    assert [e["seed"] for e in summary["episodes"]["loop"]["exchange_off"]] == [0]
    captured = capsys.readouterr()
    assert "episode 3 (seed 1) failed again: OSError: out of memory" in captured.err
    assert "listed in summary.json" in captured.out


def test_fidelity_cli__resume_refuses_a_log_of_other_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    common = ["--out", str(tmp_path), "--quiet", "--no-pictures"]
    assert main([*FIDELITY, *common]) == 0
    capsys.readouterr()
    assert main([*FIDELITY, *common, "--resume", "--policy-set", "gain=visible"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "another study configuration" in err and "episodes.jsonl" in err
    assert main([*FIDELITY, *common, "--resume"]) == 0  # the same options: nothing to run
    assert "--resume: 4 of 4 episodes already in" in capsys.readouterr().err


def test_study_flags__one_line_errors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = ["--out", str(tmp_path / "o"), "--quiet"]
    cases = {
        "--workers counts local processes": ["--address", "h:1", "--workers", "2"],
        "needs ray: pip install 'polyslam[ray]'": ["--address", "h:1"],
    }
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ModuleNotFoundError
    for command in (FIDELITY, ["reproduce", "--paper", "seif", "--runs", "1"]):
        for text, flags in cases.items():
            assert main([*command, *out, *flags]) == 2
            err = capsys.readouterr().err
            assert len(err.strip().splitlines()) == 1 and text in err, err
    monkeypatch.setenv("RAY_ADDRESS", "h:1")  # as --address, unless --workers is given
    assert main(["evaluate", "--episodes", "1", "--steps", "2", "--quiet"]) == 2
    assert "needs ray" in capsys.readouterr().err
    assert main(["evaluate", "--episodes", "1", "--resume", "--workers", "1"]) == 2
    assert "--resume: needs --out" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing written


def test_fidelity_cli__sigterm_stops_the_workers_and_resume_gives_the_straight_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 2 seeds × 2 settings of 30 steps (about a second each) in 2 local processes: a real
    # SIGTERM to the CLI once the first episode is logged
    study = [*FIDELITY[:-4], "--steps", "30", "--robots", "2", "--quiet", "--no-pictures"]
    killed, straight = tmp_path / "killed", tmp_path / "straight"
    proc = subprocess.Popen(
        [sys.executable, "-m", "polyslam_env.cli", *study, "--workers", "2", "--out", str(killed)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    log = killed / "episodes.jsonl"
    try:
        deadline = time.monotonic() + 240
        while not (log.exists() and log.read_bytes().count(b"\n")) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        workers = _children(proc.pid)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 143, stderr
    assert "polyslam: interrupted (SIGTERM):" in stderr and "--resume" in stderr
    assert workers and not [pid for pid in workers if Path(f"/proc/{pid}").exists()]
    assert 1 <= log.read_bytes().count(b"\n") < 4, "the study was not killed half-way"

    assert main([*study, "--workers", "2", "--out", str(killed), "--resume"]) == 0
    assert main([*study, "--workers", "1", "--out", str(straight)]) == 0
    assert (killed / "table.md").read_text() == (straight / "table.md").read_text()


def _children(pid: int) -> list[int]:
    """The processes ``pid`` started (Linux /proc)."""
    tasks = Path(f"/proc/{pid}/task").glob("*/children")
    return [int(child) for path in tasks for child in path.read_text().split()]

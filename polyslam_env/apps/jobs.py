"""Running a study's independent jobs: in this process, in a pool of local processes, or as
tasks on a Ray cluster; each finished job kept in a results log the study can resume from.

A study hands :func:`run_jobs` a module-level function and picklable jobs, each seeded by
its own seed (never by the worker that runs it), so that where a job runs changes nothing in
its result. A :class:`Runner` says where the jobs run (``workers`` local processes, or the
Ray cluster at ``address``), where their results log is and whether to resume from it, and
whether to draw a progress bar (jobs done, failed, estimated time left).

With a log (:mod:`polyslam_env.apps.joblog`), every finished job is appended to it as it
finishes, so a kill (SIGTERM, Ctrl-C, a lost node) loses only the jobs then running;
``resume`` skips the jobs the log already has, and refuses a log of another study. The
results returned are then the ones read back from the log, so a resumed study's results, and
every table made from them, equal an uninterrupted one's.

A job that raises (or whose worker dies) is reported on stderr with its index and seed and
tried once more; if it fails again, it is reported, logged and listed in ``Runner.failed``,
its place in the results is ``None``, and the study goes on with the others.
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

from polyslam_env.apps.joblog import ResultsLog, decode, encode, study_hash
from polyslam_env.core.errors import Interrupted, PolyslamError

__all__ = ["Runner", "run_jobs", "runner_of", "succeeded"]

J = TypeVar("J")
R = TypeVar("R")

#: How often a job is tried before it counts as failed.
TRIES = 2


@dataclass
class Runner:
    """Where a study's jobs run, and what is kept of them.

    ``workers`` local processes (1: this process), or, with ``address`` (``host:port`` of a
    Ray head, or ``auto``), one Ray task per job on that cluster, one CPU each (``workers``
    is then not used). ``log``: the results log file, none kept if ``None``; ``resume``:
    skip the jobs it already has. ``bar``: draw a progress bar named ``desc``, counting
    ``noun`` s. ``failed`` gathers the jobs that failed on both tries: ``{"index", "seed",
    "error"}`` each.
    """

    workers: int = 1
    address: str | None = None
    log: Path | None = None
    resume: bool = False
    bar: bool = False
    desc: str = "jobs"
    noun: str = "episode"
    failed: list[dict[str, Any]] = field(default_factory=list)

    def settings(self) -> dict[str, Any]:
        """Where the jobs ran, for a study's summary: ``workers`` or the Ray ``address``."""
        return {"address": self.address} if self.address else {"workers": self.workers}


def runner_of(workers: int | Runner) -> Runner:
    """``workers`` as a :class:`Runner` (a number: that many local processes)."""
    return workers if isinstance(workers, Runner) else Runner(workers=workers)


def run_jobs(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    workers: int | Runner = 1,
    progress: Callable[[int], None] | None = None,
    seed_of: Callable[[J], int] | None = None,
) -> list[R | None]:
    """``[fn(job) for job in jobs]``, run as ``workers`` says (a :class:`Runner`, or a number
    of local processes); ``None`` in the place of a job that failed on both tries (see the
    module docstring). ``fn`` and the jobs must pickle, and :func:`encode` with a log.
    ``progress(k)`` is called after each of the k jobs finished (or failed) by this call;
    ``seed_of(job)`` names a job's seed in reports and in the log.

    Raises :class:`Interrupted` on SIGTERM or Ctrl-C (after stopping the jobs in flight),
    and :class:`PolyslamError` when every job failed.
    """
    runner = runner_of(workers)
    seeds = [seed_of(job) if seed_of else None for job in jobs]
    results: list[Any] = [None] * len(jobs)
    log = None
    if runner.log is not None:
        log = ResultsLog(runner.log, study_hash(fn, jobs))
        if runner.resume:
            for index, result in _logged(log, len(jobs)).items():
                results[index] = result
        log.open(runner.resume)
    todo = [k for k in range(len(jobs)) if results[k] is None]
    kept = len(jobs) - len(todo)
    if kept:
        _say(f"--resume: {kept} of {len(jobs)} {runner.noun}s already in {runner.log}")
    study = _Study(runner, seeds, log, progress)
    sigterm = _SigTerm()
    with _bar(runner, len(jobs), kept) as bar:
        study.bar = bar
        try:
            backend = _backend(runner, fn, jobs)
            with sigterm, backend:  # after Ray is joined: it installs a SIGTERM handler too
                _drive(backend, todo, study, results)
        except KeyboardInterrupt:
            raise _interrupted(sigterm.seen, runner, len(jobs), kept + study.done) from None
    if log is not None:
        results = [None] * len(jobs)
        for index, result in _logged(log, len(jobs)).items():
            results[index] = result
    if runner.failed and all(r is None for r in results):
        first = runner.failed[0]
        raise PolyslamError(
            f"every {runner.noun} failed; the first, {runner.noun} {first['index']}"
            f" (seed {first['seed']}): {first['error']}"
        )
    return results


def succeeded(results: Sequence[R | None]) -> list[R]:
    """The results of the jobs that did not fail, in order."""
    return [r for r in results if r is not None]


def _logged(log: ResultsLog, count: int) -> dict[int, Any]:
    """The decoded result of each job in ``log`` that finished (the last line of a job
    wins: a job that failed and then finished on a resumed run has both)."""
    return {
        int(r["index"]): decode(r["result"])
        for r in log.read()
        if "result" in r and 0 <= int(r["index"]) < count
    }


@dataclass
class _Study:
    """One call's bookkeeping: reports, the log, the bar and the counts."""

    runner: Runner
    seeds: list[int | None]
    log: ResultsLog | None
    progress: Callable[[int], None] | None
    bar: Any = None
    done: int = 0
    tries: dict[int, int] = field(default_factory=dict)

    def finished(self, k: int, result: Any, results: list[Any]) -> None:
        if self.log is not None:
            self.log.append(k, self.seeds[k], result=encode(result))
        results[k] = result
        self.done += 1
        self._advance()

    def raised(self, k: int, error: BaseException) -> bool:
        """Report the failure of job ``k``; whether to try it again."""
        self.tries[k] = self.tries.get(k, 0) + 1
        what = f"{self.runner.noun} {k} (seed {self.seeds[k]})"
        text = _error_text(error)
        if self.tries[k] < TRIES:
            _say(f"{what} failed: {text}; trying it once more", self.bar)
            return True
        _say(f"{what} failed again: {text}; going on without it", self.bar)
        self.runner.failed.append({"index": k, "seed": self.seeds[k], "error": text})
        if self.log is not None:
            self.log.append(k, self.seeds[k], failed=text)
        self._advance()
        return False

    def _advance(self) -> None:
        self.bar.update(1)
        self.bar.set_postfix_str(f"failed {len(self.runner.failed)}", refresh=False)
        if self.progress is not None:
            self.progress(self.done + len(self.runner.failed))


def _drive(backend: _Backend, todo: list[int], study: _Study, results: list[Any]) -> None:
    """Run the jobs ``todo`` on ``backend`` until each finished or failed twice."""
    for k in todo:
        backend.submit(k)
    remaining = len(todo)
    while remaining:
        k, result, error = backend.next()
        if error is None:
            study.finished(k, result, results)
            remaining -= 1
        elif study.raised(k, error):
            backend.submit(k)
        else:
            remaining -= 1


def _error_text(error: BaseException) -> str:
    """``Type: first line`` of an error; a Ray task's error is its cause's (Ray wraps the
    exception a task raised, with the remote traceback, in ``RayTaskError``)."""
    error = getattr(error, "cause", None) or error
    lines = str(error).strip().splitlines()
    return f"{type(error).__name__}: {lines[0]}" if lines else type(error).__name__


def _say(text: str, bar: Any = None) -> None:
    """A line on stderr, above the progress bar if one is drawn."""
    if bar is not None and not bar.disable:
        bar.write(text, file=sys.stderr)
    else:
        print(text, file=sys.stderr, flush=True)


@contextmanager
def _bar(runner: Runner, total: int, kept: int) -> Iterator[Any]:
    from tqdm import tqdm

    with tqdm(
        total=total,
        initial=kept,
        desc=runner.desc,
        unit={"episode": "ep"}.get(runner.noun, runner.noun),
        disable=not runner.bar,
    ) as bar:
        bar.set_postfix_str("failed 0", refresh=False)
        yield bar


# -- stopping --------------------------------------------------------------------------------
class _SigTerm:
    """While inside (in the main thread), SIGTERM raises ``KeyboardInterrupt``, as Ctrl-C
    does, and sets ``seen``. (KeyboardInterrupt is what Ray's blocking calls pass on from a
    signal handler; another exception comes out of them as a SystemError.)"""

    def __init__(self) -> None:
        self.seen = self.installed = False
        self.previous: Any = None

    def _handler(self, signum: int, frame: Any) -> None:
        self.seen = True
        raise KeyboardInterrupt

    def __enter__(self) -> _SigTerm:
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGTERM, self._handler)
            self.installed = True
        return self

    def __exit__(self, kind: Any, value: Any, tb: Any) -> None:
        if self.installed:  # None: a handler set outside Python (Ray's), gone with Ray
            previous = signal.SIG_DFL if self.previous is None else self.previous
            signal.signal(signal.SIGTERM, previous)


def _interrupted(sigterm: bool, runner: Runner, total: int, done: int) -> Interrupted:
    name, code = ("SIGTERM", 143) if sigterm else ("Ctrl-C", 130)
    where = (
        f"in {runner.log}; the same command with --resume goes on from there"
        if runner.log is not None
        else "(no results log kept)"
    )
    return Interrupted(f"interrupted ({name}): {done} of {total} {runner.noun}s done {where}", code)


# -- backends --------------------------------------------------------------------------------
class _Backend(Protocol):
    """Runs jobs by index; ``next`` blocks until one has finished: ``(index, result, error)``
    with exactly one of result and error set (a job's result may itself be ``None``)."""

    def submit(self, k: int) -> None: ...
    def next(self) -> tuple[int, Any, BaseException | None]: ...
    def __enter__(self) -> _Backend: ...
    def __exit__(self, kind: Any, value: Any, tb: Any) -> None: ...


def _backend(runner: Runner, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> _Backend:
    if runner.address:
        return _RayTasks(fn, jobs, runner.address)
    if runner.workers > 1:
        return _Processes(fn, jobs, runner.workers)
    return _InProcess(fn, jobs)


class _InProcess:
    """One job after another in this process."""

    def __init__(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> None:
        self.fn, self.jobs, self.queue = fn, jobs, deque[int]()

    def submit(self, k: int) -> None:
        self.queue.append(k)

    def next(self) -> tuple[int, Any, BaseException | None]:
        k = self.queue.popleft()
        try:
            return k, self.fn(self.jobs[k]), None
        except Exception as error:
            return k, None, error

    def __enter__(self) -> _InProcess:
        return self

    def __exit__(self, kind: Any, value: Any, tb: Any) -> None:
        pass


def _ignore_sigint() -> None:
    """In a pool worker: Ctrl-C reaches the whole process group, but only the parent acts on
    it (it stops the workers); else each worker would print a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Processes:
    """A pool of ``workers`` local processes; stopped at once on an interrupt."""

    def __init__(self, fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int) -> None:
        self.fn, self.jobs, self.workers = fn, jobs, workers
        self.running: dict[Future[Any], int] = {}
        self.before = set(multiprocessing.active_children())
        self.pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, initializer=_ignore_sigint)

    def submit(self, k: int) -> None:
        try:
            future = self.pool.submit(self.fn, self.jobs[k])
        except BrokenProcessPool:  # a worker died (killed, out of memory): a new pool
            self.pool.shutdown(wait=False)
            self.pool = self._new_pool()
            future = self.pool.submit(self.fn, self.jobs[k])
        self.running[future] = k

    def next(self) -> tuple[int, Any, BaseException | None]:
        done, _ = wait(self.running, return_when=FIRST_COMPLETED)
        future = min(done, key=self.running.__getitem__)
        k = self.running.pop(future)
        error = future.exception()
        return k, None if error else future.result(), error

    def __enter__(self) -> _Processes:
        return self

    def __exit__(self, kind: Any, value: Any, tb: Any) -> None:
        if kind is None:
            self.pool.shutdown()
            return
        self.pool.shutdown(wait=False, cancel_futures=True)
        for child in set(multiprocessing.active_children()) - self.before:
            child.terminate()  # the jobs in flight: lost, as the log says
            child.join(timeout=10)


def _call(fn: Callable[[Any], Any], job: Any) -> Any:
    """A Ray task: one job."""
    return fn(job)


class _RayTasks:
    """One Ray task per job on the cluster at ``address``, one CPU each, at most twice the
    cluster's CPUs submitted at a time (the rest wait here, so a kill loses only those).
    Ray's own retries are off: a failure comes back here, to be reported and tried again."""

    def __init__(self, fn: Callable[[Any], Any], jobs: Sequence[Any], address: str) -> None:
        import ray

        from polyslam_env.apps.cluster import init_ray

        self.fn, self.jobs = fn, jobs
        self.started = not ray.is_initialized()
        if self.started:
            init_ray(address, 1)
        self.task = ray.remote(_call).options(num_cpus=1, max_retries=0)
        self.capacity = 2 * max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.queue = deque[int]()
        self.running: dict[Any, int] = {}

    def submit(self, k: int) -> None:
        self.queue.append(k)
        self._fill()

    def _fill(self) -> None:
        while self.queue and len(self.running) < self.capacity:
            k = self.queue.popleft()
            self.running[self.task.remote(self.fn, self.jobs[k])] = k

    def next(self) -> tuple[int, Any, BaseException | None]:
        import ray

        ready, _ = ray.wait(list(self.running), num_returns=1)
        k = self.running.pop(ready[0])
        try:
            result, error = ray.get(ready[0]), None
        except ray.exceptions.RayError as err:  # the task raised, or its worker or node died
            result, error = None, err
        self._fill()
        return k, result, error

    def __enter__(self) -> _RayTasks:
        return self

    def __exit__(self, kind: Any, value: Any, tb: Any) -> None:
        import ray

        if self.started:
            # the job ends with this driver's connection, and its tasks with it; cancelling
            # them first raced with a task's completion in Ray's core worker, which then
            # aborted this process (RAY_CHECK "it != submissible_tasks_.end()", seen with Ray
            # 2.60 on SIGTERM; ray-project/ray#54798) instead of the clean exit --resume needs
            ray.shutdown()
        elif kind is not None:  # a Ray the caller started stays up: stop what this study ran
            for ref in self.running:
                ray.cancel(ref, force=True)

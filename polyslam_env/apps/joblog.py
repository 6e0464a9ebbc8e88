"""A study's results log: one JSON line per finished job, appended as the jobs finish, so that
a study killed half-way can go on from what it had (:func:`polyslam_env.apps.jobs.run_jobs`).

A line is ``{"study": HASH, "index": K, "seed": S, "result": ...}`` for a job that finished
and ``{"study": HASH, "index": K, "seed": S, "failed": "Error: text"}`` for one that raised
on both tries. ``HASH`` is :func:`study_hash` of the job function and every job, so a log is
never resumed under another configuration. Each line goes to the file in one ``write`` of
the whole line, then flush and fsync; a kill during that write can only leave a torn last
line, which :meth:`ResultsLog.read` ignores and :meth:`ResultsLog.open` cuts off.

Results (and jobs, for the hash) go to JSON through :func:`encode`: JSON's own types as
they are; tuples, dicts with keys other than strings, numpy arrays and scalars, dataclasses
and floats JSON cannot write (NaN, ±inf) as tagged objects, so that :func:`decode` gives back
an equal object of the same types, floats bit for bit (Python writes the shortest repr that
reads back to the same double).
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import importlib
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from polyslam_env.core.errors import OutputError, PolyslamError

__all__ = ["ResultsLog", "decode", "encode", "study_hash"]

TAG = "__type__"
#: Modules whose dataclasses :func:`decode` may rebuild (a log is data, never code to run).
TRUSTED_MODULES = ("polyslam_env.", "policies.")


def encode(value: Any) -> Any:
    """``value`` as JSON-ready data that :func:`decode` turns back into an equal value."""
    if value is None or isinstance(value, bool | str):
        return value
    if type(value) is int:
        return value
    if type(value) is float:
        return value if math.isfinite(value) else {TAG: "float", "value": repr(value)}
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise TypeError(f"cannot log a numpy array of dtype {value.dtype}")
        data = [encode(v) for v in value.ravel().tolist()]
        return {TAG: "ndarray", "dtype": value.dtype.str, "shape": list(value.shape), "data": data}
    if isinstance(value, np.generic):
        return {TAG: "numpy", "dtype": value.dtype.str, "value": encode(value.item())}
    if isinstance(value, list):
        return [encode(v) for v in value]
    if isinstance(value, tuple):
        return {TAG: "tuple", "items": [encode(v) for v in value]}
    if isinstance(value, dict):
        if all(type(k) is str for k in value) and TAG not in value:
            return {k: encode(v) for k, v in value.items()}
        return {TAG: "dict", "items": [[encode(k), encode(v)] for k, v in value.items()]}
    if isinstance(value, enum.Enum):
        return {TAG: "enum", "class": _class_name(type(value)), "value": encode(value.value)}
    if isinstance(value, PurePath):
        return {TAG: "path", "value": str(value)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {
            f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init
        }
        return {TAG: "dataclass", "class": _class_name(type(value)), "fields": fields}
    raise TypeError(f"cannot log a {type(value).__name__} (results and jobs must be plain data)")


def decode(data: Any) -> Any:
    """The value :func:`encode` turned into ``data``."""
    if isinstance(data, list):
        return [decode(v) for v in data]
    if not isinstance(data, dict):
        return data
    kind = data.get(TAG)
    if kind is None:
        return {k: decode(v) for k, v in data.items()}
    if kind == "float":
        return float(data["value"])
    if kind == "ndarray":
        flat = np.array([decode(v) for v in data["data"]], dtype=np.dtype(data["dtype"]))
        return flat.reshape(data["shape"])
    if kind == "numpy":
        return np.dtype(data["dtype"]).type(decode(data["value"]))
    if kind == "tuple":
        return tuple(decode(v) for v in data["items"])
    if kind == "dict":
        return {decode(k): decode(v) for k, v in data["items"]}
    if kind == "path":
        return Path(data["value"])
    if kind == "enum":
        return _trusted_class(data["class"])(decode(data["value"]))
    if kind == "dataclass":
        cls = _trusted_class(data["class"])
        return cls(**{k: decode(v) for k, v in data["fields"].items()})
    raise ValueError(f"unknown tagged value {kind!r}")


def _class_name(obj: Any) -> str:
    """``module:qualname`` of a class or function."""
    return f"{obj.__module__}:{obj.__qualname__}"


def _trusted_class(name: str) -> Any:
    module, _, qualname = name.partition(":")
    if not module.startswith(TRUSTED_MODULES):
        raise ValueError(f"{name}: not a class of this package")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def study_hash(fn: Callable[..., Any], jobs: Sequence[Any]) -> str:
    """A short hash of the job function and every job (configs, seeds, options): two studies
    with the same hash run the same jobs, so one's log can be resumed by the other."""
    from polyslam_env import __version__

    text = json.dumps(
        [__version__, _class_name(fn), [encode(job) for job in jobs]],
        sort_keys=True,
        allow_nan=False,
        separators=(",", ":"),
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class ResultsLog:
    """The results log at ``path`` of the study whose hash is ``study``."""

    def __init__(self, path: str | Path, study: str) -> None:
        self.path = Path(path)
        self.study = study

    def read(self) -> list[dict[str, Any]]:
        """Every whole line of the log (none if there is no log); a torn last line (no
        newline after it: a kill mid-write) is left out. A line of another study raises
        :class:`PolyslamError` naming the log."""
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return []
        lines = raw.split(b"\n")[:-1]  # what follows the last newline is torn (or empty)
        records = []
        for number, line in enumerate(lines, 1):
            try:
                record = json.loads(line)
            except ValueError:
                raise PolyslamError(f"{self.path}:{number}: not a results-log line") from None
            if not isinstance(record, dict) or record.get("study") != self.study:
                other = record.get("study") if isinstance(record, dict) else None
                raise PolyslamError(
                    f"--resume: {self.path} holds the results of another study configuration"
                    f" (study {other}, this one is {self.study}): use the same options, or"
                    " another --out"
                )
            records.append(record)
        return records

    def open(self, resume: bool) -> None:
        """Get the log ready for appending: a new, empty log unless ``resume``; when resuming,
        a torn last line is cut off, so that the next line starts on a line of its own."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if not resume or not self.path.exists():
                with open(self.path, "wb") as f:
                    os.fsync(f.fileno())
                return
            raw = self.path.read_bytes()
            whole = raw.rfind(b"\n") + 1
            if whole < len(raw):
                with open(self.path, "r+b") as f:
                    f.truncate(whole)
                    os.fsync(f.fileno())
        except OSError as err:
            raise OutputError(f"{self.path}: cannot write ({err.strerror or err})") from None

    def append(self, index: int, seed: int | None, **fields: Any) -> None:
        """Add the line of job ``index``: ``result=encode(...)`` or ``failed="text"``."""
        record = {"study": self.study, "index": index, "seed": seed, **fields}
        line = json.dumps(record, allow_nan=False, separators=(",", ":")) + "\n"
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
            try:
                data = line.encode()
                while data:  # one write of the whole line, unless the system cuts it short
                    data = data[os.write(fd, data) :]
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as err:
            raise OutputError(f"{self.path}: cannot write ({err.strerror or err})") from None

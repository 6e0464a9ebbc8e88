"""Atomic result files."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from polyslam_env.core.io import write_atomic, write_json


def test_write_json__nan_becomes_null_and_file_is_readable_by_others(tmp_path: Path) -> None:
    path = write_json(tmp_path / "sub" / "m.json", {"a": float("nan"), "b": [1.0, float("inf")]})
    assert json.loads(path.read_text()) == {"a": None, "b": [1.0, None]}
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


def test_write_atomic__interrupt_leaves_old_file_and_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C between writing and renaming: the old result survives, no temp file remains."""
    path = tmp_path / "r.json"
    path.write_text("old")

    def interrupted(*_args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_atomic(path, "new")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]

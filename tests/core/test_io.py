"""Atomic result files; YAML read with libyaml."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from polyslam_env.core.errors import OutputError
from polyslam_env.core.io import parse_yaml, write_atomic, write_json
from polyslam_env.core.resources import configs_dir


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


def test_write_atomic__full_disk_is_an_output_error_naming_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno

    def full(*_args: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match=r"r\.json.*No space left"):
        write_atomic(tmp_path / "r.json", "data")
    assert list(tmp_path.iterdir()) == []


def test_write_atomic__folder_or_path_under_a_file_is_an_output_error(tmp_path: Path) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="is a folder"):
        write_atomic(tmp_path / "folder", "data")
    with pytest.raises(OutputError, match="cannot write"):
        write_atomic(tmp_path / "file" / "r.json", "data")


def test_parse_yaml__same_data_as_safe_load_on_every_shipped_file() -> None:
    files = sorted(configs_dir().rglob("*.yaml"))
    assert len(files) > 10  # configs, maps and paths
    for path in files:
        text = path.read_text(encoding="utf-8")
        assert parse_yaml(text) == yaml.safe_load(text), path


def test_parse_yaml__bad_yaml_raises_yaml_error() -> None:
    with pytest.raises(yaml.YAMLError):
        parse_yaml("a: [1, 2")

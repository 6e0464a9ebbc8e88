"""Exceptions raised on bad input. Each names the file, field and value at fault."""

from __future__ import annotations


class PolyslamError(Exception):
    """Base class of every error this package raises on bad input."""


class ConfigError(PolyslamError, ValueError):
    """A configuration key is unknown or its value is invalid."""


class MapFileError(PolyslamError, ValueError):
    """A map file (or map data) does not follow the documented schema."""


class OutputError(PolyslamError, ValueError):
    """An output cannot be written where asked: a folder where a file is needed, a path under
    a regular file, an unknown video extension, or the system refusing the write (full disk,
    permissions)."""


class DisplayError(PolyslamError, RuntimeError):
    """No window can be opened for ``render_mode="human"`` (e.g. a headless machine)."""


class Interrupted(Exception):
    """A long run stopped by SIGTERM or Ctrl-C after keeping what it had; the message says
    what was kept and how to go on, ``code`` is the exit status (143 for SIGTERM, 130 for
    Ctrl-C, as a shell reports a process those signals ended)."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code

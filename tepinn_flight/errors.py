"""Errors that reach the user as one line (``tepinn-flight: error: ...``) and exit code 2."""

from __future__ import annotations

import os


class TepinnError(Exception):
    """A problem with the user's input or configuration: reported in one line, exit code 2."""

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class UnknownLogFormat(TepinnError):
    """The file is none of the formats we read (sniffed from its content)."""


class CorruptLog(TepinnError):
    """The file has the right format but cannot be parsed (truncated, garbled, missing fields)."""


class NoImuData(TepinnError):
    """The log holds no usable IMU samples."""


class RecordFormatError(TepinnError):
    """A flight record that is not one we can read (unknown format_version, missing columns)."""


class ConfigError(TepinnError):
    """A TOML configuration with unknown keys, wrong types or bad values."""


class OutputError(TepinnError, OSError):
    """An output path that cannot be written (read-only place, a file where a folder is needed).
    Also an ``OSError``, as the failure it replaces, for callers that catch those."""

"""The bridge's session log: every frame it routes or sends, as a tlog.

``[uint64 BE UNIX µs][frame]`` records (the autopilot's frames, the ground stations' and the
bridge's own) into ``FILE.part``, renamed to FILE when the session ends.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from ..errors import ConfigError


class SessionTlog:
    """``[uint64 BE UNIX µs][frame]`` records into ``FILE.part``, renamed to FILE on close."""

    def __init__(self, path: str):
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".part")
        if not self.path.parent.exists():
            raise ConfigError(f"--tlog {path}: folder {self.path.parent} does not exist")
        if self.path.is_dir():  # (review60: recorded beside it, then not put in place, unsaid)
            raise ConfigError(f"--tlog {path}: a folder; name the session's tlog file")
        try:
            self.f = open(self.tmp, "wb", buffering=1 << 16)
        except OSError as exc:
            raise ConfigError(f"--tlog {path}: cannot write ({exc.strerror or exc})") from None
        self.records = 0
        self.bytes = 0

    def write(self, frames, t_unix_s: float) -> None:
        ts = struct.pack(">Q", int(t_unix_s * 1e6))
        for fr in frames:
            self.f.write(ts)
            self.f.write(fr)
            self.records += 1
            self.bytes += 8 + len(fr)

    def flush(self) -> None:
        self.f.flush()

    def close(self) -> None:
        self.f.close()
        os.replace(self.tmp, self.path)

"""Tell a log's format from its content, never from its file name."""

from __future__ import annotations

import os
import stat

from ..conventions import UNIX_TIME_THRESHOLD_US
from ..errors import UnknownLogFormat

FORMATS = ("ulog", "dataflash-bin", "dataflash-text", "hdf5", "parquet", "tlog")

_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_MAVLINK_STX = (0xFE, 0xFD)


def _plausible_tlog(head: bytes) -> bool:
    """Timestamp records: 8-byte big-endian µs, then a MAVLink frame (possibly after junk).

    We accept UNIX time between 2000 and 2100, or a boot-time-like value, as long as a MAVLink
    start byte shows up within the first records.
    """
    if len(head) < 10:
        return False
    us = int.from_bytes(head[:8], "big")
    unix_ok = 946_684_800e6 <= us <= 4_102_444_800e6
    boot_ok = 0 < us < UNIX_TIME_THRESHOLD_US
    if not (unix_ok or boot_ok):
        return False
    if any(b in _MAVLINK_STX for b in head[8:64]):
        return True
    # junk after the first timestamps (seen in a real SITL tlog): the timestamp's high bytes recur
    return unix_ok and head[8:].count(head[:4]) >= 3


def sniff_bytes(head: bytes) -> str:
    """Format name from the first KB of a file (see :data:`FORMATS`)."""
    if head.startswith(b"ULog"):
        return "ulog"
    if head[:2] == b"\xa3\x95":
        return "dataflash-bin"
    if head.startswith(_HDF5_MAGIC):
        return "hdf5"
    if head.startswith(b"PAR1"):
        return "parquet"
    if b"FMT," in head[:1024]:
        return "dataflash-text"
    if _plausible_tlog(head):
        return "tlog"
    raise UnknownLogFormat("not a ULog, DataFlash, HDF5 (BROAD), MAVLink tlog or flight record")


def sniff(path: str | os.PathLike) -> str:
    """Format of the file at ``path``; one-line errors for missing, empty or unknown files, and for a pipe or a
    device (a log is read more than once, from its start: ``info <(cat f.tlog)`` had been "not a … tlog", and a FIFO
    with no writer had hung the command)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        mode = None  # (said by open below)
    if mode is not None and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise UnknownLogFormat("a pipe or a device, not a file: logs are read from their start more than once; "
                               "save it to a file first", path)  # fmt: skip
    try:
        with open(path, "rb") as f:
            head = f.read(1024)
    except FileNotFoundError:
        raise UnknownLogFormat("no such file", path) from None
    except IsADirectoryError:
        raise UnknownLogFormat("is a directory, not a log file", path) from None
    except OSError as exc:
        raise UnknownLogFormat(f"cannot read ({exc.strerror})", path) from None
    if not head:
        raise UnknownLogFormat("empty file", path)
    try:
        return sniff_bytes(head)
    except UnknownLogFormat as exc:
        raise UnknownLogFormat(exc.reason, path) from None

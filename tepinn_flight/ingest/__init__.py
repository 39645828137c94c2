"""Real logs → flight records: format sniffing and dispatch to one reader per format.

Each reader module (``tlog``, ``dataflash``, ``ulog``, ``broad``) exposes
``read(path, imu=None, reference=None) -> RawLog``; :func:`ingest_log` sniffs the content,
calls the reader and assembles the record. :func:`load_record` is the one way to get a record from
any file: a flight record (Parquet) is read, any log is sniffed and ingested. No torch here.
"""

from __future__ import annotations

import importlib
import os

from ..errors import TepinnError, UnknownLogFormat
from ..record import FlightRecord, read_record
from .assemble import build_record
from .sniff import sniff

_READERS = {
    "tlog": "tlog",
    "dataflash-bin": "dataflash",
    "dataflash-text": "dataflash",
    "ulog": "ulog",
    "hdf5": "broad",
}


def read_raw(path: str | os.PathLike, imu: int | None = None, reference: str | None = None):
    """Sniff and parse ``path`` into a :class:`~tepinn_flight.ingest.streams.RawLog`."""
    fmt = sniff(path)
    if fmt == "parquet":
        raise UnknownLogFormat("already a flight record (Parquet), not a log to ingest", path)
    module = importlib.import_module(f".{_READERS[fmt]}", __name__)
    try:
        raw = module.read(path, imu=imu, reference=reference)
    except TepinnError as exc:
        if exc.path is None:
            raise type(exc)(exc.reason, path) from None
        raise
    raw.meta.setdefault("format", fmt)
    return raw


def ingest_log(path: str | os.PathLike, imu: int | None = None, reference: str | None = None) -> FlightRecord:
    """Parse any supported log into a validated flight record (not yet written)."""
    raw = read_raw(path, imu=imu, reference=reference)
    return build_record(raw, path)


def load_record(path: str | os.PathLike, imu: int | None = None, reference: str | None = None) -> FlightRecord:
    """The flight record in ``path``: a record (Parquet) is read as it is, any other file is sniffed
    and ingested (``imu`` and ``reference`` as for :func:`ingest_log`; ignored for a record)."""
    if sniff(path) == "parquet":
        return read_record(path)
    return ingest_log(path, imu=imu, reference=reference)

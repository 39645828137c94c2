"""What a folder given to a verb stands for: the flight records and the logs ``ingest`` reads in it,
told by their content (:func:`~tepinn_flight.ingest.sniff.sniff`), not by their names — an ArduPilot
``LOGS`` folder, a ground station's tlogs, a PX4 SD card's ``log/`` or a folder of records alike.

Files named on the command line are taken as given (the verb reports what it cannot read); only
the files a folder holds are chosen here. Hidden files and files none of our readers know are left
out silently: a log folder also holds ``LASTLOG.TXT``, parameter files and the ground station's
notes — and Parquet files that are not flight records, such as the estimates ``estimate`` wrote there.
A file named as a log is (:data:`LOG_SUFFIXES`) but not one — an empty ``00000042.BIN``, the commonest broken log on
an ArduPilot SD card — is left out with a note, where the caller asks for them (session 58: it had gone unsaid). One
that cannot be read (its permissions), or that holds no log under a name only logs go by (:data:`LOG_ONLY_SUFFIXES`:
a damaged ``.BIN``), is a log that cannot be read: it is handed to the verb, which says its error and exits 2 as for a
file named on the command line (session 60: a folder run had exited 0 with such logs in it). A ``.log`` holding no
DataFlash text is left out with a note: the name is every program's (``estimate LOGS/ > LOGS/run.log``).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import TepinnError
from ..record import file_key, is_flight_record
from .sniff import FORMATS, sniff

#: formats of the logs ``ingest`` reads (a flight record, Parquet, is already ingested)
LOG_FORMATS = frozenset(FORMATS) - {"parquet"}
#: what ``estimate``, ``evaluate`` and ``info`` take: records and logs (ingested on the fly)
RECORD_OR_LOG_FORMATS = frozenset(FORMATS)


#: the file names a log or record goes by: one of them that holds none is said to be left out
LOG_SUFFIXES = frozenset({".bin", ".log", ".tlog", ".ulg", ".hdf5", ".h5", ".parquet"})
#: the names only our formats go by, each with the formats it is: a non-empty file under one that holds none of them
#: is a damaged log or record, not some other program's file
LOG_ONLY_SUFFIXES = {".bin": ("dataflash-bin", "dataflash-text"), ".tlog": ("tlog",), ".ulg": ("ulog",),
                     ".hdf5": ("hdf5",), ".h5": ("hdf5",), ".parquet": ("parquet",)}


def _unreadable_log(f: Path, reason: str, formats: frozenset[str]) -> bool:
    """Whether ``f``, which :func:`~.sniff.sniff` refused for ``reason``, is a log of ``formats`` that cannot be read
    (handed to the verb, an error) rather than a file that is no log (left out with a note)."""
    suffix = f.suffix.lower()
    if suffix not in LOG_SUFFIXES or reason == "empty file":
        return False
    if reason.startswith("cannot read"):
        return True
    return any(fmt in formats for fmt in LOG_ONLY_SUFFIXES.get(suffix, ()))


def files_in(folder: str | os.PathLike, formats: frozenset[str], recursive: bool = False,
             notes: list[str] | None = None) -> list[Path]:
    """The files in ``folder`` (and its subfolders where ``recursive``) whose content is one of
    ``formats``, and those named as such a log that cannot be read (:func:`_unreadable_log`: the verb says its
    error), sorted by path; ``notes`` gets a line, in path order, for each other file named as a log that is none
    (empty, unknown)."""
    root = Path(folder)
    candidates = root.rglob("*") if recursive else root.iterdir()
    out, left = [], []
    for f in candidates:
        if f.name.startswith(".") or any(part.startswith(".") for part in f.relative_to(root).parts[:-1]):
            continue
        if not f.is_file():
            continue
        try:
            fmt = sniff(f)
        except TepinnError as exc:
            if _unreadable_log(f, exc.reason, formats):
                out.append(f)
            elif f.suffix.lower() in LOG_SUFFIXES:
                left.append(f"{f}: left out ({exc.reason})")
            continue
        if fmt == "parquet" and not is_flight_record(f):  # an estimate written beside the records, another table
            continue
        if fmt in formats:
            out.append(f)
    if notes is not None:
        notes += sorted(left)
    return sorted(out)


def expand(items: list[str], formats: frozenset[str] = RECORD_OR_LOG_FORMATS, recursive: bool = False,
           notes: list[str] | None = None) -> list[Path]:
    """Paths from the command line: a file as given, a folder for the files in it of ``formats`` (``notes``: as
    :func:`files_in` gives them).

    One-line errors: an item that does not exist, a folder holding none of them."""
    what = "logs" if "parquet" not in formats else "flight records or logs"
    out: list[Path] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            found = files_in(p, formats, recursive, notes)
            if not found:
                below = " or its subfolders" if recursive else ""
                raise TepinnError(f"folder{below} holds no {what} (told by content: ULog, DataFlash, tlog, BROAD HDF5"
                                  + (", Parquet record)" if "parquet" in formats else ")"), p)
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise TepinnError("no such file or folder", p)
    return _once_each(out)


def _once_each(paths: list[Path]) -> list[Path]:
    """``paths`` with a file named twice (``a.BIN ./a.BIN``, a file and its folder, a link and its target) kept once,
    at its first place: it would be read twice and give two outputs."""
    seen, out = set(), []
    for p in paths:
        key = file_key(p) or p
        if key not in seen:
            seen.add(key)
            out.append(p)
    return out

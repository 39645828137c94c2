"""A record's samples on the log's own clock: what the autopilot stamped them with.

A record's ``t_s`` starts at 0 and runs on across reboots (:mod:`tepinn_flight.ingest.assemble`), so an estimate
cannot be laid beside the log in the analyst's own viewer (Mission Planner, MAVExplorer, PlotJuggler, FlightPlot)
by ``t_s`` alone. Ingest records each boot epoch's offset (``epoch_time_offsets_s``: record time = log time +
offset) and, since session 45, where each epoch starts in record time (``epoch_start_t_s``); this turns ``t_s``
back into the log's clock: DataFlash ``TimeUS`` / ``TimeMS``, MAVLink ``time_usec`` / ``time_boot_ms``, ULog
``timestamp`` (seconds since boot; UNIX time where the autopilot stamped its IMU with it), BROAD's own time. A
reboot makes it start again, as the log's clock does. Simulations have no log clock.
"""

from __future__ import annotations

import numpy as np

from .record import SIMULATED_KINDS


def log_clock_s(t_s: np.ndarray, meta: dict) -> np.ndarray | None:
    """Each sample's time on the log's clock (s), or None where the record cannot tell it (a simulation; a
    record of several boots ingested before ``epoch_start_t_s`` was kept)."""
    offsets = meta.get("epoch_time_offsets_s")
    if not offsets or meta.get("source_kind") in SIMULATED_KINDS:
        return None
    t = np.asarray(t_s, np.float64)
    # (a ULog stamped in UNIX µs is read from its first whole second, to keep µs in float64: added back here)
    origin = float(meta.get("time_origin_unix_s") or 0.0)
    off = {int(k): float(v) for k, v in offsets.items()}
    if len(off) == 1:
        return t - next(iter(off.values())) + origin
    starts = {int(k): float(v) for k, v in (meta.get("epoch_start_t_s") or {}).items()}
    if set(starts) != set(off):
        return None
    epochs = sorted(off, key=lambda e: starts[e])
    first = np.array([starts[e] for e in epochs])
    shift = np.array([off[e] for e in epochs])
    k = np.clip(np.searchsorted(first, t, side="right") - 1, 0, len(epochs) - 1)
    return t - shift[k] + origin


#: the logs whose own clock a tlog written from their record, and a replay of it, run on
LOG_CLOCK_KINDS = ("dataflash", "ulog", "tlog", "broad")


def boot_time_at_start_s(t_s: np.ndarray, meta: dict) -> float | None:
    """The autopilot's time since boot at the record's first sample, where the record is of a DataFlash, ULog or
    MAVLink log (or a BROAD trial, its own time) on a boot clock that a MAVLink ``time_boot_ms`` (uint32) can carry;
    else None. What a tlog written from the record (``estimate --tlog``) and a replay of it (``replay``) stamp their
    messages from, so that they line up with the log's own clock — ``estimate``'s ``t_log_s`` (review61: a tlog's
    record without its source tlog beside it and a BROAD trial had run 10 s after it). A record of several boots runs
    on from its first boot's clock across the reboots, where ``t_log_s`` starts again."""
    if meta.get("source_kind") not in LOG_CLOCK_KINDS or not meta.get("epoch_time_offsets_s"):
        return None
    if meta.get("time_base") == "unix" or not len(t_s):
        return None
    t = np.asarray(t_s, np.float64)
    start = log_clock_s(t[:1], meta)
    if start is None:
        return None
    boot0 = float(start[0])  # (one boot: the log's clock throughout; several: the first's, run on across them)
    return boot0 if boot0 >= 0.0 and (boot0 + t[-1] - t[0]) * 1e3 < 2**32 else None


def unix_time_at_start_s(t_s: np.ndarray, meta: dict) -> float | None:
    """The UNIX time of the record's first sample, where the log stamped its IMU with it (PX4 SITL ULogs); else None."""
    if meta.get("time_base") != "unix" or not len(t_s):
        return None
    t_log = log_clock_s(np.asarray(t_s[:1]), meta)
    return None if t_log is None else float(t_log[0])

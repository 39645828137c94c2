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
    # (a ULog stamped in UNIX µs is read from its first whole second, to keep µs in float64: added back here)
    t = np.asarray(t_s, np.float64) + float(meta.get("time_origin_unix_s") or 0.0)
    off = {int(k): float(v) for k, v in offsets.items()}
    if len(off) == 1:
        return t - next(iter(off.values()))
    starts = {int(k): float(v) for k, v in (meta.get("epoch_start_t_s") or {}).items()}
    if set(starts) != set(off):
        return None
    epochs = sorted(off, key=lambda e: starts[e])
    first = np.array([starts[e] for e in epochs])
    shift = np.array([off[e] for e in epochs])
    k = np.clip(np.searchsorted(first, t, side="right") - 1, 0, len(epochs) - 1)
    return t - shift[k]

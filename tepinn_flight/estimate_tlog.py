"""The estimate as a tlog beside the autopilot's own messages (``tepinn-flight estimate --tlog``).

What the file holds
    * the **source tlog's records, byte for byte** (every message, junk and all, with its receive
      timestamp) when the record was ingested from a ``.tlog``; for other sources (DataFlash, ULog,
      BROAD, simulations) the record's IMU and reference attitude written by :mod:`.tlog_writer` as an
      ArduPilot-like system 1 / component 1 (HEARTBEAT, HIGHRES_IMU, RAW_IMU, ATTITUDE,
      ATTITUDE_QUATERNION);
    * the estimate, from the autopilot's system id and component **191**
      (``MAV_COMP_ID_ONBOARD_COMPUTER``, like the live bridge): a 1 Hz HEARTBEAT
      (``MAV_TYPE_ONBOARD_CONTROLLER``) and, at ``rate_hz`` of log time, the messages chosen by
      ``messages`` (:data:`TLOG_MESSAGES`).

Time
    Each estimate is inserted right after the IMU message it was computed from, with that message's
    tlog receive timestamp, and stamped with that message's own clock (``time_boot_ms`` /
    ``time_usec`` since the autopilot's boot): the estimate and the autopilot's ATTITUDE interleave
    in file order and line up on either clock. Reboots are followed through the record's
    ``epoch_time_offsets_s``. (An IMU stamped with UNIX time gives a ``time_boot_ms`` modulo 2³².)
    Written from a record of one boot of a DataFlash, ULog or MAVLink log, or a BROAD trial, the autopilot's
    messages keep the log's own clock (the estimate's ``time_boot_ms`` is the log's ``TimeUS`` / ``timestamp`` /
    ``time_boot_ms``, BROAD's time: ``estimate``'s ``t_log_s``); a ULog stamped in UNIX time gives the receive times
    that UNIX time. A record of several boots runs on from its first boot's clock across the reboots (``t_log_s``
    starts again at each); simulations and records without a log clock start 10 s after boot on 2023-11-14
    (``tlog_writer``'s defaults). The "autopilot's" ATTITUDE written then is the
    record's reference (the log's ATT turned into the IMU board's frame by the level trim, or XKQ, or the
    truth), not the log's own ATT rows.
    ``rate_hz``: every sample of a log at that rate, through its stamps' jitter; a faster log thinned
    to about it (:func:`~tepinn_flight.rate_thinning.due_at_rate`).

Why not ATTITUDE by default
    Log tools that key messages by type only (pymavlink's ``messages``, MAVExplorer graphs) would mix
    a second ATTITUDE stream into the autopilot's. ``DEBUG_VECT TP_RPY`` (degrees) is unambiguous in
    every tool; ATTITUDE_QUATERNION is not sent by ArduPilot by default. ``attitude`` can be added.
"""

from __future__ import annotations

import math
import os
import struct
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import TepinnError
from .record import EST_BIAS_COLS, EST_Q_COLS, FlightRecord, atomic_write

#: Estimate messages a tlog can carry: ATTITUDE (rad), ATTITUDE_QUATERNION (w, x, y, z),
#: NAMED_VALUE_FLOAT tp_roll/tp_pitch/tp_yaw (deg), DEBUG_VECT TP_RPY (deg).
TLOG_MESSAGES = ("attitude_quaternion", "attitude", "debug_vect", "named_value")
DEFAULT_TLOG_MESSAGES = ("attitude_quaternion", "debug_vect")
DEFAULT_TLOG_RATE_HZ = 50.0


def parse_messages(spec: str) -> tuple[str, ...]:
    """``"attitude_quaternion,debug_vect"`` → a tuple of :data:`TLOG_MESSAGES` (ValueError otherwise)."""
    kinds = tuple(k.strip().lower() for k in spec.split(",") if k.strip())
    bad = [k for k in kinds if k not in TLOG_MESSAGES]
    if bad or not kinds:
        raise ValueError(f"choose from {', '.join(TLOG_MESSAGES)} (comma-separated), not {spec!r}")
    return tuple(dict.fromkeys(kinds))


def _record_length(data: bytes, off: int) -> int:
    """Bytes of the tlog record at ``off``: timestamp + frame (v1 or v2, signature included)."""
    stx, ln = data[off + 8], data[off + 9]
    if stx == 0xFD:
        return 8 + 10 + ln + 2 + (13 if data[off + 10] & 0x01 else 0)
    return 8 + 6 + ln + 2


def _imu_frames(base: Path, imu_name: str, instance: int, sysid: int):
    """(file offsets, sample times in s, clock, boot epoch, gyro rad/s as the reader converts it) of the autopilot's
    chosen IMU stream."""
    from .ingest.mavlink_scan import scan_tlog
    from .ingest.tlog import IMU_MESSAGES, MAV_COMP_ID_AUTOPILOT1, _imu_si, _time_s, boot_epochs

    if imu_name not in IMU_MESSAGES:
        raise TepinnError(f"the record's IMU message {imu_name!r} is not a MAVLink IMU message")
    tfield, fixed = IMU_MESSAGES[imu_name]
    fr = scan_tlog(base, [imu_name]).frames[imu_name]
    inst = np.full(len(fr.offset), fixed) if fixed is not None else fr.fields["id"].astype(np.int64)
    m = (fr.sysid == sysid) & (fr.compid == MAV_COMP_ID_AUTOPILOT1) & (inst == instance)
    t_src, clock = _time_s(fr.fields[tfield][m], tfield)
    epoch = boot_epochs(t_src) if clock == "boot" else np.zeros(len(t_src), np.int64)
    return fr.offset[m], t_src, clock, epoch, _imu_si(imu_name, fr.fields[m])[0]


#: a source tlog's gyro sample and the record's at the same time agree to this (rad/s): the record holds the reader's
#: conversion of that very sample (float32 fields, stored as float64), so they are equal but for rounding
SAME_SAMPLE_RAD_S = 1e-5


def _same_samples(gyr_rec: np.ndarray, gyr_src: np.ndarray) -> bool:
    """Whether the matched samples are the record's own: at least half of those with finite values on both sides
    equal (another flight of the same autopilot matches in boot time, not in its gyro's noise)."""
    ok = np.all(np.isfinite(gyr_rec), axis=1) & np.all(np.isfinite(gyr_src), axis=1)
    if not ok.any():
        return True  # nothing to compare (the times matched)
    same = np.all(np.abs(gyr_rec[ok] - gyr_src[ok]) <= SAME_SAMPLE_RAD_S, axis=1)
    return bool(np.mean(same) >= 0.5)


def _tlog_clock(rec: FlightRecord) -> tuple[float, float]:
    """(the boot time of the record's first sample, the UNIX receive time of it) for a tlog written from a record:
    the log's own clock where :func:`~tepinn_flight.log_clock.boot_time_at_start_s` gives it (one boot: the
    estimate then lines up with the log's TimeUS / timestamp), the UNIX time for a ULog stamped in it; else the
    writer's defaults."""
    from .log_clock import boot_time_at_start_s, unix_time_at_start_s
    from .tlog_writer import DEFAULT_BOOT_OFFSET_S, DEFAULT_START_UNIX_S

    boot = boot_time_at_start_s(rec.t_s, rec.meta)
    unix = unix_time_at_start_s(rec.t_s, rec.meta)
    return (DEFAULT_BOOT_OFFSET_S if boot is None else boot), (DEFAULT_START_UNIX_S if unix is None else unix)


def write_estimate_tlog(
    path: str | os.PathLike,
    rec: FlightRecord,
    est: pd.DataFrame,
    *,
    source: str | os.PathLike | None = None,
    messages: tuple[str, ...] = DEFAULT_TLOG_MESSAGES,
    rate_hz: float = DEFAULT_TLOG_RATE_HZ,
    compid: int = 191,
) -> dict[str, int]:
    """Write the tlog (see the module doc) atomically; returns the counts of the added messages.

    ``est`` has one row per record row (``estimate_record``'s output). ``source`` is the ``.tlog``
    the record was ingested from, or None to write the record itself as the autopilot's messages.
    """
    from .live.messages import Encoder, attitude_msg, attitude_quaternion_msg, estimate_msgs, heartbeat_onboard_msg
    from .rate_thinning import due_at_rate
    from .tlog_writer import write_tlog

    messages = tuple(messages)
    if not messages or any(k not in TLOG_MESSAGES for k in messages):
        raise ValueError(f"messages must be taken from {TLOG_MESSAGES}")
    if len(est) != len(rec):
        raise ValueError("the estimate must have one row per record row")
    t = rec.t_s
    q = est[EST_Q_COLS].to_numpy(np.float64)
    bias = est[EST_BIAS_COLS].to_numpy(np.float64) if all(c in est for c in EST_BIAS_COLS) else np.zeros((len(t), 3))
    from .model.estimate import bridge_holes

    # the rates the estimator used: a non-finite sample bridged with the last finite one, as the estimate was made
    # (review61: NaN rollspeed in the estimate's ATTITUDE where the record's gyro had a hole)
    rates = bridge_holes(rec)[0].gyr_rad_s - np.nan_to_num(bias)
    counts: dict[str, int] = {}
    if len(t) == 0:
        raise TepinnError("the record has no samples")

    with tempfile.TemporaryDirectory(prefix="tepinn-tlog-") as td:
        if source is None:
            base = Path(td) / "record.tlog"
            boot0_s, start_unix_s = _tlog_clock(rec)
            write_tlog(base, rec, boot_offset_s=boot0_s, start_unix_s=start_unix_s)  # t_s → t - t0 + boot0 (on across reboots)
            imu_name, instance, sysid = "HIGHRES_IMU", 0, 1
            offsets = {0: float(t[0]) - boot0_s}
        else:
            base = Path(source)
            meta = rec.meta
            if meta.get("source_kind") != "tlog":
                raise TepinnError(f"the record was not ingested from a tlog (source_kind {meta.get('source_kind')!r})")
            imu_name, instance, sysid = meta["imu_message"], int(meta["imu_instance"]), int(meta["autopilot_sysid"])
            offsets = {int(k): float(v) for k, v in (meta.get("epoch_time_offsets_s") or {"0": 0.0}).items()}
        off, t_src, clock, epoch, gyr_src = _imu_frames(base, imu_name, instance, sysid)
        known = np.isin(epoch, list(offsets))
        t_rec = t_src[known] + np.array([offsets[int(e)] for e in epoch[known]])
        off, t_src, gyr_src = off[known], t_src[known], gyr_src[known]

        # estimates due: finite, at about rate_hz of log time (every sample of a log at that rate, jitter and all)
        rows = np.flatnonzero(due_at_rate(t, rate_hz, np.all(np.isfinite(q), axis=1)))
        # the IMU message of each due row: nearest in record time, within a quarter of a sample period
        order = np.argsort(t_rec, kind="stable")
        ts = t_rec[order]
        dt = np.diff(t)
        tol = 0.25 * float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1e-3
        match = np.full(len(rows), -1)
        if len(ts):
            k = np.clip(np.searchsorted(ts, t[rows]), 1, max(len(ts) - 1, 1))
            lo = np.clip(k - 1, 0, len(ts) - 1)
            hi = np.clip(k, 0, len(ts) - 1)
            best = np.where(np.abs(ts[lo] - t[rows]) <= np.abs(ts[hi] - t[rows]), lo, hi)
            good = np.abs(ts[best] - t[rows]) <= tol
            match[good] = order[best[good]]
        if len(rows) and np.mean(match >= 0) < 0.5:
            raise TepinnError(f"{base.name} does not hold the record's {imu_name} samples (wrong source log?)")
        if source is not None and not _same_samples(rec.gyr_rad_s[rows[match >= 0]], gyr_src[match[match >= 0]]):
            raise TepinnError(f"{base.name} holds {imu_name} samples at the record's times but not the record's gyro "
                              "readings (another flight of the same autopilot?): pass the tlog it was ingested from")

        data = base.read_bytes()
        enc = Encoder(sysid, compid)
        inserts: list[tuple[int, bytes]] = []
        last_hb = None
        used: set[int] = set()
        for r, j in zip(rows.tolist(), match.tolist()):
            if j < 0 or j in used:
                continue
            used.add(j)
            o = int(off[j])
            rx = int.from_bytes(data[o : o + 8], "big")
            end = o + _record_length(data, o)
            ts_s = float(t_src[j])
            ms = int(round(ts_s * 1e3))
            us = int(round(ts_s * 1e6))
            msgs = []
            sec = math.floor(t[r])
            if sec != last_hb:
                last_hb = sec
                msgs.append(heartbeat_onboard_msg())
            qi, ri = q[r], rates[r]
            for kind in messages:
                if kind == "attitude":
                    msgs.append(attitude_msg(ms, qi, ri))
                elif kind == "attitude_quaternion":
                    msgs.append(attitude_quaternion_msg(ms, qi, ri))
                else:
                    msgs += estimate_msgs(ms, qi, ri, kind, us)
            buf = b"".join(struct.pack(">Q", rx) + enc.pack(m) for m in msgs)
            for m in msgs:
                counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
            inserts.append((end, buf))
        inserts.sort(key=lambda x: x[0])

        def write(tmp: str) -> None:
            with open(tmp, "wb") as f:
                pos = 0
                for end, buf in inserts:
                    f.write(data[pos:end])
                    f.write(buf)
                    pos = end
                f.write(data[pos:])

        atomic_write(path, write)
    return counts

"""Write a flight record as a MAVLink 2 telemetry log (``.tlog``), as an ArduPilot vehicle sends it.

The story (one, consistent): system 1, component 1 (``MAV_COMP_ID_AUTOPILOT1``) is an ArduPilot
autopilot on a high-rate link (SITL-like; real radios carry 1–10 Hz):

=====================  ==========  =================================================================
message                rate        content
=====================  ==========  =================================================================
HEARTBEAT              1 Hz        ``autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA``, ``type`` QUADROTOR /
                                   FIXED_WING / GENERIC from ``meta["vehicle_type"]``, armed, ACTIVE
HIGHRES_IMU (id 0)     IMU rate    float m/s², rad/s, gauss (full precision); ``fields_updated``
                                   sets acc/gyro (and mag when present) and temperature
RAW_IMU (id 0)         IMU rate    ArduPilot-scaled int16: mG, mrad/s, mGauss (saturating at the
                                   int16 limits: ±32.7 g, ±32.7 rad/s), temperature in cdegC
ATTITUDE               50 Hz       the record's ``q_ref`` (the true attitude for simulations) as
                                   roll/pitch/yaw; rates = gyro minus the true gyro bias where the
                                   record has it (what an EKF reports), else the gyro
ATTITUDE_QUATERNION    50 Hz       the same attitude, q1..q4 = w, x, y, z (body FRD → NED)
=====================  ==========  =================================================================

Time: the autopilot booted ``boot_offset_s`` before the record's ``t_s = 0``; ``time_usec`` and
``time_boot_ms`` are ``t_s + boot_offset_s`` (µs / ms since boot). Every record of the file is
``[uint64 big-endian UNIX µs][frame]``, with the receive time ``start_unix_s + t_s + latency``
(a fixed, plausible UNIX time by default, so the same record gives the same bytes). Sequence
numbers count 0..255 over all messages. Encoding uses the MAVLink 2 dialect of
:mod:`.mavlink_dialect` (``all``, a superset of ``ardupilotmega``: the same bytes).
"""

from __future__ import annotations

import os
import struct
from typing import BinaryIO

import numpy as np

from .conventions import GRAVITY_M_S2
from .mavlink_dialect import dialect
from .vehicle_class import mav_type_suffix
from .quat import quat_to_euler_zyx
from .rate_thinning import due_at_rate
from .record import GYR_BIAS_COLS, FlightRecord, atomic_write

#: 2023-11-14T22:13:20Z: the default receive time of the record's first sample.
DEFAULT_START_UNIX_S = 1_700_000_000.0
DEFAULT_BOOT_OFFSET_S = 10.0
DEFAULT_LATENCY_S = 0.002
ATTITUDE_RATE_HZ = 50.0
HEARTBEAT_RATE_HZ = 1.0

_INT16 = (-32768, 32767)
_HIGHRES_ACC_GYRO = 0x003F  # bits 0-5: x/y/z acc, x/y/z gyro
_HIGHRES_MAG = 0x01C0  # bits 6-8
_HIGHRES_TEMP = 0x1000  # bit 12
_TEMPERATURE_C = 25.0


class TlogWriter:
    """Encodes MAVLink 2 messages into tlog records on an open binary file."""

    def __init__(self, f: BinaryIO, sysid: int = 1, compid: int = 1):
        self.m = dialect()
        self.mav = self.m.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.f = f
        self.counts: dict[str, int] = {}

    def put(self, t_unix_us: int, msg) -> None:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256  # pack() does not advance the sequence; send() would
        self.f.write(struct.pack(">Q", int(t_unix_us)) + buf)
        name = msg.get_type()
        self.counts[name] = self.counts.get(name, 0) + 1


def _i16(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(np.nan_to_num(x)), *_INT16).astype(np.int64)


def write_tlog(
    path: str | os.PathLike,
    record: FlightRecord,
    *,
    start_unix_s: float = DEFAULT_START_UNIX_S,
    boot_offset_s: float = DEFAULT_BOOT_OFFSET_S,
    latency_s: float = DEFAULT_LATENCY_S,
    attitude_rate_hz: float = ATTITUDE_RATE_HZ,
    sysid: int = 1,
    compid: int = 1,
) -> dict[str, int]:
    """Write ``record`` to ``path`` atomically; returns the message counts by type."""
    counts: dict[str, int] = {}

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            w = TlogWriter(f, sysid, compid)
            _write_messages(w, record, start_unix_s, boot_offset_s, latency_s, attitude_rate_hz)
            counts.update(w.counts)

    atomic_write(path, write)
    return counts


def _write_messages(w: TlogWriter, rec: FlightRecord, start_unix_s, boot_offset_s, latency_s, att_rate):
    m = w.m
    t = rec.t_s
    n = len(t)
    if n == 0:
        return
    gyr, acc, mag, q = rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut, rec.q_ref_wxyz
    rates = gyr - rec.data[GYR_BIAS_COLS].to_numpy(float) if all(c in rec.data for c in GYR_BIAS_COLS) else gyr
    has_mag = np.all(np.isfinite(mag), axis=1)
    has_att = np.all(np.isfinite(q), axis=1)
    roll, pitch, yaw = quat_to_euler_zyx(np.where(has_att[:, None], q, [1.0, 0, 0, 0]))
    boot_us = np.round((t - t[0] + boot_offset_s) * 1e6).astype(np.int64)
    boot_ms = np.round((t - t[0] + boot_offset_s) * 1e3).astype(np.int64)
    rx_us = np.round((start_unix_s + (t - t[0]) + latency_s) * 1e6).astype(np.int64)
    rel = t - t[0]
    att_due = due_at_rate(t, att_rate, has_att)
    hb_tick = np.floor(rel * HEARTBEAT_RATE_HZ + 1e-6).astype(np.int64)
    hb_due = np.concatenate([[True], np.diff(hb_tick) != 0])
    # RAW_IMU: ArduPilot scaled units
    raw_acc = _i16(acc * 1000.0 / GRAVITY_M_S2)
    raw_gyr = _i16(gyr * 1000.0)
    raw_mag = _i16(np.where(has_mag[:, None], mag, 0.0) * 10.0)  # µT → mGauss
    hr_mag = np.where(has_mag[:, None], mag, 0.0) / 100.0  # µT → gauss
    temp_c = int(round(_TEMPERATURE_C * 100))
    mav_type = getattr(m, "MAV_TYPE_" + mav_type_suffix(rec.meta.get("vehicle_type")))
    base_mode = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_SAFETY_ARMED
    enc = w.mav
    for i in range(n):
        rx = int(rx_us[i])
        if hb_due[i]:
            w.put(rx, enc.heartbeat_encode(mav_type, m.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode, 0, m.MAV_STATE_ACTIVE, 3))
        a, g, hm = acc[i], gyr[i], hr_mag[i]
        flags = _HIGHRES_ACC_GYRO | _HIGHRES_TEMP | (_HIGHRES_MAG if has_mag[i] else 0)
        w.put(rx, enc.highres_imu_encode(int(boot_us[i]), a[0], a[1], a[2], g[0], g[1], g[2], hm[0], hm[1], hm[2],
                                         0.0, 0.0, 0.0, _TEMPERATURE_C, flags, 0))  # fmt: skip
        ra, rg, rm = raw_acc[i], raw_gyr[i], raw_mag[i]
        w.put(rx, enc.raw_imu_encode(int(boot_us[i]), int(ra[0]), int(ra[1]), int(ra[2]), int(rg[0]), int(rg[1]),
                                     int(rg[2]), int(rm[0]), int(rm[1]), int(rm[2]), 0, temp_c))  # fmt: skip
        if att_due[i]:
            r = rates[i]
            ms = int(boot_ms[i])
            w.put(rx, enc.attitude_encode(ms, roll[i], pitch[i], yaw[i], r[0], r[1], r[2]))
            qi = q[i]
            w.put(rx, enc.attitude_quaternion_encode(ms, qi[0], qi[1], qi[2], qi[3], r[0], r[1], r[2], [0, 0, 0, 0]))

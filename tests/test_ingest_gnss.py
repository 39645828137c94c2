"""GNSS horizontal velocity in flight records: each reader's clock, checked against independent references.

The crux is the clock: a GNSS stream on the wrong clock gives a record with all-NaN or time-shifted
velocity columns. Each real-log test therefore compares the record's velocity (on the record's
samples, mapped back to the source clock) with an independent velocity read directly by pymavlink
or pyulog: the derivative of the GPS positions (DataFlash), the EKF's ``vehicle_local_position``
(ULog) or ``GLOBAL_POSITION_INT`` (tlog), by RMS difference, by the lag at which they correlate
best and by coverage. Synthetic variants of real logs exercise the clock rules the shared logs do
not: a DataFlash GPS timed by ``TimeMS`` only, a 4.x log with two receivers and a reboot, a tlog
whose GPS_RAW_INT is on UNIX time.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from tepinn_flight.ingest import load_record, read_raw
from tepinn_flight.ingest.tlog import _unix_minus_boot_us
from tepinn_flight.record import read_record, write_record

from .conftest import real_log

ERLE = "erle_pxf_copter_15-12-2014_16.BIN"
EARTH_RADIUS_M = 6378137.0
LAGS_S = np.arange(-3.0, 3.0 + 1e-9, 0.02)


# --------------------------------------------------------------------------- helpers


def _source_times(rec) -> np.ndarray:
    """The record's sample times on the source clock (single-boot logs)."""
    offsets = rec.meta["epoch_time_offsets_s"]
    assert len(offsets) == 1
    return rec.t_s - next(iter(offsets.values()))


def _interp(t, t_ref, v_ref):
    return np.column_stack([np.interp(t, t_ref, v_ref[:, k], left=np.nan, right=np.nan) for k in range(2)])


def _agreement(rec, t_ref, v_ref) -> tuple[float, float, float]:
    """(coverage, RMS of the horizontal velocity difference at lag 0 (m/s), lag (s) of the best
    correlation) of the record's GNSS velocity against a reference on the source clock; a positive
    lag: the record's velocity is ahead of the reference."""
    v = rec.gnss_vel_ne_m_s
    ok = np.isfinite(v[:, 0])
    t, v = _source_times(rec)[ok], v[ok]
    ref = _interp(t, t_ref, v_ref)
    m = np.isfinite(ref[:, 0])
    rms = float(np.sqrt(np.mean(np.sum((v[m] - ref[m]) ** 2, axis=1))))
    corr = []
    for lag in LAGS_S:
        r = _interp(t + lag, t_ref, v_ref)
        m = np.isfinite(r[:, 0])
        a, b = (v[m] - v[m].mean(0)).ravel(), (r[m] - r[m].mean(0)).ravel()
        corr.append(a @ b / np.sqrt((a @ a) * (b @ b)))
    return float(ok.mean()), rms, float(LAGS_S[int(np.argmax(corr))])


def _gnss_notes(rec) -> list[str]:
    return [n for n in rec.meta["notes"] if "GPS" in n or "GNSS" in n or "gps" in n]


# --------------------------------------------------------------------------- DataFlash


def _dataflash_position_velocity(path) -> tuple[np.ndarray, np.ndarray]:
    """Velocity north, east (m/s) from differentiating the 3-D-fix GPS positions, on boot time ``T``."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    rows = []
    while (g := conn.recv_match(type="GPS")) is not None:
        if g.Status >= 3:
            rows.append((g.T * 1e-3, g.Lat, g.Lng))
    t, lat, lng = np.array(rows).T
    north = np.radians(lat - lat[0]) * EARTH_RADIUS_M
    east = np.radians(lng - lng[0]) * EARTH_RADIUS_M * np.cos(np.radians(lat[0]))
    return t, np.column_stack([np.gradient(north, t), np.gradient(east, t)])


def test_dataflash_gps_velocity_agrees_with_its_positions_on_the_imu_clock():
    """ArduCopter 3.3: GPS ``TimeMS`` is GPS time of week (~148000 s); the boot time is ``T``."""
    path = real_log(ERLE)
    rec = load_record(path)
    assert rec.gnss_vel_ne_m_s is not None
    assert rec.meta["gnss_source"] == "GPS" and rec.meta["gnss_time_field"] == "T"
    assert rec.meta["gnss_rate_hz"] == pytest.approx(5.0, rel=0.01)
    t_ref, v_ref = _dataflash_position_velocity(path)
    speed = np.hypot(*v_ref.T)
    assert speed.max() > 4.0  # the vehicle moves (5.3 m/s): the comparison has something to see
    cover, rms, lag = _agreement(rec, t_ref, v_ref)
    # measured: coverage 0.999, RMS 0.24 m/s, best correlation at -0.10 s (half a GPS period)
    assert cover > 0.95
    assert rms < 0.4
    assert abs(lag) <= 0.2


def _text_log_with_gps_time(tmp_path, name: str, boot_in_timems: bool):
    """aplogan_nan.log (Copter 3.1, GPS ``TimeMS`` = time of week, ``T`` = boot ms) with ``T`` removed;
    ``boot_in_timems``: ``TimeMS`` replaced by the boot time ``T`` first."""
    src = real_log("aplogan_nan.log").read_text()
    fmt = "FMT, 130, 45, GPS, BIHBcLLeeEefI, Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T"
    assert fmt in src
    without_t = fmt[: fmt.rindex(",")].replace("45, GPS, BIHBcLLeeEefI", "41, GPS, BIHBcLLeeEef")
    lines = []
    for line in src.replace(fmt, without_t).split("\n"):
        if line.startswith("GPS,"):
            parts = line.split(",")
            if boot_in_timems:
                parts[2] = parts[-1]
            line = ",".join(parts[:-1])
        lines.append(line)
    p = tmp_path / name
    p.write_text("\n".join(lines))
    return p


def test_dataflash_gps_timems_is_used_only_on_the_imu_clock(tmp_path):
    orig = read_raw(real_log("aplogan_nan.log"))
    assert orig.gnss is not None and orig.meta["gnss_time_field"] == "T"

    week = read_raw(_text_log_with_gps_time(tmp_path, "week.log", boot_in_timems=False))
    assert week.gnss is None and "gnss_time_field" not in week.meta
    assert any("not on the IMU's boot clock" in n for n in week.meta["notes"])

    boot = read_raw(_text_log_with_gps_time(tmp_path, "boot.log", boot_in_timems=True))
    assert boot.gnss is not None and boot.meta["gnss_time_field"] == "TimeMS"
    np.testing.assert_array_equal(boot.gnss.t_s, orig.gnss.t_s)
    np.testing.assert_allclose(boot.gnss.vel_ne_m_s, orig.gnss.vel_ne_m_s, rtol=0, atol=1e-12)


_ST = {"Q": "Q", "B": "B", "f": "f", "I": "I", "H": "H", "h": "h", "c": "h", "L": "i", "e": "i"}
IMU_F, GPS_F = "QBffffffIIfBBHH", "QBBIHBcLLeffffB"


def _df(tid: int, fmt: str, *vals) -> bytes:
    return bytes([0xA3, 0x95, tid]) + struct.pack("<" + "".join(_ST[c] for c in fmt), *vals)


def _df_fmt(tid: int, name: str, fmt: str, cols: str) -> bytes:
    length = struct.calcsize("<" + "".join(_ST[c] for c in fmt)) + 3
    return struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, tid, length, name.encode(), fmt.encode(), cols.encode())


def test_dataflash_4x_first_receiver_3d_fixes_and_boot_epochs(tmp_path):
    """4.x log: IMU 100 Hz, GPS[I=0] and GPS[I=1] 5 Hz, the first GPS rows a 2-D fix, a reboot."""
    out = [
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"),
        _df_fmt(10, "IMU", IMU_F, "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
        _df_fmt(11, "GPS", GPS_F, "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
    ]
    n, reboot = 400, 250
    want_t, want_v, want_ep = [], [], []
    for k in range(n):
        t_us = 10_000_000 + 10_000 * k if k < reboot else 2_000_000 + 10_000 * (k - reboot)
        out.append(_df(10, IMU_F, t_us, 0, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8, 0, 0, 25.0, 1, 1, 1000, 1000))
        if k % 20 == 5:
            spd, crs = np.float32(2.0 + 0.01 * k), np.float32((7.0 * k) % 360.0)
            status = 2 if k < 60 else 3
            for inst, s in ((0, spd), (1, 99.0)):
                out.append(_df(11, GPS_F, t_us, inst, status, 0, 0, 10, 100, 0, 0, 0, s, crs, 0.0, 0.0, 1))
            if status == 3:
                want_t.append(t_us / 1e6)
                want_v.append([spd * np.cos(np.radians(crs)), spd * np.sin(np.radians(crs))])
                want_ep.append(int(k >= reboot))
    path = tmp_path / "gps4x.bin"
    path.write_bytes(b"".join(out))

    raw = read_raw(path)
    g = raw.gnss
    assert g.source == "GPS" and raw.meta["gnss_time_field"] == "TimeUS"
    np.testing.assert_array_equal(g.t_s, want_t)
    np.testing.assert_allclose(g.vel_ne_m_s, want_v, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(g.epoch, want_ep)
    assert np.unique(raw.imu.epoch).tolist() == [0, 1]

    rec = load_record(path)
    v = rec.gnss_vel_ne_m_s
    fixes_2nd_boot = [k for k in range(reboot, n) if k % 20 == 5]
    after = slice(fixes_2nd_boot[0], fixes_2nd_boot[-1] + 1)  # the second boot's samples between its fixes
    assert np.isfinite(v[after]).all()  # a GPS row given the wrong epoch would leave them NaN
    assert np.nanmax(np.abs(v)) < 10.0  # never the second receiver (99 m/s)


# --------------------------------------------------------------------------- ULog


def _ulog_local_velocity(path, rec) -> tuple[np.ndarray, np.ndarray]:
    """The EKF's ``vehicle_local_position`` vx, vy on the reader's clock (UNIX logs: minus the origin)."""
    from pyulog import ULog

    d = ULog(str(path), ["vehicle_local_position"]).get_dataset("vehicle_local_position").data
    origin_us = round(rec.meta["time_origin_unix_s"] * 1e6)
    return (d["timestamp"].astype(np.int64) - origin_us) * 1e-6, np.column_stack([d["vx"], d["vy"]]).astype(float)


def test_ulog_gps_velocity_on_unix_time_lines_up_with_the_ekf():
    """PX4 v1.15 SITL: every timestamp is UNIX time; the GNSS stream must share the IMU's origin."""
    path = real_log("pyulog_sample_px4_events.ulg")
    rec = load_record(path)
    assert rec.meta["time_base"] == "unix" and rec.meta["gnss_source"] == "vehicle_gps_position"
    v = rec.gnss_vel_ne_m_s
    covered = np.isfinite(v[:, 0])
    first_fix = int(np.argmax(covered))
    # no 3-D fix for the first 9 s of 31 s; from the first fix on, every sample is covered
    assert covered.mean() > 0.65 and covered[first_fix:].mean() > 0.99
    cover, rms, _ = _agreement(rec, *_ulog_local_velocity(path, rec))
    assert rms < 0.05  # measured 0.017 m/s: the vehicle stands still (|v| ≤ 0.05 m/s)


def test_ulog_gps_velocity_agrees_with_the_ekf_in_flight():
    """A real PX4 v1.9 flight at up to 5.9 m/s (IMU logged at 9.6 Hz; a record is still built)."""
    path = real_log("pxrs_esc_status_log.ulg")
    rec = load_record(path)
    assert rec.meta["gnss_source"] == "vehicle_gps_position"
    t_ref, v_ref = _ulog_local_velocity(path, rec)
    assert np.hypot(*v_ref.T).max() > 5.0
    cover, rms, lag = _agreement(rec, t_ref, v_ref)
    # measured: coverage 0.94, RMS 0.20 m/s, best correlation at -0.06 s
    assert cover > 0.9
    assert rms < 0.4
    assert abs(lag) <= 0.2


# --------------------------------------------------------------------------- tlog


def _tlog_messages(path):
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out = []
    while (m := conn.recv_match()) is not None:
        out.append(m)
    return out


def _global_position_velocity(msgs) -> tuple[np.ndarray, np.ndarray]:
    gp = [m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT" and m.get_srcSystem() == m.get_srcComponent() == 1]
    t = np.array([m.time_boot_ms * 1e-3 for m in gp])
    return t, np.array([[m.vx * 0.01, m.vy * 0.01] for m in gp])


@pytest.fixture(scope="module")
def vtol():
    path = real_log("uavlv_vtol.tlog")
    return path, _tlog_messages(path)


def test_tlog_gps_velocity_agrees_with_global_position_int(vtol):
    """ArduPilot SITL QuadPlane: GPS_RAW_INT on boot time, IMU ~4 Hz, speeds up to 28 m/s."""
    path, msgs = vtol
    rec = load_record(path)
    assert rec.meta["gnss_source"] == "GPS_RAW_INT"
    t_ref, v_ref = _global_position_velocity(msgs)
    assert np.hypot(*v_ref.T).max() > 20.0
    cover, rms, lag = _agreement(rec, t_ref, v_ref)
    # measured: coverage 0.98, RMS 0.83 m/s, best correlation at -0.22 s (the simulated GPS lag,
    # which the EKF compensates)
    assert cover > 0.9
    assert rms < 1.5
    assert abs(lag) <= 0.5


def _vtol_with_unix_gps_time(tmp_path, msgs, keep_system_time: bool):
    """The vtol tlog with GPS_RAW_INT.time_usec moved to UNIX time (+ the SYSTEM_TIME offset), re-encoded."""
    from pymavlink import mavutil

    st = [m for m in msgs if m.get_type() == "SYSTEM_TIME" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 1)]
    unix_minus_boot_us = int(np.median([m.time_unix_usec - 1000 * m.time_boot_ms for m in st]))
    mav = mavutil.mavlink.MAVLink(None)
    out = []
    for m in msgs:
        kind = m.get_type()
        if kind == "SYSTEM_TIME" and not keep_system_time:
            continue
        buf = m.get_msgbuf()
        if kind == "GPS_RAW_INT" and m.time_usec > 0:
            fields = {f: getattr(m, f) for f in m.get_fieldnames()}
            fields["time_usec"] += unix_minus_boot_us
            mav.srcSystem, mav.srcComponent, mav.seq = m.get_srcSystem(), m.get_srcComponent(), m.get_seq()
            buf = mavutil.mavlink.MAVLink_gps_raw_int_message(**fields).pack(mav)
        out.append(struct.pack(">Q", int(round(m._timestamp * 1e6))) + bytes(buf))
    p = tmp_path / f"vtol_unix_gps_{int(keep_system_time)}.tlog"
    p.write_bytes(b"".join(out))
    return p


def test_tlog_gps_on_unix_time_is_mapped_to_boot_time_by_system_time(tmp_path, vtol):
    path, msgs = vtol
    orig = read_raw(path)
    unix = _vtol_with_unix_gps_time(tmp_path, msgs, keep_system_time=True)
    raw = read_raw(unix)
    g = raw.gnss
    assert g.source == "GPS_RAW_INT" and orig.gnss.source == "GPS_RAW_INT"
    assert any("mapped by SYSTEM_TIME" in n for n in raw.meta["notes"])
    assert not any("GPS_RAW_INT" in n for n in orig.meta["notes"])
    assert len(g.t_s) == len(orig.gnss.t_s)
    # SYSTEM_TIME's offset jitters by ±0.5 ms about its median
    np.testing.assert_allclose(g.t_s, orig.gnss.t_s, rtol=0, atol=1e-3)
    np.testing.assert_array_equal(g.vel_ne_m_s, orig.gnss.vel_ne_m_s)
    inside = (g.t_s >= raw.imu.t_s.min() - 0.5) & (g.t_s <= raw.imu.t_s.max() + 0.5)
    assert inside.all()
    rec = load_record(unix)
    _, rms, lag = _agreement(rec, *_global_position_velocity(msgs))
    assert rms < 1.5 and abs(lag) <= 0.5


def test_tlog_gps_on_unix_time_without_system_time_falls_back_to_global_position_int(tmp_path, vtol):
    path, msgs = vtol
    unix = _vtol_with_unix_gps_time(tmp_path, msgs, keep_system_time=False)
    raw = read_raw(unix)
    assert raw.gnss.source == "GLOBAL_POSITION_INT"
    assert any("GLOBAL_POSITION_INT" in n and "UNIX" in n for n in raw.meta["notes"])
    first_gps = next(k for k, m in enumerate(msgs) if m.get_type() == "GPS_RAW_INT")
    assert all(m.fix_type >= 3 for m in msgs if m.get_type() == "GPS_RAW_INT")
    t_ref, v_ref = _global_position_velocity(msgs[first_gps:])  # the rows after a 3-D fix
    o = np.argsort(t_ref, kind="stable")  # a few rows arrive late: the reader sorts by time
    np.testing.assert_allclose(raw.gnss.t_s, t_ref[o], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(raw.gnss.vel_ne_m_s, v_ref[o])
    rec = load_record(unix)
    assert rec.meta["gnss_source"] == "GLOBAL_POSITION_INT"


def test_unix_to_boot_offset_follows_reboots():
    """SYSTEM_TIME rows across a reboot: each GPS row takes the median of its own boot's offsets."""
    dtype = [("time_unix_usec", "<u8"), ("time_boot_ms", "<u4")]
    unix0 = 1_700_000_000_000_000
    jitter = np.array([0, 300, -200, 100, 0])
    boot_ms = np.r_[np.arange(5) * 1000 + 100_000, np.arange(5) * 1000 + 2_000]
    offset_us = np.r_[np.full(5, unix0), np.full(5, unix0 + 150_000_000)]  # the second boot began 150 s later
    st = np.zeros(10, dtype)
    st["time_boot_ms"] = boot_ms
    st["time_unix_usec"] = offset_us + 1000 * boot_ms + np.r_[jitter, jitter]
    st["time_unix_usec"][2] = 0  # no GPS time yet: ignored
    st_off = np.arange(10) * 100
    got = _unix_minus_boot_us(st_off, st, np.array([-5, 150, 450, 550, 999]))
    np.testing.assert_array_equal(got, [unix0 + 50, unix0 + 50, unix0 + 50, unix0 + 150_000_000, unix0 + 150_000_000])
    st["time_unix_usec"] = 0
    assert _unix_minus_boot_us(st_off, st, np.array([5])) is None


def test_tlog_without_a_3d_fix_says_so():
    rec = load_record(real_log("ardusub_2023-04-18_11-03-34.tlog"))
    assert rec.gnss_vel_ne_m_s is None and rec.meta["gnss_source"] == "none"
    assert any("3-D fix" in n for n in _gnss_notes(rec))


# --------------------------------------------------------------------------- no GNSS, round trip


@pytest.mark.parametrize("name", ["ardusub_small.BIN", "pyulog_sample_appended_multiple.ulg"])
def test_log_without_gps_gives_no_gnss_columns(name):
    rec = load_record(real_log(name))
    assert rec.gnss_vel_ne_m_s is None and "gnss_vel_n_m_s" not in rec.data
    assert rec.meta["gnss_source"] == "none" and rec.meta["gnss_rate_hz"] is None
    assert _gnss_notes(rec) == []


def test_a_bridged_dropout_keeps_the_gnss_columns_interpolated():
    """record_gaps.bridge_gaps fills a short dropout; the GNSS velocity is filled like the IMU's columns."""
    from tepinn_flight.record import FlightRecord
    from tepinn_flight.record_gaps import bridge_gaps

    rec = load_record(real_log("pyulog_sample_px4_events.ulg"))
    t, v = rec.t_s, rec.gnss_vel_ne_m_s
    a = float(t[np.flatnonzero(np.isfinite(v[:, 0]))[0]]) + 5.0
    keep = ~((t > a) & (t < a + 0.04))  # a 40 ms logging dropout where GNSS fixes cover the log
    data = rec.data[keep].reset_index(drop=True)
    data["segment"] = np.r_[0, np.cumsum(np.diff(data.t_s.to_numpy()) > 0.02)].astype(np.int32)
    br = bridge_gaps(FlightRecord(data, dict(rec.meta)))
    assert br.gaps == 1 and br.filled > 0
    vb = br.record.gnss_vel_ne_m_s
    np.testing.assert_array_equal(vb[br.rows], v[keep])
    filled = np.setdiff1d(np.arange(len(vb)), br.rows)
    before, after = vb[filled[0] - 1], vb[filled[-1] + 1]
    assert np.isfinite(vb[filled]).all()
    assert np.all((vb[filled] >= np.minimum(before, after) - 1e-12) & (vb[filled] <= np.maximum(before, after) + 1e-12))


def test_gnss_columns_survive_a_write_read_round_trip(tmp_path):
    rec = load_record(real_log(ERLE))
    p = tmp_path / "erle.parquet"
    write_record(rec, p)
    back = read_record(p)
    np.testing.assert_array_equal(back.gnss_vel_ne_m_s, rec.gnss_vel_ne_m_s)  # NaN where NaN
    assert np.isfinite(back.gnss_vel_ne_m_s).any()
    assert back.meta["gnss_source"] == "GPS" and back.meta["gnss_rate_hz"] == pytest.approx(rec.meta["gnss_rate_hz"])


def test_info_says_whether_a_record_carries_gnss_velocity():
    from tepinn_flight.cli.summary import render_info
    from tepinn_flight.record_stats import summarize

    rec = load_record(real_log(ERLE))
    s = summarize(rec)
    vel = rec.gnss_vel_ne_m_s
    ok = np.all(np.isfinite(vel), axis=1)
    assert s["gnss"]["source"] == "GPS" and s["gnss"]["coverage"] == pytest.approx(ok.mean())
    assert s["gnss"]["max_speed_m_s"] == pytest.approx(np.hypot(vel[ok, 0], vel[ok, 1]).max())
    assert "GNSS velocity        GPS at 5.0 Hz" in render_info("erle", s)
    bare = summarize(load_record(real_log("ardusub_small.BIN")))
    assert "gnss" not in bare and "GNSS velocity        no" in render_info("sub", bare)


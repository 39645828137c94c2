"""What a reader takes by default where a log holds more than one of a thing (review59, each built from a known
truth): the IMU that covers the log where the first one stops in flight (DataFlash and tlogs), the EKF the autopilot
flies on (DataFlash AHRS_EKF_TYPE), the autopilot system with the IMU data (a tlog of two vehicles), and a fast
RAW_IMU over a ground station's slow HIGHRES_IMU of the same IMU (the bridge's own rule)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.ingest import ingest_log
from tests.test_ingest_dataflash import IMU_F, _fmt, _msg
from tests.test_ingest_tlog import _mav, _write

Q4 = "QffffI"  # NKQ1 / XKQ1 (4.0 style: one message per core): TimeUS, Q1..Q4, an unused field


def _parm(tid, t_us, name, value):
    return bytes([0xA3, 0x95, tid]) + struct.pack("<Q16sf", t_us, name.encode(), value)


def _dataflash(path, n=2000, imu0_until=None, ekf_type=None, gps_fix=None, mag_until=None):
    """A 4.x log: IMU[I=0,1] at 100 Hz (IMU 0 stopping at row ``imu0_until``), NKQ1 4° off the truth, XKQ1 the truth
    (a rotation about z growing with time), PARM AHRS_EKF_TYPE where given."""
    out = [
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"),
        _fmt(10, "IMU", IMU_F, "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
        _fmt(15, "MSG", "QZ", "TimeUS,Message"),
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 16, 3 + struct.calcsize("<Qffff"), b"NKQ1", b"Qffff", b"TimeUS,Q1,Q2,Q3,Q4"),
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 17, 3 + struct.calcsize("<Qffff"), b"XKQ1", b"Qffff", b"TimeUS,Q1,Q2,Q3,Q4"),
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 18, 3 + struct.calcsize("<Q16sf"), b"PARM", b"QNf", b"TimeUS,Name,Value"),
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 19, 3 + struct.calcsize("<QBBff"), b"GPS", b"QBBff",
                    b"TimeUS,I,Status,Spd,GCrs"),
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 20, 3 + struct.calcsize("<QBhhh"), b"MAG", b"QBhhh",
                    b"TimeUS,I,MagX,MagY,MagZ"),
    ]
    out.append(_msg(15, "QZ", 1, b"ArduCopter V4.0.7 (abcdef01)"))
    if ekf_type is not None:
        out.append(_parm(18, 2, "AHRS_EKF_TYPE", float(ekf_type)))
    rate = 0.2  # rad/s about z
    for k in range(n):
        t_us = 10_000_000 + k * 10_000
        for inst in (0, 1):
            if inst == 0 and imu0_until is not None and k >= imu0_until:
                continue
            out.append(_msg(10, IMU_F, t_us, inst, 0.0, 0.0, rate, 0.0, 0.0, -9.81, 0, 0, 25.0, 1, 1, 1000, 1000))
        if mag_until is not None and k % 10 == 0:  # 10 Hz: compass i reads (200 + 100 i, 0, 400) mGauss
            for i, until in enumerate(mag_until):
                if until is None or k < until:
                    out.append(bytes([0xA3, 0x95, 20]) + struct.pack("<QBhhh", t_us + 30, i, 200 + 100 * i, 0, 400))
        if gps_fix is not None and k % 20 == 0:  # 5 Hz: receiver i with its fix status and a velocity of its own
            for i, status in enumerate(gps_fix):
                out.append(bytes([0xA3, 0x95, 19]) + struct.pack("<QBBff", t_us + 20, i, status, 5.0 + i, 90.0))
        if k % 2 == 0:
            yaw = rate * k * 0.01
            truth = Rotation.from_euler("z", yaw)
            off = truth * Rotation.from_euler("x", 4.0, degrees=True)
            for tid, rot in ((16, off), (17, truth)):
                q = rot.as_quat(scalar_first=True).astype(np.float32)
                out.append(bytes([0xA3, 0x95, tid]) + struct.pack("<Qffff", t_us + 50, *q))
    path.write_bytes(b"".join(out))
    return path


def _max_tilt_deg(rec) -> float:
    """The reference's largest tilt (the truth's is 0: it turns about z only)."""
    q = rec.q_ref_wxyz
    z = Rotation.from_quat(q[np.all(np.isfinite(q), axis=1)][:, [1, 2, 3, 0]]).apply([0.0, 0.0, 1.0])
    return float(np.degrees(np.max(np.arccos(np.clip(z[:, 2], -1, 1)))))


def test_dataflash_reads_the_imu_that_covers_the_log_where_the_first_stops(tmp_path):
    log = _dataflash(tmp_path / "imu0_stops.bin", imu0_until=500)
    rec = ingest_log(log)
    assert rec.meta["imu_instance"] == 1 and len(rec) == 2000  # (IMU 0's 500 rows, 5 s of 20, were read before)
    assert any("IMU 1 read" in n and "--imu 0" in n for n in rec.meta.get("notes", []))
    assert ingest_log(log, imu=0).meta["imu_instance"] == 0 and len(ingest_log(log, imu=0)) == 500
    both = ingest_log(_dataflash(tmp_path / "both.bin"))
    assert both.meta["imu_instance"] == 0 and not any("IMU 1 read" in n for n in both.meta.get("notes", []))


def test_dataflash_takes_the_reference_of_the_ekf_the_autopilot_flies_on(tmp_path):
    for ekf_type, want, tilt in ((3, "XKQ1", 0.0), (2, "NKQ1", 4.0), (None, "NKQ1", 4.0)):
        rec = ingest_log(_dataflash(tmp_path / f"ekf{ekf_type}.bin", n=400, ekf_type=ekf_type))
        assert rec.meta["reference_source"].startswith(want), (ekf_type, rec.meta["reference_source"])
        got = _max_tilt_deg(rec)
        assert abs(got - tilt) < 0.01, (ekf_type, got)  # the truth's tilt is 0: the off EKF's is its 4°
    assert any("AHRS_EKF_TYPE 3" in n for n in ingest_log(tmp_path / "ekf3.bin").meta.get("notes", []))


def _tlog_two(path, order, highres_too=False):
    """ArduPilot vehicles in one tlog: sysid 1 with RAW_IMU + ATTITUDE at 50 Hz, sysid 2 (heartbeat first where
    ``order`` says) at 2 Hz; with ``highres_too`` sysid 1 also sends a 2-Hz HIGHRES_IMU and sysid 2 nothing."""
    from pymavlink.dialects.v20 import all as m2

    mavs = {1: _mav(1, 1), 2: _mav(2, 1)}
    items = []
    for k in range(1000):  # 20 s at 50 Hz
        tb = 5_000 + 20 * k
        if k % 50 == 0:
            for s in order:
                if s == 2 and highres_too:
                    continue
                items.append((mavs[s], m2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3), {}))  # quadrotor, ArduPilot
        items.append((mavs[1], m2.MAVLink_raw_imu_message(tb * 1000, 0, 0, -1000, 0, 0, 200, 0, 0, 0), {}))
        items.append((mavs[1], m2.MAVLink_attitude_message(tb, 0.0, 0.0, 0.004 * k, 0, 0, 0.2), {}))
        if k % 25 == 0:
            if highres_too:
                items.append((mavs[1], m2.MAVLink_highres_imu_message(tb * 1000, 0, 0, -9.81, 0, 0, 0.2, 0, 0, 0, 1013, 0, 0, 20, 0x3F, 0), {}))
            else:
                items.append((mavs[2], m2.MAVLink_raw_imu_message(tb * 1000, 0, 0, -1000, 0, 0, 0, 0, 0, 0), {}))
                items.append((mavs[2], m2.MAVLink_attitude_message(tb, 0.1, 0.0, 0.0, 0, 0, 0), {}))
    return _write(path, items)


def test_a_tlog_of_two_vehicles_reads_the_one_with_the_imu_data(tmp_path):
    for order in ((2, 1), (1, 2)):  # (which heartbeat comes first had decided it)
        rec = ingest_log(_tlog_two(tmp_path / f"two{order[0]}.tlog", order))
        assert rec.meta["autopilot_sysid"] == 1 and rec.meta["imu_rate_hz"] > 45, (order, rec.meta["imu_rate_hz"])
        assert any("2 autopilots (systems 1, 2): read system 1" in n for n in rec.meta.get("notes", []))


def test_a_slow_highres_imu_does_not_hide_a_fast_raw_imu(tmp_path):
    rec = ingest_log(_tlog_two(tmp_path / "slowhr.tlog", (1,), highres_too=True))
    assert rec.meta["imu_message"] == "RAW_IMU" and rec.meta["imu_rate_hz"] > 45
    assert np.allclose(rec.gyr_rad_s[:, 2], 0.2, atol=1e-6)  # mrad/s → rad/s


def test_a_ulog_reads_the_full_rate_vehicle_imu_where_sensor_combined_is_decimated(tmp_path):
    """sensor_combined decimated to 10 Hz by the logging profile, vehicle_imu[0] (the selected IMU) and [1] logged at
    200 Hz by a custom topic list: the 200-Hz copy of the selected IMU is read (it had been neither listed nor read,
    and the log called too slow to estimate)."""
    from tests.ulog_writer import SENSOR_COMBINED_V1_14, ULogWriter

    w = ULogWriter()
    w.fmt("sensor_combined", SENSOR_COMBINED_V1_14)
    w.fmt("vehicle_imu", [("uint64_t", "timestamp_sample"), ("uint32_t", "accel_device_id"),
                          ("uint32_t", "gyro_device_id"), ("float[3]", "delta_angle"), ("float[3]", "delta_velocity"),
                          ("uint16_t", "delta_angle_dt"), ("uint16_t", "delta_velocity_dt")])  # fmt: skip
    w.fmt("sensor_selection", [("uint32_t", "accel_device_id"), ("uint32_t", "gyro_device_id")])
    w.subscribe("sensor_combined")
    w.subscribe("vehicle_imu", 0)
    w.subscribe("vehicle_imu", 1)
    w.subscribe("sensor_selection")
    w.data("sensor_selection", 0, 1_000_000, 1000, 2000)
    rate = (0.0, 0.0, 0.3)
    for k in range(4000):  # 20 s at 200 Hz
        t_us = 1_000_000 + 5000 * (k + 1)
        for i in (0, 1):
            w.data("vehicle_imu", i, t_us + 300, t_us, 1000 + i, 2000 + i, np.multiply(rate, 0.005),
                   (0.0, 0.0, -9.81 * 0.005), 5000, 5000)  # fmt: skip
        if k % 20 == 0:  # 10 Hz
            w.data("sensor_combined", 0, t_us, rate, 5000, 0, (0.0, 0.0, -9.81), 5000, 0)
    rec = ingest_log(w.write(tmp_path / "sc10_vimu200.ulg"))
    assert rec.meta["imu_instance"] == 0 and rec.meta["imu_topic"].startswith("vehicle_imu")
    assert rec.meta["imu_rate_hz"] > 150 and np.allclose(rec.gyr_rad_s, rate, atol=1e-5)
    assert np.allclose(rec.acc_m_s2, (0.0, 0.0, -9.81), atol=1e-4)


def test_dataflash_reads_the_gps_receiver_with_a_fix(tmp_path):
    """4.x GPS[I]: the first receiver without a 3-D fix, the second with one — its velocity is read (review59: the
    first receiver only, so no GNSS velocity at all); both fixed: the first, as before."""
    rec = ingest_log(_dataflash(tmp_path / "gps.bin", n=1000, gps_fix=(1, 3)))
    v = rec.gnss_vel_ne_m_s
    assert v is not None and np.nanmedian(v[:, 1]) == pytest.approx(6.0, abs=1e-4)  # receiver 1: 6 m/s east
    assert any("GPS: receiver 1 read" in n for n in rec.meta.get("notes", []))
    both = ingest_log(_dataflash(tmp_path / "gps2.bin", n=1000, gps_fix=(3, 3)))
    assert np.nanmedian(both.gnss_vel_ne_m_s[:, 1]) == pytest.approx(5.0, abs=1e-4)


@pytest.mark.parametrize("mag_until,want", [((None, None), 0), ((500, None), 1)])
def test_dataflash_chooses_the_compass_on_its_own_not_by_the_imus_number(tmp_path, mag_until, want):
    """IMU 0 stops and IMU 1 is read: the compass read is still the first (the autopilot's primary) where it covers
    the log, and the second only where the first stops too — compasses and IMUs are numbered apart (session 60: the
    compass had followed the IMU's instance number). Compass i reads (20 + 10 i, 0, 40) µT."""
    rec = ingest_log(_dataflash(tmp_path / "mags.bin", imu0_until=500, mag_until=mag_until))
    assert rec.meta["imu_instance"] == 1 and rec.meta["mag_instance"] == want
    m = rec.mag_ut
    m = m[np.all(np.isfinite(m), axis=1)]
    assert len(m) > 100 and np.allclose(m, [20.0 + 10.0 * want, 0.0, 40.0])


def _imu_imu2_log(path, imu_fmt: str | None):
    """A 3.x-style log: IMU and IMU2 (no instance column) at 100 Hz, IMU 0 reading gyro z 0.2, IMU2 0.3 rad/s;
    ``imu_fmt`` the columns IMU's FMT names (None: no FMT for IMU, its rows still there)."""
    cols = "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"
    out = [struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"),
           _fmt(11, "IMU2", "Qffffff", cols), _fmt(15, "MSG", "QZ", "TimeUS,Message")]  # fmt: skip
    if imu_fmt is not None:
        out.append(_fmt(10, "IMU", "Qffffff", imu_fmt))
    out.append(_msg(15, "QZ", 1, b"ArduCopter V3.6.9 (abcdef01)"))
    for k in range(1000):
        t_us = 10_000_000 + k * 10_000
        out.append(_msg(10, "Qffffff", t_us, 0.0, 0.0, 0.2, 0.0, 0.0, -9.81))
        out.append(_msg(11, "Qffffff", t_us, 0.0, 0.0, 0.3, 0.0, 0.0, -9.81))
    path.write_bytes(b"".join(out))
    return path


@pytest.mark.parametrize("imu_fmt,note", [(None, "no usable definition (FMT) of IMU: IMU2 read"),
                                          ("TimeUS,GyrX", "IMU 0 left out: its definition (FMT) lacks")])
def test_dataflash_reads_imu2_where_imus_own_definition_is_damaged_and_says_so(tmp_path, imu_fmt, note):
    """IMU's FMT lost (review60: the whole log refused, "no IMU message defined", though IMU2 was whole) or naming too
    few columns (IMU2 read unsaid): IMU2 is read, and a note says why."""
    cols = "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"
    whole = ingest_log(_imu_imu2_log(tmp_path / "whole.bin", cols))
    assert whole.meta["imu_instance"] == 0 and np.allclose(whole.gyr_rad_s[:, 2], 0.2)
    rec = ingest_log(_imu_imu2_log(tmp_path / "damaged.bin", imu_fmt))
    assert rec.meta["imu_instance"] == 1 and np.allclose(rec.gyr_rad_s[:, 2], 0.3) and len(rec) == 1000
    assert any(note in n for n in rec.meta["notes"]), rec.meta["notes"]


def test_an_int16_log_bitmask_is_said_as_the_bits_it_sets(tmp_path):
    """ArduCopter 3.1's LOG_BITMASK is an int16: -22530 is the bits of 43006, said so where no IMU row was logged
    (review60: shown negative)."""
    from tepinn_flight.errors import NoImuData

    out = [struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"),
           _fmt(10, "IMU", "Qffffff", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
           struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 18, 3 + struct.calcsize("<Q16sf"), b"PARM", b"QNf",
                       b"TimeUS,Name,Value"), _parm(18, 2, "LOG_BITMASK", -22530.0)]  # fmt: skip
    (tmp_path / "l.bin").write_bytes(b"".join(out))
    with pytest.raises(NoImuData, match=r"LOG_BITMASK=43006\)"):
        ingest_log(tmp_path / "l.bin")

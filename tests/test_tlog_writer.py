"""The MAVLink 2 tlog writer: read back by pymavlink (reference decoder) and by our own ingest."""

from __future__ import annotations

import os
import struct

os.environ["MAVLINK20"] = "1"  # before pymavlink (mavlink.md §2)

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.sim.sensors import load_sensor_config
from tepinn_flight.sim.simulate import record_from_truth
from tepinn_flight.tlog_writer import DEFAULT_BOOT_OFFSET_S, DEFAULT_START_UNIX_S, write_tlog
from tests.sim_truths import wobble_truth

RATE = 200.0
SECONDS = 3.0


@pytest.fixture(scope="module")
def rec():
    return record_from_truth(wobble_truth(int(RATE * SECONDS), RATE), load_sensor_config("consumer"), seed=2)


@pytest.fixture(scope="module")
def tlog(rec, tmp_path_factory):
    path = tmp_path_factory.mktemp("tlog") / "flight.tlog"
    counts = write_tlog(path, rec)
    return path, counts


def _read_all(path):
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := conn.recv_match()) is not None:
        out.append(msg)
    return out


def test_pymavlink_reads_every_message_with_ids_rates_and_units(rec, tlog):
    path, counts = tlog
    msgs = _read_all(path)
    by = {}
    for m in msgs:
        by.setdefault(m.get_type(), []).append(m)
    assert "BAD_DATA" not in by
    n = len(rec)
    assert len(by["HIGHRES_IMU"]) == n and len(by["RAW_IMU"]) == n
    assert len(by["ATTITUDE"]) == len(by["ATTITUDE_QUATERNION"]) == int(SECONDS * 50)
    assert len(by["HEARTBEAT"]) == int(SECONDS)
    assert counts == {k: len(v) for k, v in by.items()}
    assert all(m.get_srcSystem() == 1 and m.get_srcComponent() == 1 for m in msgs)
    assert all(m.get_header().mlen > 0 and m._header.srcSystem == 1 for m in msgs[:3])
    hb = by["HEARTBEAT"][0]
    assert hb.autopilot == 3 and hb.type == 2  # ARDUPILOTMEGA, QUADROTOR ("multirotor")

    # HIGHRES_IMU: SI floats (float32 on the wire), time since boot consistent with t_s
    hr_t = np.array([m.time_usec for m in by["HIGHRES_IMU"]]) * 1e-6 - DEFAULT_BOOT_OFFSET_S
    np.testing.assert_allclose(hr_t, rec.t_s, atol=1e-6)
    hr_acc = np.array([[m.xacc, m.yacc, m.zacc] for m in by["HIGHRES_IMU"]])
    hr_gyr = np.array([[m.xgyro, m.ygyro, m.zgyro] for m in by["HIGHRES_IMU"]])
    hr_mag = np.array([[m.xmag, m.ymag, m.zmag] for m in by["HIGHRES_IMU"]])
    np.testing.assert_array_equal(hr_acc, rec.acc_m_s2.astype(np.float32))
    np.testing.assert_array_equal(hr_gyr, rec.gyr_rad_s.astype(np.float32))
    np.testing.assert_allclose(hr_mag * 100.0, rec.mag_ut, rtol=1e-6)
    assert all(m.fields_updated & 0x1FF == 0x1FF for m in by["HIGHRES_IMU"])
    # RAW_IMU: ArduPilot scaled integers
    raw = by["RAW_IMU"]
    np.testing.assert_array_equal([m.time_usec for m in raw], [m.time_usec for m in by["HIGHRES_IMU"]])
    raw_acc = np.array([[m.xacc, m.yacc, m.zacc] for m in raw]) * GRAVITY_M_S2 / 1000
    raw_gyr = np.array([[m.xgyro, m.ygyro, m.zgyro] for m in raw]) / 1000
    raw_mag = np.array([[m.xmag, m.ymag, m.zmag] for m in raw]) / 10
    assert np.max(np.abs(raw_acc - rec.acc_m_s2)) <= 0.5 * GRAVITY_M_S2 / 1000 + 1e-9
    assert np.max(np.abs(raw_gyr - rec.gyr_rad_s)) <= 0.5e-3 + 1e-12
    assert np.max(np.abs(raw_mag - rec.mag_ut)) <= 0.05 + 1e-9


def test_attitude_messages_carry_the_reference(rec, tlog):
    msgs = _read_all(tlog[0])
    aq = [m for m in msgs if m.get_type() == "ATTITUDE_QUATERNION"]
    at = [m for m in msgs if m.get_type() == "ATTITUDE"]
    t = np.array([m.time_boot_ms for m in aq]) * 1e-3 - DEFAULT_BOOT_OFFSET_S
    np.testing.assert_allclose(np.diff(t), 0.02, atol=1e-9)
    idx = np.searchsorted(rec.t_s, t - 1e-9)
    q_ref = rec.q_ref_wxyz[idx]
    q = np.array([[m.q1, m.q2, m.q3, m.q4] for m in aq])
    np.testing.assert_allclose(q, q_ref, atol=1e-6)
    # ATTITUDE Euler angles by an independent library: scipy intrinsic Z-Y-X
    rpy = np.array([[m.roll, m.pitch, m.yaw] for m in at])
    ypr = Rotation.from_quat(q_ref[:, [1, 2, 3, 0]]).as_euler("ZYX")
    np.testing.assert_allclose(rpy, ypr[:, ::-1], atol=1e-5)
    rates = np.array([[m.rollspeed, m.pitchspeed, m.yawspeed] for m in at])
    want = rec.gyr_rad_s[idx] - rec.data[["gyr_bias_x_rad_s", "gyr_bias_y_rad_s", "gyr_bias_z_rad_s"]].to_numpy()[idx]
    np.testing.assert_allclose(rates, want, atol=1e-6)


def test_receive_timestamps_are_plausible_unix_and_file_is_deterministic(rec, tlog, tmp_path):
    path = tlog[0]
    data = path.read_bytes()
    first = struct.unpack(">Q", data[:8])[0]
    assert abs(first * 1e-6 - DEFAULT_START_UNIX_S) < 1.0
    assert data[8] == 0xFD  # MAVLink 2 frames
    msgs = _read_all(path)
    ts = np.array([m._timestamp for m in msgs])
    assert np.all(np.diff(ts) >= 0) and ts[-1] - ts[0] == pytest.approx(rec.t_s[-1], abs=1e-3)
    seqs = np.array([m.get_seq() for m in msgs])
    np.testing.assert_array_equal(seqs, np.arange(len(msgs)) % 256)
    again = tmp_path / "again.tlog"
    write_tlog(again, rec)
    assert again.read_bytes() == data


def test_own_ingest_reads_the_tlog_back(rec, tlog):
    pytest.importorskip("tepinn_flight.ingest.tlog")
    from tepinn_flight.ingest import ingest_log

    back = ingest_log(tlog[0])
    assert back.meta["source_kind"] == "tlog"
    assert len(back) == len(rec)
    np.testing.assert_allclose(back.t_s, rec.t_s, atol=1e-6)
    np.testing.assert_allclose(back.gyr_rad_s, rec.gyr_rad_s, atol=1e-6)
    np.testing.assert_allclose(back.acc_m_s2, rec.acc_m_s2, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(back.mag_ut, rec.mag_ut, rtol=1e-6, atol=1e-4)
    # the reference comes back from the 50 Hz attitude, slerped onto the IMU samples
    ok = np.all(np.isfinite(back.q_ref_wxyz), axis=1)
    assert ok.mean() > 0.95
    dot = np.abs(np.sum(back.q_ref_wxyz[ok] * rec.q_ref_wxyz[ok], axis=1))
    assert np.degrees(2 * np.arccos(np.clip(dot, -1, 1))).max() < 0.2

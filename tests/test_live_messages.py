"""Every message the bridge and the emulator send, packed by us and decoded by pymavlink's parser;
the IMU/EKF decoders against closed-form unit conversions and scipy rotations. No network."""

from __future__ import annotations

import math
import os

os.environ["MAVLINK20"] = "1"  # before pymavlink (mavlink.md §2)

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.live import dialect
from tepinn_flight.live.inputs import EkfComparator, ekf_attitude, imu_sample, tilt_difference
from tepinn_flight.live.messages import (
    DEFAULT_ESTIMATE_AS,
    DIAG_NAMES,
    ESTIMATE_AS,
    Encoder,
    attitude_msg,
    attitude_quaternion_msg,
    debug_vect_msg,
    diagnostic_msgs,
    estimate_msgs,
    heartbeat_autopilot_msg,
    heartbeat_onboard_msg,
    highres_imu_msg,
    named_value_float_msg,
    scaled_imu_msg,
    set_message_interval_msg,
)

M = dialect()
RNG = np.random.default_rng(7)
ARDUPILOT, PX4 = 3, 12


def _decode(frames: bytes):
    """pymavlink's own parser (CRC-checked); fails on anything but good frames."""
    rx = M.MAVLink(None)
    rx.robust_parsing = True
    msgs = rx.parse_buffer(frames) or []
    assert all(m.get_type() != "BAD_DATA" for m in msgs), [getattr(m, "reason", "") for m in msgs]
    return msgs


def _roundtrip(msg, sysid=7, compid=191):
    enc = Encoder(sysid, compid)
    (m,) = _decode(enc.pack(msg))
    assert (m.get_srcSystem(), m.get_srcComponent()) == (sysid, compid)
    assert m.get_msgbuf()[0] == 0xFD  # MAVLink 2
    return m


def _random_quats(n):
    return Rotation.random(n, random_state=3)


def test_attitude_and_quaternion_roundtrip_against_scipy():
    rots = _random_quats(50)
    for k, r in enumerate(rots):
        x, y, z, w = r.as_quat()  # scipy is scalar-last
        q = (w, x, y, z)
        rates = RNG.normal(size=3)
        ms = 1_000_000 + 20 * k
        a = _roundtrip(attitude_msg(ms, q, rates))
        aq = _roundtrip(attitude_quaternion_msg(ms, q, rates))
        yaw, pitch, roll = r.as_euler("ZYX")  # intrinsic Z-Y-X = aerospace yaw, pitch, roll
        assert a.get_type() == "ATTITUDE" and a.time_boot_ms == ms
        np.testing.assert_allclose([a.roll, a.pitch, a.yaw], [roll, pitch, yaw], atol=2e-6)
        np.testing.assert_allclose([a.rollspeed, a.pitchspeed, a.yawspeed], rates, rtol=1e-6, atol=1e-7)
        assert aq.get_type() == "ATTITUDE_QUATERNION" and aq.time_boot_ms == ms
        np.testing.assert_allclose([aq.q1, aq.q2, aq.q3, aq.q4], q, atol=1e-7)
        np.testing.assert_allclose([aq.rollspeed, aq.pitchspeed, aq.yawspeed], rates, rtol=1e-6, atol=1e-7)


def test_estimate_msgs_stamps_and_wraps_time_boot_ms():
    q = (1.0, 0.0, 0.0, 0.0)
    enc = Encoder(1)
    msgs = _decode(b"".join(enc.pack(m) for m in estimate_msgs(2**32 + 5, q, (0, 0, 0))))
    assert [m.get_type() for m in msgs] == ["ATTITUDE", "ATTITUDE_QUATERNION"]
    assert all(m.time_boot_ms == 5 for m in msgs)  # uint32 wraps like the autopilot's own counter


@pytest.mark.parametrize("kind", ESTIMATE_AS)
def test_estimate_as_each_kind_carries_the_estimate(kind):
    """``--estimate-as``: each kind is its own message type, from 1/191, with the estimate's values."""
    r = Rotation.from_euler("ZYX", [2.5, -0.4, 0.3])  # yaw, pitch, roll
    x, y, z, w = r.as_quat()
    q, rates, ms, us = (w, x, y, z), (0.1, -0.2, 0.3), 123_456, 123_456_789
    enc = Encoder(1, 191)
    msgs = _decode(b"".join(enc.pack(m) for m in estimate_msgs(ms, q, rates, kind, us)))
    assert all((m.get_srcSystem(), m.get_srcComponent()) == (1, 191) for m in msgs)
    deg = np.degrees([0.3, -0.4, 2.5])  # roll, pitch, yaw
    types = [m.get_type() for m in msgs]
    if kind == "attitude_quaternion":
        assert types == ["ATTITUDE", "ATTITUDE_QUATERNION"]
        np.testing.assert_allclose([msgs[0].roll, msgs[0].pitch, msgs[0].yaw], [0.3, -0.4, 2.5], atol=2e-6)
        np.testing.assert_allclose([msgs[1].q1, msgs[1].q2, msgs[1].q3, msgs[1].q4], q, atol=1e-7)
        assert all(m.time_boot_ms == ms for m in msgs)
    elif kind == "named_value":
        assert types == ["NAMED_VALUE_FLOAT"] * 3
        assert [m.name for m in msgs] == ["tp_roll", "tp_pitch", "tp_yaw"]
        np.testing.assert_allclose([m.value for m in msgs], deg, atol=1e-4)
        assert all(m.time_boot_ms == ms for m in msgs)
    else:
        assert types == ["DEBUG_VECT"] and msgs[0].name == "TP_RPY" and msgs[0].time_usec == us
        np.testing.assert_allclose([msgs[0].x, msgs[0].y, msgs[0].z], deg, atol=1e-4)
    # no kind but attitude_quaternion sends a message a ground station could put on its HUD
    assert (kind == "attitude_quaternion") == bool({"ATTITUDE", "ATTITUDE_QUATERNION"} & set(types))


def test_estimate_as_default_and_unknown_kind():
    assert DEFAULT_ESTIMATE_AS in ("named_value", "debug_vect")
    with pytest.raises(ValueError, match="named_value"):
        estimate_msgs(0, (1.0, 0, 0, 0), (0, 0, 0), "hud")
    # diagnostics leave out TP_RPY when the estimate itself is that DEBUG_VECT
    kw = dict(sigma_rad=0.01, latency_s=0.002, imu_rate_hz=200.0, bias_rad_s=(0, 0, 0))
    names = lambda rpy: [m.name for m in diagnostic_msgs(0, 0, (1.0, 0, 0, 0), rpy=rpy, **kw) if m.get_type() == "DEBUG_VECT"]  # noqa: E731
    assert "TP_RPY" in names(True) and "TP_RPY" not in names(False)


def test_heartbeats():
    hb = _roundtrip(heartbeat_onboard_msg())
    assert (hb.type, hb.autopilot, hb.system_status) == (
        M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, M.MAV_STATE_ACTIVE)  # fmt: skip
    assert (hb.type, hb.autopilot) == (18, 8)  # the numbers from minimal.xml (mavlink.md §3)
    ap = _roundtrip(heartbeat_autopilot_msg(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4), compid=1)
    assert (ap.type, ap.autopilot) == (2, 12)
    assert ap.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED


def test_named_value_float_and_debug_vect():
    for name in DIAG_NAMES:
        assert len(name) <= 10
        m = _roundtrip(named_value_float_msg(1234, name, 1.25))
        assert (m.name, m.value, m.time_boot_ms) == (name, 1.25, 1234)
    d = _roundtrip(debug_vect_msg("TP_RPY", 10_000_123, 1.5, -2.5, 3.0))
    assert (d.name, d.time_usec, d.x, d.y, d.z) == ("TP_RPY", 10_000_123, 1.5, -2.5, 3.0)
    with pytest.raises(ValueError):
        named_value_float_msg(0, "much_too_long", 1.0)


def test_set_message_interval_command():
    c = _roundtrip(set_message_interval_msg(1, 1, M.MAVLINK_MSG_ID_RAW_IMU, 200.0))
    assert c.get_type() == "COMMAND_LONG"
    assert (c.target_system, c.target_component, c.command) == (1, 1, 511)
    assert (c.param1, c.param2) == (27.0, 5000.0)  # RAW_IMU id, 1e6 / 200 Hz µs


def test_diagnostics_carry_the_difference_in_degrees():
    q = tuple(np.roll(_random_quats(1)[0].as_quat(), 1))
    diff = (math.radians(1.0), math.radians(-2.0), math.radians(3.0), math.radians(-40.0))
    msgs = _decode(b"".join(Encoder(1).pack(m) for m in diagnostic_msgs(
        500, 500_000, q, sigma_rad=math.radians(0.5), latency_s=0.004, imu_rate_hz=400.0,
        bias_rad_s=(0.01, 0.02, 0.03), diff=diff)))  # fmt: skip
    nvf = {m.name: m.value for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"}
    dv = {m.name: (m.x, m.y, m.z) for m in msgs if m.get_type() == "DEBUG_VECT"}
    assert set(nvf) == set(DIAG_NAMES)
    assert nvf["tp_dincl"] == pytest.approx(3.0, abs=1e-5)
    assert nvf["tp_dhead"] == pytest.approx(-40.0, abs=1e-4)
    assert nvf["tp_sigma"] == pytest.approx(0.5, abs=1e-5)
    assert nvf["tp_lat_ms"] == pytest.approx(4.0, abs=1e-4)
    np.testing.assert_allclose(dv["TP_DIFF"], (1.0, -2.0, 3.0), atol=1e-5)
    r = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    np.testing.assert_allclose(dv["TP_RPY"], np.degrees(r.as_euler("ZYX")[::-1]), atol=1e-4)
    no_diff = diagnostic_msgs(500, 500_000, q, sigma_rad=0.01, latency_s=0.0, imu_rate_hz=0.0, bias_rad_s=(0, 0, 0))
    assert "tp_dincl" not in {getattr(m, "name", "") for m in no_diff}


def test_sequence_numbers_wrap():
    enc = Encoder(1)
    seqs = [_decode(enc.pack(heartbeat_onboard_msg()))[0].get_seq() for _ in range(300)]
    assert seqs[:3] == [0, 1, 2] and seqs[255] == 255 and seqs[256] == 0


# ---------------------------------------------------------------------------- decoding what we read
def test_highres_imu_roundtrip_si_units():
    gyr, acc, mag = (0.1, -0.2, 3.0), (0.5, -0.25, -9.81), (20.0, -5.0, 40.0)
    m = _roundtrip(highres_imu_msg(12_345_678, gyr, acc, mag), compid=1)
    assert m.xmag == pytest.approx(0.20) and m.fields_updated & 0x1FF == 0x1FF  # gauss, all flags
    s = imu_sample(m, PX4)
    assert s.message == "HIGHRES_IMU" and s.instance == 0
    assert (s.time_usec, s.time_boot_ms, s.t_s) == (12_345_678, 12_345, 12.345678)
    np.testing.assert_allclose(s.gyr_rad_s, gyr, rtol=1e-6)
    np.testing.assert_allclose(s.acc_m_s2, acc, rtol=1e-6)
    np.testing.assert_allclose(s.mag_ut, mag, rtol=1e-6)
    s2 = imu_sample(_roundtrip(highres_imu_msg(1, gyr, acc, None), compid=1), PX4)
    assert s2.mag_ut is None


def test_scaled_imu_milli_units_and_saturation():
    g0 = 9.80665
    m = _roundtrip(scaled_imu_msg(4321, (0.5, -1.0, 40.0), (0.0, g0, -g0), (25.0, 0, -30.0)), compid=1)
    assert (m.xacc, m.yacc, m.zacc) == (0, 1000, -1000)  # 1 g = 1000 mG exactly
    assert (m.xgyro, m.ygyro, m.zgyro) == (500, -1000, 32767)  # mrad/s, saturating int16
    assert (m.xmag, m.zmag) == (250, -300)  # mGauss = µT × 10
    s = imu_sample(m, None)  # SCALED_IMU: known units whatever the autopilot
    assert s.t_s == pytest.approx(4.321) and s.time_boot_ms == 4321
    np.testing.assert_allclose(s.acc_m_s2, (0.0, g0, -g0), atol=1e-12)
    np.testing.assert_allclose(s.gyr_rad_s, (0.5, -1.0, 32.767), atol=1e-12)
    np.testing.assert_allclose(s.mag_ut, (25.0, 0.0, -30.0), atol=1e-12)


def test_raw_imu_units_follow_the_autopilot():
    raw = M.MAVLink_raw_imu_message(5_000_000, 10, -20, -1000, 100, 200, -300, 1, 2, 3, 0, 2500)
    m = _roundtrip(raw, compid=1)
    s = imu_sample(m, ARDUPILOT)
    np.testing.assert_allclose(s.acc_m_s2, np.array([10, -20, -1000]) * 9.80665e-3)
    np.testing.assert_allclose(s.gyr_rad_s, (0.1, 0.2, -0.3))
    assert imu_sample(m, PX4) is None  # raw counts possible: unknown scale, refused
    assert imu_sample(m, None) is None


def test_unusable_imu_messages_are_skipped():
    zero = M.MAVLink_scaled_imu2_message(100, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    assert imu_sample(_roundtrip(zero, compid=1), ARDUPILOT) is None  # a missing 2nd IMU
    part = highres_imu_msg(1000, (0.1, 0, 0), (0, 0, -9.8))
    part.fields_updated = 0x0007  # accelerometer only
    assert imu_sample(_roundtrip(part, compid=1), PX4) is None
    unix = _roundtrip(highres_imu_msg(1_700_000_000_000_000, (0.1, 0, 0), (0, 0, -9.8)), compid=1)
    s = imu_sample(unix, PX4)
    assert s.time_boot_ms is None and s.t_s == pytest.approx(1.7e9)
    imu2 = M.MAVLink_scaled_imu2_message(100, 0, 0, -1000, 1, 0, 0, 0, 0, 0, 0)
    assert imu_sample(_roundtrip(imu2, compid=1), ARDUPILOT).instance == 1
    assert imu_sample(_roundtrip(heartbeat_onboard_msg()), ARDUPILOT) is None


def test_ekf_attitude_from_both_messages_against_scipy():
    for r in _random_quats(20):
        x, y, z, w = r.as_quat()
        t1, _, q1 = ekf_attitude(_roundtrip(attitude_msg(777, (w, x, y, z)), compid=1))
        t2, ms, q2 = ekf_attitude(_roundtrip(attitude_quaternion_msg(777, (w, x, y, z)), compid=1))
        assert t1 == t2 == 0.777 and ms == 777
        for q in (q1, q2):
            got = Rotation.from_quat([q[1], q[2], q[3], q[0]])
            assert (got.inv() * r).magnitude() < 1e-5
    zero = M.MAVLink_attitude_quaternion_message(1, 0, 0, 0, 0, 0, 0, 0, [0, 0, 0, 0])
    assert ekf_attitude(_roundtrip(zero, compid=1)) is None


def test_tilt_difference_ignores_heading_and_matches_scipy():
    rots = _random_quats(30)
    for r in rots:
        x, y, z, w = r.as_quat()
        q = (w, x, y, z)
        spin = Rotation.from_euler("z", RNG.uniform(-np.pi, np.pi)) * r  # heading change (earth z)
        sx, sy, sz, sw = spin.as_quat()
        assert tilt_difference((sw, sx, sy, sz), q)[2] == pytest.approx(0.0, abs=1e-6)
        # ... and the heading difference is the yaw difference (scipy's ZYX), wrapped
        ye, yr = spin.as_euler("ZYX")[0], r.as_euler("ZYX")[0]
        want_h = math.atan2(math.sin(ye - yr), math.cos(ye - yr))
        assert tilt_difference((sw, sx, sy, sz), q)[3] == pytest.approx(want_h, abs=1e-6)
        other = Rotation.random(random_state=int(RNG.integers(1e9)))
        ox, oy, oz, ow = other.as_quat()
        g_a = r.inv().apply([0, 0, 1])  # earth down in body axes
        g_b = other.inv().apply([0, 0, 1])
        want = math.acos(np.clip(np.dot(g_a, g_b), -1, 1))
        assert tilt_difference(q, (ow, ox, oy, oz))[2] == pytest.approx(want, abs=1e-6)


def test_ekf_comparator_interpolates_on_the_autopilot_clock():
    rate = 0.5  # rad/s roll
    def q_at(t):  # noqa: E306
        return (math.cos(rate * t / 2), math.sin(rate * t / 2), 0.0, 0.0)
    cmp = EkfComparator()
    assert cmp.add_estimate(0.99, q_at(0.99)) == []  # no EKF yet: waits
    out = cmp.add_ekf(1.0, q_at(1.0))  # 0.99 is before the first EKF sample: dropped
    assert out == []
    est_q = q_at(1.015 + 0.1)  # estimate off by 0.05 rad of roll at t = 1.015
    assert cmp.add_estimate(1.015, est_q) == []  # waits for the bracket
    (d,) = cmp.add_ekf(1.02, q_at(1.02))
    assert d[0] == 1.015
    assert d[1] == pytest.approx(rate * 0.1, abs=1e-9) and d[3] == pytest.approx(rate * 0.1, abs=1e-9)
    (d,) = cmp.add_estimate(1.01, q_at(1.01))  # bracketed already: answered at once
    assert d[3] == pytest.approx(0.0, abs=1e-9)
    cmp.add_ekf(1.5, q_at(1.5))
    assert cmp.add_estimate(1.3, q_at(1.3)) == []  # bracket 1.02..1.5 longer than 0.25 s: unused
    cmp.add_ekf(0.2, q_at(0.2))  # reboot: the EKF clock went back
    assert list(cmp.ekf) == [(0.2, q_at(0.2))]

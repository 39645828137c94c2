"""When a sample counts as clipped: one rule (ingest.saturation) for the DataFlash and tlog readers
and the live bridge, the gyro's saturation apart from the accelerometer's."""

from __future__ import annotations

import math

import numpy as np

from tepinn_flight.ingest import ingest_log
from tepinn_flight.ingest.saturation import (
    CLIP_FRACTION,
    GYRO_FULL_SCALE_RAD_S,
    accel_saturated,
    gyro_full_scale_rad_s,
    gyro_saturated,
    saturated_f,
)
from tepinn_flight.ingest.tlog import MAV_AUTOPILOT_ARDUPILOTMEGA
from tepinn_flight.live.inputs import imu_sample
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import ACC_COLS, GYR_COLS
from tepinn_flight.tlog_writer import write_tlog


def test_full_scales_are_the_sensor_range_or_the_int16_field_limit():
    assert GYRO_FULL_SCALE_RAD_S == math.radians(2000.0)
    assert gyro_full_scale_rad_s("HIGHRES_IMU") == gyro_full_scale_rad_s(None) == math.radians(2000.0)
    for name in ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"):
        assert gyro_full_scale_rad_s(name) == 32.767  # int16 mrad/s stops below 2000 °/s (34.9 rad/s)
    lim = CLIP_FRACTION * math.radians(2000.0)
    g = np.array([[lim - 1e-9, 0, 0], [0, -lim, 0], [0, 0, 1.0], [0, 0, 33.0]])
    np.testing.assert_array_equal(gyro_saturated(g), [False, True, False, False])
    np.testing.assert_array_equal(gyro_saturated(g, 32.767), [True, True, False, True])  # 98 % of 32.767: 32.11
    a = np.array([[0, 0, -9.81], [0, 0, -15.7 * 9.80665], [160.0, 0, 0]])
    np.testing.assert_array_equal(accel_saturated(a), [False, True, True])
    for gi, ai in zip(g, np.r_[a, a[:1]]):  # the per-sample form agrees with the rows'
        c, gc = saturated_f(tuple(gi), tuple(ai), 32.767)
        assert gc == gyro_saturated(gi[None], 32.767)[0]
        assert c == (gc or accel_saturated(ai[None])[0])


def test_a_tlog_marks_the_samples_the_live_bridge_marks(tmp_path):
    """The tlog reader and the bridge's per-message decoding mark the same samples: the gyro's
    saturation as clipped and gyr_clipped, the accelerometer's as clipped alone."""
    from pymavlink import mavutil

    rec = synthetic_record(seed=4, duration_s=6.0, rate_hz=100.0)
    gyr, acc = rec.gyr_rad_s.copy(), rec.acc_m_s2.copy()
    gyr[100:110, 0] = 40.0  # beyond 2000 °/s
    acc[300:305, 1] = 20 * 9.80665  # beyond 16 g
    rec.data[GYR_COLS] = gyr
    rec.data[ACC_COLS] = acc
    path = tmp_path / "sat.tlog"
    write_tlog(path, rec)
    back = ingest_log(path)
    want_g = np.zeros(len(rec), bool)
    want_g[100:110] = True
    want = want_g.copy()
    want[300:305] = True
    np.testing.assert_array_equal(back.gyr_clipped, want_g)
    np.testing.assert_array_equal(back.clipped, want)
    assert any("marked clipped" in n for n in back.meta["notes"])
    live = {"HIGHRES_IMU": [], "RAW_IMU": []}
    mlog = mavutil.mavlink_connection(str(path))
    while (m := mlog.recv_match(type=["HIGHRES_IMU", "RAW_IMU"])) is not None:
        s = imu_sample(m, MAV_AUTOPILOT_ARDUPILOTMEGA)
        live[m.get_type()].append((s.clipped, s.gyr_clipped))
    np.testing.assert_array_equal(np.array(live["HIGHRES_IMU"]), np.c_[want, want_g])  # what the reader read
    # RAW_IMU's int16 mrad/s stops at 32.767 rad/s: the same samples, seen at that field's limit
    np.testing.assert_array_equal(np.array(live["RAW_IMU"])[:, 1], want_g)

"""ArduPilot's RAW_IMU.time_usec is a 32-bit µs count (``AP_HAL::micros()``) that wraps 71.6 min after boot,
while ATTITUDE's time_boot_ms goes on (session 53). The tlog reader and the live bridge put it back on a running
clock against the autopilot's boot clock; a reboot, which sets both clocks back, stays a reboot.

Each tlog below is built with pymavlink: RAW_IMU at 50 Hz turning about z at a steady 1 rad/s from 70 min after
boot (so its yaw is known at every sample), ATTITUDE beside it with the same yaw.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from tepinn_flight.ingest import load_record
from tepinn_flight.ingest.clock_wrap import US32_WRAP_S, top_to_bottom, wrap_count
from tepinn_flight.quat import quat_to_euler_zyx

WRAP_US = 2**32
T0_MS = 4_200_000  # 70 min after boot: the wrap is 95 s in


def _mav():
    from pymavlink.dialects.v20 import all as m

    return m, m.MAVLink(None, srcSystem=1, srcComponent=1)


def _yaw(tb_ms: int) -> float:
    return (1e-3 * (tb_ms - T0_MS) + np.pi) % (2 * np.pi) - np.pi


def _write(path, n: int, attitude: bool = True, reboot_at: int | None = None, step_ms: int = 20):
    """A tlog of n RAW_IMU samples step_ms apart (and ATTITUDE each one); from sample ``reboot_at`` on, a reboot:
    both clocks start again at 3 s after 2 s of silence."""
    m, mav = _mav()
    out = []
    t_unix = 1.7e9
    for k in range(n):
        tb = T0_MS + step_ms * k
        if reboot_at is not None and k >= reboot_at:
            tb = 3000 + step_ms * (k - reboot_at)
            if k == reboot_at:
                t_unix += 2.0
        msgs = [m.MAVLink_raw_imu_message((tb * 1000) % WRAP_US, 0, 0, -1000, 0, 0, 1000, 0, 0, 0, 0, 0)]
        if k % 50 == 0:
            msgs.insert(0, m.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))
        if attitude:
            msgs.append(m.MAVLink_attitude_message(tb, 0.0, 0.0, _yaw(tb), 0.0, 0.0, 1.0))
        for msg in msgs:
            out.append(struct.pack(">Q", int(t_unix * 1e6)) + bytes(msg.pack(mav)))
            mav.seq = (mav.seq + 1) % 256
        t_unix += step_ms / 1e3
    path.write_bytes(b"".join(out))
    return path


def test_wrap_count_against_the_boot_clock():
    # 2 s after the wrap, the boot clock 4296.97 s: one wrap; 10 min off the boot clock: no count
    assert wrap_count(2.0, US32_WRAP_S + 2.0) == 1
    assert wrap_count(2.0, 2.5) == 0
    assert wrap_count(2.0, US32_WRAP_S + 600.0) == -1
    assert wrap_count(np.array([1.0, 4000.0]), np.array([2 * US32_WRAP_S + 1.0, 4000.0])).tolist() == [2, 0]
    assert top_to_bottom(US32_WRAP_S - 0.01, 0.01) and not top_to_bottom(3000.0, 0.01)


def test_tlog_across_the_wrap_keeps_time_and_reference(tmp_path):
    n = 10_000  # 200 s
    rec = load_record(_write(tmp_path / "wrap.tlog", n))
    assert rec.meta["boot_epochs"] == 1 and rec.meta["segments"] == 1
    assert len(rec) == n
    np.testing.assert_allclose(np.diff(rec.t_s), 0.02, atol=1e-6)  # one running clock, in order
    assert any("wrapped at 2^32" in s for s in rec.meta["notes"])
    _, _, yaw = quat_to_euler_zyx(rec.q_ref_wxyz)
    assert np.all(np.isfinite(yaw))  # the reference covers every sample
    true = np.array([_yaw(T0_MS + 20 * k) for k in range(n)])  # sample k's own yaw (rows in time order)
    err = np.degrees(np.abs(np.angle(np.exp(1j * (yaw - true)))))
    assert err.max() < 0.5


def test_tlog_wrap_without_a_boot_clock(tmp_path):
    rec = load_record(_write(tmp_path / "wrap_imu_only.tlog", 8000, attitude=False))
    assert rec.meta["boot_epochs"] == 1 and rec.meta["segments"] == 1
    np.testing.assert_allclose(np.diff(rec.t_s), 0.02, atol=1e-6)


def test_tlog_reboot_is_not_taken_for_a_wrap(tmp_path):
    # 66 min of uptime then a reboot: RAW_IMU falls by ~3960 s, within a wrap's reach, but ATTITUDE falls too
    rec = load_record(_write(tmp_path / "reboot.tlog", 6000, reboot_at=3000))
    assert rec.meta["boot_epochs"] == 2
    assert not any("wrapped" in s for s in rec.meta["notes"])


def _live_stream(n: int, reboot_at: int | None = None):
    from tepinn_flight.live.autopilot import AutopilotTracker
    from tepinn_flight.live.imu_stream import ImuStream
    from tepinn_flight.live.sample_order import REBOOT

    m, _ = _mav()
    notes = []
    ap = AutopilotTracker(None, 191, notes.append)
    ap.heartbeat(m.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3), 1, 0.0)
    imu = ImuStream(0, notes.append)
    ts = []
    t_in = 100.0
    for k in range(n):
        tb = 4_294_000 + 20 * k  # 1 s before the wrap
        if reboot_at is not None and k >= reboot_at:
            tb = 3000 + 20 * (k - reboot_at)
            t_in += 2.0 if k == reboot_at else 0.0
        att = m.MAVLink_attitude_message(tb, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        ap.message("ATTITUDE", 1, t_in, att.time_boot_ms)
        raw = m.MAVLink_raw_imu_message((tb * 1000) % WRAP_US, 0, 0, -1000, 0, 0, 1000, 0, 0, 0, 0, 0)
        s, _ = imu.take(raw, t_in, ap.autopilot, ap.name, ap.boot_ms_at(t_in))
        if s is not None:
            ts.append((s.t_s, s.time_boot_ms))
        t_in += 0.02
    return np.array(ts), imu.order.counts[REBOOT], notes


def test_bridge_takes_the_wrap_as_time_going_on():
    ts, reboots, notes = _live_stream(200)
    assert reboots == 0 and len(ts) == 200  # nothing dropped as stale, no estimator reset
    np.testing.assert_allclose(np.diff(ts[:, 0]), 0.02, atol=1e-6)
    assert ts[-1, 1] == 4_294_000 + 20 * 199  # the estimate's boot ms is ATTITUDE's clock (the comparison pairs)
    assert any("wrapped at 2^32" in s for s in notes)


@pytest.mark.parametrize("reboot_at", [30, 150])
def test_bridge_reboot_before_or_after_the_wrap_stays_a_reboot(reboot_at):
    ts, reboots, _ = _live_stream(300, reboot_at=reboot_at)
    assert reboots == 1
    assert ts[-1, 1] == 3000 + 20 * (299 - reboot_at)

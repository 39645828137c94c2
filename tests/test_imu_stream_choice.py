"""Which IMU message the bridge takes when the autopilot sends more than one for the same IMU (session 53): the
preferred one only where it comes about as fast, another where it is much faster; a ground station asking the
autopilot for a slow HIGHRES_IMU must not take the bridge off its fast RAW_IMU."""

from __future__ import annotations

import pytest

from tepinn_flight.live import dialect
from tepinn_flight.live.imu_stream import ImuStream
from tepinn_flight.live.messages import Encoder

M = dialect()
ARDUPILOT = 3


def _msg(kind: str, t: float):
    enc = Encoder(1, 1)
    us = int(t * 1e6) + 10_000_000
    if kind == "RAW_IMU":
        m = M.MAVLink_raw_imu_message(us, 0, 0, -1000, 1, 2, 3, 0, 0, 0, 0, 0)
    else:
        m = M.MAVLink_highres_imu_message(us, 0.0, 0.0, -9.8, 0.001, 0.002, 0.003, 0, 0, 0, 0, 0, 0, 25.0, 0x3F, 0)
    return M.MAVLink(None).parse_buffer(enc.pack(m))[0]


def _run(streams, duration_s: float = 10.0):
    """streams: (message, rate_hz, from_s, until_s) each → (samples taken per message, switches, time of each switch)."""
    ev = sorted((t0 + k / hz, name) for name, hz, t0, t1 in streams for k in range(int((min(t1, duration_s) - t0) * hz)))
    imu = ImuStream(0, lambda s: None)
    taken, switches = {"RAW_IMU": 0, "HIGHRES_IMU": 0}, []
    for t, name in ev:
        s, sw = imu.take(_msg(name, t), t, ARDUPILOT, lambda: "ardupilotmega")
        if sw:
            switches.append((round(t, 2), imu.message))
        if s is not None:
            taken[s.message] += 1
    return taken, switches


@pytest.mark.parametrize("hi_hz", [1.0, 5.0, 50.0])
def test_a_slow_preferred_message_does_not_take_over_a_fast_one(hi_hz):
    taken, switches = _run([("RAW_IMU", 200.0, 0.0, 99), ("HIGHRES_IMU", hi_hz, 0.3, 99)])
    assert switches == [] and taken == {"RAW_IMU": 2000, "HIGHRES_IMU": 0}


def test_a_preferred_message_as_fast_takes_over_after_a_second():
    taken, switches = _run([("RAW_IMU", 200.0, 0.0, 99), ("HIGHRES_IMU", 200.0, 2.0, 99)])
    assert len(switches) == 1 and switches[0][1] == "HIGHRES_IMU" and 3.0 <= switches[0][0] <= 3.1
    assert taken["HIGHRES_IMU"] > 1300


def test_a_much_faster_message_takes_over_a_slow_preferred_one():
    _, switches = _run([("HIGHRES_IMU", 2.0, 0.0, 99), ("RAW_IMU", 200.0, 0.5, 99)])
    assert len(switches) == 1 and switches[0][1] == "RAW_IMU" and 1.5 <= switches[0][0] <= 1.6


def test_the_current_message_falling_silent_hands_over_at_once():
    _, switches = _run([("HIGHRES_IMU", 200.0, 0.0, 3.0), ("RAW_IMU", 20.0, 0.0, 99)])
    assert switches == [(4.0, "RAW_IMU")]  # the first RAW_IMU over 1 s after the last HIGHRES_IMU

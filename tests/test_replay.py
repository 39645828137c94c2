"""The vehicle emulator: playback timing from the messages' own clocks (pure), frames unchanged, and
logs other than tlogs sent as an autopilot stream; over loopback UDP with a raw-socket listener."""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before pymavlink (mavlink.md §2)

import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tepinn_flight.live import dialect
from tepinn_flight.live.replay import Frame, TlogFrames, record_stream, schedule
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import write_record
from tepinn_flight.tlog_writer import DEFAULT_BOOT_OFFSET_S, write_tlog

M = dialect()
CLI = [sys.executable, "-m", "tepinn_flight"]


# ---------------------------------------------------------------------------- helpers (also used by test_bridge)
class UdpListener:
    """A ground station that only records datagrams (raw socket: never the bottleneck)."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.datagrams: list[tuple[float, bytes]] = []
        self.peer = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            except OSError:
                return
            self.datagrams.append((time.monotonic(), data))
            self.peer = addr

    def send(self, data: bytes) -> None:
        """Reply to whoever sent to us (a GCS talking back over the same link)."""
        self.sock.sendto(data, self.peer)

    def close(self) -> list[tuple[float, bytes]]:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()
        return self.datagrams

    def messages(self):
        """(arrival, msg) for every good frame, each datagram parsed on its own by pymavlink."""
        out = []
        for t, d in list(self.datagrams):
            rx = M.MAVLink(None)
            rx.robust_parsing = True
            for m in rx.parse_buffer(d) or []:
                assert m.get_type() != "BAD_DATA", m
                out.append((t, m))
        return out


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def tlog_records(path) -> list[tuple[int, bytes]]:
    """(receive µs, frame) of a clean tlog, walked with the header lengths (independent of pymavlink)."""
    data = Path(path).read_bytes()
    out, i = [], 0
    while i < len(data):
        ts = struct.unpack_from(">Q", data, i)[0]
        stx, ln = data[i + 8], data[i + 9]
        hdr = 10 if stx == 0xFD else 6
        sig = 13 if stx == 0xFD and data[i + 10] & 1 else 0
        n = hdr + ln + 2 + sig
        out.append((ts, data[i + 8 : i + 8 + n]))
        i += 8 + n
    return out


def write_records(path, records) -> None:
    path.write_bytes(b"".join(struct.pack(">Q", ts) + fr for ts, fr in records))


def run_cli(*args, timeout=60):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def small_tlog(tmp_path_factory):
    """2 s of a 200 Hz synthetic flight as an ArduPilot-style tlog, receive times made bursty
    (radio-like blocks of 0.25 s, all stamped at the block's end) and junk between records."""
    d = tmp_path_factory.mktemp("replay")
    rec = synthetic_record(seed=1, duration_s=2.0, rate_hz=200.0)
    clean = d / "clean.tlog"
    write_tlog(clean, rec)
    recs = tlog_records(clean)
    t0 = recs[0][0]
    bursty = [(t0 + (((ts - t0) // 250_000) + 1) * 250_000, fr) for ts, fr in recs]
    path = d / "bursty.tlog"
    data = b""
    for k, (ts, fr) in enumerate(bursty):
        data += struct.pack(">Q", ts) + fr
        if k % 97 == 50:
            data += b"\x00\x11garbage\xfe\x03"  # junk between records
    path.write_bytes(data)
    return {"rec": rec, "path": path, "frames": [fr for _, fr in recs], "dir": d}


# ---------------------------------------------------------------------------- schedule (pure)
def _f(rx, t=None):
    return Frame(rx, t, b"")


def test_timed_frames_play_on_their_own_clock_despite_bursty_receive_times():
    own = 100.0 + np.arange(40) * 0.01
    frames = [_f(100.0 + (k // 10) * 0.5, t) for k, t in enumerate(own)]  # 4 bursts
    p = [x for x, _ in schedule(frames)]
    np.testing.assert_allclose(p, own - own[0], atol=1e-12)


def test_untimed_frames_are_interpolated_by_receive_time():
    frames = [_f(10.0, 5.0), _f(10.1), _f(10.3), _f(10.4, 6.0), _f(10.9)]
    p = [x for x, _ in schedule(frames)]
    assert p[0] == 0.0 and p[3] == pytest.approx(1.0)
    assert p[1] == pytest.approx(0.25) and p[2] == pytest.approx(0.75)  # 0.1/0.4 and 0.3/0.4 of the way
    assert p[4] == pytest.approx(1.5)  # after the last timed frame: the receive-time step


def test_reboot_restarts_the_clock_and_a_single_late_frame_does_not():
    t = list(np.arange(20) * 0.1 + 50.0)
    late = [_f(1.0 + k * 0.1, x) for k, x in enumerate(t[:10])]
    late.insert(5, _f(1.45, 40.0))  # one message 10 s late: not a reboot
    late += [_f(2.0 + k * 0.1, x) for k, x in enumerate(t[10:])]
    p = [x for x, _ in schedule(late)]
    assert p[5] == pytest.approx(0.45)  # placed between its neighbours by receive time
    assert np.all(np.diff(p) >= -1e-12) and p[-1] == pytest.approx(1.9)
    boot2 = [_f(10.0 + k * 0.1, 3.0 + k * 0.1) for k in range(20)]  # boot clock restarts at 3 s
    q = [x for x, _ in schedule([*late[:11], *boot2])]
    assert q[11] == pytest.approx(q[10] + 2.0)  # receive gap 4.55 s, capped at max_gap_s = 2
    np.testing.assert_allclose(np.diff(q[11:]), 0.1, atol=1e-9)


def test_gaps_are_shortened_and_spikes_ignored():
    a = [_f(k * 0.1, 1.0 + k * 0.1) for k in range(10)]
    b = [_f(60.0 + k * 0.1, 60.0 + k * 0.1) for k in range(12)]  # 59 s logging pause
    p = [x for x, _ in schedule(a + b)]
    assert p[10] - p[9] == pytest.approx(2.0)
    np.testing.assert_allclose(np.diff(p[10:]), 0.1, atol=1e-9)
    spike = [*a[:5], _f(0.45, 5000.0), *a[5:]]  # a corrupt time field far ahead
    s = [x for x, _ in schedule(spike)]
    assert s[5] == pytest.approx(0.45) and s[-1] == pytest.approx(0.9)


# ---------------------------------------------------------------------------- tlog frames and timing
def test_tlog_frames_are_the_written_bytes_and_play_on_the_own_clock(small_tlog):
    frames = TlogFrames(small_tlog["path"])
    got = list(schedule(frames))
    assert [f.buf for _, f in got] == small_tlog["frames"]  # every frame, unchanged, in order, junk skipped
    assert frames.sysid == 1
    t0 = None
    for p, f in got:
        rx = M.MAVLink(None)
        (m,) = rx.parse_buffer(f.buf)
        if m.get_type() == "HIGHRES_IMU":
            t0 = m.time_usec / 1e6 - p if t0 is None else t0
            assert m.time_usec / 1e6 - p == pytest.approx(t0, abs=1e-9)  # timing = own time, not receive time


def test_replay_cli_over_udp_keeps_frames_and_timing(small_tlog):
    lis = UdpListener()
    try:
        r = run_cli("replay", small_tlog["path"], "--to", f"udpout:127.0.0.1:{lis.port}", "--speed", "2")
        time.sleep(0.2)
    finally:
        lis.close()
    assert r.returncode == 0, r.stderr
    assert "replayed" in r.stdout
    assert [d for _, d in lis.datagrams] == small_tlog["frames"]  # one datagram per frame, bytes unchanged
    t_arr, t_own = [], []
    for t, m in lis.messages():
        if m.get_type() == "HIGHRES_IMU":
            t_arr.append(t)
            t_own.append(m.time_usec / 1e6)
    t_arr, t_own = np.array(t_arr), np.array(t_own)
    slope, icpt = np.polyfit(t_own, t_arr, 1)
    assert slope == pytest.approx(0.5, abs=0.02)  # --speed 2: half the own-clock time
    lag = t_arr - (icpt + 0.5 * t_own)
    assert np.percentile(np.abs(lag), 90) < 0.02  # bursty receive times did not leak into the timing


# ---------------------------------------------------------------------------- records as an autopilot
def _decode_all(frames):
    rx = M.MAVLink(None)
    out = []
    for fr in frames:
        out += rx.parse_buffer(fr) or []
    return out


@pytest.mark.parametrize("imu", ["highres", "scaled"])
def test_record_stream_is_an_autopilot(imu):
    rec = synthetic_record(seed=2, duration_s=2.5, rate_hz=200.0)
    items = list(record_stream(rec, imu_message=imu))
    msgs = _decode_all([fr for _, fr in items])
    assert all((m.get_srcSystem(), m.get_srcComponent()) == (1, 1) for m in msgs)
    assert [m.get_seq() for m in msgs] == [k % 256 for k in range(len(msgs))]
    by = {}
    for (p, _), m in zip(items, msgs):
        by.setdefault(m.get_type(), []).append((p, m))
    t = rec.t_s
    imu_name = "HIGHRES_IMU" if imu == "highres" else "SCALED_IMU"
    assert len(by[imu_name]) == len(t)
    assert len(by["HEARTBEAT"]) == 3  # boot 10.0, 11.0, 12.0 s
    assert len(by["ATTITUDE"]) == len(by["ATTITUDE_QUATERNION"]) == 125  # 50 Hz of a 200 Hz record
    for k, (p, m) in enumerate(by[imu_name]):
        assert p == pytest.approx(t[k] - t[0])
        if imu == "highres":
            assert m.time_usec == round((t[k] - t[0] + DEFAULT_BOOT_OFFSET_S) * 1e6)
            np.testing.assert_allclose([m.xgyro, m.ygyro, m.zgyro], rec.gyr_rad_s[k], rtol=1e-6, atol=1e-7)
            np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], rec.acc_m_s2[k], rtol=1e-6, atol=1e-6)
        else:
            np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], rec.acc_m_s2[k] * 1000 / 9.80665, atol=0.5 + 1e-9)
    q_ref = rec.q_ref_wxyz
    for p, m in by["ATTITUDE_QUATERNION"]:
        k = int(round(p * 200))
        np.testing.assert_allclose([m.q1, m.q2, m.q3, m.q4], q_ref[k], atol=1e-6)
        assert m.time_boot_ms == round((t[k] - t[0] + DEFAULT_BOOT_OFFSET_S) * 1e3)


def test_replay_cli_plays_a_flight_record_and_loops(tmp_path):
    rec = synthetic_record(seed=3, duration_s=0.5, rate_hz=100.0)
    path = tmp_path / "flight.parquet"
    write_record(rec, path)
    lis = UdpListener()
    try:
        r = run_cli("replay", path, "--to", f"udpout:127.0.0.1:{lis.port}", "--speed", "4", "--loop", "--duration", "0.9")
        time.sleep(0.1)
    finally:
        lis.close()
    assert r.returncode == 0, r.stderr
    us = [m.time_usec for _, m in lis.messages() if m.get_type() == "HIGHRES_IMU"]
    backs = int(np.sum(np.diff(us) < 0))
    assert backs >= 3  # 0.5 s of log at 4x, looped for 0.9 s: the boot clock restarts each pass
    assert len(us) >= 150


def test_replay_cli_errors_are_one_line(tmp_path, small_tlog):
    for args, words in [
        (("replay", small_tlog["path"], "--to", "udp:127.0.0.1:14550"), "udpin"),
        (("replay", tmp_path / "missing.tlog", "--to", "udpout:127.0.0.1:14550"), "no such file"),
        (("replay", small_tlog["path"], "--to", "udpout:127.0.0.1:14550", "--speed", "0"), "speed"),
    ]:
        r = run_cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and words in lines[0] and "Traceback" not in r.stderr, r.stderr


def test_a_dataflash_log_is_replayed_on_its_own_clock_and_its_attitude_through_the_jitter():
    """`replay erle.BIN` stamped its IMU 10 s after an invented boot (the log's first IMU is TimeMS 51686), so live
    output could not be laid over the log; and fixed 20-ms ticks dropped some of its 50-Hz ATT (stamps step 18–21 ms).
    Now the boot clock is the log's, every IMU sample checked against pymavlink's TimeMS, and every reference sample
    goes out as ATTITUDE."""
    from pymavlink import mavutil

    from tests.conftest import real_log
    from tepinn_flight.live.replay import load_source

    path = real_log("erle_pxf_copter_15-12-2014_16.BIN")
    kind, make, rec = load_source(path)
    mav = dialect().MAVLink(None)
    imu_us, att = [], 0
    for _, fr in make():
        m = mav.parse_char(fr)
        if m.get_type() == "HIGHRES_IMU":
            imu_us.append(m.time_usec)
        elif m.get_type() == "ATTITUDE":
            att += 1
    conn = mavutil.mavlink_connection(str(path))
    want = []
    while (m := conn.recv_match(type="IMU")) is not None:
        want.append(m.TimeMS * 1000)
    got = np.array(imu_us)
    assert got[0] == want[0] == 51686000
    assert np.isin(got, np.array(want)).all()  # each sample on the log's own clock
    assert att == int(np.all(np.isfinite(rec.q_ref_wxyz), axis=1).sum())  # a 50 Hz reference: every sample

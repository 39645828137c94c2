"""The vehicle emulator: a log played back as the live MAVLink 2 stream of an autopilot.

**tlogs** are played frame by frame, unchanged (ids, sequence numbers, signatures), in file order,
with the timing of the messages' *own* clocks (``time_boot_ms``, and ``time_usec`` where it is a
uint64 boot time) of the autopilot (the component 1 whose HEARTBEAT names a real autopilot).
The tlog's receive timestamps (bursty, compressed in SITL) only place frames that carry no time
field (HEARTBEAT, AHRS*, VFR_HUD, other components): linearly between the neighbouring timed
frames by receive time. :func:`schedule` turns frames into playback times:

* a timed frame more than ``backstep_s`` before the clock is a **reboot** when the next
  ``confirm`` timed frames stay back too (the clock restarts, playback goes on at once), else a
  single late frame (placed as if untimed);
* a jump forward by more than ``max_gap_s`` is a **gap** (logging paused) when the next frames
  continue after it: playback waits ``max_gap_s`` at most; a lone frame far ahead is placed as
  untimed.

**DataFlash, ULog, BROAD and flight records** are ingested into a flight record, then sent as an
autopilot would (sysid 1, compid 1): HEARTBEAT at 1 Hz, the IMU at its logged rate as
HIGHRES_IMU (rad/s, m/s², gauss) or SCALED_IMU (mrad/s, mG, mGauss), and ATTITUDE plus
ATTITUDE_QUATERNION from the reference at about 50 Hz, stamped with a boot clock: the log's own for a
DataFlash, ULog or MAVLink log or a BROAD trial (``log_clock.boot_time_at_start_s``; a log of several boots from its
first boot's clock, on across them), else one that starts ``boot_offset_s`` before the record.
"""

from __future__ import annotations

import math
import os
import select
import time
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from ..errors import CorruptLog, NoImuData
from ..rate_thinning import due_at_rate
from ..vehicle_class import mav_type_suffix
from . import MAV_COMP_ID_AUTOPILOT1, mavutil
from .messages import (
    Encoder,
    attitude_msg,
    attitude_quaternion_msg,
    heartbeat_autopilot_msg,
    highres_imu_msg,
    scaled_imu_msg,
)
from .status import latency_histogram

BACKSTEP_S = 1.0
MAX_GAP_S = 2.0
CONFIRM = 8
ATTITUDE_RATE_HZ = 50.0
BOOT_OFFSET_S = 10.0
MAV_AUTOPILOT_INVALID = 8


@dataclass(frozen=True)
class Frame:
    rx_s: float  # tlog receive time, s
    t_own: float | None  # the autopilot's own time of this message, s (None: no usable time field)
    buf: bytes  # the frame, unchanged


# ---------------------------------------------------------------------------- tlog frames
def _own_times(fields: np.ndarray) -> np.ndarray | None:
    """Own boot-clock times (s, NaN where unusable) from a message's decoded fields, or None."""
    names = fields.dtype.names or ()
    if "time_boot_ms" in names:
        ms = fields["time_boot_ms"].astype(np.float64)
        return np.where(ms > 0, ms / 1e3, np.nan)
    if "time_usec" in names and fields.dtype["time_usec"] == np.dtype("<u8"):
        us = fields["time_usec"].astype(np.float64)  # uint32 time_usec (SERVO_OUTPUT_RAW) wraps: not used
        return np.where((us > 0) & (us < 1e15), us / 1e6, np.nan)  # above 1e15: UNIX time
    return None


def _autopilot_sysid(scan) -> int | None:
    """The component-1 HEARTBEATs naming a real autopilot (as the tlog reader picks it)."""
    hb = scan.frames["HEARTBEAT"]
    real = (hb.compid == MAV_COMP_ID_AUTOPILOT1) & (hb.fields["autopilot"] != MAV_AUTOPILOT_INVALID)
    if np.any(real):
        ids, counts = np.unique(hb.sysid[real], return_counts=True)
        return int(ids[np.argmax(counts)])
    c1 = {s: n for (s, c), n in scan.sources.items() if c == MAV_COMP_ID_AUTOPILOT1}
    return max(c1, key=lambda s: (c1[s], -s)) if c1 else None


class TlogFrames:
    """The good frames of a tlog in file order, with their receive times and own times.

    Frames are found by the project's vectorised, CRC-checking walker
    (:func:`~tepinn_flight.ingest.mavlink_scan.scan_tlog`, every message of the dialect), which
    resyncs after junk without losing the frames around it (pymavlink's sequential readers drop
    frames next to junk, and ``mavmmaplog`` can merge the first frames). Frames of message ids
    unknown to the dialect (no CRC check possible) and CRC failures are skipped and counted.
    """

    def __init__(self, path):
        from ..ingest.mavlink_scan import dialect as scan_dialect  # noqa: PLC0415
        from ..ingest.mavlink_scan import scan_tlog  # noqa: PLC0415

        self.path = str(path)
        names = sorted({cls.msgname for cls in scan_dialect().mavlink_map.values()})
        try:
            scan = scan_tlog(self.path, names)
        except OSError as exc:
            raise CorruptLog(f"cannot read the tlog ({exc.strerror or exc})", path) from None
        self.sysid = _autopilot_sysid(scan)
        self.bad = int(scan.corrupt_frames)
        self.unknown = int(scan.unknown_frames)
        self.junk_bytes = int(scan.junk_bytes)
        offs, times = [], []
        for fr in scan.frames.values():
            if len(fr.offset) == 0:
                continue
            t = _own_times(fr.fields)
            if t is None:
                t = np.full(len(fr.offset), np.nan)
            else:
                t[(fr.sysid != self.sysid) | (fr.compid != MAV_COMP_ID_AUTOPILOT1)] = np.nan
            offs.append(fr.offset)
            times.append(t)
        if offs:
            off = np.concatenate(offs)
            order = np.argsort(off, kind="stable")
            self.offsets = off[order]
            self.t_own = np.concatenate(times)[order]
        else:
            self.offsets = np.zeros(0, np.int64)
            self.t_own = np.zeros(0)
        self.count = len(self.offsets)

    def __iter__(self) -> Iterator[Frame]:
        import mmap  # noqa: PLC0415

        with open(self.path, "rb") as f:
            if self.count == 0:
                return
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            try:
                for off, t in zip(self.offsets.tolist(), self.t_own.tolist()):
                    rx = int.from_bytes(data[off : off + 8], "big") / 1e6
                    a = off + 8
                    if data[a] == 0xFD:
                        n = 10 + data[a + 1] + 2 + (13 if data[a + 2] & 1 else 0)
                    else:
                        n = 6 + data[a + 1] + 2
                    yield Frame(rx, None if t != t else t, bytes(data[a : a + n]))
            finally:
                data.close()


# ---------------------------------------------------------------------------- timing
def schedule(frames: Iterable[Frame], backstep_s: float = BACKSTEP_S, max_gap_s: float = MAX_GAP_S,
             confirm: int = CONFIRM) -> Iterator[tuple[float, Frame]]:  # fmt: skip
    """(playback time in s at speed 1, frame) for every frame, in file order (see the module doc)."""
    it = iter(frames)
    buf: deque = deque()
    timed_in_buf = 0
    eof = False
    p_a = t_a = tmax = None  # anchor (playback, own time) and the latest accepted own time
    last = None  # (playback time, rx) of the latest placed timed frame
    p_last = 0.0

    def fill():
        nonlocal timed_in_buf, eof
        while not eof and timed_in_buf < confirm + 1:
            try:
                f = next(it)
            except StopIteration:
                eof = True
                return
            buf.append(f)
            timed_in_buf += f.t_own is not None

    def upcoming(n):
        out = []
        for g in buf:
            if g.t_own is not None:
                out.append(g.t_own)
                if len(out) == n:
                    break
        return out

    while True:
        fill()
        if not buf:
            return
        f = buf.popleft()
        timed_in_buf -= f.t_own is not None
        ok = False
        if f.t_own is not None:
            t = f.t_own
            if tmax is None:
                p_a, t_a, tmax, ok = p_last, t, t, True
            elif t < tmax - backstep_s:
                if all(u < tmax - backstep_s for u in upcoming(confirm)):  # a reboot: restart the clock
                    gap = 0.0 if last is None else min(max(f.rx_s - last[1], 0.0), max_gap_s)
                    p_a, t_a, tmax, ok = p_last + gap, t, t, True
            elif t > tmax + max_gap_s:
                if all(u >= t - backstep_s for u in upcoming(confirm)):  # a gap: wait max_gap_s at most
                    p_a, t_a = p_a + (tmax - t_a) + max_gap_s, t
                    tmax, ok = t, True
            else:
                tmax, ok = max(tmax, t), True
        if ok:
            p = p_a + (f.t_own - t_a)
            last = (p, f.rx_s)
        elif last is None:
            p = p_last
        else:
            nxt = None
            for g in buf:
                if g.t_own is not None and tmax - backstep_s <= g.t_own <= tmax + max_gap_s:
                    nxt = g
                    break
            p0, r0 = last
            if nxt is not None:
                p1 = p_a + (nxt.t_own - t_a)
                span = nxt.rx_s - r0
                u = (f.rx_s - r0) / span if span > 0 else 0.0
                p = p0 + min(max(u, 0.0), 1.0) * max(p1 - p0, 0.0)
            else:
                p = p0 + min(max(f.rx_s - r0, 0.0), max_gap_s)
        p_last = max(p_last, p)
        yield p, f


# ---------------------------------------------------------------------------- records as a stream
_AUTOPILOTS = {"ardupilot": "ARDUPILOTMEGA", "px4": "PX4"}


def record_stream(rec, imu_message: str = "highres", attitude_rate_hz: float = ATTITUDE_RATE_HZ,
                  boot_offset_s: float = BOOT_OFFSET_S, max_gap_s: float = MAX_GAP_S,
                  sysid: int = 1) -> Iterator[tuple[float, bytes]]:  # fmt: skip
    """(playback time, frame) of a flight record sent as an autopilot (see the module doc)."""
    from ..record import GYR_BIAS_COLS  # noqa: PLC0415

    m = mavutil().mavlink
    t = rec.t_s
    n = len(t)
    if n == 0:
        raise NoImuData("the record has no IMU samples")
    if imu_message not in ("highres", "scaled"):
        raise ValueError(imu_message)
    gyr, acc, mag, q = rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut, rec.q_ref_wxyz
    rates = gyr - rec.data[GYR_BIAS_COLS].to_numpy(float) if all(c in rec.data for c in GYR_BIAS_COLS) else gyr
    has_q = np.all(np.isfinite(q), axis=1)
    has_mag = np.all(np.isfinite(mag), axis=1)
    mav_type = getattr(m, "MAV_TYPE_" + mav_type_suffix(rec.meta.get("vehicle_type")))
    autopilot = getattr(m, "MAV_AUTOPILOT_" + _AUTOPILOTS.get(str(rec.meta.get("autopilot", "")).lower(), "GENERIC"))
    enc = Encoder(sysid, MAV_COMP_ID_AUTOPILOT1)
    t0 = float(t[0])
    boot = t - t0 + boot_offset_s
    att_due = due_at_rate(t, attitude_rate_hz, has_q)  # (fixed ticks lost a jittery 50 Hz log's samples)
    p = 0.0
    hb_k = None
    for i in range(n):
        if i:
            dt = float(t[i] - t[i - 1])
            p += min(max(dt, 0.0), max_gap_s)
        b = float(boot[i])
        frames = []
        k = math.floor(b + 1e-9)
        if k != hb_k:
            hb_k = k
            frames.append(enc.pack(heartbeat_autopilot_msg(mav_type, autopilot)))
        mg = mag[i] if has_mag[i] else None
        if imu_message == "highres":
            frames.append(enc.pack(highres_imu_msg(int(round(b * 1e6)), gyr[i], acc[i], mg)))
        else:
            frames.append(enc.pack(scaled_imu_msg(int(round(b * 1e3)), gyr[i], acc[i], mg)))
        if att_due[i]:
            ms = int(round(b * 1e3))
            frames.append(enc.pack(attitude_msg(ms, q[i], rates[i])))
            frames.append(enc.pack(attitude_quaternion_msg(ms, q[i], rates[i])))
        for fr in frames:
            yield p, fr


def load_source(path, imu_message: str = "highres"):
    """(kind, factory of a fresh (playback time, frame) iterator, description) for any log."""
    from ..ingest import load_record  # noqa: PLC0415
    from ..ingest.sniff import sniff  # noqa: PLC0415
    from ..log_clock import boot_time_at_start_s  # noqa: PLC0415

    fmt = sniff(path)
    if fmt == "tlog":
        frames = TlogFrames(path)
        if frames.sysid is None:
            raise CorruptLog("no MAVLink frames from an autopilot (component 1) in the tlog", path)

        def make():
            return ((p, f.buf) for p, f in schedule(frames))

        return "tlog", make, frames
    rec = load_record(path)

    boot = boot_time_at_start_s(rec.t_s, rec.meta)  # a DataFlash or ULog log played on its own clock

    def make():
        return record_stream(rec, imu_message=imu_message, boot_offset_s=BOOT_OFFSET_S if boot is None else boot)

    return fmt, make, rec


# ---------------------------------------------------------------------------- the player
class ViewTap:
    """Feeds a :class:`~tepinn_flight.live.view.LiveView` from the played stream: the autopilot's
    attitude (ATTITUDE_QUATERNION, else ATTITUDE, of system ``sysid`` component 1) from the frames
    sent, TE-PINN's from what a bridge sends back (``bridge --estimates-to-master``)."""

    _ATTITUDE_IDS = (30, 31)  # ATTITUDE, ATTITUDE_QUATERNION

    def __init__(self, view, sysid: int | None):
        from .inputs import EstimateDecoder  # noqa: PLC0415

        self.view = view
        self.sysid = sysid
        self.parser = mavutil().mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.estimates = EstimateDecoder(MAV_COMP_ID_AUTOPILOT1)
        self.last_ekf_t: float | None = None

    def sent(self, frame: bytes) -> None:
        from .inputs import ekf_attitude  # noqa: PLC0415

        v2 = frame[0] == 0xFD
        msgid = int.from_bytes(frame[7:10], "little") if v2 else frame[5]
        src = (frame[5], frame[6]) if v2 else (frame[3], frame[4])
        if msgid not in self._ATTITUDE_IDS or src != (self.sysid, MAV_COMP_ID_AUTOPILOT1):
            return
        for m in self.parser.parse_buffer(frame) or []:
            a = ekf_attitude(m) if m.get_type() != "BAD_DATA" else None
            if a is None:
                continue
            t = a[0]
            if self.last_ekf_t is not None and self.last_ekf_t - 1.0 <= t <= self.last_ekf_t:
                continue  # the same attitude as the other message, or a stale one
            self.last_ekf_t = t
            self.view.ekf(t, a[2])

    def received(self, msg) -> None:
        got = self.estimates.add(msg)
        if got is not None:
            self.view.estimate(*got)


class Player:
    """Sends (playback time, frame) items at ``speed`` × real time to a link; counts replies.
    ``tap`` (a :class:`ViewTap`) sees every frame sent and every message received."""

    def __init__(self, link, speed: float = 1.0, clock=time.monotonic, tap=None):
        if not speed > 0:
            raise ValueError("speed must be > 0")
        self.link = link
        self.speed = speed
        self.clock = clock
        self.tap = tap
        self.sent = 0
        self.late = latency_histogram()
        self.received: dict[str, int] = {}
        self.played_s = 0.0

    def _drain(self) -> None:
        while True:
            data = self.link.read()
            if not data:
                return
            for m in self.link.parse(data):
                k = m.get_type()
                self.received[k] = self.received.get(k, 0) + 1
                if self.tap is not None:
                    self.tap.received(m)

    def _wait(self, until: float, stop) -> bool:
        while True:
            if stop is not None and stop.is_set():
                return False
            d = until - self.clock()
            if d <= 0:
                return True
            step = min(d, 0.1)
            fd = self.link.fileno()  # (each time: a read below may find the peer gone and close the link)
            if fd is not None:
                r, _, _ = select.select([fd], [], [], step)
                if r:
                    self._drain()
            else:
                time.sleep(step)

    def play(self, items: Iterable[tuple[float, bytes]], stop=None, deadline: float | None = None) -> bool:
        """Play until the items end (True) or ``stop``/``deadline`` (False)."""
        w0 = self.clock()
        p0 = None
        batch: list[bytes] = []
        due = None
        for p, fr in items:
            if p0 is None:
                p0 = p
            d = w0 + (p - p0) / self.speed
            if due is not None and d > due + 1e-6:
                if not self._flush(batch, due, stop, deadline):
                    return False
                batch = []
            if not batch:
                due = d
            batch.append(fr)
            self.played_s = max(self.played_s, p - p0)
        if batch and not self._flush(batch, due, stop, deadline):
            return False
        return True

    def _flush(self, batch, due, stop, deadline) -> bool:
        if deadline is not None and due > deadline:
            self._wait(deadline, stop)
            return False
        if not self._wait(due, stop):
            return False
        for fr in batch:  # one datagram per frame, as an autopilot sends them
            self.link.write(fr)
        if self.tap is not None:
            for fr in batch:
                self.tap.sent(fr)
        self.sent += len(batch)
        self.late.add(max(0.0, self.clock() - due))
        return True


def replay(path, to: str, speed: float = 1.0, loop: bool = False, imu_message: str = "highres",
           duration_s: float | None = None, stop=None, on_open=None, view=None) -> dict:  # fmt: skip
    """Play ``path`` to the endpoint ``to``; returns counts and timing figures. ``view`` (a
    :class:`~tepinn_flight.live.view.ViewConfig`): draw the autopilot's attitude and the estimates
    coming back in Rerun (``--view``/``--rrd``)."""
    from .router import Link  # noqa: PLC0415
    from .view import open_view  # noqa: PLC0415

    kind, make, src = load_source(path, imu_message)
    live_view = open_view(view) if view is not None else None
    try:
        link = Link(to, "--to")
    except BaseException:
        if live_view is not None:
            live_view.discard()
        raise
    if on_open is not None:
        on_open(link)
    tap = ViewTap(live_view, src.sysid if kind == "tlog" else 1) if live_view is not None else None
    player = Player(link, speed, tap=tap)
    t0 = time.monotonic()
    deadline = None if duration_s is None else t0 + duration_s
    loops = 0
    try:
        while True:
            done = player.play(make(), stop=stop, deadline=deadline)
            loops += 1
            if not done or not loop:
                break
            time.sleep(0.05)
    finally:
        link.close()
        if live_view is not None:
            live_view.close()
    out = {
        "source": os.fspath(path),
        "kind": kind,
        "messages_sent": player.sent,
        "loops": loops,
        "wall_s": round(time.monotonic() - t0, 3),
        "log_s": round(player.played_s, 3),
        "lateness_ms": player.late.summary(1e3, 3),
        "received": dict(sorted(player.received.items())),
    }
    if kind == "tlog":
        out["skipped"] = {"crc_failed_frames": src.bad, "unknown_id_frames": src.unknown, "junk_bytes": src.junk_bytes}
    return out

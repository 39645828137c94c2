"""The autopilot's IMU stream as the bridge takes it: which message, in what order, at what rate.

* **which**: IMU messages become samples (:func:`~tepinn_flight.live.inputs.imu_sample`) of one
  instance (``--imu``), HIGHRES_IMU preferred, then RAW_IMU, then SCALED_IMU; a message of unknown
  scale (RAW_IMU of a non-ArduPilot autopilot) is refused, once said. The first message taken stays
  until another has come for :data:`SWITCH_AFTER_S` at a rate that earns it — a preferred one at
  ≥ :data:`PREFERRED_RATE_SHARE` of the current one's rate, any other at ≥ :data:`FASTER_RATE_FACTOR` × it
  (session 53: a ground station asking for a 1-Hz HIGHRES_IMU had taken the bridge off a 200-Hz RAW_IMU) —
  or the current one is silent for 1 s. A switch restarts the message's clock and asks for an estimator
  reset.
* **clock**: ArduPilot's ``RAW_IMU.time_usec`` is a 32-bit µs count that wraps 71.6 min after boot; the
  sample takes the wrap count that puts it at the autopilot's boot clock of its moment
  (:mod:`tepinn_flight.ingest.clock_wrap`, as the tlog reader), so a long flight is not taken for a reboot.
* **order**: samples whose own time is not newer than the newest one taken (duplicates, stale
  copies from a redundant link, reordered UDP) are dropped here (they were forwarded already) and
  counted; a reboot is told apart by :class:`~tepinn_flight.live.sample_order.SampleOrder`.
* **rate**: when the autopilot has been seen for ``request_grace_s`` and its IMU stream is below
  ``min_imu_rate_hz``, :class:`ImuRateRequests` asks for ``request_imu_rate_hz`` with
  ``MAV_CMD_SET_MESSAGE_INTERVAL`` (up to 3 times, ``request_spacing_s`` apart) and says so, with a
  warning if it did not help; the estimates are withheld only below 20 Hz (:class:`ImuRateRequests`).
"""

from __future__ import annotations

import dataclasses

from ..ingest.clock_wrap import top_to_bottom, wrap_count
from ..ingest.streams import PREFER_FACTOR
from ..ingest.tlog import MAV_AUTOPILOT_ARDUPILOTMEGA
from ..record import MIN_ESTIMATION_RATE_HZ
from . import MAV_COMP_ID_AUTOPILOT1
from .inputs import ImuSample, imu_preference, imu_sample, imu_scale_known
from .messages import set_message_interval_msg
from .sample_order import DUPLICATE, REBOOT, STALE, SampleOrder
from .status import RateMeter

MAV_CMD_SET_MESSAGE_INTERVAL = 511
REQUEST_ATTEMPTS = 3
#: an IMU counts as slow below (1 − this) × ``min_imu_rate_hz`` (the rate meter's count over its window jitters)
RATE_ALLOWANCE = 0.1
#: the IMU messages the bridge reads
IMU_NAMES = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
#: another IMU message is weighed against the current one after coming this long (s) ...
SWITCH_AFTER_S = 1.0
#: ... a preferred one taken at this share of the current one's rate or more ...
PREFERRED_RATE_SHARE = 0.8
#: ... a less preferred one at this many times it (the readers' rule offline: ingest/streams.py)
FASTER_RATE_FACTOR = PREFER_FACTOR


class ImuStream:
    def __init__(self, instance: int, note):
        self.instance = instance
        self.note = note
        self.message: str | None = None
        self.seen: dict[str, float] = {}
        self.meters: dict[str, RateMeter] = {}  # each message's own rate (which one to take)
        self.rate = RateMeter(2.0)
        self.samples = 0
        self.last_t = None
        self.span = 0.0
        self.intervals = 0
        self.time_jumps = 0
        self.order = SampleOrder()  # duplicates / out-of-order frames dropped, reboots told apart
        self.unknown_scale_noted = False
        self.wraps = 0  # RAW_IMU's 32-bit time_usec: the wraps counted so far (clock_wrap)
        self.wraps_noted = 0
        self.raw_prev_t = None  # the last RAW_IMU time_usec as sent (s), for a wrap read without a boot clock

    def take(self, m, t_in: float, autopilot: int | None, autopilot_name,
             boot_ms_now: int | None = None) -> tuple[ImuSample | None, bool]:  # fmt: skip
        """(the sample for the estimator or None, whether the stream switched to another message:
        the estimator must then be reset before the sample). ``boot_ms_now``: the autopilot's boot clock (ms)
        at ``t_in`` where its other messages gave one (:meth:`AutopilotTracker.boot_ms_at`), which RAW_IMU's
        32-bit clock is unwrapped against."""
        name = m.get_type()
        if not imu_scale_known(name, autopilot):
            if not self.unknown_scale_noted:
                self.unknown_scale_noted = True
                self.note(f"tepinn-flight bridge: {name} from a {autopilot_name()} autopilot has an unknown "
                          "scale (raw counts?): ignored")  # fmt: skip
            return None, False
        s = imu_sample(m, autopilot)
        if s is None or s.instance != self.instance:
            return None, False
        if s.message == "RAW_IMU" and s.time_boot_ms is not None:
            s = self._unwrapped(s, boot_ms_now)
        self.seen[s.message] = t_in
        self.meters.setdefault(s.message, RateMeter(2.0)).tick(t_in)
        cur = self.message
        switched = False
        if cur != s.message and (cur is None or t_in - self.seen.get(cur, -1e9) > 1.0 or self._earns(s.message, t_in)):
            self.message = s.message
            switched = cur is not None
            self.last_t = None
            self.order.reset()  # another message: its own clock
        if s.message != self.message:
            return None, switched
        verdict = self.order.accept(s.t_s, t_in)
        if verdict in (DUPLICATE, STALE):
            return None, switched  # forwarded already; never to the estimator (it would reset on the time reversal)
        if verdict == REBOOT:
            self.note(f"tepinn-flight bridge: {s.message} clock restarted at {s.t_s:.3f} s "
                      "(autopilot reboot?): estimator reset")  # fmt: skip
        self.rate.tick(t_in)
        self.samples += 1
        if self.last_t is not None:
            dt = s.t_s - self.last_t
            if 0 < dt <= 1.0:
                self.span += dt
                self.intervals += 1
            else:
                self.time_jumps += 1
        self.last_t = s.t_s
        return s, switched

    def _earns(self, name: str, t_in: float) -> bool:
        """Whether message ``name``, not the current one, has come long and fast enough to take its place."""
        m = self.meters[name]
        if t_in - m.first < SWITCH_AFTER_S:
            return False
        r, r_cur = m.rate(t_in), self.meters[self.message].rate(t_in)
        if imu_preference(name) < imu_preference(self.message):
            return r >= PREFERRED_RATE_SHARE * r_cur
        return r >= FASTER_RATE_FACTOR * r_cur

    def _unwrapped(self, s: ImuSample, boot_ms_now: int | None) -> ImuSample:
        """``s`` on a running clock: its 32-bit ``time_usec`` plus the wraps counted (a new count where the
        autopilot's boot clock, or the stream alone without one, shows a wrap)."""
        k = wrap_count(s.t_s, boot_ms_now / 1e3) if boot_ms_now is not None else -1
        if k >= 0:
            self.wraps = k
        elif boot_ms_now is None and self.raw_prev_t is not None and top_to_bottom(self.raw_prev_t, s.t_s):
            self.wraps += 1
        self.raw_prev_t = s.t_s
        if self.wraps > self.wraps_noted:
            self.wraps_noted = self.wraps
            self.note(f"tepinn-flight bridge: RAW_IMU time_usec wrapped at 2^32 µs (ArduPilot's 32-bit clock, "
                      f"{self.wraps} time(s)): unwrapped")  # fmt: skip
        if self.wraps == 0:
            return s
        us = s.time_usec + (self.wraps << 32)
        return dataclasses.replace(s, t_s=us / 1e6, time_usec=us, time_boot_ms=us // 1000)

    def summary(self) -> dict:
        return {
            "message": self.message,
            "rate_hz": round(self.intervals / self.span, 2) if self.span > 0 else None,
            "samples": self.samples,
            "time_jumps": self.time_jumps,
            "duplicates": self.order.counts[DUPLICATE],
            "out_of_order": self.order.counts[STALE],
            "reboots": self.order.counts[REBOOT],
        }


class ImuRateRequests:
    """Asks a slow autopilot for a faster IMU stream; ``warning`` when it was not granted, ``withhold`` when the
    stream is then too slow to estimate from at all.

    The IMU is slow when its rate stays under ``min_rate_hz`` (less :data:`RATE_ALLOWANCE`: a 50-Hz IMU counted over
    the meter's window reads 43–49.5 Hz) for ``slow_for_s`` (a stream that stops is not a slow one). Estimates are
    withheld only below :data:`~tepinn_flight.record.MIN_ESTIMATION_RATE_HZ` (20 Hz), the rate below which a log is
    too slow offline too; between that and ``min_rate_hz`` the bridge asks, warns if not granted, and estimates on
    (a 25-Hz ArduSub IMU; the network's gates stay shut below the rates it learned)."""

    def __init__(self, min_rate_hz: float, request_rate_hz: float, grace_s: float, spacing_s: float, note,
                 slow_for_s: float = 2.0):  # fmt: skip
        self.slow_for_s = slow_for_s
        self.min_rate_hz = min_rate_hz
        self.request_rate_hz = request_rate_hz
        self.grace_s = grace_s
        self.spacing_s = spacing_s
        self.note = note
        self.attempts = 0
        self.next_at = 0.0
        self.msg = None
        self.ack = None
        self.warning = None
        self.withhold = False
        self.slow_since = None

    def check(self, now: float, ap, imu_rate: RateMeter, send) -> None:
        """``ap``: the :class:`~tepinn_flight.live.autopilot.AutopilotTracker`; ``imu_rate``: the IMU
        stream's rate meter; ``send(msg)``: to the autopilot."""
        if ap.enc is None or ap.lost or ap.first_seen is None or self.min_rate_hz <= 0:
            return
        if now - ap.first_seen < self.grace_s or now - ap.last_seen > 1.0:
            self.slow_since = None
            return  # too early to judge, or the autopilot itself is silent
        rate = imu_rate.rate(now)
        if rate >= (1.0 - RATE_ALLOWANCE) * self.min_rate_hz:
            self.slow_since = None
            if self.warning:
                self.note(f"tepinn-flight bridge: IMU now at {rate:.0f} Hz")
                self.warning = None
                self.withhold = False
            return
        if self.slow_since is None:
            self.slow_since = now
        if now - self.slow_since < self.slow_for_s or now < self.next_at:
            return
        if self.attempts < REQUEST_ATTEMPTS:
            name = "RAW_IMU" if ap.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else "HIGHRES_IMU"
            self.msg = name
            send(set_message_interval_msg(ap.sysid, MAV_COMP_ID_AUTOPILOT1, getattr(ap.m, f"MAVLINK_MSG_ID_{name}"),
                                          self.request_rate_hz))  # fmt: skip
            self.attempts += 1
            self.next_at = now + self.spacing_s
            self.note(f"tepinn-flight bridge: IMU at {rate:.1f} Hz (< {self.min_rate_hz:.0f} Hz): asking the "
                      f"autopilot for {name} at {self.request_rate_hz:.0f} Hz (MAV_CMD_SET_MESSAGE_INTERVAL, "
                      f"attempt {self.attempts})")  # fmt: skip
        elif self.warning is None:
            ack = f"ack: {self.ack}" if self.ack else "no COMMAND_ACK"
            self.withhold = self._too_slow(rate)
            then = (f"estimates withheld: they need >= {MIN_ESTIMATION_RATE_HZ:.0f} Hz" if self.withhold else
                    f"estimating at this rate (the network's gates stay shut below {MIN_ESTIMATION_RATE_HZ:.0f} Hz; "
                    f"a faster IMU helps in fast motion)")  # fmt: skip
            self.warning = (f"IMU at {rate:.1f} Hz (< {self.min_rate_hz:.0f} Hz); asked for {self.msg} at "
                            f"{self.request_rate_hz:.0f} Hz {REQUEST_ATTEMPTS}x ({ack}): not granted; {then} "
                            "(set SRx_RAW_SENS / the stream rate on the autopilot)")  # fmt: skip
            self.note(f"tepinn-flight bridge: {self.warning}")
        else:  # the warning stands: the estimates follow the rate (a 10-Hz stream that rises to 30 Hz is estimated)
            self.withhold = self._too_slow(rate)

    @staticmethod
    def _too_slow(rate: float) -> bool:
        """Too slow to estimate from: under 20 Hz, with the same allowance for the meter's count."""
        return rate < (1.0 - RATE_ALLOWANCE) * MIN_ESTIMATION_RATE_HZ

    def on_ack(self, m, enums) -> None:
        """A COMMAND_ACK of MAV_CMD_SET_MESSAGE_INTERVAL."""
        res = int(m.result)
        entry = enums.get("MAV_RESULT", {}).get(res)
        self.ack = entry.name.removeprefix("MAV_RESULT_").lower() if entry else str(res)

"""The live bridge: a transparent MAVLink router that adds TE-PINN attitude estimates.

One thread runs a ``select`` loop over the master link (the autopilot), the ``--out`` links
(ground stations) and the estimator worker's pipe; this module is that loop and the wiring between
the rooms, each in its own module:

* **routing** (:mod:`~tepinn_flight.live.forwarding`): every good frame from the autopilot to every
  out unchanged, every good frame from a ground station to the autopilot; our own echoes and
  unvouched unknown message ids dropped; the session tlog
  (:mod:`~tepinn_flight.live.session_tlog`, ``FILE.part`` renamed at the end).
* **inspection** (here, after forwarding): the autopilot is the component 1 whose HEARTBEAT names a
  real autopilot (:mod:`~tepinn_flight.live.autopilot`: the first seen, or ``sysid``; seen, lost,
  its boot clock); its IMU messages become samples (:mod:`~tepinn_flight.live.imu_stream`:
  HIGHRES_IMU preferred, then RAW_IMU, then SCALED_IMU, one instance; duplicates, stale frames and
  reboots told apart; the IMU rate asked for with ``MAV_CMD_SET_MESSAGE_INTERVAL`` when below
  ``min_imu_rate_hz``), its ATTITUDE_QUATERNION (else ATTITUDE) feeds the comparison
  (:mod:`~tepinn_flight.live.comparison`), COMMAND_ACKs of our rate requests are noted.
* **estimates** (:mod:`~tepinn_flight.live.estimate_path`): samples into the worker (a child process
  or a thread, restarted with a backoff), estimates (decimated to ``rate_hz`` on the autopilot's
  clock) out as the ``--estimate-as`` messages from (autopilot sysid, 191), stamped with the IMU
  sample's ``time_boot_ms``; diagnostics (NAMED_VALUE_FLOAT, DEBUG_VECT) at ``diag_rate_hz``; a
  HEARTBEAT as an onboard controller at 1 Hz (also to the autopilot).
* **view** (:mod:`~tepinn_flight.live.view`, ``--view``/``--rrd``): the comparison's EKF attitudes,
  estimates and differences drawn in Rerun.

Latency figures: "IMU in → estimate out" is the wall time from reading the IMU message off the
socket to writing the estimate frames; "forwarding" is from reading a datagram to having written it
to every out (both ``time.monotonic``, which the worker process shares).
"""

from __future__ import annotations

import math
import os
import select
import threading
import time
from dataclasses import dataclass

from ..errors import ConfigError, TepinnError
from ..ingest.ahrs_trim import TRIM_PARAMS
from ..ingest.tlog import MAV_AUTOPILOT_ARDUPILOTMEGA
from . import MAV_COMP_ID_AUTOPILOT1, MAV_COMP_ID_ONBOARD_COMPUTER, dialect
from .autopilot import AutopilotTracker
from .comparison import LiveComparison
from .estimate_path import EstimateOutput, EstimatorFeed
from .forwarding import Forwarder
from .imu_stream import IMU_NAMES, MAV_CMD_SET_MESSAGE_INTERVAL, ImuRateRequests, ImuStream
from .messages import DEFAULT_ESTIMATE_AS, ESTIMATE_AS, Encoder, heartbeat_onboard_msg, param_request_read_msg
from .router import SOCKET_BUFFER_BYTES
from .sample_order import DUPLICATE, STALE
from .status import StatusPrinter, format_summary
from .view import ViewConfig, open_view

#: the fastest IMU rate the bridge asks for or waits for (an interval of 100 µs; no autopilot streams faster)
MAX_IMU_RATE_HZ = 10000.0


@dataclass(frozen=True)
class BridgeConfig:
    master: str
    outs: tuple[str, ...] = ()
    model_path: str | None = None
    runtime: str = "auto"  # the network's runtime: "torch", "onnx" or "auto" (model.runtime)
    # 6d, 9d (the magnetometer's heading, magnetic north) or auto (9-D when the vehicle sends a
    # magnetometer); "" keeps the model's own (6d for the shipped one)
    mode: str = ""
    # every N-th window where the network stays busy (AnchorConfig.busy_stride, the speed knob); 0: the model's own
    busy_stride: int = 0
    tlog_path: str | None = None
    rate_hz: float = 50.0  # estimates out, on the autopilot's clock
    diag_rate_hz: float = 10.0  # NAMED_VALUE_FLOAT / DEBUG_VECT
    imu_instance: int = 0
    min_imu_rate_hz: float = 50.0
    request_imu_rate_hz: float = 200.0
    sysid: int | None = None  # the autopilot's system id (None: the first one seen)
    compid: int = MAV_COMP_ID_ONBOARD_COMPUTER
    estimates_to_master: bool = False
    estimate_as: str = DEFAULT_ESTIMATE_AS  # one of messages.ESTIMATE_AS
    worker: str = "process"  # "process" or "thread"
    max_sample_age_s: float = 0.2
    queue_samples: int = 256
    duration_s: float | None = None
    autopilot_timeout_s: float = 3.0
    request_grace_s: float = 2.0  # judge the IMU rate only after seeing the autopilot this long
    request_spacing_s: float = 3.0  # between MAV_CMD_SET_MESSAGE_INTERVAL attempts
    imu_slow_for_s: float = 2.0  # the IMU counts as slow after this long below min_imu_rate_hz (a stopping one: not)
    view: bool = False  # --view: TE-PINN beside the EKF in the Rerun viewer (live/view.py)
    rrd_path: str | None = None  # --rrd: the same recorded to a Rerun file

    def __post_init__(self):
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0) or not (math.isfinite(self.diag_rate_hz) and self.diag_rate_hz >= 0):
            raise ConfigError("--rate must be a number > 0 and --diag-rate one >= 0")
        if self.estimate_as not in ESTIMATE_AS:
            raise ConfigError(f"--estimate-as must be one of {', '.join(ESTIMATE_AS)}, not {self.estimate_as!r}")
        if self.worker not in ("process", "thread"):
            raise ConfigError(f"worker must be 'process' or 'thread', not {self.worker!r}")
        if self.mode not in ("", "6d", "9d", "auto"):
            raise ConfigError(f"mode must be 6d, 9d or auto, not {self.mode!r}")
        if self.runtime not in ("auto", "torch", "onnx"):
            raise ConfigError(f"runtime must be 'auto', 'torch' or 'onnx', not {self.runtime!r}")
        if not (isinstance(self.busy_stride, int) and self.busy_stride >= 0):
            raise ConfigError(f"busy_stride must be an integer >= 0 (0: the model's own), not {self.busy_stride!r}")
        if self.sysid is not None and not 1 <= self.sysid <= 255:
            raise ConfigError("--sysid must be in 1..255")
        if not 1 <= self.compid <= 255:
            raise ConfigError("--compid must be in 1..255")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError("--duration must be > 0")
        if not self.max_sample_age_s > 0 or self.queue_samples < 1:
            raise ConfigError("--max-age must be > 0 and the queue at least 1 sample")
        if not 0 <= self.min_imu_rate_hz <= MAX_IMU_RATE_HZ or not 1 <= self.request_imu_rate_hz <= MAX_IMU_RATE_HZ:
            # (an infinite rate had asked for an interval of 0 µs, MAVLink's "default rate"; 1e-9 Hz for 1e15 µs)
            raise ConfigError(f"--min-imu-rate must be 0 to {MAX_IMU_RATE_HZ:g} Hz and --request-imu-rate 1 to "
                              f"{MAX_IMU_RATE_HZ:g} Hz")  # fmt: skip


class Bridge:
    def __init__(self, config: BridgeConfig, make_estimator=None, status: StatusPrinter | None = None,
                 clock=time.monotonic):  # fmt: skip
        """``make_estimator`` (thread worker only): a callable returning an object with
        ``push(t, gyr, acc, mag)`` and ``reset()`` like StreamingEstimator (tests inject faults)."""
        self.cfg = c = config
        self.clock = clock
        self.status = status or StatusPrinter(quiet=True)
        if c.worker == "process" and not c.model_path:
            raise ConfigError("the process worker needs a model path")
        if c.worker == "thread" and make_estimator is None:
            from .worker import model_estimator_factory  # noqa: PLC0415

            if not c.model_path:
                raise ConfigError("no model given")
            make_estimator = model_estimator_factory(c.model_path, c.runtime, c.mode, c.busy_stride)
        self.view = open_view(ViewConfig(spawn=c.view, rrd_path=c.rrd_path), compare=False)
        try:
            self.fwd = Forwarder(c.master, c.outs, c.tlog_path, clock)
        except BaseException:
            if self.view is not None:
                self.view.discard()
            raise
        self.master = self.fwd.master
        self.m = dialect()
        note = self.status.note
        self.ap = AutopilotTracker(c.sysid, c.compid, note)
        self.imu = ImuStream(c.imu_instance, note)
        self.requests = ImuRateRequests(c.min_imu_rate_hz, c.request_imu_rate_hz, c.request_grace_s,
                                        c.request_spacing_s, note, c.imu_slow_for_s)  # fmt: skip
        self.comparison = LiveComparison(self.view)
        self.trim_asked = False  # AHRS_TRIM_X/Y requested from an ArduPilot autopilot
        self.feed = EstimatorFeed(c, make_estimator, note)
        self.ready = self.feed.ready
        self.out = EstimateOutput(c, clock)
        self.internal_errors = 0
        self.next_hb = 0.0
        self.next_rate_check = 0.0
        self.next_flush = 0.0
        self.t_start = None
        self.t_end = None
        got = self.master.rcvbuf_bytes
        if got is not None and got < SOCKET_BUFFER_BYTES:  # Linux reports twice what was set when granted
            self.status.note(f"tepinn-flight bridge: master UDP receive buffer {got >> 10} KiB (asked "
                             f"{SOCKET_BUFFER_BYTES >> 20} MiB, capped by net.core.rmem_max): a burst may be lost "
                             f"in the kernel; sysctl -w net.core.rmem_max={2 * SOCKET_BUFFER_BYTES} to raise it")  # fmt: skip

    # ------------------------------------------------------------------ main loop
    def run(self, stop: threading.Event | None = None) -> dict:
        c = self.cfg
        self.t_start = self.clock()
        self.feed.start()
        try:
            while not (stop is not None and stop.is_set()):
                now = self.clock()
                if c.duration_s is not None and now - self.t_start >= c.duration_s:
                    break
                if self.feed.failed_to_start:
                    raise TepinnError(f"the estimator could not start: {self.feed.fatal}")
                self._timers(now)
                fds = self.fwd.fds()
                wfd, efd = self.feed.fds()
                rlist = list(fds) + [x for x in (wfd, efd) if x is not None]
                try:
                    ready, _, _ = select.select(rlist, [], [], 0.02)
                except InterruptedError:
                    continue
                for fd in ready:
                    link = fds.get(fd)
                    if link is self.master:
                        self._on_master()
                    elif link is not None:
                        self.fwd.from_out(link, self.ap.own)
                if efd is not None and efd in ready and self.feed.worker is not None:
                    self.feed.worker.read_stderr()
                if wfd is not None and wfd in ready and self.feed.worker is not None:
                    self.feed.read(self.clock(), self._emit, self._internal_error)
        finally:
            self.t_end = self.clock()
            self.status.end_line()
            self.feed.stop(self._emit, self._internal_error, self.clock())
            if self.view is not None:
                try:
                    self.view.close()
                except Exception as exc:  # noqa: BLE001 - the summary still comes
                    self.status.note(f"tepinn-flight bridge: the Rerun view could not be closed cleanly ({exc})")
            self.fwd.close()
        return self.summary()

    def _on_master(self) -> None:
        keep, t_in = self.fwd.from_master(self.ap.own)
        for m in keep:
            try:
                self._inspect(m, t_in)
            except Exception as exc:  # noqa: BLE001 - a message we cannot read must not stop the routing
                self._internal_error(exc, m.get_type())

    def _send_own(self, msgs, to_outs: bool = True, to_master: bool = False) -> list[bytes]:
        return self.fwd.send_own(self.ap.enc, msgs, to_outs, to_master)

    def _internal_error(self, exc: Exception, what: str) -> None:
        self.internal_errors += 1
        if self.internal_errors == 1:
            self.status.note(f"tepinn-flight bridge: internal error on {what}: {type(exc).__name__}: {exc} "
                             "(forwarding goes on; set TEPINN_DEBUG=1 to stop on it)")  # fmt: skip
        if os.environ.get("TEPINN_DEBUG") not in (None, "", "0"):
            raise exc

    # ------------------------------------------------------------------ inspection
    def _inspect(self, m, t_in: float) -> None:
        if m.get_srcComponent() != MAV_COMP_ID_AUTOPILOT1:
            return
        name = m.get_type()
        sid = m.get_srcSystem()
        if name == "HEARTBEAT":
            if self.ap.heartbeat(m, sid, t_in):
                self._seen(t_in)
                if not self.trim_asked and self.ap.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:  # its level trim, once
                    self.trim_asked = True
                    self._send_own([param_request_read_msg(sid, MAV_COMP_ID_AUTOPILOT1, n) for n in TRIM_PARAMS],
                                   to_outs=False, to_master=True)  # fmt: skip
            return
        if not self.ap.message(name, sid, t_in, getattr(m, "time_boot_ms", None)):
            return
        self._seen(t_in)
        if name in IMU_NAMES:
            self._on_imu(m, t_in)
        elif name in ("ATTITUDE_QUATERNION", "ATTITUDE"):
            self.comparison.on_ekf(m, name, t_in)
        elif name == "PARAM_VALUE" and self.ap.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.comparison.on_param(m)
        elif name == "COMMAND_ACK" and int(m.command) == MAV_CMD_SET_MESSAGE_INTERVAL:
            self.requests.on_ack(m, self.m.enums)

    def _seen(self, t_in: float) -> None:
        if self.ap.seen(t_in):
            self.requests.attempts = 0  # back after being lost: ask again if the IMU is slow

    def _on_imu(self, m, t_in: float) -> None:
        s, switched = self.imu.take(m, t_in, self.ap.autopilot, self.ap.name, self.ap.boot_ms_at(t_in))
        if switched:
            self.feed.reset()
        if s is None:
            return
        boot_ms = s.time_boot_ms
        if boot_ms is None:  # UNIX-stamped IMU: carry the boot clock on
            boot_ms = self.ap.boot_ms_at(t_in)
        self.feed.submit(s, t_in, boot_ms, self.ap.type_name())

    # ------------------------------------------------------------------ estimates out
    def _emit(self, est: dict) -> None:
        if self.ap.enc is None:
            return
        if self.requests.withhold:  # the IMU stays below 20 Hz, not granted more: an estimate from it would mislead
            self.out.withheld += 1
            return
        self.out.emit(est, self.comparison, self.imu.rate,
                      lambda msgs: self._send_own(msgs, to_outs=True, to_master=self.cfg.estimates_to_master))  # fmt: skip

    # ------------------------------------------------------------------ timers
    def _timers(self, now: float) -> None:
        c = self.cfg
        for link in self.fwd.reconnect(now):
            self.status.note(f"tepinn-flight bridge: {link.role} {link.spec} reconnected")
        self.feed.upkeep(now, self._emit, self._internal_error)
        if now >= self.next_hb:
            self.next_hb = now + 1.0
            if self.ap.enc is not None:
                self._send_own([heartbeat_onboard_msg()], to_outs=True, to_master=True)
            elif self.master.kind == "udpout":  # let an autopilot that waits for a peer learn our address
                hello = Encoder(c.sysid or 1, c.compid)
                self.master.write(hello.pack(heartbeat_onboard_msg()))
        self.ap.check_lost(now, c.autopilot_timeout_s)
        if now >= self.next_rate_check:
            self.next_rate_check = now + 0.25
            self.requests.check(now, self.ap, self.imu.rate, lambda msg: self._send_own([msg], to_outs=False, to_master=True))
        if self.fwd.tlog is not None and now >= self.next_flush:
            self.next_flush = now + 1.0
            self.fwd.tlog.flush()
        if self.status.due(now):
            self.status.show(self.status_line(now), now)

    # ------------------------------------------------------------------ reporting
    def status_line(self, now: float) -> str:
        ap = "AP -" if self.ap.sysid is None or self.ap.enc is None else f"AP {self.ap.sysid}{' LOST' if self.ap.lost else ''}"
        imu = f"{self.imu.message or 'IMU -'} {self.imu.rate.rate(now):.0f} Hz"
        est = self.feed.state()
        if est is None:
            if self.requests.withhold:
                est = "est withheld (IMU too slow)"
            elif self.out.lat_hist.count == 0:
                est = "est - (first window filling)" if self.imu.samples else "est - (no IMU yet)"
            else:
                est = self.out.status(now)
        drops = self.feed.stale_drops()
        line = (f"{ap} | {imu} | {est} | {self.comparison.status()} | fwd {self.fwd.fwd_rate.rate(now):.0f} msg/s | "
                f"bad {self.fwd.bad_frames} | stale {drops}")  # fmt: skip
        order = self.imu.order
        if order.dropped:
            line += f" | IMU dup {order.counts[DUPLICATE]} old {order.counts[STALE]}"
        if self.requests.warning:
            line += " | IMU RATE LOW"
        return line

    def summary(self) -> dict:
        wc = self.feed.counters()
        dur = (self.t_end or self.clock()) - (self.t_start or self.clock())
        n = self.fwd.n
        messages = {k: n[k] for k in ("from_master", "forwarded_to_outs", "from_outs", "forwarded_to_master",
                                      "sent_own", "own_echoes")}  # fmt: skip
        messages.update(other_sources=self.ap.other_sources, unknown_dropped=n["unknown_dropped"], **self.fwd.link_counts(),
                        internal_errors=self.internal_errors, master_rcvbuf_bytes=self.master.rcvbuf_bytes)  # fmt: skip
        out = self.out
        return {
            "duration_s": round(dur, 3),
            "autopilot": self.ap.summary(),
            "imu": {
                **self.imu.summary(),
                "ekf_dropped": self.comparison.order.dropped,
                "requested": self.requests.attempts,
                "request_ack": self.requests.ack,
                "warning": self.requests.warning,
            },
            "messages": messages,
            "estimates": {
                "count": out.count,
                "withheld_imu_too_slow": out.withheld,
                "rate_hz": round(out.intervals / out.span, 2) if out.span > 0 else None,
                "samples_processed": wc[0],
                "dropped_stale": wc[1],
                "dropped_queue_full": self.feed.dropped_queue,
                "samples_without_estimator": self.feed.no_worker_samples,
                "resets": wc[2],
                "errors": wc[3],
                "model_runs": wc[4],
                "model_ms_mean": round(wc[5] / wc[4] * 1e3, 3) if wc[4] else None,
                "step_us_mean": round(wc[6] / wc[7] * 1e6, 2) if wc[7] else None,
                "steps": wc[7],  # the pushes that did not run the network (it ran between samples, or not at all)
                "push_ms": out.push_hist.summary(1e3, 3),  # the worker's push of each sent estimate's sample
                "sent_after_network": out.after_network,  # sent estimates whose push ran the network
                "worker": self.cfg.worker,
                "worker_restarts": self.feed.restarts,
                "worker_hangs": self.feed.hangs,
                "worker_error": self.feed.fatal or self.feed.error,
            },
            "latency_ms": out.lat_hist.summary(1e3, 3),
            "forward_latency_ms": self.fwd.fwd_hist.summary(1e3, 4),
            "ekf_difference_deg": self.comparison.summary(),
            "tlog": str(self.fwd.tlog.path) if self.fwd.tlog is not None else None,
        }

    def format_summary(self, s: dict | None = None) -> str:
        return format_summary(s or self.summary())

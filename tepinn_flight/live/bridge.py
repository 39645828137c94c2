"""The live bridge: a transparent MAVLink router that adds TE-PINN attitude estimates.

One thread runs a ``select`` loop over the master link (the autopilot), the ``--out`` links
(ground stations) and the estimator worker's pipe:

* **master → outs**: every good frame from the autopilot is written to every out unchanged
  (``get_msgbuf()``: ids, sequence, signature kept); the frames of one read go out together.
* **outs → master**: every good frame from a ground station goes to the autopilot unchanged.
* frames from our own (sysid, 191) are dropped wherever they come in (echoes in some topologies);
  garbage and CRC failures are counted and dropped. A message id the dialect does not know cannot
  be CRC-checked (no CRC_EXTRA), so garbage often parses as one: such a frame is forwarded only
  when its (system, component) has sent a CRC-checked frame on the same link before (custom-dialect
  messages of a real autopilot, gimbal or companion keep flowing), else dropped and counted
  (``messages.unknown_dropped``).
* **inspection** (after forwarding): the autopilot is the component 1 whose HEARTBEAT names a real
  autopilot (the first seen, or ``sysid``); its IMU messages become samples for the worker
  (HIGHRES_IMU preferred, then RAW_IMU, then SCALED_IMU, one instance), its ATTITUDE_QUATERNION
  (else ATTITUDE) feeds the comparison, COMMAND_ACKs of our rate requests are noted.
* **order**: IMU samples (and EKF attitudes) whose own time is not newer than the newest one taken
  (duplicates, stale copies from a redundant link, reordered UDP) are forwarded like every frame
  but dropped before the estimator and counted (``imu.duplicates``/``imu.out_of_order`` in the
  summary); a reboot is told apart by :class:`~tepinn_flight.live.sample_order.SampleOrder`
  (frames counting up from the new time after the old stream fell silent), so a stale frame never
  resets the estimator.
* **estimates** (from the worker, decimated to ``rate_hz`` on the autopilot's clock) go out as
  ATTITUDE + ATTITUDE_QUATERNION from (autopilot sysid, 191), stamped with the IMU sample's
  ``time_boot_ms``; diagnostics (NAMED_VALUE_FLOAT, DEBUG_VECT) at ``diag_rate_hz``; a HEARTBEAT
  as an onboard controller at 1 Hz (also to the autopilot).
* **IMU rate**: when the autopilot has been seen for 2 s and its IMU stream is below
  ``min_imu_rate_hz``, the bridge asks for ``request_imu_rate_hz`` with
  ``MAV_CMD_SET_MESSAGE_INTERVAL`` (up to 3 times, 3 s apart) and says so if it did not help.
* a tlog of the session (autopilot, ground stations and our frames, ``[uint64 BE µs][frame]``),
  written to ``FILE.part`` and renamed at the end.

Latency figures: "IMU in → estimate out" is the wall time from reading the IMU message off the
socket to writing the estimate frames; "forwarding" is from reading a datagram to having written it
to every out (both ``time.monotonic``, which the worker process shares).
"""

from __future__ import annotations

import math
import os
import select
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, TepinnError
from ..ingest.tlog import MAV_AUTOPILOT_ARDUPILOTMEGA
from . import MAV_COMP_ID_AUTOPILOT1, MAV_COMP_ID_ONBOARD_COMPUTER, dialect
from .inputs import EkfComparator, ekf_attitude, imu_preference, imu_sample, imu_scale_known
from .messages import (
    DEFAULT_ESTIMATE_AS,
    ESTIMATE_AS,
    Encoder,
    diagnostic_msgs,
    estimate_msgs,
    heartbeat_onboard_msg,
    set_message_interval_msg,
)
from .router import SOCKET_BUFFER_BYTES, Link
from .sample_order import DUPLICATE, REBOOT, STALE, SampleOrder
from .status import RateMeter, StatusPrinter, angle_histogram, format_summary, latency_histogram
from .view import ViewConfig, open_view
from .worker import COUNTERS, ProcessWorker, ThreadWorker, pack_sample, reset_record, unpack_estimate

MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
MAV_CMD_SET_MESSAGE_INTERVAL = 511
REQUEST_ATTEMPTS = 3
RESTART_BACKOFF_S = (2.0, 4.0, 8.0, 16.0, 30.0)


@dataclass(frozen=True)
class BridgeConfig:
    master: str
    outs: tuple[str, ...] = ()
    model_path: str | None = None
    runtime: str = "auto"  # the network's runtime: "torch", "onnx" or "auto" (model.runtime)
    # 6d, 9d (the magnetometer's heading, magnetic north) or auto (9-D when the vehicle sends a
    # magnetometer); "" keeps the model's own (6d for the shipped one)
    mode: str = ""
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
    view: bool = False  # --view: TE-PINN beside the EKF in the Rerun viewer (live/view.py)
    rrd_path: str | None = None  # --rrd: the same recorded to a Rerun file

    def __post_init__(self):
        if not self.rate_hz > 0 or not self.diag_rate_hz >= 0:
            raise ConfigError("--rate must be > 0 and --diag-rate >= 0")
        if self.estimate_as not in ESTIMATE_AS:
            raise ConfigError(f"--estimate-as must be one of {', '.join(ESTIMATE_AS)}, not {self.estimate_as!r}")
        if self.worker not in ("process", "thread"):
            raise ConfigError(f"worker must be 'process' or 'thread', not {self.worker!r}")
        if self.mode not in ("", "6d", "9d", "auto"):
            raise ConfigError(f"mode must be 6d, 9d or auto, not {self.mode!r}")
        if self.runtime not in ("auto", "torch", "onnx"):
            raise ConfigError(f"runtime must be 'auto', 'torch' or 'onnx', not {self.runtime!r}")
        if self.sysid is not None and not 1 <= self.sysid <= 255:
            raise ConfigError("--sysid must be in 1..255")
        if not 1 <= self.compid <= 255:
            raise ConfigError("--compid must be in 1..255")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError("--duration must be > 0")
        if not self.max_sample_age_s > 0 or self.queue_samples < 1:
            raise ConfigError("--max-age must be > 0 and the queue at least 1 sample")
        if not self.min_imu_rate_hz >= 0 or not self.request_imu_rate_hz > 0:
            raise ConfigError("IMU rates must be positive")


class SessionTlog:
    """``[uint64 BE UNIX µs][frame]`` records into ``FILE.part``, renamed to FILE on close."""

    def __init__(self, path: str):
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".part")
        if not self.path.parent.exists():
            raise ConfigError(f"--tlog {path}: folder {self.path.parent} does not exist")
        try:
            self.f = open(self.tmp, "wb", buffering=1 << 16)
        except OSError as exc:
            raise ConfigError(f"--tlog {path}: cannot write ({exc.strerror or exc})") from None
        self.records = 0
        self.bytes = 0

    def write(self, frames, t_unix_s: float) -> None:
        ts = struct.pack(">Q", int(t_unix_s * 1e6))
        for fr in frames:
            self.f.write(ts)
            self.f.write(fr)
            self.records += 1
            self.bytes += 8 + len(fr)

    def flush(self) -> None:
        self.f.flush()

    def close(self) -> None:
        self.f.close()
        os.replace(self.tmp, self.path)


class Bridge:
    def __init__(self, config: BridgeConfig, make_estimator=None, status: StatusPrinter | None = None,
                 clock=time.monotonic):  # fmt: skip
        """``make_estimator`` (thread worker only): a callable returning an object with
        ``push(t, gyr, acc, mag)`` and ``reset()`` like StreamingEstimator (tests inject faults)."""
        self.cfg = config
        self.clock = clock
        self.status = status or StatusPrinter(quiet=True)
        self.make_estimator = make_estimator
        if config.worker == "process" and not config.model_path:
            raise ConfigError("the process worker needs a model path")
        if config.worker == "thread" and make_estimator is None:
            from .worker import model_estimator_factory  # noqa: PLC0415

            if not config.model_path:
                raise ConfigError("no model given")
            self.make_estimator = model_estimator_factory(config.model_path, config.runtime, config.mode)
        self.links: list[Link] = []
        self.view = None
        try:
            self.view = open_view(ViewConfig(spawn=config.view, rrd_path=config.rrd_path), compare=False)
            self.master = Link(config.master, "master")
            self.links.append(self.master)
            self.outs = []
            for spec in config.outs:
                link = Link(spec, "out")
                self.outs.append(link)
                self.links.append(link)
            self.tlog = SessionTlog(config.tlog_path) if config.tlog_path else None
        except BaseException:
            self._close_links()
            if self.view is not None:
                self.view.discard()
            raise
        self.m = dialect()
        self.ready = threading.Event()
        self._reset_state()
        got = self.master.rcvbuf_bytes
        if got is not None and got < SOCKET_BUFFER_BYTES:  # Linux reports twice what was set when granted
            self.status.note(f"tepinn-flight bridge: master UDP receive buffer {got >> 10} KiB (asked "
                             f"{SOCKET_BUFFER_BYTES >> 20} MiB, capped by net.core.rmem_max): a burst may be lost "
                             f"in the kernel; sysctl -w net.core.rmem_max={2 * SOCKET_BUFFER_BYTES} to raise it")  # fmt: skip

    # ------------------------------------------------------------------ state
    def _reset_state(self) -> None:
        c = self.cfg
        self.enc: Encoder | None = None
        self.ap_sysid: int | None = c.sysid
        self.ap_autopilot: int | None = None
        self.ap_type: int | None = None
        self.ap_first_seen: float | None = None
        self.ap_last_seen: float | None = None
        self.ap_lost = False
        self.ap_lost_count = 0
        self.last_boot = None  # (time_boot_ms, monotonic) of the autopilot's latest message with one
        self.imu_msg: str | None = None
        self.imu_seen: dict[str, float] = {}
        self.imu_rate = RateMeter(2.0)
        self.imu_samples = 0
        self.imu_last_t = None
        self.imu_span = 0.0
        self.imu_intervals = 0
        self.time_jumps = 0
        self.imu_order = SampleOrder()  # duplicates / out-of-order frames dropped, reboots told apart
        self.ekf_order = SampleOrder()
        self.unknown_scale_noted = False
        self.ekf_src_seen: dict[str, float] = {}
        self.cmp = EkfComparator()
        self.diff_hist = angle_histogram()
        self.last_diff = None
        self.lat_hist = latency_histogram()
        self.fwd_hist = latency_histogram()
        self.last_latency = None
        self.est_count = 0
        self.est_rate = RateMeter(2.0)
        self.est_last_t = None
        self.est_span = 0.0
        self.est_intervals = 0
        self.next_diag_k = None
        self.seq = 0
        self.n = dict(from_master=0, forwarded_to_outs=0, from_outs=0, forwarded_to_master=0, sent_own=0,
                      own_echoes=0, other_sources=0, unknown_dropped=0)  # fmt: skip
        self.known_sources: dict[int, set] = {}  # id(link) -> (sysid, compid) seen with CRC-checked frames
        self.fwd_rate = RateMeter(2.0)
        # worker
        self.worker = None
        self.worker_ready = False
        self.worker_ever_ready = False
        self.worker_error = None
        self.worker_restarts = 0
        self.restart_at = None
        self.worker_fatal = None
        self.wc = [0, 0, 0, 0, 0, 0.0, 0.0]  # counters of the current worker
        self.wc_done = [0, 0, 0, 0, 0, 0.0, 0.0]  # of the previous ones
        self.dropped_queue = 0
        self.no_worker_samples = 0
        self.internal_errors = 0
        # IMU rate requests
        self.req_attempts = 0
        self.req_next = 0.0
        self.req_msg = None
        self.req_ack = None
        self.imu_warning = None
        self.est_withheld = 0  # estimates not published while the IMU is too slow (imu_warning)
        # timers
        self.next_hb = 0.0
        self.next_rate_check = 0.0
        self.next_flush = 0.0
        self.t_start = None
        self.t_end = None

    # ------------------------------------------------------------------ worker
    def _start_worker(self) -> None:
        c = self.cfg
        if c.worker == "process":
            self.worker = ProcessWorker(c.model_path, c.rate_hz, c.max_sample_age_s, c.runtime, c.mode)
        else:
            self.worker = ThreadWorker(self.make_estimator, c.rate_hz, c.max_sample_age_s)
        self.worker_ready = False
        self.wc = [0, 0, 0, 0, 0, 0.0, 0.0]

    def _worker_died(self, now: float) -> None:
        w = self.worker
        w.read_stderr()
        w.stop(0.5)
        code = w.exit_code()
        if code is not None and code < 0:
            how = f"killed by signal {-code}"
        else:
            how = f"exit code {code}"
        why = self.worker_fatal or w.last_stderr_line() or how
        self.worker = None
        self.worker_ready = False
        self.wc_done = [a + b for a, b in zip(self.wc_done, self.wc)]
        self.wc = [0, 0, 0, 0, 0, 0.0, 0.0]
        if not self.worker_ever_ready:
            self.worker_fatal = why
            return
        self.worker_error = f"estimator stopped ({why})"
        delay = RESTART_BACKOFF_S[min(self.worker_restarts, len(RESTART_BACKOFF_S) - 1)]
        self.restart_at = now + delay
        self.status.note(f"tepinn-flight bridge: {self.worker_error}; restarting in {delay:.0f} s (forwarding goes on)")

    def _on_worker(self, now: float) -> None:
        for kind, payload in self.worker.read():
            if kind == b"E":
                est, counters = unpack_estimate(payload)
                self.wc = list(counters)
                try:
                    self._emit(est)
                except Exception as exc:  # noqa: BLE001 - an estimate we cannot send must not stop the routing
                    self._internal_error(exc, "estimate")
            elif kind == b"S":
                self.wc = list(COUNTERS.unpack_from(payload))
            elif kind == b"R":
                self.worker_ready = True
                if not self.worker_ever_ready:
                    self.status.note("tepinn-flight bridge: estimator ready")
                else:
                    self.status.note("tepinn-flight bridge: estimator restarted")
                self.worker_ever_ready = True
                self.ready.set()
            elif kind == b"X":
                self.worker_error = payload.decode(errors="replace")  # the worker sends the 1st, 100th, 200th ...
                self.status.note(f"tepinn-flight bridge: {self.worker_error} (estimator reset; forwarding goes on)")
            elif kind == b"F":
                self.worker_fatal = payload.decode(errors="replace")
        if self.worker is not None and self.worker.eof:
            self._worker_died(now)

    # ------------------------------------------------------------------ main loop
    def run(self, stop: threading.Event | None = None) -> dict:
        c = self.cfg
        self.t_start = self.clock()
        self._start_worker()
        try:
            while not (stop is not None and stop.is_set()):
                now = self.clock()
                if c.duration_s is not None and now - self.t_start >= c.duration_s:
                    break
                if self.worker_fatal and not self.worker_ever_ready:
                    raise TepinnError(f"the estimator could not start: {self.worker_fatal}")
                self._timers(now)
                fds = {}
                for link in self.links:
                    fd = link.fileno()
                    if fd is not None:
                        fds[fd] = link
                wfd = efd = None
                if self.worker is not None:
                    wfd = self.worker.out_fd
                    efd = getattr(self.worker, "err_fd", None)
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
                        self._on_out(link)
                if efd is not None and efd in ready and self.worker is not None:
                    self.worker.read_stderr()
                if wfd is not None and wfd in ready and self.worker is not None:
                    self._on_worker(self.clock())
        finally:
            self.t_end = self.clock()
            self.status.end_line()
            if self.worker is not None:
                try:
                    self._on_worker(self.clock())
                except Exception:  # noqa: BLE001 - shutting down
                    pass
                if self.worker is not None:
                    self.worker.stop()
                    self.wc_done = [a + b for a, b in zip(self.wc_done, self.wc)]
                    self.wc = [0, 0, 0, 0, 0, 0.0, 0.0]
                    self.worker = None
            if self.tlog is not None:
                try:
                    self.tlog.close()
                except OSError:
                    pass
            if self.view is not None:
                try:
                    self.view.close()
                except Exception as exc:  # noqa: BLE001 - the summary still comes
                    self.status.note(f"tepinn-flight bridge: the Rerun view could not be closed cleanly ({exc})")
            self._close_links()
        return self.summary()

    def _close_links(self) -> None:
        for link in self.links:
            link.close()

    # ------------------------------------------------------------------ traffic
    def _own(self, m) -> bool:
        return self.enc is not None and m.get_srcComponent() == self.cfg.compid and m.get_srcSystem() == self.enc.sysid

    def _vouched(self, link: Link, m) -> bool:
        """False for a frame of an unknown message id from a source not seen with a CRC-checked
        frame on this link (garbage that happens to parse); True otherwise, noting known sources."""
        known = self.known_sources.setdefault(id(link), set())
        buf = m.get_msgbuf()
        src = (buf[5], buf[6]) if buf[0] == 0xFD else (buf[3], buf[4])
        if m.get_type().startswith("UNKNOWN"):
            if src in known:
                return True
            self.n["unknown_dropped"] += 1
            return False
        if len(known) < 4096:
            known.add(src)
        return True

    def _on_master(self) -> None:
        data = self.master.read()
        t_in = self.clock()
        if not data:
            return
        msgs = self.master.parse(data)
        keep = []
        for m in msgs:
            if self._own(m):
                self.n["own_echoes"] += 1
            elif self._vouched(self.master, m):
                keep.append(m)
        if not keep:
            return
        frames = [bytes(m.get_msgbuf()) for m in keep]
        out = b"".join(frames)
        for o in self.outs:
            if o.write(out):
                self.n["forwarded_to_outs"] += len(frames)
        self.fwd_hist.add(self.clock() - t_in)
        self.n["from_master"] += len(frames)
        self.fwd_rate.tick(t_in)
        if self.tlog is not None:
            self.tlog.write(frames, time.time())
        for m in keep:
            try:
                self._inspect(m, t_in)
            except Exception as exc:  # noqa: BLE001 - a message we cannot read must not stop the routing
                self._internal_error(exc, m.get_type())

    def _on_out(self, link: Link) -> None:
        data = link.read()
        if not data:
            return
        msgs = []
        for m in link.parse(data):
            if self._own(m):
                self.n["own_echoes"] += 1
            elif self._vouched(link, m):
                msgs.append(m)
        if not msgs:
            return
        frames = [bytes(m.get_msgbuf()) for m in msgs]
        self.n["from_outs"] += len(frames)
        if self.master.write(b"".join(frames)):
            self.n["forwarded_to_master"] += len(frames)
        if self.tlog is not None:
            self.tlog.write(frames, time.time())

    def _send_own(self, msgs, to_outs: bool = True, to_master: bool = False) -> list[bytes]:
        frames = [self.enc.pack(m) for m in msgs]
        buf = b"".join(frames)
        if to_outs:
            for o in self.outs:
                o.write(buf)
        if to_master:
            self.master.write(buf)
        self.n["sent_own"] += len(frames)
        if self.tlog is not None:
            self.tlog.write(frames, time.time())
        return frames

    # ------------------------------------------------------------------ inspection
    def _inspect(self, m, t_in: float) -> None:
        if m.get_srcComponent() != MAV_COMP_ID_AUTOPILOT1:
            return
        name = m.get_type()
        sid = m.get_srcSystem()
        if name == "HEARTBEAT":
            if m.autopilot == MAV_AUTOPILOT_INVALID:
                return
            if self.ap_sysid is None:
                self.ap_sysid = sid
            if sid != self.ap_sysid:
                self.n["other_sources"] += 1
                return
            self.ap_autopilot, self.ap_type = int(m.autopilot), int(m.type)
            if self.enc is None or self.enc.sysid != sid:
                self.enc = Encoder(sid, self.cfg.compid)
                self.status.note(f"tepinn-flight bridge: autopilot system {sid} found ({self._ap_name()})")
            self._seen(t_in)
            return
        if self.ap_sysid is None or sid != self.ap_sysid:
            if name in ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "ATTITUDE", "ATTITUDE_QUATERNION"):
                self.n["other_sources"] += 1
            return
        if self.ap_autopilot is None:
            return  # wait for its HEARTBEAT (RAW_IMU units depend on the autopilot)
        self._seen(t_in)
        tb = getattr(m, "time_boot_ms", None)
        if tb is not None and (self.last_boot is None or int(tb) >= self.last_boot[0] or t_in - self.last_boot[1] > 1.0):
            self.last_boot = (int(tb), t_in)  # a stale copy does not set the clock back; a reboot does within 1 s
        if name in ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"):
            self._on_imu(m, t_in)
        elif name in ("ATTITUDE_QUATERNION", "ATTITUDE"):
            self._on_ekf(m, name, t_in)
        elif name == "COMMAND_ACK" and int(m.command) == MAV_CMD_SET_MESSAGE_INTERVAL:
            res = int(m.result)
            entry = self.m.enums.get("MAV_RESULT", {}).get(res)
            self.req_ack = entry.name.removeprefix("MAV_RESULT_").lower() if entry else str(res)

    def _internal_error(self, exc: Exception, what: str) -> None:
        self.internal_errors += 1
        if self.internal_errors == 1:
            self.status.note(f"tepinn-flight bridge: internal error on {what}: {type(exc).__name__}: {exc} "
                             "(forwarding goes on; set TEPINN_DEBUG=1 to stop on it)")  # fmt: skip
        if os.environ.get("TEPINN_DEBUG") not in (None, "", "0"):
            raise exc

    def _seen(self, t_in: float) -> None:
        if self.ap_first_seen is None:
            self.ap_first_seen = t_in
        if self.ap_lost:
            self.ap_lost = False
            self.ap_first_seen = t_in
            self.req_attempts = 0
            self.status.note(f"tepinn-flight bridge: autopilot system {self.ap_sysid} is back")
        self.ap_last_seen = t_in

    def _ap_name(self) -> str:
        e = self.m.enums.get("MAV_AUTOPILOT", {}).get(self.ap_autopilot)
        return e.name.removeprefix("MAV_AUTOPILOT_").lower() if e else str(self.ap_autopilot)

    def _on_imu(self, m, t_in: float) -> None:
        name = m.get_type()
        if not imu_scale_known(name, self.ap_autopilot):
            if not self.unknown_scale_noted:
                self.unknown_scale_noted = True
                self.status.note(f"tepinn-flight bridge: {name} from a {self._ap_name()} autopilot has an unknown "
                                 "scale (raw counts?): ignored")  # fmt: skip
            return
        s = imu_sample(m, self.ap_autopilot)
        if s is None or s.instance != self.cfg.imu_instance:
            return
        self.imu_seen[s.message] = t_in
        cur = self.imu_msg
        if cur != s.message and (
            cur is None or imu_preference(s.message) < imu_preference(cur) or t_in - self.imu_seen.get(cur, -1e9) > 1.0
        ):
            self.imu_msg = s.message
            if cur is not None and self.worker is not None:
                self.worker.submit(reset_record())
            self.imu_last_t = None
            self.imu_order.reset()  # another message: its own clock
        if s.message != self.imu_msg:
            return
        verdict = self.imu_order.accept(s.t_s, t_in)
        if verdict in (DUPLICATE, STALE):
            return  # forwarded already; never to the estimator (it would reset on the time reversal)
        if verdict == REBOOT:
            self.status.note(f"tepinn-flight bridge: {s.message} clock restarted at {s.t_s:.3f} s "
                             "(autopilot reboot?): estimator reset")  # fmt: skip
        self.imu_rate.tick(t_in)
        self.imu_samples += 1
        if self.imu_last_t is not None:
            dt = s.t_s - self.imu_last_t
            if 0 < dt <= 1.0:
                self.imu_span += dt
                self.imu_intervals += 1
            else:
                self.time_jumps += 1
        self.imu_last_t = s.t_s
        boot_ms = s.time_boot_ms
        if boot_ms is None and self.last_boot is not None:  # UNIX-stamped IMU: carry the boot clock on
            boot_ms = self.last_boot[0] + int(round((t_in - self.last_boot[1]) * 1e3))
        w = self.worker
        if w is None or not self.worker_ready:
            self.no_worker_samples += 1
            return
        in_flight = w.submitted - self.wc[0] - self.wc[1] - self.wc[3]
        if in_flight >= self.cfg.queue_samples:
            self.dropped_queue += 1
            return
        self.seq += 1
        rec = pack_sample(self.seq, s.t_s, t_in, s.gyr_rad_s, s.acc_m_s2, s.mag_ut, s.time_usec, boot_ms)
        if not w.submit(rec):
            self.dropped_queue += 1

    def _on_ekf(self, m, name: str, t_in: float) -> None:
        self.ekf_src_seen[name] = t_in
        if name == "ATTITUDE" and t_in - self.ekf_src_seen.get("ATTITUDE_QUATERNION", -1e9) < 2.0:
            return  # ATTITUDE_QUATERNION is there: use it alone
        a = ekf_attitude(m)
        if a is None:
            return
        if self.ekf_order.accept(a[0], t_in) in (DUPLICATE, STALE):
            return
        if self.view is not None:
            self.view.ekf(a[0], a[2])
        for d in self.cmp.add_ekf(a[0], a[2]):
            self._diff(d)

    def _diff(self, d) -> None:
        self.diff_hist.add(d[3])
        self.last_diff = d
        if self.view is not None:
            self.view.differences([d])

    # ------------------------------------------------------------------ estimates out
    def _emit(self, est: dict) -> None:
        if self.enc is None:
            return
        if self.imu_warning:  # the IMU stays below min_imu_rate_hz: an estimate from it would mislead
            self.est_withheld += 1
            return
        q, bias, gyr = est["q"], est["bias"], est["gyr"]
        rates = tuple(gyr[i] - bias[i] for i in range(3))
        ms = est["time_boot_ms"] if est["time_boot_ms"] is not None else 0
        c = self.cfg
        msgs = estimate_msgs(ms, q, rates, c.estimate_as, est["time_usec"])
        if self.view is not None:
            self.view.estimate(est["t_s"], q)
        for d in self.cmp.add_estimate(est["t_s"], q):
            self._diff(d)
        if c.diag_rate_hz > 0:
            k = math.floor(est["t_s"] * c.diag_rate_hz + 1e-9)
            if k != self.next_diag_k:
                self.next_diag_k = k
                diff = self.last_diff[1:] if self.last_diff is not None and abs(self.last_diff[0] - est["t_s"]) < 0.5 else None
                lat = self.clock() - est["arrival"]
                msgs += diagnostic_msgs(ms, est["time_usec"], q, sigma_rad=est["sigma"], latency_s=lat,
                                        imu_rate_hz=self.imu_rate.rate(self.clock()), bias_rad_s=bias, diff=diff,
                                        rpy=c.estimate_as != "debug_vect")  # fmt: skip
        self._send_own(msgs, to_outs=True, to_master=c.estimates_to_master)
        now = self.clock()
        lat = now - est["arrival"]
        self.lat_hist.add(lat)
        self.last_latency = lat
        self.est_count += 1
        self.est_rate.tick(now)
        if self.est_last_t is not None:
            dt = est["t_s"] - self.est_last_t
            if 0 < dt <= 1.0:
                self.est_span += dt
                self.est_intervals += 1
        self.est_last_t = est["t_s"]

    # ------------------------------------------------------------------ timers
    def _timers(self, now: float) -> None:
        c = self.cfg
        for link in self.links:
            if link.maintain(now):
                self.status.note(f"tepinn-flight bridge: {link.role} {link.spec} reconnected")
        if self.worker is None and self.restart_at is not None and now >= self.restart_at:
            self.restart_at = None
            self.worker_restarts += 1
            self._start_worker()
        if self.worker is not None and self.worker.exit_code() is not None and not self.worker.eof:
            self._on_worker(now)  # drain what is left; EOF follows
        if now >= self.next_hb:
            self.next_hb = now + 1.0
            if self.enc is not None:
                self._send_own([heartbeat_onboard_msg()], to_outs=True, to_master=True)
            elif self.master.kind == "udpout":  # let an autopilot that waits for a peer learn our address
                hello = Encoder(c.sysid or 1, c.compid)
                self.master.write(hello.pack(heartbeat_onboard_msg()))
        if self.ap_last_seen is not None and not self.ap_lost and now - self.ap_last_seen > c.autopilot_timeout_s:
            self.ap_lost = True
            self.ap_lost_count += 1
            self.status.note(f"tepinn-flight bridge: autopilot system {self.ap_sysid} silent for "
                             f"{c.autopilot_timeout_s:.0f} s (forwarding goes on)")  # fmt: skip
        if now >= self.next_rate_check:
            self.next_rate_check = now + 0.25
            self._check_imu_rate(now)
        if self.tlog is not None and now >= self.next_flush:
            self.next_flush = now + 1.0
            self.tlog.flush()
        if self.status.due(now):
            self.status.show(self.status_line(now), now)

    def _check_imu_rate(self, now: float) -> None:
        c = self.cfg
        if self.enc is None or self.ap_lost or self.ap_first_seen is None or c.min_imu_rate_hz <= 0:
            return
        if now - self.ap_first_seen < c.request_grace_s or now - self.ap_last_seen > 1.0:
            return  # too early to judge, or the autopilot itself is silent
        rate = self.imu_rate.rate(now)
        if rate >= c.min_imu_rate_hz:
            if self.imu_warning:
                self.status.note(f"tepinn-flight bridge: IMU now at {rate:.0f} Hz")
                self.imu_warning = None
            return
        if now < self.req_next:
            return
        if self.req_attempts < REQUEST_ATTEMPTS:
            name = "RAW_IMU" if self.ap_autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else "HIGHRES_IMU"
            self.req_msg = name
            msg = set_message_interval_msg(self.ap_sysid, MAV_COMP_ID_AUTOPILOT1, getattr(self.m, f"MAVLINK_MSG_ID_{name}"),
                                           c.request_imu_rate_hz)  # fmt: skip
            self._send_own([msg], to_outs=False, to_master=True)
            self.req_attempts += 1
            self.req_next = now + c.request_spacing_s
            self.status.note(f"tepinn-flight bridge: IMU at {rate:.1f} Hz (< {c.min_imu_rate_hz:.0f} Hz): asking the "
                             f"autopilot for {name} at {c.request_imu_rate_hz:.0f} Hz (MAV_CMD_SET_MESSAGE_INTERVAL, "
                             f"attempt {self.req_attempts})")  # fmt: skip
        elif self.imu_warning is None:
            ack = f"ack: {self.req_ack}" if self.req_ack else "no COMMAND_ACK"
            self.imu_warning = (f"IMU at {rate:.1f} Hz (< {c.min_imu_rate_hz:.0f} Hz); asked for {self.req_msg} at "
                                f"{c.request_imu_rate_hz:.0f} Hz {REQUEST_ATTEMPTS}x ({ack}): not granted; "
                                "estimates need >= 50 Hz (set SRx_RAW_SENS / the stream rate on the autopilot)")  # fmt: skip
            self.status.note(f"tepinn-flight bridge: {self.imu_warning}")

    # ------------------------------------------------------------------ reporting
    def status_line(self, now: float) -> str:
        ap = "AP -" if self.ap_sysid is None or self.enc is None else f"AP {self.ap_sysid}{' LOST' if self.ap_lost else ''}"
        imu = f"{self.imu_msg or 'IMU -'} {self.imu_rate.rate(now):.0f} Hz"
        if self.worker_fatal:
            est = "estimator failed"
        elif self.worker is None:
            est = "estimator restarting"
        elif not self.worker_ready:
            est = "estimator starting"
        elif self.lat_hist.count == 0:
            est = "est - (first window filling)" if self.imu_samples else "est - (no IMU yet)"
        else:
            lat = self.lat_hist
            est = f"est {self.est_rate.rate(now):.0f} Hz lat p50 {lat.percentile(50) * 1e3:.1f} p99 {lat.percentile(99) * 1e3:.1f} ms"
        diff = (f"dIncl {math.degrees(self.last_diff[3]):.2f} deg dHead {math.degrees(self.last_diff[4]):.1f} deg"
                if self.last_diff is not None else "dIncl -")  # fmt: skip
        drops = self.wc[1] + self.wc_done[1] + self.dropped_queue
        bad = sum(link.bad_frames for link in self.links)
        line = f"{ap} | {imu} | {est} | {diff} | fwd {self.fwd_rate.rate(now):.0f} msg/s | bad {bad} | stale {drops}"
        if self.imu_order.dropped:
            line += f" | IMU dup {self.imu_order.counts[DUPLICATE]} old {self.imu_order.counts[STALE]}"
        if self.imu_warning:
            line += " | IMU RATE LOW"
        return line

    def summary(self) -> dict:
        wc = [a + b for a, b in zip(self.wc_done, self.wc)]
        dur = (self.t_end or self.clock()) - (self.t_start or self.clock())
        bad = sum(link.bad_frames for link in self.links)
        bad_bytes = sum(link.bad_bytes for link in self.links)
        werr = sum(link.write_errors for link in self.links)
        n = dict(self.n)
        dif = self.diff_hist.summary(math.degrees(1.0), 3)
        if self.diff_hist.count:
            dif["rms"] = round(math.degrees(self.diff_hist.rms()), 3)
        return {
            "duration_s": round(dur, 3),
            "autopilot": {
                "sysid": self.ap_sysid if self.enc is not None else None,
                "autopilot": self._ap_name() if self.ap_autopilot is not None else None,
                "vehicle_type": self._type_name(),
                "lost": self.ap_lost_count,
            },
            "imu": {
                "message": self.imu_msg,
                "rate_hz": round(self.imu_intervals / self.imu_span, 2) if self.imu_span > 0 else None,
                "samples": self.imu_samples,
                "time_jumps": self.time_jumps,
                "duplicates": self.imu_order.counts[DUPLICATE],
                "out_of_order": self.imu_order.counts[STALE],
                "reboots": self.imu_order.counts[REBOOT],
                "ekf_dropped": self.ekf_order.dropped,
                "requested": self.req_attempts,
                "request_ack": self.req_ack,
                "warning": self.imu_warning,
            },
            "messages": {**n, "bad_frames": bad, "bad_bytes": bad_bytes, "write_errors": werr,
                         "internal_errors": self.internal_errors, "master_rcvbuf_bytes": self.master.rcvbuf_bytes},
            "estimates": {
                "count": self.est_count,
                "withheld_imu_too_slow": self.est_withheld,
                "rate_hz": round(self.est_intervals / self.est_span, 2) if self.est_span > 0 else None,
                "samples_processed": wc[0],
                "dropped_stale": wc[1],
                "dropped_queue_full": self.dropped_queue,
                "samples_without_estimator": self.no_worker_samples,
                "resets": wc[2],
                "errors": wc[3],
                "model_runs": wc[4],
                "model_ms_mean": round(wc[5] / wc[4] * 1e3, 3) if wc[4] else None,
                "step_us_mean": round(wc[6] / max(1, wc[0] - wc[4]) * 1e6, 2) if wc[0] else None,
                "worker": self.cfg.worker,
                "worker_restarts": self.worker_restarts,
                "worker_error": self.worker_fatal or self.worker_error,
            },
            "latency_ms": self.lat_hist.summary(1e3, 3),
            "forward_latency_ms": self.fwd_hist.summary(1e3, 4),
            "ekf_difference_deg": dif,
            "tlog": str(self.tlog.path) if self.tlog is not None else None,
        }

    def _type_name(self):
        if self.ap_type is None:
            return None
        e = self.m.enums.get("MAV_TYPE", {}).get(self.ap_type)
        return e.name.removeprefix("MAV_TYPE_").lower() if e else str(self.ap_type)

    def format_summary(self, s: dict | None = None) -> str:
        return format_summary(s or self.summary())


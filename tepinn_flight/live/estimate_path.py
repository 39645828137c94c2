"""The estimate path: IMU samples into the estimator worker, estimates out as MAVLink.

:class:`EstimatorFeed` runs the estimator off the forwarding path (:mod:`~tepinn_flight.live.worker`:
a child process, or a thread) and feeds it: a sample is dropped (and counted) when the worker is
not ready or its bounded queue is full; a worker that dies after it was ready is restarted with a
backoff (2, 4, 8, 16, 30 s) while forwarding goes on, one that never got ready stops the bridge. A
worker process that sends nothing for :data:`HANG_S` while samples wait for it (it answers every batch
within :data:`~tepinn_flight.live.worker.STATS_INTERVAL_S`) is hung: killed and restarted the same way
(session 53: a stopped worker had left the bridge without estimates for the rest of the flight, silently).

:class:`EstimateOutput` turns each estimate (decimated by the worker to ``rate_hz`` on the
autopilot's clock) into the messages of ``--estimate-as`` from (autopilot sysid, our compid),
stamped with the IMU sample's ``time_boot_ms``, plus diagnostics (NAMED_VALUE_FLOAT, DEBUG_VECT) at
``diag_rate_hz``; it keeps the latency ("IMU in → estimate out": the wall time from reading the IMU
message off the socket to writing the estimate frames, ``time.monotonic`` which the worker process
shares) and rate figures.
"""

from __future__ import annotations

import math
import threading

from .messages import diagnostic_msgs, estimate_msgs
from .status import RateMeter, latency_histogram
from .worker import COUNTERS, ProcessWorker, ThreadWorker, pack_sample, reset_record, unpack_estimate, vehicle_record

RESTART_BACKOFF_S = (2.0, 4.0, 8.0, 16.0, 30.0)
#: a ready worker process silent this long (s) while samples wait for it is taken for hung
HANG_S = 10.0
_NOT_TOLD = object()  # EstimatorFeed.vehicle_told before the worker was told anything (None: told "not known")
_ZERO = (0, 0, 0, 0, 0, 0.0, 0.0, 0)  # the worker's counters: processed, stale, resets, errors, model runs, model s, step s, steps


class EstimatorFeed:
    """The worker: started, fed, read, restarted; its counters over all its lives."""

    def __init__(self, cfg, make_estimator, note):
        self.cfg = cfg
        self.make_estimator = make_estimator
        self.note = note
        self.ready = threading.Event()  # set when an estimator first got ready
        self.worker = None
        self.worker_ready = False
        self.ever_ready = False
        self.error = None
        self.restarts = 0
        self.restart_at = None
        self.fatal = None
        self.wc = list(_ZERO)  # counters of the current worker
        self.wc_done = list(_ZERO)  # of the previous ones
        self.dropped_queue = 0
        self.no_worker_samples = 0
        self.seq = 0
        self.vehicle_told = _NOT_TOLD  # what the current worker was told the vehicle is (its MAV_TYPE name)
        self.controls = 0  # reset and vehicle records the current worker was sent (not samples: never processed)
        self.waiting_since = None  # when a sample was first sent after the worker last said anything
        self.hangs = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        c = self.cfg
        if c.worker == "process":
            self.worker = ProcessWorker(c.model_path, c.rate_hz, c.max_sample_age_s, c.runtime, c.mode, c.busy_stride)
        else:
            self.worker = ThreadWorker(self.make_estimator, c.rate_hz, c.max_sample_age_s)
        self.worker_ready = False
        self.wc = list(_ZERO)
        self.vehicle_told = _NOT_TOLD  # a new worker knows nothing of the vehicle
        self.controls = 0
        self.waiting_since = None

    def _died(self, now: float, why: str | None = None) -> None:
        w = self.worker
        w.read_stderr()
        w.stop(0.5)
        code = w.exit_code()
        if code is not None and code < 0:
            how = f"killed by signal {-code}"
        else:
            how = f"exit code {code}"
        why = why or self.fatal or w.last_stderr_line() or how
        self.worker = None
        self.worker_ready = False
        self.wc_done = [a + b for a, b in zip(self.wc_done, self.wc)]
        self.wc = list(_ZERO)
        if not self.ever_ready:
            self.fatal = why
            return
        self.error = f"estimator stopped ({why})"
        delay = RESTART_BACKOFF_S[min(self.restarts, len(RESTART_BACKOFF_S) - 1)]
        self.restart_at = now + delay
        self.note(f"tepinn-flight bridge: {self.error}; restarting in {delay:.0f} s (forwarding goes on)")

    def read(self, now: float, emit, internal_error) -> None:
        """What the worker sent: estimates to ``emit(est)`` (an exception there goes to
        ``internal_error(exc, "estimate")``), counters, ready / error / fatal notes."""
        frames = self.worker.read()
        if frames:
            self.waiting_since = None  # it answers
        for kind, payload in frames:
            if kind == b"E":
                est, counters = unpack_estimate(payload)
                self.wc = list(counters)
                try:
                    emit(est)
                except Exception as exc:  # noqa: BLE001 - an estimate we cannot send must not stop the routing
                    internal_error(exc, "estimate")
            elif kind == b"S":
                self.wc = list(COUNTERS.unpack_from(payload))
            elif kind == b"R":
                self.worker_ready = True
                if not self.ever_ready:
                    self.note("tepinn-flight bridge: estimator ready")
                else:
                    self.note("tepinn-flight bridge: estimator restarted")
                self.ever_ready = True
                self.ready.set()
            elif kind == b"X":
                self.error = payload.decode(errors="replace")  # the worker sends the 1st, 100th, 200th ...
                self.note(f"tepinn-flight bridge: {self.error} (estimator reset; forwarding goes on)")
            elif kind == b"F":
                self.fatal = payload.decode(errors="replace")
        if self.worker is not None and self.worker.eof:
            self._died(now)

    def upkeep(self, now: float, emit, internal_error) -> None:
        """Restart a dead worker when its backoff is over; drain one that exited."""
        if self.worker is None and self.restart_at is not None and now >= self.restart_at:
            self.restart_at = None
            self.restarts += 1
            self.start()
        if self.worker is not None and self.worker.exit_code() is not None and not self.worker.eof:
            self.read(now, emit, internal_error)  # drain what is left; EOF follows
        w = self.worker
        if (w is not None and self.worker_ready and self.waiting_since is not None and now - self.waiting_since > HANG_S
                and hasattr(w, "proc") and w.exit_code() is None):  # fmt: skip
            self.hangs += 1
            w.proc.kill()  # (a thread cannot be stopped: the thread worker is the tests' and the benchmarks')
            w.proc.wait()
            self._died(now, f"no reply for {now - self.waiting_since:.0f} s while fed: hung, killed")

    @property
    def failed_to_start(self) -> bool:
        return bool(self.fatal) and not self.ever_ready

    def fds(self) -> tuple[int | None, int | None]:
        """(the worker's output pipe, its stderr pipe or None); (None, None) without a worker."""
        if self.worker is None:
            return None, None
        return self.worker.out_fd, getattr(self.worker, "err_fd", None)

    def stop(self, emit, internal_error, now: float) -> None:
        """At the end: take what the worker still has, stop it."""
        if self.worker is None:
            return
        try:
            self.read(now, emit, internal_error)
        except Exception:  # noqa: BLE001 - shutting down
            pass
        if self.worker is not None:
            self.worker.stop()
            self.wc_done = [a + b for a, b in zip(self.wc_done, self.wc)]
            self.wc = list(_ZERO)
            self.worker = None

    # ------------------------------------------------------------------ feeding
    def reset(self) -> None:
        """The estimator starts over (the IMU stream switched to another message)."""
        if self.worker is not None:
            self.controls += self.worker.submit(reset_record())

    def submit(self, s, t_in: float, boot_ms: int | None, vehicle: str | None = None) -> None:
        """One IMU sample (:class:`~tepinn_flight.live.inputs.ImuSample`) read at ``t_in``; ``vehicle``: what the
        autopilot's heartbeat says the vehicle is (its MAV_TYPE name; None: not known), told the worker before the
        first sample and whenever it changes (as offline from a record's ``vehicle_type``)."""
        w = self.worker
        if w is None or not self.worker_ready:
            self.no_worker_samples += 1
            return
        if (self.vehicle_told is _NOT_TOLD or self.vehicle_told != vehicle) and w.submit(vehicle_record(vehicle)):
            self.vehicle_told = vehicle
            self.controls += 1
        in_flight = w.submitted - self.controls - self.wc[0] - self.wc[1] - self.wc[3]
        if in_flight >= self.cfg.queue_samples:
            self.dropped_queue += 1
            return
        self.seq += 1
        rec = pack_sample(self.seq, s.t_s, t_in, s.gyr_rad_s, s.acc_m_s2, s.mag_ut, s.time_usec, boot_ms,
                          clipped=s.clipped, gyr_clipped=s.gyr_clipped)  # fmt: skip
        if not w.submit(rec):
            self.dropped_queue += 1
        elif self.waiting_since is None:
            self.waiting_since = t_in

    # ------------------------------------------------------------------ reporting
    def counters(self) -> list:
        return [a + b for a, b in zip(self.wc_done, self.wc)]

    def stale_drops(self) -> int:
        return self.wc[1] + self.wc_done[1] + self.dropped_queue

    def state(self) -> str | None:
        """The status line's word when there is no estimate to show yet, else None."""
        if self.fatal:
            return "estimator failed"
        if self.worker is None:
            return "estimator restarting"
        if not self.worker_ready:
            return "estimator starting"
        return None


class EstimateOutput:
    """Estimates to MAVLink messages, with their latency and rate."""

    def __init__(self, cfg, clock):
        self.cfg = cfg
        self.clock = clock
        self.lat_hist = latency_histogram()
        # the worker's own time on each sent estimate's sample (its push), and how many of those pushes ran the network:
        # the part of the latency the estimator adds (the rest is the pipes and the scheduling)
        self.push_hist = latency_histogram()
        self.after_network = 0
        self.last_latency = None
        self.count = 0
        self.rate = RateMeter(2.0)
        self.last_t = None
        self.span = 0.0
        self.intervals = 0
        self.next_diag_k = None
        self.withheld = 0  # estimates not published while the IMU is too slow (ImuRateRequests.warning)

    def emit(self, est: dict, comparison, imu_rate: RateMeter, send) -> None:
        """Send ``est`` (``send(msgs)``) after ``comparison`` has seen it; diagnostics at
        ``diag_rate_hz`` with the latest difference and the IMU rate."""
        q, bias, gyr = est["q"], est["bias"], est["gyr"]
        rates = tuple(gyr[i] - bias[i] for i in range(3))
        ms = est["time_boot_ms"] if est["time_boot_ms"] is not None else 0
        c = self.cfg
        msgs = estimate_msgs(ms, q, rates, c.estimate_as, est["time_usec"])
        comparison.on_estimate(est["t_s"], q, est["sigma"])
        if c.diag_rate_hz > 0:
            k = math.floor(est["t_s"] * c.diag_rate_hz + 1e-9)
            if k != self.next_diag_k:
                self.next_diag_k = k
                diff = comparison.diff_near(est["t_s"])
                lat = self.clock() - est["arrival"]
                msgs += diagnostic_msgs(ms, est["time_usec"], q, sigma_rad=est["sigma"], latency_s=lat,
                                        imu_rate_hz=imu_rate.rate(self.clock()), bias_rad_s=bias, diff=diff,
                                        rpy=c.estimate_as != "debug_vect")  # fmt: skip
        send(msgs)
        now = self.clock()
        lat = now - est["arrival"]
        self.lat_hist.add(lat)
        self.push_hist.add(est["compute_s"])
        self.after_network += est["model_ran"]
        self.last_latency = lat
        self.count += 1
        self.rate.tick(now)
        if self.last_t is not None:
            dt = est["t_s"] - self.last_t
            if 0 < dt <= 1.0:
                self.span += dt
                self.intervals += 1
        self.last_t = est["t_s"]

    def status(self, now: float) -> str:
        lat = self.lat_hist
        return f"est {self.rate.rate(now):.0f} Hz lat p50 {lat.percentile(50) * 1e3:.1f} p99 {lat.percentile(99) * 1e3:.1f} ms"

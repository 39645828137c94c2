"""Counters for a live session: latency histograms, rate meters, the status line and the summary.

Memory stays bounded for sessions of any length: latencies go into fixed 10 µs bins (percentiles
exact to 10 µs up to 1 s, the rest in an overflow bin whose largest value is kept), rates are
counted over a sliding window, difference statistics are running sums plus a fixed histogram.
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque

import numpy as np


class Histogram:
    """Values in [0, ``top``) in ``n`` equal bins, plus an overflow bin; exact count, mean and max."""

    def __init__(self, top: float, n: int):
        self.top = float(top)
        self.n = int(n)
        self.width = self.top / self.n
        self.bins = np.zeros(self.n + 1, np.int64)
        self.count = 0
        self.total = 0.0
        self.total_sq = 0.0
        self.max = float("-inf")

    def add(self, v: float) -> None:
        if not math.isfinite(v):
            return
        k = int(v / self.width) if v >= 0 else 0
        self.bins[min(k, self.n)] += 1
        self.count += 1
        self.total += v
        self.total_sq += v * v
        if v > self.max:
            self.max = v

    def percentile(self, p: float) -> float:
        """The upper edge of the bin holding the ``p``-th percentile (the max if it overflows)."""
        if self.count == 0:
            return float("nan")
        target = p / 100.0 * self.count
        k = int(np.searchsorted(np.cumsum(self.bins), max(target, 1), side="left"))
        if k >= self.n:
            return self.max
        return min((k + 1) * self.width, self.max)

    def mean(self) -> float:
        return self.total / self.count if self.count else float("nan")

    def rms(self) -> float:
        return math.sqrt(self.total_sq / self.count) if self.count else float("nan")

    def summary(self, scale: float = 1.0, digits: int = 3) -> dict:
        if self.count == 0:
            return {"n": 0}
        r = lambda v: round(v * scale, digits)  # noqa: E731
        return {"n": self.count, "mean": r(self.mean()), "p50": r(self.percentile(50)),
                "p90": r(self.percentile(90)), "p99": r(self.percentile(99)), "max": r(self.max)}  # fmt: skip


def latency_histogram() -> Histogram:
    return Histogram(1.0, 100_000)  # seconds, 10 µs bins


def angle_histogram() -> Histogram:
    return Histogram(math.pi, 18_000)  # rad, 0.01° bins


class RateMeter:
    """Events per second over the last ``window_s`` seconds (wall clock)."""

    def __init__(self, window_s: float = 2.0):
        self.window_s = window_s
        self.t: deque = deque()
        self.first = None

    def tick(self, now: float) -> None:
        if self.first is None:
            self.first = now
        self.t.append(now)
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self.t and self.t[0] < now - self.window_s:
            self.t.popleft()

    def rate(self, now: float) -> float:
        """Over the window, or over the time since the first event when that is shorter."""
        self._trim(now)
        if self.first is None:
            return 0.0
        return len(self.t) / max(min(self.window_s, now - self.first), 0.25)


class StatusPrinter:
    """The live status: one rewritten line on a TTY, a plain line every ``interval_s`` otherwise."""

    def __init__(self, stream=None, quiet: bool = False, interval_s: float | None = None):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        try:
            self.tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self.tty = False
        self.interval_s = interval_s if interval_s is not None else (0.5 if self.tty else 10.0)
        self.next_t = 0.0
        self.dirty = False

    def due(self, now: float) -> bool:
        return not self.quiet and now >= self.next_t

    def show(self, line: str, now: float) -> None:
        self.next_t = now + self.interval_s
        if self.quiet:
            return
        if self.tty:
            width = 200
            self.stream.write("\r\x1b[K" + line[:width])
            self.dirty = True
        else:
            self.stream.write(time.strftime("%H:%M:%S ") + line + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        """A one-off message (kept on its own line, also on a TTY)."""
        if self.quiet:
            return
        self.end_line()
        self.stream.write(text + "\n")
        self.stream.flush()

    def end_line(self) -> None:
        if self.tty and self.dirty:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self.dirty = False


def _f(v, fmt: str, none: str = "-") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return none
    return format(v, fmt)


def no_estimate_reason(s: dict) -> str:
    """Why a bridge run gave no estimate, from its summary (the first cause that applies)."""
    imu = s.get("imu", {})
    est = s.get("estimates", {})
    if est.get("worker_error"):
        return "the estimator failed (the line above)"
    if not imu.get("samples"):
        if not imu.get("message"):
            return ("no usable IMU message arrived (RAW_IMU, SCALED_IMU or HIGHRES_IMU of the --imu "
                    "instance, in a known scale: ask for them, e.g. SRx_RAW_SENS on ArduPilot)")
        return f"every {imu['message']} sample was a duplicate or out of order"
    if est.get("withheld_imu_too_slow"):
        return f"{est['withheld_imu_too_slow']} withheld: the IMU came too slowly (the IMU warning above)"
    if est.get("samples_processed", 0) == 0 and est.get("samples_without_estimator"):
        return f"the estimator was still starting ({est['samples_without_estimator']} samples came before it was ready)"
    return (f"the first window was still filling ({est.get('samples_processed', 0)} samples estimated): "
            "run the bridge longer")


def format_summary(s: dict) -> str:
    """The exit summary as readable lines."""
    ap = s.get("autopilot", {})
    imu = s.get("imu", {})
    msg = s.get("messages", {})
    est = s.get("estimates", {})
    lat = s.get("latency_ms", {})
    fwd = s.get("forward_latency_ms", {})
    dif = s.get("ekf_difference_deg", {})
    lines = [f"bridge summary ({_f(s.get('duration_s'), '.1f')} s)"]
    if ap.get("sysid") is not None:
        lines.append(
            f"  autopilot      : system {ap['sysid']} ({ap.get('autopilot', '?')}, {ap.get('vehicle_type', '?')}); "
            f"lost {ap.get('lost', 0)}x"
        )
    else:
        lines.append("  autopilot      : never seen (no HEARTBEAT from component 1)")
    lines.append(
        f"  IMU            : {imu.get('message') or 'none'} at {_f(imu.get('rate_hz'), '.1f')} Hz, "
        f"{imu.get('samples', 0)} samples; time jumps/reboots {imu.get('time_jumps', 0)}"
    )
    if imu.get("duplicates") or imu.get("out_of_order") or imu.get("reboots") or imu.get("ekf_dropped"):
        lines.append(
            f"  IMU order      : dropped duplicates {imu.get('duplicates', 0)}, out of order {imu.get('out_of_order', 0)} "
            f"(not estimated); reboots {imu.get('reboots', 0)}; EKF attitudes dropped {imu.get('ekf_dropped', 0)}"
        )
    if imu.get("warning"):
        lines.append(f"  IMU warning    : {imu['warning']}")
    lines.append(
        f"  messages       : autopilot {msg.get('from_master', 0)} -> outs {msg.get('forwarded_to_outs', 0)}; "
        f"ground {msg.get('from_outs', 0)} -> autopilot {msg.get('forwarded_to_master', 0)}; "
        f"own {msg.get('sent_own', 0)}"
    )
    lines.append(
        f"  dropped        : garbled frames {msg.get('bad_frames', 0)} ({msg.get('bad_bytes', 0)} bytes), "
        f"own echoes {msg.get('own_echoes', 0)}, unknown ids {msg.get('unknown_dropped', 0)}, write errors {msg.get('write_errors', 0)}, "
        f"stale samples {est.get('dropped_stale', 0)} + queue full {est.get('dropped_queue_full', 0)}"
    )
    lines.append(
        f"  estimates      : {est.get('count', 0)} at {_f(est.get('rate_hz'), '.1f')} Hz"
        + (f", {est['withheld_imu_too_slow']} withheld (IMU too slow)" if est.get("withheld_imu_too_slow") else "")
        + "; model runs "
        f"{est.get('model_runs', 0)} ({_f(est.get('model_ms_mean'), '.2f')} ms each), resets {est.get('resets', 0)}, "
        f"errors {est.get('errors', 0)}, worker restarts {est.get('worker_restarts', 0)}"
    )
    if est.get("worker_error"):
        lines.append(f"  estimator error: {est['worker_error']}")
    if lat.get("n"):
        lines.append(
            f"  latency        : IMU in -> estimate out p50 {lat['p50']:.2f} / p90 {lat['p90']:.2f} / "
            f"p99 {lat['p99']:.2f} / max {lat['max']:.2f} ms"
        )
    if fwd.get("n"):
        lines.append(
            f"  forwarding     : in -> out p50 {fwd['p50']:.3f} / p99 {fwd['p99']:.3f} / max {fwd['max']:.3f} ms"
        )
    if dif.get("n"):
        lines.append(
            f"  vs EKF (incl.) : mean {dif['mean']:.2f} / p50 {dif['p50']:.2f} / p90 {dif['p90']:.2f} / "
            f"max {dif['max']:.2f} deg, rms {dif.get('rms', float('nan')):.2f} deg over {dif['n']} estimates"
            + (f"; within 3σ {100 * dif['within_3sigma']:.1f} %, NEES {dif['nees']:.2f}" if "nees" in dif else "")
        )
    elif not est.get("count"):  # (the autopilot's attitude may well have come: nothing of ours to pair it with)
        lines.append(f"  vs EKF (incl.) : no comparison (no TE-PINN estimates: {no_estimate_reason(s)})")
    else:
        lines.append("  vs EKF (incl.) : no comparison (no ATTITUDE / ATTITUDE_QUATERNION from the autopilot)")
    if s.get("tlog"):
        lines.append(f"  tlog           : {s['tlog']}")
    return "\n".join(lines)

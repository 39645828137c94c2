"""The estimator, off the forwarding path: a child process (default) or a thread, fed through pipes.

Why a process by default: the network's forward pass holds the GIL for part of its ~2–3 ms, so an
estimator thread can delay the forwarding thread (measured: a 0.5 ms sleep overslept by 5 ms at p99
next to a thread running the estimator flat out, 0.09 ms without it), and a crash or hang of the
model in a child process cannot take the router down (the bridge restarts it). The child runs at a
lower priority (nice 10) so that the router goes first. In the bridge the estimator is busy only
~7–10 % of a core at 400 Hz, and on the shared 2-core test machine both modes measured alike
(``benchmarks/bridge_latency.py``); the thread worker also serves tests and embedding.

Protocol (both modes, the same :func:`worker_loop`):

* bridge → worker: fixed-size ``SAMPLE`` records written to a **non-blocking** pipe. A record is
  smaller than ``PIPE_BUF``, so a write is all-or-nothing: when the pipe is full the sample is
  dropped by the bridge ("queue full") instead of queued without bound. The bridge also caps the
  samples in flight (sent − processed − dropped) at its ``queue_samples``.
* worker: reads whatever is waiting, drops samples older than ``max_age_s`` (wall clock since
  the IMU message arrived; "stale") and pushes the rest through
  :class:`~tepinn_flight.model.streaming.StreamingEstimator`, which resets itself on time
  reversals and gaps. Of the samples due at about ``rate_hz`` on the autopilot's clock
  (:class:`~tepinn_flight.rate_thinning.RateThinner`: every sample of an IMU at that rate, through its stamps' jitter)
  only the newest of a batch is sent back. Then, before waiting for the next samples, the estimator's
  ``prepare`` runs the network's next window where the next sample will need it
  (:meth:`~tepinn_flight.model.streaming.StreamingEstimator.prepare`): the estimate of the sample that opens a
  token no longer waits for the network (the same estimates, to the bit).
* worker → bridge: length-prefixed frames: ``R`` ready (JSON), ``E`` estimate + counters,
  ``S`` counters, ``X`` a non-fatal error line (the estimator raised: it is reset and goes on),
  ``F`` a fatal error line (the model could not be loaded; the worker exits).

Run as ``python -m tepinn_flight.live.worker --model CKPT [--runtime torch|onnx|auto]``: records on
stdin, frames on stdout. The network runs in PyTorch or onnxruntime (:mod:`~tepinn_flight.model.runtime`;
with an ``.onnx`` model and ``--runtime onnx``/``auto`` torch is never imported).
"""

from __future__ import annotations

import argparse
import fcntl
import json
import math
import os
import signal
import struct
import subprocess
import sys
import threading
import time

from ..rate_thinning import RateThinner
from ..vehicle_class import CLASSES as VEHICLE_CLASSES
from ..vehicle_class import vehicle_class

#: kind, seq, t_s, arrival (monotonic s), gyr(3), acc(3), mag(3, NaN = none), time_usec, time_boot_ms (-1 = none),
#: flags (CLIPPED | GYR_CLIPPED: the sample at its range, ingest.saturation)
SAMPLE = struct.Struct("<BIdd3d3d3dQiB")
CLIPPED, GYR_CLIPPED = 1, 2
KIND_SAMPLE = 1
KIND_RESET = 2
KIND_VEHICLE = 3  # what the vehicle is: its class's index in vehicle_class.CLASSES in the seq field
#: seq, t_s, arrival, q(4), sigma, bias(3), gyr(3), time_usec, time_boot_ms, model_ran, compute_s
EST = struct.Struct("<Idd4dd3d3dQiBd")
#: processed, dropped_stale, resets, errors, model_runs (in a push or between samples), model_s, step_s (the pushes
#: that did not run the network), steps (those pushes)
COUNTERS = struct.Struct("<IIIIIddI")
HEADER = struct.Struct("<HB")
STATS_INTERVAL_S = 0.05
#: Scheduling priority of the worker process below the bridge's (forwarding first).
NICE = 10
_NAN3 = (math.nan, math.nan, math.nan)


def pack_sample(seq, t_s, arrival, gyr, acc, mag, time_usec, time_boot_ms, kind=KIND_SAMPLE, clipped=False,
                gyr_clipped=False) -> bytes:  # fmt: skip
    m = mag if mag is not None else _NAN3
    flags = (CLIPPED if clipped else 0) | (GYR_CLIPPED if gyr_clipped else 0)
    return SAMPLE.pack(kind, seq & 0xFFFFFFFF, t_s, arrival, *gyr, *acc, *m, int(time_usec) & 0xFFFFFFFFFFFFFFFF,
                       -1 if time_boot_ms is None else int(time_boot_ms) & 0x7FFFFFFF, flags)  # fmt: skip


def reset_record() -> bytes:
    return SAMPLE.pack(KIND_RESET, 0, 0.0, 0.0, *([0.0] * 9), 0, -1, 0)


def vehicle_record(vehicle: str | None) -> bytes:
    """What the vehicle is (the autopilot's MAV_TYPE name, ...: :func:`..vehicle_class.vehicle_class`)."""
    return SAMPLE.pack(KIND_VEHICLE, VEHICLE_CLASSES.index(vehicle_class(vehicle)), 0.0, 0.0, *([0.0] * 9), 0, -1, 0)


def unpack_estimate(payload: bytes) -> tuple[dict, tuple]:
    v = EST.unpack_from(payload)
    c = COUNTERS.unpack_from(payload, EST.size)
    est = {
        "seq": v[0], "t_s": v[1], "arrival": v[2], "q": v[3:7], "sigma": v[7], "bias": v[8:11],
        "gyr": v[11:14], "time_usec": v[14], "time_boot_ms": None if v[15] < 0 else v[15],
        "model_ran": bool(v[16]), "compute_s": v[17],
    }  # fmt: skip
    return est, c


class _Out:
    """Writes frames to the bridge (blocking: the bridge always reads)."""

    def __init__(self, fd: int):
        self.fd = fd

    def send(self, kind: bytes, payload: bytes = b"") -> None:
        data = HEADER.pack(len(payload), kind[0]) + payload
        view = memoryview(data)
        while view:
            n = os.write(self.fd, view)
            view = view[n:]


def worker_loop(in_fd: int, out_fd: int, make_estimator, rate_hz: float = 50.0, max_age_s: float = 0.2,
                clock=time.monotonic) -> int:  # fmt: skip
    """Serve one bridge until ``in_fd`` reaches EOF. Returns an exit code."""
    out = _Out(out_fd)
    try:
        est = make_estimator()
    except Exception as exc:  # noqa: BLE001 - reported to the bridge as one line
        out.send(b"F", _one_line(exc).encode()[:2000])
        return 3
    from ..jit_warmup import warm_up as compile_loops

    compile_loops()  # a cold numba cache (the first run after installing): compiled in two processes at once
    warm_up(est)
    info = {"pid": os.getpid()}
    cfg = getattr(getattr(est, "model", None), "config", None)
    if cfg is not None:
        info.update(token_rate_hz=cfg.token_rate_hz, window_tokens=cfg.window_tokens)
    out.send(b"R", json.dumps(info).encode())
    buf = bytearray()
    size = SAMPLE.size
    processed = dropped = resets = errors = model_runs = steps = 0
    model_s = step_s = 0.0
    thin = RateThinner(rate_hz)  # the estimates sent: about rate_hz, every sample of a stream at that rate
    prepare = getattr(est, "prepare", None)  # StreamingEstimator.prepare: the network between samples
    reported = 0  # estimator errors, a sample's (counted in ``errors``: the bridge counts it consumed) or prepare's

    def failed(exc: BaseException, sample: bool) -> None:
        """The estimator raised (on a sample's push, or in prepare): count it, report the first and every 100th, reset
        it and go on."""
        nonlocal errors, reported
        errors += sample
        reported += 1
        if reported == 1 or reported % 100 == 0:
            out.send(b"X", f"estimator error #{reported}: {_one_line(exc)}".encode()[:2000])
        try:
            est.reset()
        except Exception:  # noqa: BLE001
            pass
        thin.reset()

    t0_prev = None
    last_stats = 0.0
    while True:
        try:
            data = os.read(in_fd, 1 << 16)
        except InterruptedError:
            continue
        except OSError:
            break
        if not data:
            break
        buf += data
        n = len(buf) // size
        recs = [SAMPLE.unpack_from(buf, i * size) for i in range(n)]
        del buf[: n * size]
        due = None
        for r in recs:
            if r[0] == KIND_RESET:
                est.reset()
                thin.reset()
                continue
            if r[0] == KIND_VEHICLE:
                if r[1] < len(VEHICLE_CLASSES) and hasattr(est, "set_vehicle"):
                    est.set_vehicle(VEHICLE_CLASSES[r[1]])
                continue
            if clock() - r[3] > max_age_s:
                dropped += 1
                continue
            t_s = r[2]
            mag = r[10:13]
            try:
                e = est.push(t_s, r[4:7], r[7:10], None if math.isnan(mag[0]) else mag, bool(r[15] & CLIPPED),
                             bool(r[15] & GYR_CLIPPED))  # fmt: skip
            except Exception as exc:  # noqa: BLE001 - the model raised: reset, report, go on
                failed(exc, sample=True)
                continue
            processed += 1
            t0 = getattr(est, "t0", None)
            if t0_prev is not None and t0 != t0_prev:
                resets += 1
            t0_prev = t0
            if e.model_ran:
                model_runs += 1
                model_s += e.compute_s
            else:
                step_s += e.compute_s
                steps += 1
            thin.seen(t_s)
            if e.q_nb_wxyz is None:
                continue
            if thin.due(t_s):
                due = (r, e)
        counters = COUNTERS.pack(processed, dropped, resets, errors, model_runs, model_s, step_s, steps)
        now = clock()
        if due is not None:
            r, e = due
            payload = EST.pack(r[1], r[2], r[3], *e.q_nb_wxyz, e.sigma_rad, *e.gyr_bias_rad_s, *r[4:7], r[13], r[14],
                               int(e.model_ran), e.compute_s)  # fmt: skip
            out.send(b"E", payload + counters)
            last_stats = now
        elif now - last_stats >= STATS_INTERVAL_S:
            out.send(b"S", counters)
            last_stats = now
        if prepare is not None:  # the next sample's network window, run now while the stream is idle (same estimates)
            try:
                ran, secs = prepare()
            except Exception as exc:  # noqa: BLE001 - as a push that raised (no sample lost: not in ``errors``)
                failed(exc, sample=False)
                continue
            if ran:
                model_runs += 1
                model_s += secs
    return 0


def warm_up(est, seconds: float = 4.0, rate_hz: float = 200.0) -> None:
    """Run ``est`` over ``seconds`` of a still, level IMU (longer than one network window), then
    reset it: the compiled loops (numba, built on first use after a fresh install) and the network
    runtime are ready before the bridge's first real sample, so no real sample waits for them and
    goes stale — the last few samples marked saturated, so those paths are built too (a flip's
    first clipped sample must not wait for a compile). Only the shipped kind of estimator
    (:class:`StreamingEstimator`); an error here is left to show on the real samples."""
    from ..model.streaming import StreamingEstimator

    if not isinstance(est, StreamingEstimator):
        return
    acc = (0.0, 0.0, -9.80665)  # specific force of a level FRD body at rest
    n = int(seconds * rate_hz)
    try:
        for i in range(n):
            sat = i >= n - 3
            est.push(i / rate_hz, (0.0, 0.0, 0.0), acc, None, sat, sat)
        from ..model.anchor_kernels import fusion_tilt_f

        fusion_tilt_f(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)  # what a saturation spell's samples call (3 marked
        # samples do not open the gate)
    except Exception:  # noqa: BLE001 - reported when it happens on real samples
        pass
    est.reset(sensor=True)  # its made-up samples at 1 g must not count toward the accelerometer's scale


def _one_line(exc: BaseException) -> str:
    first = (str(exc).strip().splitlines() or [""])[0]
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def _set_nonblocking(fd: int) -> None:
    fl = fcntl.fcntl(fd, fcntl.F_GETFL)
    fcntl.fcntl(fd, fcntl.F_SETFL, fl | os.O_NONBLOCK)


class FrameReader:
    """Non-blocking reads of worker frames; ``eof`` once the worker closed its end."""

    def __init__(self, fd: int):
        self.fd = fd
        self.buf = bytearray()
        self.eof = False

    def read(self) -> list[tuple[bytes, bytes]]:
        while True:
            try:
                data = os.read(self.fd, 1 << 16)
            except BlockingIOError:
                break
            except OSError:
                self.eof = True
                break
            if not data:
                self.eof = True
                break
            self.buf += data
            if len(data) < (1 << 16):
                break
        out = []
        b = self.buf
        i = 0
        while len(b) - i >= HEADER.size:
            n, kind = HEADER.unpack_from(b, i)
            if len(b) - i - HEADER.size < n:
                break
            out.append((bytes([kind]), bytes(b[i + HEADER.size : i + HEADER.size + n])))
            i += HEADER.size + n
        del b[:i]
        return out


class _WorkerBase:
    mode = "?"

    def __init__(self):
        self.in_fd = None
        self.reader = None
        self.submitted = 0
        self.full = 0

    @property
    def out_fd(self) -> int:
        return self.reader.fd

    def submit(self, record: bytes) -> bool:
        """Queue one record without blocking; False when the pipe is full or the worker gone."""
        if self.in_fd is None:
            return False
        try:
            os.write(self.in_fd, record)
        except BlockingIOError:
            self.full += 1
            return False
        except OSError:
            return False
        self.submitted += 1
        return True

    def read(self):
        return self.reader.read()

    @property
    def eof(self) -> bool:
        return self.reader.eof

    def _close_input(self) -> None:
        if self.in_fd is not None:
            try:
                os.close(self.in_fd)
            except OSError:
                pass
            self.in_fd = None


class ProcessWorker(_WorkerBase):
    """``python -m tepinn_flight.live.worker`` as a child process."""

    mode = "process"

    def __init__(self, model_path: str, rate_hz: float, max_age_s: float, runtime: str = "auto", mode: str = "",
                 busy_stride: int = 0):  # fmt: skip
        super().__init__()
        cmd = [sys.executable, "-m", "tepinn_flight.live.worker", "--model", str(model_path),
               "--rate", repr(float(rate_hz)), "--max-age", repr(float(max_age_s)), "--runtime", runtime]  # fmt: skip
        if mode:
            cmd += ["--mode", mode]
        if busy_stride:
            cmd += ["--busy-stride", str(int(busy_stride))]
        env = dict(os.environ)
        env.setdefault("OMP_NUM_THREADS", "1")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     env=env, bufsize=0, start_new_session=True)  # fmt: skip
        self.in_fd = self.proc.stdin.fileno()
        _set_nonblocking(self.in_fd)
        _set_nonblocking(self.proc.stdout.fileno())
        _set_nonblocking(self.proc.stderr.fileno())
        self.reader = FrameReader(self.proc.stdout.fileno())
        self.err_fd = self.proc.stderr.fileno()
        self.stderr_tail = bytearray()

    def read_stderr(self) -> None:
        while self.err_fd is not None:
            try:
                data = os.read(self.err_fd, 1 << 16)
            except (BlockingIOError, OSError):
                return
            if not data:  # the child closed stderr: stop selecting on it
                self.err_fd = None
                self.proc.stderr.close()
                return
            self.stderr_tail = (self.stderr_tail + data)[-4000:]

    def last_stderr_line(self) -> str:
        lines = [ln for ln in self.stderr_tail.decode(errors="replace").splitlines() if ln.strip()]
        return lines[-1].strip() if lines else ""

    def exit_code(self) -> int | None:
        return self.proc.poll()

    def stop(self, timeout_s: float = 3.0) -> None:
        self._close_input()
        try:
            self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.read_stderr()
        self.err_fd = None  # closed below: never read a recycled descriptor number
        for f in (self.proc.stdout, self.proc.stderr, self.proc.stdin):
            try:
                f.close()
            except (OSError, AttributeError):
                pass


class ThreadWorker(_WorkerBase):
    """:func:`worker_loop` in a daemon thread of the bridge's process (shares the GIL)."""

    mode = "thread"

    def __init__(self, make_estimator, rate_hz: float, max_age_s: float):
        super().__init__()
        r_in, self.in_fd = os.pipe()
        r_out, w_out = os.pipe()
        _set_nonblocking(self.in_fd)
        _set_nonblocking(r_out)
        self.reader = FrameReader(r_out)
        self.err_fd = None
        self._fds = (r_in, w_out)
        self.code = None

        def run():
            try:
                self.code = worker_loop(r_in, w_out, make_estimator, rate_hz, max_age_s)
            finally:
                for fd in (r_in, w_out):
                    try:
                        os.close(fd)
                    except OSError:
                        pass

        self.thread = threading.Thread(target=run, name="tepinn-estimator", daemon=True)
        self.thread.start()

    def read_stderr(self) -> None:
        return None

    def last_stderr_line(self) -> str:
        return ""

    def exit_code(self) -> int | None:
        return None if self.thread.is_alive() else (self.code if self.code is not None else 1)

    def stop(self, timeout_s: float = 3.0) -> None:
        self._close_input()
        self.thread.join(timeout_s)
        try:
            os.close(self.reader.fd)
        except OSError:
            pass


def model_estimator_factory(model_path: str, runtime: str = "auto", mode: str = "", busy_stride: int = 0):
    """A factory building a StreamingEstimator from a checkpoint or an ``.onnx`` export, run by
    ``runtime`` (imports torch when called, for the torch runtime only), in ``mode`` (6d/9d/auto;
    "": the model's own) where the model runs the anchored estimator, with ``busy_stride`` (0: the
    model's own; :func:`~tepinn_flight.model.anchor.with_busy_stride`)."""

    def make():
        import dataclasses  # noqa: PLC0415

        from ..model.anchor import with_busy_stride  # noqa: PLC0415
        from ..model.runtime import load_runner  # noqa: PLC0415 - torch only where needed
        from ..model.streaming import StreamingEstimator  # noqa: PLC0415

        runner, fusion, _ = load_runner(model_path, runtime)
        if mode and hasattr(fusion, "mode"):
            fusion = dataclasses.replace(fusion, mode=mode)
        fusion = with_busy_stride(fusion, busy_stride, os.path.basename(model_path))
        return StreamingEstimator(runner, fusion, threads=1)

    return make


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tepinn_flight.live.worker")
    p.add_argument("--model", required=True)
    p.add_argument("--rate", type=float, default=50.0)
    p.add_argument("--max-age", type=float, default=0.2)
    p.add_argument("--runtime", choices=["auto", "torch", "onnx"], default="auto")
    p.add_argument("--mode", choices=["", "6d", "9d", "auto"], default="")
    p.add_argument("--busy-stride", type=int, default=0)
    a = p.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the bridge stops us by closing stdin
    try:
        os.nice(NICE)  # the router goes first when a frame arrives (a 2-core machine has no spare core)
    except OSError:
        pass
    out_fd = os.dup(1)
    os.dup2(2, 1)  # stray prints of libraries go to stderr, never into the protocol
    return worker_loop(0, out_fd, model_estimator_factory(a.model, a.runtime, a.mode, a.busy_stride), a.rate, a.max_age)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""Work for the second core: a generator run in a forked process beside this one, its results read back in order.

The offline estimate of one long record has parts that wait on nothing the anchored pass makes — the gyro's
self-calibration, what the GNSS aid reads from the receiver alone (session 40), and VQF run forward and backward over
each whole segment, which is what the offline smoothing asks for wherever no gate acts (every shared real file; on a
record whose GNSS velocity changed the accelerometer, a second helper forked then makes those runs on the aided
accelerometer beside the last anchored pass). ``vqf.offlineVQF``
holds Python's GIL, so a thread would not run it beside the pass; a forked process does, on its own core, from the
same arrays (copy-on-write: nothing is sent to it). After its first result it runs at the lowest priority, on what
the caller's own threads (the network's) leave idle. The caller reads the results back (pickled through a pipe)
where they are ready when it needs them or soon after and, where the helper had not finished (a machine busy with
other work), failed or was killed, computes them itself: the results are the same bits either way (the same code on
the same inputs), so the helper changes how long an estimate takes, never what it is.

Used only where it pays (:func:`worth_it`): a record of at least ``min_samples``, a machine that lets this process run
on two cores or more, Linux (``fork`` without surprises in the child: macOS's system libraries may refuse to run after
it; Windows has none), and not switched off (``TEPINN_FLIGHT_BESIDE=0``; ``estimate --workers N`` sets it in its
workers, which already keep every core busy).
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import struct
import sys
import time
import warnings
from collections.abc import Callable, Iterator

#: the environment variable that switches the helper off ("0")
ENV = "TEPINN_FLIGHT_BESIDE"
#: records shorter than this are estimated in one process (the fork and the pipe cost ~10 ms; offline VQF on
#: 100 k samples ~0.15 s)
MIN_SAMPLES = 100_000
#: the child's niceness after its first result (before it: the caller's): the rest runs on what the caller's threads
#: leave idle (a result not ready when the caller needs it is computed there instead, :meth:`Beside.take`). Session 35,
#: the one-hour default log, three rounds each: lowest priority throughout 212–221 k samples/s, the first result at the
#: caller's 215–238 k, at the caller's throughout 186–259 k, no helper 155–166 k
NICE = 19
#: how long the caller waits for a result not yet there, per sample of the record, before it computes it itself: a
#: fraction of what that costs it (the smoothing's VQF run both ways 1.3–1.5 µs a sample on this 2-core machine, the
#: self-calibration ~0.6 µs), so a helper that falls behind costs little and one about to finish is not wasted
WAIT_S_PER_SAMPLE = 0.3e-6
#: ... and, past that, how long it goes on waiting (in all, per sample of the record) while the child keeps computing:
#: it then has the core the waiting caller leaves idle, and what it has done is not thrown away. Session 42: the busy
#: GNSS-aided F450 hour's second helper (the smoothing's VQF runs on the aided accelerometer, ~3 s) had had the last
#: anchored pass's 1.4 s beside it; the caller waited 0.4 s more, then ran those 3 s itself
MAX_WAIT_S_PER_SAMPLE = 2.0e-6
#: ... "computing": the child's CPU time grew by at least this share of each slice of ``PROGRESS_SLICE_S`` waited (a
#: child starved by other work on a busy machine gives up its results to the caller as before). A quarter of a core:
#: a late helper has most of its work behind it, and the kernel counts CPU time in 10-ms ticks (half of each 0.1 s
#: failed a CI run where the other test worker shared the child's core)
PROGRESS_SHARE = 0.25
PROGRESS_SLICE_S = 0.2


class BesideFailed(RuntimeError):
    """The helper process gave no result (it raised, was killed or exited): compute it here instead."""


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worth_it(n_samples: int, min_samples: int = MIN_SAMPLES) -> bool:
    """Whether a record of ``n_samples`` gets a helper process here."""
    return (n_samples >= min_samples and sys.platform.startswith("linux") and os.environ.get(ENV, "1") != "0"
            and usable_cores() >= 2)  # fmt: skip


class Beside:
    """``work()`` (a generator) run in a forked child (at the lowest priority after its first result); :meth:`next`
    reads its results in the order it yields them, :meth:`ready` says whether the next one is there. Use as a context
    manager: leaving it stops a child still running; the child dies with its parent."""

    def __init__(self, work: Callable[[], Iterator]):
        r, w = os.pipe()
        parent = os.getpid()
        with warnings.catch_warnings():  # Python ≥ 3.12 warns of fork() beside threads (the network runtime's idle
            # pool): the child runs none of their code, only numpy, numba and VQF on arrays it was given
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                _die_with_parent(parent)
                os.close(r)
                # the parent's handlers (a CLI's cleanup of its partial outputs) are not the child's to run
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                signal.signal(signal.SIGINT, signal.SIG_DFL)
                later = _Writer(w)  # results after the first: written by a thread, so that the next is computed while a
                # large one waits in the pipe for the caller to read it (a pipe holds 64 KB)
                try:
                    for k, item in enumerate(work()):
                        data = pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL)
                        frame = struct.pack("<Q", len(data)) + data
                        if k == 0:  # the first result was wanted soon; the rest fills what the caller leaves idle
                            _write_all(w, frame)
                            os.nice(NICE)
                        else:
                            later.put(frame)
                    code = 0
                finally:
                    later.close()  # what was made is written (or the caller has gone) before the child ends
            except BaseException:  # noqa: BLE001 - the parent sees a short stream and computes it itself
                pass
            finally:
                os._exit(code)
        os.close(w)
        self.pid = pid
        self._fd = r

    def ready(self, wait_s: float = 0.0) -> bool:
        """Whether :meth:`next` would return (or fail) without waiting for the child to compute (waiting for that
        at most ``wait_s``)."""
        return self._fd >= 0 and bool(select.select([self._fd], [], [], max(0.0, wait_s))[0])

    def next(self):
        """The child's next result (:class:`BesideFailed` where it gave none)."""
        if self._fd < 0:
            raise BesideFailed("the helper process was closed")
        try:
            (size,) = struct.unpack("<Q", self._read(8))
            return pickle.loads(self._read(size))
        except Exception as e:  # EOF: it raised or was killed before this result
            self.close()
            raise BesideFailed(f"the helper process gave no result ({type(e).__name__})") from None

    def take(self, wait_s: float = 0.0, max_wait_s: float | None = None):
        """The next result where it is :meth:`ready` within ``wait_s``, or within ``max_wait_s`` in all while the child
        keeps computing (:meth:`_computing`); else the child is stopped (:class:`BesideFailed`): the caller computes it
        sooner than a child at the lowest priority on a busy machine would."""
        t0 = time.perf_counter()
        if not self.ready(wait_s) and not self._computing(t0 + (wait_s if max_wait_s is None else max_wait_s)):
            self.close()
            raise BesideFailed("the helper process had not finished")
        return self.next()

    def _computing(self, until: float) -> bool:
        """Wait for the next result, in slices of :data:`PROGRESS_SLICE_S` up to the clock time ``until``, while the
        child's CPU time grows by :data:`PROGRESS_SHARE` of each slice → whether it came."""
        cpu = _cpu_s(self.pid)
        while cpu is not None and (left := until - time.perf_counter()) > 0:
            t0 = time.perf_counter()
            if self.ready(min(PROGRESS_SLICE_S, left)):
                return True
            now = _cpu_s(self.pid)
            if now is None or now - cpu < PROGRESS_SHARE * (time.perf_counter() - t0):
                return False
            cpu = now
        return False

    def _read(self, n: int) -> bytearray:
        buf = bytearray()
        while len(buf) < n:
            chunk = os.read(self._fd, min(n - len(buf), 1 << 22))
            if not chunk:
                raise EOFError
            buf += chunk
        return buf

    def close(self) -> None:
        """Stop the child (if still running) and reap it."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        if self.pid:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            try:
                os.waitpid(self.pid, 0)
            except ChildProcessError:
                pass
            self.pid = 0

    def __enter__(self) -> "Beside":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _cpu_s(pid: int) -> float | None:
    """The CPU time (user and system, s) process ``pid`` has used so far (Linux's ``/proc``; None: not known)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()  # (after the command's name, which may hold spaces)
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime and stime, in clock ticks
    except (OSError, ValueError, IndexError):
        return None


def _die_with_parent(parent: int) -> None:
    """In the child: be killed when the parent dies (Linux: ``PR_SET_PDEATHSIG``; elsewhere the child ends when its
    work is done and its pipe has no reader), and end now where it already has."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:
        os._exit(1)


class _Writer:
    """In the child: frames written to the pipe in order by one thread (blocked in ``write`` without the GIL while the
    caller has not read the one before), so that the child computes meanwhile."""

    def __init__(self, fd: int):
        import queue
        import threading

        self._q = queue.Queue()
        self._fd = fd
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        try:
            while (frame := self._q.get()) is not None:
                _write_all(self._fd, frame)
        except OSError:  # the caller closed its end (it stopped reading): nothing more to write
            pass

    def put(self, frame: bytes) -> None:
        self._q.put(frame)

    def close(self) -> None:
        self._q.put(None)
        self._t.join()


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]

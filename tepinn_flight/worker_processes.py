"""Worker processes that end with the command: SIGTERM handled as Ctrl-C, and workers that exit when the main
process is gone.

A command killed by ``timeout``, systemd or a job scheduler gets SIGTERM, not SIGINT. Python's default for it is to
die at once: no ``finally``, no temporaries removed, a pool's workers left orphaned waiting on its lock.
:func:`terminate_on_sigterm` turns it into :class:`Terminated` (a ``KeyboardInterrupt``) in the main thread, so
every Ctrl-C path runs. Pool workers are the forkserver's children, not the main process's: :func:`worker_init`
makes them ignore Ctrl-C (the main process stops them) and exit within 0.5 s of the main process, even one killed
with ``kill -9`` (or left a zombie by a parent that has not reaped it), and write nothing more to the terminal once it
is gone: a worker that finished a job in that half second failed to hand its result back and printed the pool's
``BrokenPipeError`` tracebacks after the user's prompt. :func:`quiet_tracker_after_kill` keeps multiprocessing's
resource tracker, which outlives a killed main process by a moment, from warning about the pool's semaphores it
then cleans up.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread (:func:`terminate_on_sigterm`)."""


@contextmanager
def terminate_on_sigterm():
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread (elsewhere: nothing changes);
    the handler before is put back after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise Terminated

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


@contextmanager
def signals_held():
    """Ctrl-C and SIGTERM held while the block runs — a pool being started, whose ``__init__`` cleans up after an
    ``Exception`` but not after a ``KeyboardInterrupt``: workers half started were left behind, and a campaign
    resumed and terminated at that moment hung. One that came is raised when the block has ended (in the main
    thread; elsewhere nothing changes). Where the block fails while a signal came (a process it started, killed by the
    same signal: the forkserver of a pool, an ``EOFError`` here), the signal is what is raised."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    old = {s: signal.signal(s, lambda signum, frame: came.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    failed = None
    try:
        yield
    except Exception as exc:  # (raised below, unless a signal came: then that is what stopped the block)
        failed = exc
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if came:
        raise (Terminated if came[0] == signal.SIGTERM else KeyboardInterrupt) from None
    if failed is not None:
        raise failed


def start_forkserver(ctx) -> None:
    """Start ``ctx``'s forkserver (where it is one, and not yet running) with Ctrl-C blocked, which it inherits. A
    terminal sends Ctrl-C to the whole process group, and the forkserver ignores it only once it has imported its
    preload (the simulation's: seconds): it had died of one there with a traceback, and the pool's start with an
    ``EOFError`` (exit 1; session 58). The block lasts the spawn alone (a Ctrl-C then is delivered to this process
    right after). multiprocessing's resource tracker is started first: its own start unblocks Ctrl-C."""
    if ctx.get_start_method() != "forkserver" or threading.current_thread() is not threading.main_thread():
        return
    from multiprocessing import forkserver, resource_tracker

    resource_tracker.ensure_running()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        forkserver.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


@contextmanager
def signals_ignored():
    """Ctrl-C and SIGTERM dropped while the block runs — a pool being terminated and joined after the first one: a
    second (a terminal's user pressing Ctrl-C again; ``timeout``, which signals the command and then its whole
    process group, so the main process gets two) had stopped ``Pool.terminate`` before it killed the workers, and the
    ``join`` that followed waited for them for ever (session 58: 3 of 5 interrupted campaigns hung). In the main thread;
    elsewhere nothing changes. The exception already on its way is what the caller raises."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def stop_pool(pool, stopping: bool) -> None:
    """A pool's end: ``terminate`` where ``stopping`` (an exception on its way: Ctrl-C, SIGTERM, an error), then
    ``join`` — both out of reach of another signal (:func:`signals_ignored`). ``pool`` None: nothing."""
    if pool is None:
        return
    with signals_ignored():
        if stopping:
            pool.terminate()
        pool.join()


def worker_init(main_pid: int | None = None) -> None:
    """A pool worker's start: ignore Ctrl-C and SIGTERM's conversion (the main process terminates its workers), and
    exit when ``main_pid`` is gone (a watchdog thread polls it every 0.5 s), writing nothing to stderr from then
    on."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if main_pid is not None:
        sys.stderr = _SilentWithout(sys.stderr, main_pid)
        threading.Thread(target=_exit_without, args=(main_pid,), daemon=True, name="worker-watchdog").start()


def quiet_tracker_after_kill() -> None:
    """Processes this one starts from now on (the forkserver, spawned workers, the resource tracker) ignore the
    resource tracker's warning about semaphores left by a process that was killed: a pool's, cleaned up by it."""
    opt = "ignore:resource_tracker:UserWarning"
    if opt not in sys.warnoptions:
        sys.warnoptions.append(opt)  # passed on as ``-W`` (multiprocessing.util._args_from_interpreter_flags)


def main_gone(pid: int) -> bool:
    """Whether process ``pid`` has ended: no such process, or a zombie not yet reaped by its parent (``kill(pid,
    0)`` still succeeds on one)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, someone else's (cannot happen for our parent)
        return False
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            state = fh.read().rsplit(b")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False  # not Linux, or gone between the two looks (the next poll sees it)
    return state in (b"Z", b"X")


class _SilentWithout:
    """A worker's stderr that writes nothing once the main process has ended (its other attributes: the stream's)."""

    def __init__(self, stream, main_pid: int):
        self._stream, self._main_pid = stream, main_pid

    def write(self, text):
        if main_gone(self._main_pid):
            return len(text)
        return self._stream.write(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _exit_without(pid: int) -> None:
    while True:
        time.sleep(0.5)
        if main_gone(pid):
            os._exit(1)

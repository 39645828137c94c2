"""Worker processes that end with the command: SIGTERM handled as Ctrl-C, and workers that exit when the main
process is gone.

A command killed by ``timeout``, systemd or a job scheduler gets SIGTERM, not SIGINT. Python's default for it is to
die at once: no ``finally``, no temporaries removed, a pool's workers left orphaned waiting on its lock.
:func:`terminate_on_sigterm` turns it into :class:`Terminated` (a ``KeyboardInterrupt``) in the main thread, so
every Ctrl-C path runs. Pool workers are the forkserver's children, not the main process's: :func:`worker_init`
makes them ignore Ctrl-C (the main process stops them) and exit within 0.5 s of the main process, even one killed
with ``kill -9``.
"""

from __future__ import annotations

import os
import signal
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
    thread; elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    old = {s: signal.signal(s, lambda signum, frame: came.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if came:
        raise Terminated if came[0] == signal.SIGTERM else KeyboardInterrupt


def worker_init(main_pid: int | None = None) -> None:
    """A pool worker's start: ignore Ctrl-C and SIGTERM's conversion (the main process terminates its workers), and
    exit when ``main_pid`` is gone (a watchdog thread polls it every 0.5 s)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if main_pid is not None:
        threading.Thread(target=_exit_without, args=(main_pid,), daemon=True, name="worker-watchdog").start()


def _exit_without(pid: int) -> None:
    while True:
        time.sleep(0.5)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            os._exit(1)
        except PermissionError:  # alive, someone else's (cannot happen for our parent; keep waiting)
            pass

"""Work for the second core: a generator run in a forked process beside this one, its results read back in order.

The offline estimate of one long record has parts that wait on nothing the anchored pass makes — the gyro's
self-calibration, and VQF run forward and backward over each whole segment, which is what the offline smoothing asks
for wherever no gate acts (every shared real file). ``vqf.offlineVQF`` holds Python's GIL, so a thread would not run
it beside the pass; a forked process does, on its own core, from the same arrays (copy-on-write: nothing is sent to
it). The caller reads the results back as they come (pickled through a pipe) and, where the helper failed, was killed
or is not available, computes them itself: the results are the same bits either way (the same code on the same
inputs), so the helper changes how long an estimate takes, never what it is.

Used only where it pays (:func:`worth_it`): a record of at least ``min_samples``, a machine that lets this process run
on two cores or more, ``os.fork`` there, and not switched off (``TEPINN_FLIGHT_BESIDE=0``; ``estimate --workers N``
sets it in its workers, which already keep every core busy).
"""

from __future__ import annotations

import os
import pickle
import signal
import warnings
from collections.abc import Callable, Iterator

#: the environment variable that switches the helper off ("0")
ENV = "TEPINN_FLIGHT_BESIDE"
#: records shorter than this are estimated in one process (the fork and the pipe cost ~10 ms; offline VQF on
#: 100 k samples ~0.15 s)
MIN_SAMPLES = 100_000


class BesideFailed(RuntimeError):
    """The helper process gave no result (it raised, was killed or exited): compute it here instead."""


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worth_it(n_samples: int, min_samples: int = MIN_SAMPLES) -> bool:
    """Whether a record of ``n_samples`` gets a helper process here."""
    return (n_samples >= min_samples and hasattr(os, "fork") and os.environ.get(ENV, "1") != "0"
            and usable_cores() >= 2)  # fmt: skip


class Beside:
    """``work()`` (a generator) run in a forked child; :meth:`next` reads its results in the order it yields them.
    Use as a context manager: leaving it stops a child still running."""

    def __init__(self, work: Callable[[], Iterator]):
        r, w = os.pipe()
        with warnings.catch_warnings():  # Python ≥ 3.12 warns of fork() beside threads (the network runtime's idle
            # pool): the child runs none of their code, only numpy, numba and VQF on arrays it was given
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                os.close(r)
                # the parent's handlers (a CLI's cleanup of its partial outputs) are not the child's to run
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                signal.signal(signal.SIGINT, signal.SIG_DFL)
                with os.fdopen(w, "wb") as f:
                    for item in work():
                        pickle.dump(item, f, protocol=pickle.HIGHEST_PROTOCOL)
                        f.flush()
                code = 0
            except BaseException:  # noqa: BLE001 - the parent sees a short stream and computes it itself
                pass
            finally:
                os._exit(code)
        os.close(w)
        self.pid = pid
        self._f = os.fdopen(r, "rb")

    def next(self):
        """The child's next result (:class:`BesideFailed` where it gave none)."""
        if self._f is None:
            raise BesideFailed("the helper process was closed")
        try:
            return pickle.load(self._f)
        except Exception as e:  # EOF: it raised or was killed before this result
            self.close()
            raise BesideFailed(f"the helper process gave no result ({type(e).__name__})") from None

    def close(self) -> None:
        """Stop the child (if still running) and reap it."""
        if self._f is not None:
            self._f.close()
            self._f = None
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

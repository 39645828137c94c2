"""A one-line notice when numba compiles this package's loops (the first run after an install or an
upgrade, or with an empty cache), so a user does not take the pause for a hang; nothing when the
loops load from numba's cache (the ``numba:compile`` event fires only on a cache miss).

The loops are the older fusion (``model/fusion.py``, run alongside the shipped estimator), the
shipped estimator's kernels between network windows (``model/anchor_kernels.py``), the live
accelerometer-scale reading (``model/accel_scale_kernels.py``), the baseline
filters (``evaluation/filters/``), the tlog frame sync (``ingest/mavlink_sync.py``) and the simulation's
flight loop (``sim/``);
``benchmarks/jit_compile.py`` measures their compile and cache-load times.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: what the CLI prints (after its ``tepinn-flight VERB: note:`` prefix)
COMPILE_NOTICE = ("compiling the package's loops once (numba, first run after installing: about 10-30 s; "
                  "cached afterwards)")  # fmt: skip


#: the notices of the blocks open now, innermost last (:func:`announce`)
_OPEN: list = []


@contextmanager
def compile_notice(say: Callable[[str], None] | None) -> Iterator[None]:
    """Within the block, call ``say(COMPILE_NOTICE)`` once, when numba starts compiling a function
    of ``tepinn_flight`` (not on a cache load, not for other packages' functions) or when :func:`announce` says a
    helper process will (:mod:`.jit_warmup`). ``say=None``: nothing (quiet mode), and numba is not even imported."""
    if say is None:
        yield
        return
    from numba.core import event

    class _Once(event.Listener):
        done = False

        def on_start(self, ev):
            if self.done:
                return
            disp = (ev.data or {}).get("dispatcher")
            module = getattr(getattr(disp, "py_func", None), "__module__", None) or ""
            if module.startswith("tepinn_flight."):
                self.say()

        def say(self):
            if not self.done:
                self.done = True
                say(COMPILE_NOTICE)

        def on_end(self, ev):
            pass

    once = _Once()
    _OPEN.append(once)
    try:
        with event.install_listener("numba:compile", once):
            yield
    finally:
        _OPEN.remove(once)


def announce() -> None:
    """The package's loops are about to compile elsewhere (the warm-up's helper process, whose compiles this
    process does not see): the innermost open :func:`compile_notice` says so, once."""
    if _OPEN:
        _OPEN[-1].say()

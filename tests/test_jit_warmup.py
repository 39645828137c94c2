"""The warm-up's helper process (``tepinn_flight/jit_warmup.py``) is never left behind. What the warm-up compiles
where, on a cold cache, is checked with the first run's other checks in ``tests/test_first_run_compile.py`` (one
cold compile for all of them)."""

from __future__ import annotations

import subprocess
import sys


def test_a_helper_past_its_time_or_a_stopped_caller_leaves_no_process_behind():
    """``join`` waits at most its time, then ends the helper; ``stop`` (an error or Ctrl-C in the caller) ends it at
    once instead of waiting for its compiles."""
    import time

    from tepinn_flight.jit_warmup import WarmUp

    for end in (lambda w: w.join(wait_s=0.2), lambda w: w.stop()):
        p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
        t0 = time.perf_counter()
        end(WarmUp(True, p))
        assert p.poll() is not None and time.perf_counter() - t0 < 10
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    w = WarmUp(True, done)
    w.join()
    assert done.returncode == 0 and w.helper is None  # a helper that finished: reaped, not killed

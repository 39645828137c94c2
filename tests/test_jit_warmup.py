"""The warm-up on a cold numba cache (``tepinn_flight/jit_warmup.py``): the helper process compiles the anchored
filter's steps and its VQF, this process the fusion's and the estimator's other loops, and afterwards an offline
estimate (GNSS aid, a clipped gyro, rests, a magnetometer) and the live estimator compile nothing; on a warm cache it
does nothing. Run in a fresh process with its own ``NUMBA_CACHE_DIR`` (numba reads it at import), so the cache state
is known."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_SCRIPT = textwrap.dedent("""
    import sys
    import numpy as np
    from numba.core import event
    from tepinn_flight import jit_warmup
    from tepinn_flight.ingest import load_record

    names = []

    class Compiles(event.Listener):
        def on_start(self, ev):
            f = ev.data["dispatcher"].py_func
            if f.__module__.startswith("tepinn_flight."):
                names.append(f.__module__ + "." + f.__qualname__)

        def on_end(self, ev):
            pass

    with event.install_listener("numba:compile", Compiles()):
        print("cold", jit_warmup.cold())
        print("ran", jit_warmup.warm_up())
        print("here", " ".join(sorted(set(names))))
        names.clear()
        print("cold", jit_warmup.cold())
        from tepinn_flight.cli.main import main
        for path in sys.argv[1:]:
            assert main(["estimate", path, "-o", path + ".est.parquet", "-q"]) == 0
        from tepinn_flight.model.runtime import default_onnx_path, load_runner
        from tepinn_flight.model.streaming import StreamingEstimator

        runner, settings, _ = load_runner(default_onnx_path(), "onnx")
        rec = load_record(sys.argv[-1])
        live = StreamingEstimator(runner, settings, threads=1)
        mag = rec.mag_ut
        for i in range(len(rec)):
            live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i], mag[i], bool(rec.clipped[i]), bool(rec.gyr_clipped[i]))
        print("after", " ".join(sorted(set(names))))
        print("ran", jit_warmup.warm_up())
""")


@pytest.mark.slow
def test_after_the_warm_up_an_estimate_and_the_live_estimator_compile_nothing(tmp_path):
    pytest.importorskip("onnxruntime")
    from tepinn_flight.record import MAG_COLS, write_record
    from tepinn_flight.sim.simulate import simulate_record
    from tests.test_gyro_selfcal import turns_with_rests

    flight = simulate_record("F450", 12.0, rate_hz=200.0, seed=2)  # a receiver: the GNSS aid
    assert flight.gnss_vel_ne_m_s is not None
    turns, _ = turns_with_rests(clipped_turn=6, n_turns=8)  # rests (the self-calibration), a clipped gyro
    turns.data[MAG_COLS] = np.tile([20.0, 0.0, 45.0], (len(turns), 1))  # 9-D
    paths = [tmp_path / "flight.parquet", tmp_path / "turns.parquet"]
    write_record(flight, paths[0])
    write_record(turns, paths[1])
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": REPO}
    env.pop("NUMBA_DISABLE_JIT", None)
    p = subprocess.run([sys.executable, "-c", _SCRIPT, *map(str, paths)], capture_output=True, text=True, env=env,
                       cwd=REPO, timeout=900)  # fmt: skip
    assert p.returncode == 0, p.stderr
    lines = dict(line.split(" ", 1) if " " in line else (line, "") for line in p.stdout.splitlines())
    out = p.stdout.splitlines()
    assert out[0] == "cold True" and out[1] == "ran True", p.stdout
    here = set(lines["here"].split())
    assert {"tepinn_flight.model.fusion._run", "tepinn_flight.model.fusion._step", "tepinn_flight.model.fusion._step_live",
            "tepinn_flight.model.window_features._features", "tepinn_flight.model.gnss_aid_kernels.window_sums",
            "tepinn_flight.model.gyro_selfcal.attitude_at"} <= here, lines["here"]  # (this process's share)
    # the helper's share was compiled there, not here
    helper_only = {"tepinn_flight.model.anchor_steps.run_segment", "tepinn_flight.model.anchor_steps.update_one",
                   "tepinn_flight.model.anchor_steps.correct", "tepinn_flight.model.vqf_kernel.update"}
    assert not here & helper_only, lines["here"]
    assert out[3] == "cold False", p.stdout
    assert lines["after"] == "", f"compiled after the warm-up: {lines['after']}"
    assert out[-1] == "ran False", p.stdout  # a warm cache: nothing started


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

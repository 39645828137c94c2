"""Each compiled loop is compiled for one signature, whatever its callers pass: the offline and the
live fusion share ``_step``'s, and a record's read-only Fortran-ordered columns, C arrays, 6-D and
9-D calls give each filter one. (Every extra signature is another full compile on first use —
seconds each; ``benchmarks/jit_compile.py``.) Run in a fresh process, so the dispatchers hold only
what these calls compiled."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CALLS = textwrap.dedent("""
    import numpy as np
    from tepinn_flight.evaluation.estimators import FilterEstimator
    from tepinn_flight.evaluation.filters import Complementary, Ekf, Madgwick, complementary, ekf, madgwick
    from tepinn_flight.model import fusion
    from tepinn_flight.model.fusion import AttitudeFusion, FusionConfig, FusionRun
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import MAG_COLS

    rec = synthetic_record(seed=2, duration_s=6.0, rate_hz=100.0)
    n = len(rec)
    mag = np.tile([20.0, 0.0, 45.0], (n, 1))
    rec.data[MAG_COLS] = mag
    assert np.isfinite(rec.mag_ut).all()
    assert not rec.gyr_rad_s.flags.writeable and rec.gyr_rad_s.flags.f_contiguous  # as a record hands them out
    for cfg in (FusionConfig(), FusionConfig.uncalibrated()):
        for t, g in ((rec.t_s, rec.gyr_rad_s), (np.array(rec.t_s), np.ascontiguousarray(rec.gyr_rad_s))):
            run = FusionRun(t, g, cfg, rec.clipped)
            idx = np.arange(20, n, 16)
            run.add(idx, np.tile([1.0, 0, 0, 0], (len(idx), 1)), np.full(len(idx), 0.05), np.zeros((len(idx), 3)))
            run.advance(n)
        live = AttitudeFusion(cfg)
        for i in range(60):
            est = (rec.q_ref_wxyz[i], 0.05, np.zeros(3)) if i % 16 == 15 else None  # read-only rows, arrays
            live.step(rec.t_s[i], rec.gyr_rad_s[i], est, bool(rec.clipped[i]))
            live.step(rec.t_s[i] + 1e-4, tuple(rec.gyr_rad_s[i]), None if est is None else (tuple(est[0]), 0.05, (0, 0, 0)))
    for use_mag in (False, True):
        for f in (Complementary(), Madgwick(), Ekf()):
            FilterEstimator(f, use_mag=use_mag and f.name != "ekf").estimate(rec)
            f.estimate(np.ascontiguousarray(rec.gyr_rad_s), np.ascontiguousarray(rec.acc_m_s2), rec.t_s,
                       mag if use_mag else None)
    for name, d in (("fusion._run", fusion._run), ("fusion._step", fusion._step),
                    ("complementary._run", complementary._run), ("madgwick._run", madgwick._run),
                    ("ekf._loop", ekf._loop)):
        print(name, len(d.signatures))
""")


@pytest.mark.slow
def test_every_loop_is_compiled_for_one_signature(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": REPO}
    env.pop("NUMBA_DISABLE_JIT", None)
    p = subprocess.run([sys.executable, "-c", _CALLS], capture_output=True, text=True, env=env, cwd=REPO, timeout=600)
    assert p.returncode == 0, p.stderr
    counts = dict(line.split() for line in p.stdout.splitlines())
    assert counts == {k: "1" for k in ("fusion._run", "fusion._step", "complementary._run", "madgwick._run",
                                       "ekf._loop")}, p.stdout  # fmt: skip

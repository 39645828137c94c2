"""The compiled baseline filters equal the plain-Python loops they replaced
(``tests/filters_reference.py``) to 1e-9 on a real shared log (a BROAD trial: 9-D, rest phases
for the EKF's zero-rate update) and on the real ArduPilot log (6-D, 50 Hz)."""

from __future__ import annotations

import numpy as np
import pytest

from tepinn_flight.evaluation.filters import complementary, ekf, madgwick
from tepinn_flight.evaluation.filters.common import as_tuple4, check_inputs, initial_attitude
from tests import filters_reference as ref
from tests.conftest import broad_trial, real_log

N = 30_000  # samples of the trial (about 100 s at 286 Hz): the reference loops are slow


def _inputs(which):
    from tepinn_flight.ingest import load_record

    path = broad_trial("broad_06_*.hdf5") if which == "broad" else real_log("erle_pxf_copter_15-12-2014_16.BIN")
    rec = load_record(path)
    gyr, acc, dt, mag = check_inputs(rec.gyr_rad_s[:N], rec.acc_m_s2[:N], rec.t_s[:N], rec.mag_ut[:N])
    q0 = as_tuple4(initial_attitude(acc[0], None if mag is None else mag[0]))
    return gyr, acc, dt, mag, q0


def _close(got, want):
    for g, w in zip(got if isinstance(got, tuple) else (got,), want if isinstance(want, tuple) else (want,)):
        assert g.shape == w.shape and np.all(np.isfinite(g))
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["broad", "ardupilot"])
def test_compiled_filters_equal_their_python_loops_on_real_logs(which):
    gyr, acc, dt, mag, q0 = _inputs(which)
    none = np.zeros((0, 3))
    gl, al, dl = gyr.tolist(), acc.tolist(), dt.tolist()
    _close(complementary._run(gyr, acc, none, dt, 1.0, 5.0, q0), ref.complementary_run(gl, al, None, dl, 1.0, 5.0, q0))
    down = (-acc).tolist()
    _close(madgwick._run(gyr, -acc, none, dt, 0.1, 2.0, q0), ref.madgwick_run(gl, down, None, dl, 0.1, 2.0, q0))
    if mag is not None:
        ml = mag.tolist()
        _close(complementary._run(gyr, acc, mag, dt, 0.5, 2.0, q0), ref.complementary_run(gl, al, ml, dl, 0.5, 2.0, q0))
        for k in (1.0, 2.0):  # the original quirk and the corrected filter
            _close(madgwick._run(gyr, -acc, mag, dt, 0.12, k, q0), ref.madgwick_run(gl, down, ml, dl, 0.12, k, q0))
    for p, b0 in ((ekf.EkfParams(), (0.0, 0.0, 0.0)),
                  (ekf.EkfParams(acc_lowpass_tau_s=0.0, acc_dynamic_gain=0.5, acc_gate_m_s2=3.0, rest_min_s=0.5),
                   (0.01, 0.0, -0.01))):  # fmt: skip
        _close(ekf._run(gyr, acc, dt, p, q0, b0), ref.ekf_run(gyr, acc, dt, p, q0, b0))

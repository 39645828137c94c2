"""JSBSim's C++ step and reads called from compiled code (sim/jsbsim_native.py) against the Python binding."""

import math

import jsbsim
import numpy as np
import pytest

from tepinn_flight.sim import jsbsim_native as jn
from tepinn_flight.sim.flight import (AGL_PATH, AIRCRAFT, STATE_COLS, STATE_H_AT, STATE_PATHS, TRUTH_PATHS,
                                      TRUTH_PATHS_END, fly)
from tepinn_flight.sim.jsbsim_env import open_fdm

LAYOUT_KNOWN = (jsbsim.FGFDMExec.__basicsize__, jsbsim.FGPropertyNode.__basicsize__) == (jn.EXEC_SIZE, jn.NODE_SIZE)
needs_layout = pytest.mark.skipif(
    not LAYOUT_KNOWN, reason=f"jsbsim {jsbsim.__version__}'s binding has another object layout: fly() uses the binding"
)


def _fdm(aircraft="F450", rate_hz=400.0):
    veh = AIRCRAFT[aircraft].build()
    return veh, open_fdm(veh.model, 1.0 / rate_hz, own_aircraft=veh.own_aircraft, lean=getattr(veh, "lean", None))


def _row_paths(veh):
    return [*TRUTH_PATHS, *veh.log_paths, *TRUTH_PATHS_END]


@needs_layout
def test_handles_found_and_checked():
    veh, ctx = _fdm()
    with ctx as fdm:
        fdm.run_ic()
        hd = jn.native_handles(fdm, [AGL_PATH, *_row_paths(veh)])
        assert hd is not None
        assert len(hd.node_ptrs) == 1 + len(_row_paths(veh))
        # a path that does not exist, another object, the switch: no handles
        assert jn.native_handles(fdm, ["no/such-property"]) is None
        assert jn.native_handles(object(), [AGL_PATH]) is None


@needs_layout
def test_another_release_takes_the_bindings_path(monkeypatch):
    """A jsbsim release whose layout was not read (its objects may hold other things there): no pointer is
    taken from its objects, the binding runs."""
    monkeypatch.setattr(jsbsim, "__version__", "9.0.0")
    veh, ctx = _fdm()
    with ctx as fdm:
        fdm.run_ic()
        assert jn.native_handles(fdm, [AGL_PATH]) is None


def test_why_not_is_said(monkeypatch):
    """The benchmarks' line says which path runs and, where it is the binding, why."""
    if LAYOUT_KNOWN:
        assert jn.unavailable() is None and "C++" in jn.describe()
    monkeypatch.setattr(jsbsim, "__version__", "9.0.0")
    assert "jsbsim 9.0.0" in jn.unavailable() and "binding (jsbsim 9.0.0" in jn.describe()
    monkeypatch.setenv(jn.ENV_SWITCH, "0")
    assert jn.unavailable() == f"{jn.ENV_SWITCH}=0"


def test_switch_turns_it_off(monkeypatch):
    monkeypatch.setenv(jn.ENV_SWITCH, "0")
    veh, ctx = _fdm()
    with ctx as fdm:
        fdm.run_ic()
        assert jn.native_handles(fdm, [AGL_PATH]) is None
        st = jn.Stepper(fdm, AGL_PATH, _row_paths(veh), 1, -1e9, 10, STATE_COLS, STATE_H_AT)
        assert not st.native


@pytest.mark.parametrize("sub", [1, 3])
@pytest.mark.parametrize("native", [True, False])
def test_rows_and_state_are_the_bindings_reads(monkeypatch, sub, native):
    """After each block the rows hold what the binding reads at that instant, and the state what the
    controller would read (fdm[path], an independent way in): through C++ and through the binding."""
    if native and not LAYOUT_KNOWN:
        pytest.skip(f"jsbsim {jsbsim.__version__}'s binding has another object layout")
    monkeypatch.setenv(jn.ENV_SWITCH, "1" if native else "0")
    veh, ctx = _fdm()
    with ctx as fdm:
        fdm.run_ic()
        paths = _row_paths(veh)
        st = jn.Stepper(fdm, AGL_PATH, paths, sub, -1e9, 40, STATE_COLS, STATE_H_AT)
        assert st.native == native
        i = 0
        for n in (2 * sub, sub, 2 * sub + 1):
            assert st.logged(i, n) == -1
            i += n
            if i % sub == 0:
                want = [fdm[p] for p in STATE_PATHS]
                assert st.state() == want
            rows = st.rows()
            assert rows.shape == (i // sub, len(paths))
            if i % sub == 0:
                np.testing.assert_array_equal(rows[-1], [fdm[p] for p in paths])
        assert math.isclose(fdm.get_sim_time(), i * fdm.get_delta_t(), rel_tol=1e-12)


@needs_layout
@pytest.mark.parametrize("sub", [1, 2])
def test_stop_below_the_floor_like_the_binding(monkeypatch, sub):
    """A height not above the floor stops at the same step, with the same height and rows, both ways."""
    got = []
    for switch in ("1", "0"):
        monkeypatch.setenv(jn.ENV_SWITCH, switch)
        veh, ctx = _fdm()
        with ctx as fdm:
            fdm.run_ic()
            floor = fdm[AGL_PATH] - 1e-9  # the first steps fall below it
            st = jn.Stepper(fdm, AGL_PATH, _row_paths(veh), sub, floor, 50, STATE_COLS, STATE_H_AT)
            assert st.native == (switch == "1")
            stops = [st.logged(i, 4) for i in range(0, 40, 4)]
            stop = next(s for s in stops if s >= 0)
            got.append((stop, st.h, st.rows().copy()))
    assert got[0][0] == got[1][0] and got[0][1] == got[1][1]
    np.testing.assert_array_equal(got[0][2], got[1][2])


@pytest.mark.parametrize("aircraft,rate_hz,seed", [("F450", 400.0, 3), ("agile_quad", 250.0, 4), ("c172x", 100.0, 5)])
def test_flights_are_the_same_bits_both_ways(monkeypatch, aircraft, rate_hz, seed):
    """fly() through JSBSim's C++ and through the binding: every array and the metadata equal."""
    out, found = [], []
    real = jn.native_handles
    monkeypatch.setattr(jn, "native_handles", lambda *a: found.append(real(*a)) or found[-1])
    for switch in ("1", "0"):
        monkeypatch.setenv(jn.ENV_SWITCH, switch)
        out.append(fly(aircraft, 4.0, rate_hz=rate_hz, seed=seed))
    assert (found[0] is not None) == LAYOUT_KNOWN and found[1] is None  # the first flight went through C++
    a, b = out
    for name in ("t_s", "q_nb_wxyz", "gyr_true_rad_s", "acc_true_m_s2", "pos_ned_m", "vel_ned_m_s"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.meta == b.meta and a.maneuvers == b.maneuvers
    assert len(a.t_s) == round(4.0 * rate_hz)


def test_numba_turned_off_takes_the_bindings_path_with_the_same_flight(tmp_path):
    """With numba's compilation off (NUMBA_DISABLE_JIT=1, a debugging switch) the kernels would run as Python, where
    JSBSim's C++ cannot be called: the binding's path runs instead (it raised before), and flies the same numbers."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np, sys; from tepinn_flight.sim.flight import fly; from tepinn_flight.sim import "
            "jsbsim_native as jn; tr = fly('agile_quad', 1.5, 200.0, seed=3); print(jn.unavailable()); "
            "np.save(sys.argv[1], np.hstack([tr.q_nb_wxyz, tr.acc_true_m_s2, tr.gyr_true_rad_s]))")  # fmt: skip
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": repo}
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path / "off.npy")], capture_output=True, text=True,
                       env=env, cwd=repo, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "NUMBA_DISABLE_JIT" in p.stdout
    tr = fly("agile_quad", 1.5, 200.0, seed=3)
    assert np.load(tmp_path / "off.npy").tobytes() == np.hstack([tr.q_nb_wxyz, tr.acc_true_m_s2, tr.gyr_true_rad_s]).tobytes()

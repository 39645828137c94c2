"""The multirotor's compiled flight loop (sim/quad_flight_kernel.py) and its maneuvers' compiled laws
(sim/quad_maneuver_law.py): against the former pure-Python maneuvers, and against the binding's Python loop."""

import math
import subprocess
import sys

import jsbsim
import numpy as np
import pytest

from tepinn_flight.sim import jsbsim_native as jn
from tepinn_flight.sim import quad_maneuver_law as law
from tepinn_flight.sim.flight import AGL_PATH, AIRCRAFT, STATE_PATHS, fly
from tepinn_flight.sim.jsbsim_env import open_fdm
from tepinn_flight.sim.multirotor import AGILE_QUAD, F450, NATIVE_READS, QuadController
from tepinn_flight.sim.multirotor_maneuvers import LIBRARY
from tepinn_flight.sim.quad_control_law import N_OBS, N_PARAMS, N_REF, OBS_Q, OBS_W, REF_YAW_RATE_FF
from tepinn_flight.sim.quad_flight_kernel import C_CMD, C_STATE, N_CTX, N_STATE

from .quad_maneuver_reference import REF_LIBRARY, ReferenceController

LAYOUT_KNOWN = (jsbsim.FGFDMExec.__basicsize__, jsbsim.FGPropertyNode.__basicsize__) == (jn.EXEC_SIZE, jn.NODE_SIZE)
needs_layout = pytest.mark.skipif(
    not LAYOUT_KNOWN, reason=f"jsbsim {jsbsim.__version__}'s binding has another object layout: fly() uses the binding"
)


class _Node:
    def __init__(self, store, path):
        self.store, self.path = store, path

    def get_double_value(self):
        return self.store[self.path]

    def set_double_value(self, value):
        self.store[self.path] = float(value)


class _FakeFdm:
    """Properties in a dict, read and written through the same calls as JSBSim's binding."""

    def __init__(self):
        self.values = {}

    def get_property_manager(self):
        return self

    def get_node(self, path, create=False):
        self.values.setdefault(path, 0.0)
        return _Node(self.values, path)

    def __setitem__(self, path, value):
        self.values[path] = float(value)


def _random_state(fdm, rng, calm, spin=None):
    """What the controllers read: a new attitude, rates, position and velocity (small where ``calm``;
    ``spin``: the body rates, rad/s, where given)."""
    s = 0.15 if calm else 3.0
    v = fdm.values
    v["attitude/phi-rad"], v["attitude/theta-rad"] = rng.normal(0.0, s, 2)
    v["attitude/psi-rad"] = rng.uniform(-math.pi, math.pi)
    w = spin if spin is not None else rng.normal(0.0, 0.1 if calm else 15.0, 3)
    for k, path in enumerate(("velocities/pi-rad_sec", "velocities/qi-rad_sec", "velocities/ri-rad_sec")):
        v[path] = float(w[k])
    v["position/h-agl-ft"] = rng.uniform(30.0, 300.0)
    for path in ("position/from-start-neu-n-ft", "position/from-start-neu-e-ft"):
        v[path] = rng.normal(0.0, 30.0)
    for path in ("velocities/v-north-fps", "velocities/v-east-fps", "velocities/v-down-fps"):
        v[path] = rng.normal(0.0, 10.0)


def _bits(x):
    return np.asarray(x, dtype=np.float64).tobytes()


def _same_reference(new: QuadController, old: ReferenceController):
    assert new.mode == old.mode
    for field in ("pos_ref", "vel_ff", "acc_ff", "q_ref", "rate_ref", "q", "w", "pos", "vel"):
        assert _bits(getattr(new, field)) == _bits(getattr(old, field)), field
    for field in ("yaw_ref", "yaw_rate_ff", "thrust_n", "agl_m"):
        assert _bits(getattr(new, field)) == _bits(getattr(old, field)), field


@pytest.mark.parametrize("name", sorted(LIBRARY))
@pytest.mark.parametrize("params", [F450, AGILE_QUAD], ids=["F450", "agile_quad"])
def test_compiled_maneuvers_are_the_former_python_ones_bit_for_bit(name, params):
    """Each maneuver started from the same draws and updated on the same random states (the controller's
    observation as an update would leave it, calm or tumbling) writes the same references, finishes at the
    same update and leaves the same hold behind as the former pure-Python maneuver: every float's bits."""
    dt = 0.005
    finished = 0
    for seed in range(6):
        rng = np.random.default_rng(seed)
        fdm = _FakeFdm()
        new_ctl, old_ctl = QuadController(fdm, params, dt), ReferenceController(fdm, params, dt)
        _random_state(fdm, rng, calm=True)
        new_ctl.setup(fdm)
        old_ctl.setup()
        new, old = LIBRARY[name](), REF_LIBRARY[name]()
        t0 = float(rng.uniform(0.0, 30.0))
        new.start(new_ctl, t0, np.random.default_rng(100 + seed))
        old.start(old_ctl, t0, np.random.default_rng(100 + seed))
        _same_reference(new_ctl, old_ctl)
        spin = rng.choice([-1.0, 1.0]) * rng.uniform(5.0, 20.0, 3)  # a steady spin (a flip's rotation) ...
        for k in range(1, 3000):
            t = t0 + k * dt
            calm = rng.random() < (0.97 if k > 300 else 0.5)
            spin += rng.normal(0.0, 0.3, 3)  # ... wandering, for the first 300 updates of half the runs
            _random_state(fdm, rng, calm, spin if seed % 2 and k < 300 else None)
            old_ctl.read_state()  # an update's observation: the same numbers to both
            new_ctl.read_state()
            a, b = new.update(new_ctl, t), old.update(old_ctl, t)
            assert a == b, (k, t)
            _same_reference(new_ctl, old_ctl)
            if a:
                new.finish(new_ctl, t)
                old.finish(old_ctl, t)
                _same_reference(new_ctl, old_ctl)
                finished += 1
                break
    assert finished >= 3  # the laws' ends were reached and compared


def test_maneuver_law_codes():
    """The law's verdicts where they are known in closed form: a hover draws its next target when due
    (EVENT), a yaw spin's ramp is 1 in the middle and its rate reference is the drawn rate, a recovery
    settles only once level and still."""
    v, ref, obs, par = np.zeros(law.N_SLOTS), np.zeros(N_REF), np.zeros(N_OBS), np.zeros(N_PARAMS)
    obs[OBS_Q] = 1.0  # level
    v[law.M_KIND], v[law.M_T0], v[law.M_DUR], v[law.HOV_NEXT_MOVE] = law.KIND_HOVER, 0.0, 5.0, 1.0
    assert law.maneuver_update(v, ref, obs, par, 0.5) == law.CONTINUE
    assert law.maneuver_update(v, ref, obs, par, 1.0) == law.EVENT
    v[law.HOV_NEXT_MOVE] = 9.0
    assert law.maneuver_update(v, ref, obs, par, 5.0) == law.DONE
    v[:] = 0.0
    v[law.M_KIND], v[law.M_DUR], v[law.YS_RATE], v[law.YS_RAMP] = law.KIND_YAW_SPIN, 3.0, 2.5, 0.4
    assert law.maneuver_update(v, ref, obs, par, 1.5) == law.CONTINUE and ref[REF_YAW_RATE_FF] == 2.5
    assert law.maneuver_update(v, ref, obs, par, 0.2) == law.CONTINUE and ref[REF_YAW_RATE_FF] == pytest.approx(1.25)
    v[:] = 0.0
    v[law.M_KIND], v[law.REC_T_MIN] = law.KIND_RECOVERY, 1.0
    obs[OBS_W] = 2.0  # rolling at 2 rad/s: not settled before 4 s
    assert law.maneuver_update(v, ref, obs, par, 2.0) == law.CONTINUE
    assert law.maneuver_update(v, ref, obs, par, 4.01) == law.DONE
    obs[OBS_W] = 0.0
    assert law.maneuver_update(v, ref, obs, par, 0.5) == law.CONTINUE  # before its least time
    assert law.maneuver_update(v, ref, obs, par, 1.5) == law.DONE


def _arrays(tr):
    return [tr.t_s, tr.q_nb_wxyz, tr.gyr_true_rad_s, tr.acc_true_m_s2, tr.pos_ned_m, tr.vel_ned_m_s]


@needs_layout
@pytest.mark.parametrize("aircraft, rate_hz, seed", [("F450", 400.0, 3), ("agile_quad", 250.0, 4),
                                                     ("F450", 100.0, 5)])  # fmt: skip
def test_compiled_loop_flies_the_pythons_flight(monkeypatch, aircraft, rate_hz, seed):
    """Every maneuver in turn, through the compiled loop and through the binding's Python loop: the same
    arrays to the bit, the same maneuvers at the same times (the loop went back to Python for each)."""
    names = sorted(LIBRARY)
    monkeypatch.setenv(jn.ENV_SWITCH, "1")
    calls = []
    orig = QuadController.native_runner

    def counted(self, *args):
        run = orig(self, *args)
        if run is None:
            return None

        def counting(*a):
            calls.append(a[0])
            return run(*a)

        return counting

    monkeypatch.setattr(QuadController, "native_runner", counted)
    a = fly(aircraft, 40.0, rate_hz, seed=seed, maneuvers=names)
    assert calls and calls[0] == 0  # the compiled loop flew it
    monkeypatch.setenv(jn.ENV_SWITCH, "0")
    b = fly(aircraft, 40.0, rate_hz, seed=seed, maneuvers=names)
    for x, y in zip(_arrays(a), _arrays(b)):
        assert x.tobytes() == y.tobytes()
    assert a.maneuvers == b.maneuvers and a.meta == b.meta
    assert {m for _, _, m in a.maneuvers} >= set(names) - {"vibration"}
    assert len(calls) >= len(a.maneuvers)  # one return to Python per maneuver's end at least


@needs_layout
def test_native_write_is_the_bindings():
    """A value written through JSBSim's C++ setDoubleValue from compiled code is what the binding reads."""
    from numba import njit

    @njit
    def put(fn, node, value):
        jn._call_set(fn, node, value)

    veh = AIRCRAFT["F450"].build()
    with open_fdm(veh.model, 0.0025, own_aircraft=veh.own_aircraft, lean=veh.lean) as fdm:
        fdm.run_ic()
        path = F450.cmd_paths[0]
        hd = jn.native_handles(fdm, [AGL_PATH, path])
        assert hd is not None
        for value in (0.25, 0.8125, 0.0):
            put(hd.set_fn, int(hd.node_ptrs[1]), value)
            assert fdm[path] == value


_SIGNATURES = """
import os
import sys
from tepinn_flight.cli.main import main

# a first flight after installing compiles the simulation's loop: said once (stderr, before the mark)
assert main(["simulate", "--aircraft", "agile_quad", "--duration", "0.5", "-o", sys.argv[1]]) == 0
print("@@ mark", file=sys.stderr)
from tepinn_flight.sim.quad_flight_kernel import fly_quad as loop
print("@@hits", sum(loop.stats.cache_hits.values()))  # the first flight's loop loaded from the cache: it was not cold
from tepinn_flight.sim import preload  # noqa: F401  (what a campaign's workers start from: warm())
from tepinn_flight.sim.flight import fly
from tepinn_flight.sim.quad_flight_kernel import fly_quad
from tepinn_flight.sim.quad_maneuver_law import maneuver_update
from tepinn_flight.sim.quad_control_law import control_update
for aircraft, rate in (("F450", 400.0), ("agile_quad", 100.0)):
    fly(aircraft, 3.0, rate, seed=1)
os.environ["TEPINN_JSBSIM_NATIVE"] = "0"
fly("F450", 3.0, 400.0, seed=2)
print("@@", len(fly_quad.signatures), len(maneuver_update.signatures), len(control_update.signatures))
"""


def first_flights(flight: str, cache=None) -> dict:
    """``_SIGNATURES``'s flights in a fresh process (the first writing ``flight``), numba's cache in ``cache`` (None:
    this checkout's own, which must then be empty: a fresh clone) → its exit status, output and the cache's folder.
    conftest runs it as the test session's warm-up where this checkout's cache is empty (CI's clean clone: the one cold
    compile serves both), else the test runs it on a cache of its own."""
    from tests.test_first_run_compile import _env

    p = subprocess.run([sys.executable, "-c", _SIGNATURES, str(flight)], capture_output=True, text=True, env=_env(cache),
                       cwd=_env(None)["PYTHONPATH"], timeout=600)  # fmt: skip
    return {"returncode": p.returncode, "stdout": p.stdout, "stderr": p.stderr, "cache": None if cache is None else str(cache)}


@pytest.mark.slow
@needs_layout
def test_the_loop_and_laws_compile_once(tmp_path, first_flights_of_session):
    """The forkserver's warm-up compiles the loop for the signature flights call it with, and the laws called
    from Python (the binding's path) share theirs, and so does `simulate`: one compile each (each extra one is seconds
    per process). The first flight after installing (a fresh cache) says once that it compiles, the next does not
    (``tepinn_flight/jit_notice.py``; checked here, where the cold compile is paid anyway: the session's warm-up where
    this checkout's cache was empty and the loop still missing from it as the flight started — the estimator's warm-up
    beside it flies a record too — else a run on a cache of its own)."""
    from tepinn_flight.jit_notice import COMPILE_NOTICE
    from tests.test_first_run_compile import _env

    run = first_flights_of_session
    if run is None or "@@hits 0" not in run["stdout"].splitlines():  # (the session's: another process of it had
        run = first_flights(tmp_path / "f.parquet", tmp_path / "cache")  # compiled the loop first, review65)
    assert run["returncode"] == 0, run["stderr"]
    assert "@@hits 0" in run["stdout"].splitlines(), run["stdout"]
    assert [ln.split()[1:] for ln in run["stdout"].splitlines() if ln.startswith("@@ ")] == [["1", "1", "1"]], run["stdout"]
    cold = run["stderr"].split("@@ mark\n")[0]
    assert [ln for ln in cold.splitlines() if COMPILE_NOTICE in ln] == [
        f"tepinn-flight simulate: note: {COMPILE_NOTICE}"], run["stderr"]  # fmt: skip
    env = _env(run["cache"])
    warm = subprocess.run([sys.executable, "-m", "tepinn_flight", "simulate", "--aircraft", "agile_quad", "--duration",
                           "0.5", "-o", str(tmp_path / "g.parquet")], capture_output=True, text=True, env=env,
                          cwd=env["PYTHONPATH"], timeout=600)  # fmt: skip
    assert warm.returncode == 0 and COMPILE_NOTICE not in warm.stderr, warm.stderr


def test_the_loops_context_holds_the_controllers_reads():
    """The kernel's context layout (C_*) fits what the controller hands it: fly()'s state (the kernel takes it from
    the last row where it logged one), the other reads, then the four motor commands."""
    assert N_STATE == len(STATE_PATHS) and NATIVE_READS[:N_STATE] == STATE_PATHS
    assert len(NATIVE_READS) == C_CMD - C_STATE and N_CTX == C_CMD + 4

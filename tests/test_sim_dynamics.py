"""Physical checks of the JSBSim flights (tepinn_flight.sim.flight.fly).

Each test compares the truth against an independent reference: JSBSim's own direction-cosine
matrix through scipy, an RK4 integration of the logged rates written here, the time derivative of
the logged velocity with normal gravity, closed-form thresholds for the maneuvers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tepinn_flight.errors import ConfigError
from tepinn_flight.sim.flight import AIRCRAFT, fly, maneuver_names

pytest.importorskip("jsbsim")
Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

RATE = 400.0
DT = 1.0 / RATE
OMEGA_EARTH = 7.292115e-5  # rad/s
R_EARTH = 6371000.0


# --------------------------------------------------------------------------- helpers (independent)


def qmul(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return np.array([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw])


def rk4_attitude(q0, w_b, nav_rate_n=None, dt=DT):
    """Integrate q' = 1/2 q (x) w_b  (- 1/2 w_n (x) q for a rotating NED frame) with RK4.

    Rates between samples are interpolated linearly (midpoint = mean of the two samples).
    """
    def f(q, w, wn):
        d = 0.5 * qmul(q, np.concatenate([[0.0], w]))
        if wn is not None:
            d -= 0.5 * qmul(np.concatenate([[0.0], wn]), q)
        return d

    out = np.empty((len(w_b), 4))
    q = np.asarray(q0, float).copy()
    out[0] = q
    for k in range(len(w_b) - 1):
        w0, w1 = w_b[k], w_b[k + 1]
        wm = 0.5 * (w0 + w1)
        n0 = n1 = nm = None
        if nav_rate_n is not None:
            n0, n1 = nav_rate_n[k], nav_rate_n[k + 1]
            nm = 0.5 * (n0 + n1)
        k1 = f(q, w0, n0)
        k2 = f(q + 0.5 * dt * k1, wm, nm)
        k3 = f(q + 0.5 * dt * k2, wm, nm)
        k4 = f(q + dt * k3, w1, n1)
        q = q + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        q /= np.linalg.norm(q)
        out[k + 1] = q
    return out


def angle_deg(q1, q2):
    """Rotation angle between unit quaternions (q = -q), degrees; |q1 -+ q2| = 2 sin(angle / 4)."""
    d = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return np.degrees(4.0 * np.arcsin(np.clip(0.5 * d, 0.0, 1.0)))


def rotate(q, v):
    """Body -> NED with scipy (independent of tepinn_flight.quat)."""
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).apply(v)


def normal_gravity(lat_deg, h_m):
    """Somigliana normal gravity with the free-air correction, m/s^2."""
    s = math.sin(math.radians(lat_deg)) ** 2
    s2 = math.sin(math.radians(2 * lat_deg)) ** 2
    return 9.780327 * (1 + 0.0053024 * s - 0.0000058 * s2) - 3.086e-6 * h_m


def seg(tr, name, complete=False):
    """(start, end) of the maneuvers called ``name``; ``complete``: not cut by the end of the flight."""
    return [(a, b) for a, b, n in tr.maneuvers if n == name and not (complete and b > tr.t_s[-1])]


def mask(tr, a, b):
    return (tr.t_s >= a) & (tr.t_s < b)


def assert_valid(tr):
    n = len(tr.t_s)
    assert n > 0
    for arr, shape in ((tr.q_nb_wxyz, (n, 4)), (tr.gyr_true_rad_s, (n, 3)), (tr.acc_true_m_s2, (n, 3)),
                       (tr.pos_ned_m, (n, 3)), (tr.vel_ned_m_s, (n, 3))):
        assert arr.shape == shape and arr.dtype == np.float64
        assert np.isfinite(arr).all()
    assert np.allclose(np.linalg.norm(tr.q_nb_wxyz, axis=1), 1.0, atol=1e-12)
    assert np.allclose(np.diff(tr.t_s), 1.0 / tr.meta["rate_hz"])
    assert tr.mag_earth_ut.shape == (3,) and 20.0 < np.linalg.norm(tr.mag_earth_ut) < 70.0


# --------------------------------------------------------------------------- fixtures (flown once)


@pytest.fixture(scope="module")
def f450_flips():
    return fly("F450", 10.0, RATE, seed=3, maneuvers=["flip", "roll"], turbulence="none")


@pytest.fixture(scope="module")
def c172_rolls():
    return fly("c172x", 30.0, RATE, seed=2, maneuvers=["aileron_roll"], turbulence="none")


@pytest.fixture(scope="module")
def agile_mix():
    return fly("agile_quad", 10.0, RATE, seed=4, maneuvers=["roll", "figure_eight", "flip"])


# --------------------------------------------------------------------------- conventions


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")  # get_Tl2b() returns numpy.matrix
def test_quaternion_convention_matches_jsbsim_dcm():
    """Our q_nb from JSBSim's Euler angles equals the transpose of JSBSim's Tl2b DCM (via scipy),
    through a tumbling full-aft-stick maneuver that passes near the vertical and inverted."""
    from tepinn_flight.quat import quat_from_euler_zyx
    from tepinn_flight.sim.jsbsim_env import open_fdm

    eul, dcm = [], []
    with open_fdm("c172x", DT) as fdm:
        fdm["ic/lat-geod-deg"], fdm["ic/long-gc-deg"] = 47.0, 8.0
        fdm["ic/h-agl-ft"], fdm["ic/vc-kts"], fdm["ic/psi-true-deg"] = 6000.0, 110.0, 30.0
        fdm.run_ic()
        fdm.get_propulsion().init_running(-1)
        fdm.do_trim(1)
        for k in range(4000):
            fdm["fcs/elevator-cmd-norm"] = -1.0 if k > 200 else 0.0
            fdm["fcs/aileron-cmd-norm"] = 0.3 if k > 1500 else 0.0
            fdm.run()
            eul.append((fdm["attitude/phi-rad"], fdm["attitude/theta-rad"], fdm["attitude/psi-rad"]))
            dcm.append(np.asarray(fdm.get_propagate().get_Tl2b()))
    eul, dcm = np.array(eul), np.array(dcm)
    assert np.degrees(np.abs(eul[:, 1])).max() > 75.0 and np.degrees(np.abs(eul[:, 0])).max() > 170.0
    r_nb = Rotation.from_matrix(np.transpose(dcm, (0, 2, 1)))  # Tl2b maps NED -> body
    ours = np.asarray(quat_from_euler_zyx(eul[:, 0], eul[:, 1], eul[:, 2]))
    ref = r_nb.as_quat()[:, [3, 0, 1, 2]]
    assert angle_deg(ours, ref).max() < 1e-6
    # and JSBSim's Euler angles are scipy's intrinsic Z-Y-X (yaw, pitch, roll)
    sc = Rotation.from_euler("ZYX", eul[:, ::-1]).as_quat()[:, [3, 0, 1, 2]]
    assert angle_deg(sc, ref).max() < 1e-6


# --------------------------------------------------------------------------- kinematic consistency


@pytest.mark.parametrize("which", ["f450_flips", "c172_rolls", "agile_mix"])
def test_rk4_of_true_gyro_reproduces_attitude(which, request):
    """RK4 of the noise-free gyro (inertial rates, vibration included for quads) stays within 0.1 deg
    of the true attitude over 10 s; removing Earth and transport rate brings it within 0.01 deg."""
    tr = request.getfixturevalue(which)
    n = int(10.0 * RATE)
    k0 = int(np.clip(np.argmax(np.abs(tr.gyr_true_rad_s).max(1)) - n // 2, 0, len(tr.t_s) - n))
    w = tr.gyr_true_rad_s[k0:k0 + n]
    q_true = tr.q_nb_wxyz[k0:k0 + n]
    assert np.degrees(np.abs(w)).max() > 100.0  # a dynamic flight, not a straight line
    plain = rk4_attitude(q_true[0], w)
    assert angle_deg(plain, q_true).max() <= 0.1
    lat = math.radians(tr.meta["site"]["lat_deg"])
    v = tr.vel_ned_m_s[k0:k0 + n]
    earth = np.array([OMEGA_EARTH * math.cos(lat), 0.0, -OMEGA_EARTH * math.sin(lat)])
    transport = np.stack([v[:, 1] / R_EARTH, -v[:, 0] / R_EARTH, -v[:, 1] * math.tan(lat) / R_EARTH], 1)
    corrected = rk4_attitude(q_true[0], w, earth + transport)
    assert angle_deg(corrected, q_true).max() <= 0.01


@pytest.mark.parametrize("aircraft,maneuvers", [("F450", ["flip", "roll"]), ("c172x", ["loop"]),
                                                ("agile_quad", ["figure_eight"])])
def test_specific_force_is_acceleration_minus_gravity(aircraft, maneuvers):
    """R(q) f_b = dv/dt - g_n at every sample (vibration off), g = normal gravity at the site."""
    tr = fly(aircraft, 8.0, RATE, seed=5, maneuvers=maneuvers, turbulence="none", vibration=False)
    assert_valid(tr)
    f_n = rotate(tr.q_nb_wxyz, tr.acc_true_m_s2)
    a_n = np.gradient(tr.vel_ned_m_s, DT, axis=0)
    g_est = (a_n - f_n)[1:-1]
    site = tr.meta["site"]
    h = -tr.pos_ned_m[:, 2].mean() + (200.0 if aircraft == "c172x" else 100.0)
    g_ref = normal_gravity(site["lat_deg"], h)
    assert abs(np.median(g_est[:, 2]) - g_ref) < 0.02, (np.median(g_est[:, 2]), g_ref)
    assert np.abs(np.median(g_est[:, :2], axis=0)).max() < 0.01
    assert np.abs(g_est - np.median(g_est, axis=0)).max() < 0.2  # central differences, high jerk
    assert np.linalg.norm(tr.acc_true_m_s2, axis=1).max() > 15.0  # well beyond 1 g somewhere
    # exact sample alignment: JSBSim integrates the velocity with Adams-Bashforth 2 on these forces
    dv = np.diff(tr.vel_ned_m_s, axis=0) / DT
    ab2 = dv[1:] - (1.5 * f_n[1:-1] - 0.5 * f_n[:-2])
    assert np.abs(ab2 - ab2.mean(0)).max() < 0.01
    # position is the integral of velocity
    assert np.abs(np.gradient(tr.pos_ned_m, DT, axis=0) - tr.vel_ned_m_s)[2:-2].max() < 0.02


@pytest.mark.parametrize("aircraft", ["F450", "agile_quad"])
def test_hover_specific_force_is_minus_g(aircraft):
    """Hovering, the mean specific force is (0, 0, -g): in NED exactly up to the mean acceleration
    dv/T of the window, and in the body within 0.05 m/s^2 (plus that acceleration and the tilt the
    wind needs). Motor vibration is on and averages out."""
    tr = fly(aircraft, 6.0, RATE, seed=11, maneuvers=["hover"], turbulence="none")
    assert_valid(tr)
    (a, b), *_ = seg(tr, "hover")
    i = mask(tr, a, b)
    assert i.sum() > 1000
    g = normal_gravity(tr.meta["site"]["lat_deg"], 100.0)
    acc_mean = (tr.vel_ned_m_s[i][-1] - tr.vel_ned_m_s[i][0]) / (b - a)
    assert np.abs(acc_mean).max() < 0.1  # it does hover
    f_n = rotate(tr.q_nb_wxyz[i], tr.acc_true_m_s2[i]).mean(0)
    assert np.allclose(f_n, acc_mean + [0.0, 0.0, -g], atol=0.02), (f_n, acc_mean)
    tilt = np.degrees(np.arccos(rotate(tr.q_nb_wxyz[i], np.array([[0.0, 0.0, 1.0]]))[:, 2])).mean()
    f_b = tr.acc_true_m_s2[i].mean(0)
    tol = 0.05 + np.abs(acc_mean).max() + abs(g - 9.81)
    assert np.allclose(f_b, [0.0, 0.0, -9.81], atol=tol + 9.81 * math.sin(math.radians(tilt))), (f_b, tilt)
    assert abs(f_b[2] + 9.81) < tol + 9.81 * (1 - math.cos(math.radians(tilt)))
    assert tr.meta["vibration"]["acc_rms_m_s2"] > 0.1  # the vibration is there, and averages out


# --------------------------------------------------------------------------- maneuvers


def test_f450_flips_and_rolls_reach_500_deg_s_and_recover(f450_flips):
    tr = f450_flips
    assert_valid(tr)
    assert tr.meta["termination"] == "completed"
    assert tr.meta["vehicle_type"] == "multirotor"
    alt = -tr.pos_ned_m[:, 2]
    for name, axis in (("flip", 1), ("roll", 0)):
        spans = seg(tr, name, complete=True)
        assert spans, tr.maneuvers
        for a, b in spans:
            i = mask(tr, a, b)
            w = tr.gyr_true_rad_s[i, axis]
            assert np.degrees(np.abs(w)).max() >= 500.0
            assert abs(np.degrees(np.sum(w) * DT)) >= 300.0  # a full rotation (minus the brake)
    # after each flip the recovery ends level and no height is lost to the ground
    for a, b in seg(tr, "recovery"):
        if b < tr.t_s[-1] - 0.1:
            k = np.searchsorted(tr.t_s, b) - 1
            up = Rotation.from_quat(tr.q_nb_wxyz[k, [1, 2, 3, 0]]).apply([0.0, 0.0, 1.0])
            assert math.degrees(math.acos(np.clip(up[2], -1, 1))) < 20.0
    assert alt.min() > -10.0 and alt.min() + tr.meta["start_agl_m"] > 30.0


def test_c172x_aileron_rolls_reach_100_deg_s(c172_rolls):
    tr = c172_rolls
    assert_valid(tr)
    assert tr.meta["termination"] == "completed"
    assert tr.meta["vehicle_type"] == "fixed-wing"
    spans = seg(tr, "aileron_roll", complete=True)
    assert spans
    for a, b in spans:
        p = tr.gyr_true_rad_s[mask(tr, a, b), 0]
        assert np.degrees(np.abs(p)).max() >= 100.0
        assert abs(np.degrees(np.sum(p) * DT)) >= 330.0


def test_agile_quad_is_agile(agile_mix):
    tr = agile_mix
    assert_valid(tr)
    w = np.degrees(np.abs(tr.gyr_true_rad_s))
    assert w.max() >= 700.0
    (a, b), *_ = seg(tr, "figure_eight")
    lateral = np.linalg.norm(np.gradient(tr.vel_ned_m_s[mask(tr, a, b), :2], DT, axis=0), axis=1)
    assert lateral.max() > 5.0  # strong lateral acceleration, m/s^2


def test_vibration_is_zero_mean_and_stronger_in_the_vibration_maneuver():
    clean = fly("agile_quad", 8.0, RATE, seed=21, maneuvers=["hover", "vibration"], vibration=False)
    vib = fly("agile_quad", 8.0, RATE, seed=21, maneuvers=["hover", "vibration"])
    np.testing.assert_array_equal(clean.q_nb_wxyz, vib.q_nb_wxyz)  # rigid-body truth untouched
    d = vib.acc_true_m_s2 - clean.acc_true_m_s2
    dg = vib.gyr_true_rad_s - clean.gyr_true_rad_s
    rms = {}
    for name in ("hover", "vibration"):
        (a, b), *_ = seg(vib, name)
        i = mask(vib, a, b)
        assert np.abs(d[i].mean(0)).max() < 0.1 and np.abs(dg[i].mean(0)).max() < 0.01
        rms[name] = np.sqrt((d[i] ** 2).sum(1).mean())
    assert rms["hover"] > 0.1 and rms["vibration"] > 2.0 * rms["hover"], rms


# --------------------------------------------------------------------------- determinism and errors


def test_same_seed_identical_other_seed_different():
    a = fly("c172x", 5.0, RATE, seed=7, maneuvers=["turbulence"])
    b = fly("c172x", 5.0, RATE, seed=7, maneuvers=["turbulence"])
    c = fly("c172x", 5.0, RATE, seed=8, maneuvers=["turbulence"])
    for name in ("t_s", "q_nb_wxyz", "gyr_true_rad_s", "acc_true_m_s2", "pos_ned_m", "vel_ned_m_s",
                 "mag_earth_ut"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert not np.array_equal(getattr(a, name), getattr(c, name)) or name == "t_s"
    assert a.maneuvers == b.maneuvers and a.meta == b.meta
    q1 = fly("agile_quad", 3.0, RATE, seed=1)
    q2 = fly("agile_quad", 3.0, RATE, seed=1)
    np.testing.assert_array_equal(q1.acc_true_m_s2, q2.acc_true_m_s2)


def test_a_jsbsim_outside_site_packages_still_finds_its_aircraft(monkeypatch):
    """``pip install --target`` or a PYTHONPATH folder: jsbsim's own ``get_default_root_dir`` looks in
    site-packages only and raises; the flight reads the data beside the package, the same flight."""
    import jsbsim

    ref = fly("c172x", 2.0, RATE, seed=3)

    def nowhere():
        raise OSError("Can't find the default root directory")

    monkeypatch.setattr(jsbsim, "get_default_root_dir", nowhere)
    got = fly("c172x", 2.0, RATE, seed=3)
    np.testing.assert_array_equal(got.q_nb_wxyz, ref.q_nb_wxyz)
    np.testing.assert_array_equal(got.acc_true_m_s2, ref.acc_true_m_s2)


def test_low_output_rate_is_the_same_flight_subsampled():
    """At 100 Hz JSBSim still steps at 400 Hz: the samples are every 4th sample of the 400 Hz flight."""
    hi = fly("agile_quad", 4.0, 400.0, seed=9, vibration=False)
    lo = fly("agile_quad", 4.0, 100.0, seed=9, vibration=False)
    assert lo.meta["jsbsim_rate_hz"] == 400.0 and len(lo.t_s) == 400
    for name in ("q_nb_wxyz", "gyr_true_rad_s", "acc_true_m_s2", "vel_ned_m_s"):
        np.testing.assert_array_equal(getattr(lo, name), getattr(hi, name)[3::4])


def test_random_flight_chains_maneuvers_with_recoveries():
    tr = fly("F450", 25.0, RATE, seed=12)
    assert_valid(tr)
    names = [n for _, _, n in tr.maneuvers]
    assert len(set(names) - {"recovery"}) >= 3
    assert all(names[i] == "recovery" for i in range(1, len(names), 2))  # alternate
    assert all(n in maneuver_names("F450") or n == "recovery" for n in names)
    starts = [a for a, _, _ in tr.maneuvers]
    ends = [b for _, b, _ in tr.maneuvers]
    assert starts[0] == 0.0 and starts[1:] == ends[:-1] and math.isclose(ends[-1], 25.0, abs_tol=DT)


def test_maneuver_library_covers_the_required_maneuvers():
    fwl = set(maneuver_names("c172x"))
    assert {"steep_turn", "aileron_roll", "loop", "split_s", "dive_pullup", "rudder_reversal",
            "turbulence"} <= fwl
    for quad in ("F450", "agile_quad"):
        assert {"hover", "rate_steps", "flip", "roll", "yaw_spin", "figure_eight",
                "vibration"} <= set(maneuver_names(quad))
    assert {"c172x", "F450", "agile_quad"} <= set(AIRCRAFT)


@pytest.mark.parametrize("kwargs,match", [
    (dict(aircraft="c999", duration_s=1.0), "unknown aircraft"),
    (dict(aircraft="F450", duration_s=1.0, maneuvers=["loop"]), "unknown maneuver"),
    (dict(aircraft="c172x", duration_s=1.0, maneuvers=["barrel"]), "unknown maneuver"),
    (dict(aircraft="F450", duration_s=-1.0), "duration"),
    (dict(aircraft="F450", duration_s=0.0), "duration"),
    (dict(aircraft="F450", duration_s=float("nan")), "duration"),
    (dict(aircraft="F450", duration_s=1.0, rate_hz=0.0), "rate"),
    (dict(aircraft="F450", duration_s=1.0, rate_hz=-400.0), "rate"),
    (dict(aircraft="F450", duration_s=1.0, seed=-1), "seed"),
    (dict(aircraft="F450", duration_s=1.0, turbulence="hurricane"), "turbulence"),
])  # fmt: skip
def test_bad_arguments_raise_config_error(kwargs, match):
    with pytest.raises(ConfigError, match=match) as exc:
        fly(**kwargs)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("native", ["1", "0"])
def test_a_flight_that_would_crash_stops_cleanly(monkeypatch, native):
    """Motors cut once the flight starts: the quad falls; the flight stops above the ground, finite, and says
    so (through the compiled loop and through the binding's Python loop)."""
    from tepinn_flight.sim import maneuvers
    from tepinn_flight.sim.jsbsim_native import ENV_SWITCH
    from tepinn_flight.sim.quad_control_law import INV_TMAX

    monkeypatch.setenv(ENV_SWITCH, native)
    orig = maneuvers.Sequencer.start

    def start_and_cut(self, ctl, t):  # after the warm-up: every motor command becomes 0 from here on
        orig(self, ctl, t)
        ctl.par[INV_TMAX] = 0.0

    monkeypatch.setattr(maneuvers.Sequencer, "start", start_and_cut)
    tr = fly("F450", 60.0, RATE, seed=0, maneuvers=["hover"])
    assert tr.meta["termination"].startswith("stopped at t=")
    assert "ground" in tr.meta["termination"]
    assert_valid(tr)
    assert 1.0 < tr.t_s[-1] < 60.0
    assert tr.maneuvers[-1][1] <= tr.t_s[-1] + DT

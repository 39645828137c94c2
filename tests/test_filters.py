"""Baseline filters and peers on closed-form motion; Madgwick's quirk against a numerical gradient."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from tepinn_flight.errors import TepinnError
from tepinn_flight.evaluation import metrics as M
from tepinn_flight.evaluation.filters import Complementary, Ekf, EkfParams, Madgwick, MadgwickParams
from tepinn_flight.evaluation.filters.common import initial_attitude
from tepinn_flight.quat import gravity_body, quat_conj, quat_from_rotvec, quat_mul, quat_normalize, quat_rotate

G = 9.80665


def coning(duration_s=60.0, rate_hz=100.0, w=(0.6, -0.4, 0.5), bias=(0.0, 0.0, 0.0), gyr_noise=0.002, acc_noise=0.05, seed=0):
    """Closed form: constant body rate from a tilted start, gravity only. q(t) = q0 ⊗ exp(ω t)."""
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    w = np.asarray(w, float)
    q0 = quat_from_rotvec(np.array([0.3, -0.2, 0.1]))
    q = quat_normalize(quat_mul(q0[None], quat_from_rotvec(w[None] * t[:, None])))
    rng = np.random.default_rng(seed)
    gyr = w[None] + np.asarray(bias)[None] + rng.normal(0, gyr_noise, (n, 3))
    acc = -gravity_body(q, G) + rng.normal(0, acc_noise, (n, 3))
    return t, gyr, acc, q


def incl_rmse_deg(q_est, q_ref, mask):
    return math.degrees(M.rmse(M.inclination_error_rad(M.error_quat_earth(q_est, q_ref)), mask))


@pytest.mark.parametrize("flt", [Complementary(), Madgwick(), Ekf()], ids=lambda f: f.name)
def test_filters_converge_from_a_wrong_start_and_track(flt):
    t, gyr, acc, q = coning(duration_s=40.0)
    q_wrong = quat_mul(quat_from_rotvec(np.array([0.35, -0.25, 0.0])), q[0])  # 25° tilt error at the start
    out = flt.estimate(gyr, acc, t, q0=q_wrong)["q_nb_wxyz"]
    assert incl_rmse_deg(q_wrong[None], q[:1], [True]) > 20.0
    assert incl_rmse_deg(out, q, t > 20.0) < 1.0, flt.name


def test_ekf_estimates_a_constant_gyro_bias_and_its_sigma_shrinks():
    bias = np.array([0.01, -0.02, 0.015])  # rad/s: 0.6, -1.1, 0.9 °/s
    t, gyr, acc, q = coning(duration_s=90.0, bias=bias)
    out = Ekf().estimate(gyr, acc, t)
    np.testing.assert_allclose(out["bias_rad_s"][-1], bias, atol=0.0015)  # < 0.09 °/s
    assert incl_rmse_deg(out["q_nb_wxyz"], q, t > 30) < 0.3
    # the bias-free filters are off by the bias' tilt effect; the EKF beats them
    for other in (Complementary(), Madgwick()):
        assert incl_rmse_deg(other.estimate(gyr, acc, t)["q_nb_wxyz"], q, t > 30) > 2 * incl_rmse_deg(out["q_nb_wxyz"], q, t > 30)
    assert out["sigma_rad"][-1] < 0.5 * out["sigma_rad"][0]


def test_ekf_rest_update_finds_the_vertical_bias_of_a_level_sensor():
    n, rate = 3000, 100.0
    t = np.arange(n) / rate
    bias = np.array([0.0, 0.0, 0.02])  # unobservable from the accelerometer when level
    rng = np.random.default_rng(1)
    gyr = bias + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.0, 0.0, -G]) + rng.normal(0, 0.03, (n, 3))
    out = Ekf().estimate(gyr, acc, t)
    assert abs(out["bias_rad_s"][-1, 2] - 0.02) < 0.001
    off = Ekf(EkfParams(rest_gyr_sigma_rad_s=0.0)).estimate(gyr, acc, t)  # no rest updates: stays at 0
    assert abs(off["bias_rad_s"][-1, 2]) < 0.002


def test_ekf_tune_picks_the_best_grid_point_on_training_records():
    from tepinn_flight.evaluation.filters.ekf import tune
    from tepinn_flight.record import FlightRecord, make_frame

    recs = []
    for seed in (0, 1):
        t, gyr, acc, q = coning(duration_s=15.0, bias=(0.01, -0.01, 0.0), acc_noise=0.3, seed=seed)
        recs.append(FlightRecord(make_frame(t, np.zeros(len(t), int), gyr, acc, None, q), {"source_kind": "synthetic"}))
    grid = {"acc_noise_m_s2": (0.3, 30.0), "gyro_noise_rad_s_sqrt_hz": (1e-3,)}
    best, rows = tune(recs, grid, warmup_s=5.0)
    assert len(rows) == 2
    objective = {r["acc_noise_m_s2"]: r["mean_inclination_rmse_deg"] for r in rows}
    assert best.acc_noise_m_s2 == min(objective, key=objective.get)
    assert objective[0.3] < objective[30.0]  # σ_a = 30 m/s² barely corrects the bias-induced tilt drift
    with pytest.raises(Exception, match="unknown EKF parameter"):
        tune(recs, {"no_such": (1,)})


def _madgwick_gradient(q, a, m, ref_scale):
    """Numerical gradient of ½‖f‖² with f = [q*⊗(0,0,1)⊗q − â; q*⊗b⊗q − m̂] (raw 4-vector q, b fixed).

    b = ref_scale · (|h_xy|, 0, h_z), h = q ⊗ m̂ ⊗ q*. The corrected filter uses ref_scale = 1; the
    original C code's missing factor 2 amounts to ref_scale = ½.
    """
    a = a / np.linalg.norm(a)
    m = m / np.linalg.norm(m)
    qn = q / np.linalg.norm(q)
    h = quat_rotate(qn, m)
    b = ref_scale * np.array([math.hypot(h[0], h[1]), 0.0, h[2]])

    def rot_t(qq, v):  # q* ⊗ v ⊗ q written with the raw (non-unit) 4-vector, as in the derivation
        w, x, y, z = qq
        r = np.array([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])  # fmt: skip
        return r.T @ v

    def cost(qq):
        f = np.r_[rot_t(qq, np.array([0.0, 0.0, 1.0])) - a, rot_t(qq, b) - m]
        return 0.5 * f @ f

    eps = 1e-7
    return np.array([(cost(q + eps * e) - cost(q - eps * e)) / (2 * eps) for e in np.eye(4)])


@pytest.mark.parametrize("quirk, ref_scale", [(False, 1.0), (True, 0.5)])
def test_madgwick_corrected_and_original_differ_exactly_in_the_bx_bz_factor(quirk, ref_scale):
    q0 = quat_normalize(np.array([0.8, 0.3, -0.4, 0.33]))
    acc = np.array([[1.0, -2.0, -9.5]])  # specific force; the filter uses down = -acc
    mag = np.array([[20.0, -5.0, 40.0]])
    dt = 1e-6  # one tiny step: q1 ≈ q0 − β·dt·ĝ, renormalised (which removes the radial part)
    q1 = Madgwick(MadgwickParams(beta=1.0, original_quirk=quirk)).estimate(
        np.zeros((2, 3)), np.repeat(acc, 2, 0), [0.0, dt], np.repeat(mag, 2, 0), q0=q0)["q_nb_wxyz"][0]

    def direction(v):
        v = v - (v @ q0) * q0
        return v / np.linalg.norm(v)

    for scale, should_match in ((ref_scale, True), (1.5 - ref_scale, False)):
        g = _madgwick_gradient(q0, -acc[0], mag[0], scale)
        close = np.allclose(direction(q0 - q1), direction(g), atol=1e-5)
        assert close == should_match, (quirk, scale)


def test_madgwick_6d_has_no_quirk_and_nan_inputs_are_neutral():
    t, gyr, acc, q = coning(duration_s=5.0)
    a = Madgwick(MadgwickParams(original_quirk=False)).estimate(gyr, acc, t)["q_nb_wxyz"]
    b = Madgwick(MadgwickParams(original_quirk=True)).estimate(gyr, acc, t)["q_nb_wxyz"]
    np.testing.assert_array_equal(a, b)
    acc2 = acc.copy()
    acc2[100:110] = np.nan  # no accelerometer correction there, no NaN in the output
    out = Ekf().estimate(gyr, acc2, t)["q_nb_wxyz"]
    assert np.all(np.isfinite(out))
    with pytest.raises(TepinnError, match="shapes"):
        Complementary().estimate(gyr[:5], acc, t)


def test_initial_attitude_from_acc_and_mag():
    q = quat_normalize(np.array([0.9, 0.2, -0.3, 0.25]))
    down_b = gravity_body(q, 1.0)
    mag_n = np.array([20.0, 0.0, 45.0])  # magnetic north, pointing down
    mag_b = quat_rotate(quat_conj(q), mag_n)
    q_est = initial_attitude(-G * down_b, mag_b)
    assert math.degrees(M.quat_angle_error_rad(q_est, q)) < 1e-6
    q6 = initial_attitude(-G * down_b)
    assert math.degrees(M.inclination_error_rad(M.error_quat_earth(q6, q))) < 1e-6


@pytest.mark.parametrize("peer", ["vqf", "offline-vqf", "riann", "fusion"])
def test_peer_frame_conversion_tracks_closed_form_motion(peer):
    """A wrong frame convention gives tens of degrees; right ones give well under 2°."""
    from tepinn_flight.evaluation.estimators import EST_Q_COLS
    from tepinn_flight.evaluation.peers import make_peer
    from tepinn_flight.record import FlightRecord, make_frame

    t, gyr, acc, q = coning(duration_s=30.0)
    rec = FlightRecord(make_frame(t, np.zeros(len(t), int), gyr, acc, None, q), {"source_kind": "synthetic"})
    est = make_peer(peer)
    out = est.estimate(rec)[EST_Q_COLS].to_numpy()
    assert incl_rmse_deg(out, q, t > 10) < (3.0 if peer == "riann" else 1.0)


@pytest.mark.parametrize("offline", [False, True])
def test_a_9d_vqf_peer_on_a_record_without_a_magnetometer_gives_its_6d_estimate(offline):
    """`evaluate --with-mag` over a record without a magnetometer (NaN columns: a compass switched off) had stopped
    with an internal KeyError: VQF given no magnetometer returns no 9-D quaternion. The 9-D peer there is the 6-D
    one (the harness's note says so), to the bit."""
    from tepinn_flight.evaluation.estimators import EST_Q_COLS
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.record import FlightRecord, make_frame

    t, gyr, acc, q = coning(duration_s=20.0)
    rec = FlightRecord(make_frame(t, np.zeros(len(t), int), gyr, acc, None, q), {"source_kind": "synthetic"})
    nine = VqfEstimator(offline=offline, use_mag=True).estimate(rec)[EST_Q_COLS].to_numpy()
    six = VqfEstimator(offline=offline).estimate(rec)[EST_Q_COLS].to_numpy()
    np.testing.assert_array_equal(nine, six)
    assert incl_rmse_deg(nine, q, t > 10) < 1.0


def test_peers_are_regular_dependencies_and_run_out_of_the_box():
    """VQF, RIANN and x-io Fusion are declared dependencies, so the default suite runs all of them."""
    import tomllib
    from pathlib import Path

    from tepinn_flight.evaluation.suite import peer_estimators

    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    deps = {d.split(">")[0].split("=")[0].split("<")[0].strip().lower() for d in pyproject["project"]["dependencies"]}
    assert {"vqf", "riann", "imufusion"} <= deps
    notes: list[str] = []
    peers = peer_estimators(notes=notes)
    assert [p.name for p in peers] == ["vqf", "offline-vqf", "riann", "fusion"] and notes == []


def test_missing_peer_package_is_skipped_with_a_message(monkeypatch):
    from tepinn_flight.evaluation.peers import make_peer
    from tepinn_flight.evaluation.suite import peer_estimators

    monkeypatch.setitem(sys.modules, "riann", None)  # makes `import riann` raise ImportError
    monkeypatch.setitem(sys.modules, "imufusion", None)
    notes: list[str] = []
    assert make_peer("riann", notes) is None
    assert "RIANN skipped: package 'riann' is not installed" in notes[0]
    notes.clear()
    peers = peer_estimators(notes=notes)
    assert {p.name for p in peers} == {"vqf", "offline-vqf"}
    assert any("Fusion skipped" in n for n in notes) and any("RIANN skipped" in n for n in notes)



def test_check_inputs_gives_the_loops_one_array_type_and_leaves_the_callers_arrays_alone():
    """Whatever the layout and writability of the caller's arrays (a record's columns are read-only
    Fortran-ordered views), the compiled loops get float64 C-contiguous writable arrays — one
    compiled signature per loop — with the same values, and the caller's arrays are not changed."""
    from tepinn_flight.evaluation.filters.common import check_inputs

    rng = np.random.default_rng(0)
    n = 50
    gyr, acc, mag = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    gyr[3, 1], acc[5, 0], mag[7, 2] = np.nan, np.inf, np.nan
    t = np.arange(n) * 0.01
    want = check_inputs(gyr, acc, t, mag)
    originals = [a.copy() for a in (gyr, acc, mag)]
    for make in (np.ascontiguousarray, np.asfortranarray, lambda a: np.asfortranarray(a).view()):
        args = [make(a) for a in (gyr, acc, mag)]
        for a in args:
            a.flags.writeable = make is np.ascontiguousarray  # read-only views as from a record
        got = check_inputs(args[0], args[1], t, args[2])
        for g, w in zip(got, want):
            assert g.dtype == np.float64 and g.flags.c_contiguous and g.flags.writeable
            np.testing.assert_array_equal(g, w)
        for a, o in zip(args, originals):
            np.testing.assert_array_equal(a, o)  # NaN rows zeroed in copies, not in place
    assert want[0][3, 1] == 0.0 and np.all(want[1][5] == 0.0) and np.all(want[3][7] == 0.0)


def test_ekf_settings_must_be_finite_but_the_gate_may_be_off():
    """``--set ekf.acc_noise_m_s2=inf`` was taken (an EKF trusting no accelerometer, scored at 0 % coverage): every
    setting is finite and ≥ 0, except the accelerometer gate, whose default, inf, means no gate."""
    import math

    from tepinn_flight.errors import ConfigError

    for k in ("acc_noise_m_s2", "gyro_noise_rad_s_sqrt_hz", "rest_min_s"):
        for bad in (math.inf, math.nan, -1.0):
            with pytest.raises(ConfigError, match=f"ekf.{k} must be a finite number"):
                EkfParams(**{k: bad})
    assert EkfParams().acc_gate_m_s2 == math.inf and EkfParams(acc_gate_m_s2=3.0).acc_gate_m_s2 == 3.0

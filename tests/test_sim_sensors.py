"""Sensor error model: statistics against the configuration, on closed-form truths (no JSBSim)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tests.sim_truths import MAG_EARTH_UT, static_truth, wobble_truth

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.errors import ConfigError
from tepinn_flight.record import read_record, write_record
from tepinn_flight.sim.sensors import (
    AccelConfig,
    GyroConfig,
    MagConfig,
    SensorConfig,
    apply_sensors,
    ar1_process,
    list_presets,
    load_sensor_config,
)
from tepinn_flight.sim.simulate import record_from_truth

D2R = math.pi / 180.0


def cfg(gyro=None, accel=None, mag=None, **top) -> SensorConfig:
    """A sensor with every error off except the ones given (wide ranges, no quantization)."""
    return SensorConfig(
        gyro=GyroConfig(range_deg_s=1e6, **(gyro or {})),
        accel=AccelConfig(range_g=1e6, **(accel or {})),
        mag=MagConfig(range_ut=1e6, **(mag or {"enabled": False})),
        **top,
    )


def run(truth, c, seed=0):
    return apply_sensors(truth, c, np.random.default_rng(seed))


# --------------------------------------------------------------------------- white noise


def test_white_noise_sigma_is_density_times_sqrt_rate():
    rate = 1000.0
    truth = static_truth(100_000, rate)
    out = run(truth, cfg(gyro={"arw_deg_sqrt_h": 0.3}, accel={"vrw_m_s_sqrt_h": 0.2354}))
    # datasheet form: 0.3 °/√h = 0.005 °/s/√Hz; 0.2354 m/s/√h ≈ 400 µg/√Hz
    want_g = 0.005 * D2R * math.sqrt(rate)
    want_a = 400e-6 * GRAVITY_M_S2 * math.sqrt(rate)
    eg = out.gyr_rad_s - truth.gyr_true_rad_s
    ea = out.acc_m_s2 - truth.acc_true_m_s2
    np.testing.assert_allclose(eg.std(axis=0), want_g, rtol=0.02)
    np.testing.assert_allclose(ea.std(axis=0), want_a, rtol=0.02)
    assert np.all(np.abs(eg.mean(axis=0)) < 5 * want_g / math.sqrt(len(eg)))
    # white: no correlation between successive samples
    for e in (eg, ea):
        r1 = [np.corrcoef(e[1:, i], e[:-1, i])[0, 1] for i in range(3)]
        assert np.all(np.abs(r1) < 0.02)
    assert not out.clipped.any()
    np.testing.assert_array_equal(out.gyr_bias_rad_s, 0.0)


def test_preset_noise_matches_datasheet_density():
    """consumer.toml carries the MPU-6000 densities: 0.005 °/s/√Hz and 400 µg/√Hz."""
    c = dataclasses.replace(
        load_sensor_config("consumer", ["gyro.turn_on_bias_deg_s=0", "gyro.bias_rw_deg_h_sqrt_h=0",
                                        "gyro.scale_factor_pct=0", "gyro.cross_axis_pct=0", "gyro.lsb_deg_s=0",
                                        "accel.turn_on_bias_mg=0", "accel.bias_rw_mg_sqrt_h=0", "accel.lsb_mg=0",
                                        "accel.scale_factor_pct=0", "accel.cross_axis_pct=0"]),
    )  # fmt: skip
    rate = 500.0
    truth = static_truth(50_000, rate)
    out = run(truth, c, seed=4)
    np.testing.assert_allclose((out.gyr_rad_s - truth.gyr_true_rad_s).std(0), 0.005 * D2R * rate**0.5, rtol=0.03)
    np.testing.assert_allclose((out.acc_m_s2 - truth.acc_true_m_s2).std(0), 400e-6 * 9.80665 * rate**0.5, rtol=0.03)


# --------------------------------------------------------------------------- biases


def test_turn_on_bias_is_constant_with_configured_sigma():
    truth = static_truth(4, 100.0)
    c = cfg(gyro={"turn_on_bias_deg_s": 0.5}, accel={"turn_on_bias_mg": 20.0})
    gb, ab = [], []
    for seed in range(400):
        out = run(truth, c, seed)
        # constant over the flight, and exactly the measurement error (no other error term is on)
        assert np.all(out.gyr_bias_rad_s == out.gyr_bias_rad_s[0])
        np.testing.assert_allclose(out.gyr_rad_s - truth.gyr_true_rad_s, out.gyr_bias_rad_s, atol=1e-15)
        np.testing.assert_allclose(out.acc_m_s2 - truth.acc_true_m_s2, out.acc_bias_m_s2, atol=1e-12)
        gb.append(out.gyr_bias_rad_s[0])
        ab.append(out.acc_bias_m_s2[0])
    gb, ab = np.array(gb), np.array(ab)
    assert abs(gb.std() / (0.5 * D2R) - 1) < 0.08
    assert abs(ab.std() / (20e-3 * GRAVITY_M_S2) - 1) < 0.08
    assert abs(gb.mean()) < 4 * 0.5 * D2R / math.sqrt(gb.size)
    # independent axes
    assert abs(np.corrcoef(gb[:, 0], gb[:, 1])[0, 1]) < 0.15


def test_bias_random_walk_variance_grows_linearly():
    rate, dur = 20.0, 40.0
    k_deg_h_sqrt_h = 300.0
    k_si = k_deg_h_sqrt_h * D2R / 3600 / 60  # rad/s per √s
    truth = static_truth(int(rate * dur) + 1, rate)
    c = cfg(gyro={"bias_rw_deg_h_sqrt_h": k_deg_h_sqrt_h}, accel={"bias_rw_mg_sqrt_h": 3.0})
    runs = np.array([run(truth, c, s).gyr_bias_rad_s for s in range(300)])  # (R, N, 3)
    acc_runs = np.array([run(truth, c, s).acc_bias_m_s2 for s in range(60)])
    for t_lag in (5.0, 10.0, 20.0, 40.0):
        i = int(t_lag * rate)
        v = np.var(runs[:, i, :] - runs[:, 0, :])
        assert abs(v / (k_si**2 * t_lag) - 1) < 0.15, (t_lag, v / (k_si**2 * t_lag))
    # variance of increments within one realisation (Allan-style): same K at two lags
    inc1 = np.diff(runs[:, :: int(rate)], axis=1)  # 1 s increments
    inc4 = np.diff(runs[:, :: int(4 * rate)], axis=1)  # 4 s increments
    assert abs(inc1.var() / k_si**2 - 1) < 0.05
    assert abs(inc4.var() / (4 * k_si**2) - 1) < 0.08
    ka = 3.0e-3 * GRAVITY_M_S2 / 60
    assert abs(np.var(acc_runs[:, -1] - acc_runs[:, 0]) / (ka**2 * dur) - 1) < 0.3


def test_gauss_markov_bias_variance_and_correlation():
    rate, tau, k_deg = 10.0, 5.0, 600.0
    k_si = k_deg * D2R / 3600 / 60
    truth = static_truth(400, rate)
    c = cfg(gyro={"bias_rw_deg_h_sqrt_h": k_deg, "bias_corr_time_s": tau})
    b = np.array([run(truth, c, s).gyr_bias_rad_s for s in range(200)])
    t = 30.0
    want = k_si**2 * tau / 2 * (1 - math.exp(-2 * t / tau))  # exact variance of the OU process
    assert abs(np.var(b[:, int(t * rate)]) / want - 1) < 0.15
    # stationary part: lag-1 s autocorrelation exp(-1/tau)
    x, y = b[:, 200:-10].ravel(), b[:, 210:].ravel()
    assert abs(np.corrcoef(x, y)[0, 1] - math.exp(-1.0 / tau)) < 0.05


def test_ar1_process_matches_naive_recursion():
    rng = np.random.default_rng(1)
    e = rng.standard_normal((5000, 3))
    for phi in (1.0, 0.999, 0.9, 0.2):
        ref = np.zeros_like(e)
        for k in range(1, len(e)):
            ref[k] = phi * ref[k - 1] + 0.3 * e[k]
        np.testing.assert_allclose(ar1_process(e, phi, 0.3), ref, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------- deterministic errors


def test_quantization_step_and_error_bound():
    truth = static_truth(5000, 200.0)
    base = {"arw_deg_sqrt_h": 2.0}
    lsb = 1 / 16.4
    out_q = run(truth, cfg(gyro={**base, "lsb_deg_s": lsb}, accel={"vrw_m_s_sqrt_h": 0.5, "lsb_mg": 0.5}))
    out_c = run(truth, cfg(gyro=base, accel={"vrw_m_s_sqrt_h": 0.5}))  # same draws, no quantization
    g = out_q.gyr_rad_s / (lsb * D2R)
    np.testing.assert_allclose(g, np.round(g), atol=1e-6)
    steps = np.diff(np.unique(out_q.gyr_rad_s[:, 0]))
    assert abs(steps.min() / (lsb * D2R) - 1) < 1e-6
    assert np.max(np.abs(out_q.gyr_rad_s - out_c.gyr_rad_s)) <= lsb * D2R / 2 * (1 + 1e-9)
    a_lsb = 0.5e-3 * GRAVITY_M_S2
    a = out_q.acc_m_s2 / a_lsb
    np.testing.assert_allclose(a, np.round(a), atol=1e-6)
    assert np.max(np.abs(out_q.acc_m_s2 - out_c.acc_m_s2)) <= a_lsb / 2 * (1 + 1e-9)


def test_saturation_clips_and_flags():
    truth = static_truth(1000, 100.0)
    truth.gyr_true_rad_s[100:110, 0] = 40.0  # 2292 °/s > 2000 °/s
    truth.gyr_true_rad_s[200:205, 2] = -36.0
    truth.acc_true_m_s2[300:306, 1] = 20 * GRAVITY_M_S2  # > 16 g
    c = SensorConfig(gyro=GyroConfig(range_deg_s=2000.0), accel=AccelConfig(range_g=16.0),
                     mag=MagConfig(enabled=False))  # fmt: skip
    out = run(truth, c)
    want = np.zeros(1000, bool)
    want[100:110] = want[200:205] = want[300:306] = True
    np.testing.assert_array_equal(out.clipped, want)
    want_g = want.copy()
    want_g[300:306] = False  # the accelerometer's saturation is not the gyro's
    np.testing.assert_array_equal(out.gyr_clipped, want_g)
    np.testing.assert_allclose(out.gyr_rad_s[100:110, 0], 2000 * D2R)
    np.testing.assert_allclose(out.gyr_rad_s[200:205, 2], -2000 * D2R)
    np.testing.assert_allclose(out.acc_m_s2[300:306, 1], 16 * GRAVITY_M_S2)
    assert np.all(np.abs(out.gyr_rad_s) <= 2000 * D2R + 1e-12)
    np.testing.assert_array_equal(out.gyr_rad_s[~want], truth.gyr_true_rad_s[~want])


def test_scale_and_cross_axis_recovered_by_least_squares():
    truth = wobble_truth(20_000, 200.0)
    c = cfg(
        gyro={"scale_factor_pct": 2.0, "cross_axis_pct": 1.5, "turn_on_bias_deg_s": 1.0, "arw_deg_sqrt_h": 0.1},
        accel={"scale_factor_pct": 2.0, "cross_axis_pct": 1.5, "turn_on_bias_mg": 30.0, "vrw_m_s_sqrt_h": 0.02},
    )
    out = run(truth, c, seed=7)
    for x, y, name, bias in ((truth.gyr_true_rad_s, out.gyr_rad_s, "gyro", out.gyr_bias_rad_s),
                             (truth.acc_true_m_s2, out.acc_m_s2, "accel", out.acc_bias_m_s2)):  # fmt: skip
        design = np.hstack([x, np.ones((len(x), 1))])
        sol, *_ = np.linalg.lstsq(design, y, rcond=None)
        m_hat, b_hat = sol[:3].T, sol[3]
        m_true = np.array(out.truth[name]["matrix"])
        np.testing.assert_allclose(m_hat, m_true, atol=2e-4)
        np.testing.assert_allclose(b_hat, bias[0], atol=0.02 * np.abs(bias[0]).max())
        assert np.abs(m_true - np.eye(3)).max() > 5e-3  # the errors are really there
    # the drawn matrices follow the configured sigmas
    diag, off = [], []
    short = wobble_truth(4, 200.0)
    for s in range(150):
        m = np.array(run(short, c, s).truth["gyro"]["matrix"])
        diag.append(np.diag(m) - 1)
        off.append(m[~np.eye(3, dtype=bool)])
    assert abs(np.std(diag) / 0.02 - 1) < 0.12
    assert abs(np.std(off) / 0.015 - 1) < 0.1


def test_magnetometer_hard_and_soft_iron():
    truth = wobble_truth(8000, 100.0)
    c = cfg(mag={"enabled": True, "rate_hz": 100.0, "noise_ut": 0.05, "hard_iron_ut": 15.0, "soft_iron_pct": 5.0})
    out = run(truth, c, seed=3)
    # body-frame Earth field by an independent rotation library (scipy: x, y, z, w order)
    q = truth.q_nb_wxyz
    b_body = Rotation.from_quat(q[:, [1, 2, 3, 0]]).inv().apply(MAG_EARTH_UT)
    design = np.hstack([b_body, np.ones((len(q), 1))])
    sol, *_ = np.linalg.lstsq(design, out.mag_ut, rcond=None)
    soft, hard = np.array(out.truth["mag"]["soft_iron"]), np.array(out.truth["mag"]["hard_iron_ut"])
    np.testing.assert_allclose(sol[:3].T, soft, atol=2e-3)
    np.testing.assert_allclose(sol[3], hard, atol=0.05)
    np.testing.assert_allclose(soft, soft.T)  # symmetric soft iron
    assert np.abs(hard).max() > 3 and np.abs(soft - np.eye(3)).max() > 0.01
    # no soft iron: readings minus hard iron lie on a sphere of the Earth-field radius
    c2 = cfg(mag={"enabled": True, "rate_hz": 100.0, "hard_iron_ut": 15.0})
    out2 = run(truth, c2, seed=3)
    r = np.linalg.norm(out2.mag_ut - np.array(out2.truth["mag"]["hard_iron_ut"]), axis=1)
    np.testing.assert_allclose(r, np.linalg.norm(MAG_EARTH_UT), rtol=1e-9)


def test_magnetometer_rate_is_held_between_samples():
    truth = wobble_truth(4000, 400.0)  # 10 s
    c = cfg(mag={"enabled": True, "rate_hz": 50.0, "noise_ut": 0.1})
    out = run(truth, c)
    changes = np.flatnonzero(np.any(np.diff(out.mag_ut, axis=0) != 0, axis=1)) + 1
    assert len(changes) == 10 * 50 - 1
    np.testing.assert_allclose(np.diff(out.t_s[changes]), 1 / 50, atol=1e-9)


# --------------------------------------------------------------------------- rates


def test_decimation_point_and_boxcar():
    rate = 400.0
    truth = static_truth(4000, rate)
    truth.gyr_true_rad_s[:, 0] = 0.5 * truth.t_s  # a ramp: its boxcar mean is known in closed form
    out = run(truth, cfg(rate_hz=100.0))
    np.testing.assert_array_equal(out.t_s, truth.t_s[::4])
    np.testing.assert_array_equal(out.q_nb_wxyz, truth.q_nb_wxyz[::4])
    np.testing.assert_allclose(out.gyr_rad_s[:, 0], 0.5 * out.t_s)
    box = run(truth, cfg(rate_hz=100.0, anti_alias="boxcar"))
    np.testing.assert_allclose(box.gyr_rad_s[1:, 0], 0.5 * (box.t_s[1:] - 1.5 / rate), atol=1e-12)
    with pytest.raises(ConfigError, match="integer"):
        run(truth, cfg(rate_hz=150.0))
    with pytest.raises(ConfigError, match="integer"):
        run(truth, cfg(rate_hz=800.0))


# --------------------------------------------------------------------------- seeds, records, presets


def test_same_seed_same_output_different_seed_differs():
    truth = wobble_truth(2000, 200.0)
    c = load_sensor_config("consumer")
    a, b, d = run(truth, c, 11), run(truth, c, 11), run(truth, c, 12)
    for f in ("gyr_rad_s", "acc_m_s2", "mag_ut", "gyr_bias_rad_s", "acc_bias_m_s2"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert not np.array_equal(getattr(a, f), getattr(d, f))


def test_record_from_truth_carries_truths_and_is_byte_identical(tmp_path):
    truth = wobble_truth(1000, 200.0)
    c = load_sensor_config("industrial", ["rate_hz=100"])
    rec = record_from_truth(truth, c, seed=5)
    np.testing.assert_allclose(np.abs(np.sum(rec.q_ref_wxyz * truth.q_nb_wxyz[::2], axis=1)), 1.0, atol=1e-12)
    assert np.all(rec.q_ref_wxyz[:, 0] >= 0)
    assert rec.meta["imu_rate_hz"] == 100.0 and rec.meta["sensor_preset"] == "industrial"
    assert rec.meta["sensor"]["gyro"]["arw_deg_sqrt_h"] == 0.168 and rec.meta["seed"] == 5
    assert rec.meta["source_kind"] == "jsbsim" and rec.meta["reference_source"] == "jsbsim-truth"
    write_record(rec, tmp_path / "a.parquet")
    write_record(record_from_truth(truth, c, seed=5), tmp_path / "b.parquet")
    write_record(record_from_truth(truth, c, seed=6), tmp_path / "c.parquet")
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()
    assert (tmp_path / "a.parquet").read_bytes() != (tmp_path / "c.parquet").read_bytes()
    back = read_record(tmp_path / "a.parquet")
    np.testing.assert_array_equal(back.data["gyr_bias_x_rad_s"], rec.data["gyr_bias_x_rad_s"])
    assert back.meta["sensor_truth"]["gyro"]["matrix"] == rec.meta["sensor_truth"]["gyro"]["matrix"]


def test_presets_exist_and_are_ordered_by_grade():
    names = set(list_presets())
    assert {"consumer", "industrial", "tactical"} <= names
    c, i, t = (load_sensor_config(n) for n in ("consumer", "industrial", "tactical"))
    assert c.gyro.arw_deg_sqrt_h > i.gyro.arw_deg_sqrt_h > t.gyro.arw_deg_sqrt_h
    assert c.accel.vrw_m_s_sqrt_h > t.accel.vrw_m_s_sqrt_h  # (ICM-42688 white noise is below STIM300's)
    assert c.accel.bias_rw_mg_sqrt_h > i.accel.bias_rw_mg_sqrt_h > t.accel.bias_rw_mg_sqrt_h
    assert c.gyro.bias_rw_deg_h_sqrt_h > i.gyro.bias_rw_deg_h_sqrt_h > t.gyro.bias_rw_deg_h_sqrt_h


def test_bad_sensor_configuration_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="unknown sensor preset 'nope'"):
        load_sensor_config("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[gyro]\narw = 0.3\n')
    with pytest.raises(ConfigError, match="'gyro.arw'"):
        load_sensor_config(str(bad))
    with pytest.raises(ConfigError, match="'gyro.arw_deg'"):
        load_sensor_config("consumer", ["gyro.arw_deg=1"])
    with pytest.raises(ConfigError, match="must be a number"):
        load_sensor_config("consumer", ["gyro.arw_deg_sqrt_h=fast"])
    with pytest.raises(ConfigError, match=">= 0"):
        load_sensor_config("consumer", ["accel.vrw_m_s_sqrt_h=-1"])
    with pytest.raises(ConfigError, match="anti_alias"):
        load_sensor_config("consumer", ["anti_alias=median"])


def test_magnetometer_motor_interference_follows_the_thrust_and_disturbances_come_in_episodes():
    """Closed form: with only the new terms on, m − R_nbᵀ B_n = k·T·u (T = thrust in g along −z)
    outside the disturbance episodes, and inside one it is R_nbᵀ d for a constant earth-frame d."""
    import numpy as np

    from tepinn_flight.quat import quat_conj, quat_rotate
    from tepinn_flight.sim.sensors import MagConfig, _magnetometer

    n = 4000
    t = np.arange(n) / 100.0
    yaw = 0.3 * t
    q = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], 1)
    thrust = 1.0 + 0.5 * np.sin(t)  # g
    acc = np.zeros((n, 3))
    acc[:, 2] = -9.80665 * thrust
    b = np.array([20.0, -3.0, 40.0])
    cfg = MagConfig(rate_hz=100.0, motor_ut_per_g=8.0, disturbances_per_min=6.0, disturbance_ut=15.0)
    y, consts = _magnetometer(np.random.default_rng(5), t, q, b, cfg, 100.0, acc)
    base = quat_rotate(quat_conj(q), np.broadcast_to(b, (n, 3)))
    u = np.array(consts["motor_direction"])
    resid = y - base - 8.0 * thrust[:, None] * u
    inside = np.zeros(n, bool)
    for a, e in consts["disturbances"]:
        inside |= (t >= a) & (t < e)
    assert consts["disturbances"] and inside.any() and (~inside).any()
    np.testing.assert_allclose(resid[~inside], 0.0, atol=1e-9)
    d_earth = quat_rotate(q[inside], resid[inside])  # back to the earth frame: piecewise constant
    assert np.abs(d_earth).max() > 1.0
    # switched off, the earlier realisation is unchanged
    y0, _ = _magnetometer(np.random.default_rng(5), t, q, b, MagConfig(rate_hz=100.0), 100.0, acc)
    np.testing.assert_allclose(y0, base, atol=1e-9)


# --------------------------------------------------------------------------- GNSS receiver


def test_gnss_velocity_is_the_true_one_latency_late_with_the_configured_noise_and_its_own_stream():
    from tepinn_flight.sim.sensors import GnssConfig

    rate = 400.0
    truth = wobble_truth(40_000, rate)  # 100 s
    t = truth.t_s
    truth = dataclasses.replace(truth, vel_ned_m_s=np.c_[3.0 * np.sin(0.5 * t), 2.0 * np.cos(0.3 * t), np.zeros_like(t)])
    g = GnssConfig(rate_hz=5.0, vel_noise_m_s=0.0, latency_s=0.2)
    out = run(truth, cfg(gnss=g))
    v = out.gnss_vel_ne_m_s
    last_fix = 0.2 + np.floor((t[-1] - 0.2) * 5.0) / 5.0
    inside = (t >= 0.2 - 1e-9) & (t <= last_fix + 1e-9)
    assert np.isfinite(v[inside]).all() and np.isnan(v[~inside]).all()  # the first fix comes latency_s late
    fix = np.isclose((t - 0.2) * 5.0, np.round((t - 0.2) * 5.0)) & (t >= 0.2)  # samples at a fix time
    np.testing.assert_allclose(v[fix, 0], 3.0 * np.sin(0.5 * (t[fix] - 0.2)), atol=1e-9)
    np.testing.assert_allclose(v[fix, 1], 2.0 * np.cos(0.3 * (t[fix] - 0.2)), atol=1e-9)
    noisy = run(truth, cfg(gnss=dataclasses.replace(g, vel_noise_m_s=0.1))).gnss_vel_ne_m_s
    assert abs(np.std(noisy[fix] - v[fix]) - 0.1) < 0.01
    # its draws are its own: the IMU's realisations do not change with the receiver on, off or noisy
    base = run(truth, cfg(gyro={"arw_deg_sqrt_h": 0.3}, gnss=GnssConfig(enabled=False)))
    assert base.gnss_vel_ne_m_s is None
    other = run(truth, cfg(gyro={"arw_deg_sqrt_h": 0.3}, gnss=dataclasses.replace(g, vel_noise_m_s=0.1)))
    np.testing.assert_array_equal(base.gyr_rad_s, other.gyr_rad_s)
    rec = record_from_truth(truth, cfg(gnss=g), 0)
    np.testing.assert_array_equal(rec.gnss_vel_ne_m_s, v)
    assert rec.meta["gnss_source"] == "simulated" and rec.meta["gnss_rate_hz"] == 5.0


def test_a_log_that_loses_samples_and_jitters_its_stamps_keeps_every_other_draw():
    # the log's timing (lost_fraction, stamp_jitter_s) draws from a stream of its own: the kept rows carry the very
    # measurements and truth of the flight without it; the lost ones are single samples (steps of two periods)
    from tepinn_flight.record_gaps import inner_steps, lost_steps

    truth = wobble_truth(4000, 200.0)
    base = load_sensor_config("consumer")
    plain = record_from_truth(truth, base, seed=3)
    logged = record_from_truth(truth, dataclasses.replace(base, lost_fraction=0.03, stamp_jitter_s=0.0002), seed=3)
    lost = logged.meta["sensor_truth"]["lost_samples"]
    assert lost == len(plain) - len(logged) and 0.02 * len(plain) < lost < 0.04 * len(plain)
    # each row found by its stamp (σ 0.2 ms, a tenth of the 5-ms period): the kept measurements and truth are the
    # plain flight's
    pos = np.searchsorted(plain.t_s, logged.t_s - 0.0025)
    np.testing.assert_array_equal(logged.q_ref_wxyz, plain.q_ref_wxyz[pos])
    np.testing.assert_array_equal(logged.gyr_rad_s, plain.gyr_rad_s[pos])
    assert np.all(np.diff(pos) >= 1) and np.all(np.diff(pos) <= 2)
    steps = inner_steps(logged)
    assert lost_steps(steps) == int(np.sum(np.diff(pos) == 2))
    err = logged.t_s - plain.t_s[pos]
    assert np.std(err) == pytest.approx(0.0002, rel=0.1) and np.abs(err).max() <= 0.45 / 200.0 + 1e-12
    with pytest.raises(ConfigError, match="lost_fraction"):
        dataclasses.replace(base, lost_fraction=0.6)

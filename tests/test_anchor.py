"""The filter-anchored estimator: VQF with every learned correction off, the tilt pull, gates,
holes, and live = offline."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import vqf
from scipy.spatial.transform import Rotation

from tests.conftest import broad_trial
from tests.live_run import live_run
from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput, q_nb_from_vqf, tilt_pull_quat, to_sensor
from tepinn_flight.model.checkpoint import default_model_path, load_model
from tepinn_flight.model.estimate import estimate_anchored
from tepinn_flight.model.streaming import StreamingEstimator
from tepinn_flight.model.synthetic import synthetic_record

Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]


def _shipped() -> AnchorConfig:
    """The shipped estimator's settings (with the checkpoint's fusion as the pulls' target)."""
    return load_model(default_model_path())[1]


def _live(model, cfg, rec) -> np.ndarray:
    """The live estimator pushed every sample of ``rec`` (no magnetometer) → (n, 4) its estimates, NaN where none."""
    return live_run(model, cfg, rec)[0]


def _no_gates(cfg: AnchorConfig) -> AnchorConfig:
    """``cfg`` with every learned correction off but VQF fed as ``cfg`` feeds it (each gyro sample over its own
    step: a real log's stamps are uneven, test_gyro_step_weighting.py): the estimate where no gate acts."""
    return dataclasses.replace(cfg.learned_off, gyro_step_weighting=cfg.gyro_step_weighting)


def _vqf_reference(rec):
    """VQF straight from the package on the record's one segment (the frame conversion is the
    one the peers use: evaluation/peers.py)."""
    from tepinn_flight.evaluation.peers import Q_NED_ENU, body_to_zup_sensor, q_nb_from_earth_sensor

    dt = np.diff(rec.t_s[:52])
    out = vqf.VQF(float(np.median(dt))).updateBatch(body_to_zup_sensor(rec.gyr_rad_s), body_to_zup_sensor(rec.acc_m_s2))
    return q_nb_from_earth_sensor(out["quat6D"], Q_NED_ENU)


def test_with_every_learned_correction_off_it_is_vqf_on_a_real_broad_trial():
    from tepinn_flight.ingest import ingest_log

    rec = ingest_log(broad_trial("broad_10_*.hdf5"))
    model, _, _ = load_model(default_model_path())
    est = estimate_anchored(model, rec, AnchorConfig().learned_off)
    np.testing.assert_array_equal(est[Q].to_numpy(), _vqf_reference(rec))
    # and the shipped settings change nothing where no gate fires (slow hand-held translation), but for the
    # offline smoothing (a physics step: the tilt of VQF run both ways there, test_smoother.py)
    est2 = estimate_anchored(model, rec, dataclasses.replace(_shipped(), smoother=False))
    np.testing.assert_allclose(est2[Q].to_numpy(), _vqf_reference(rec), atol=1e-12)


def test_a_gyro_scale_is_vqf_on_the_scaled_gyro():
    # the vehicle's gyro calibration (train --init fits it): with every learned correction off but
    # the scale, the output is VQF on the gyro times the scale, bit for bit; learned_off drops it too
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import GYR_COLS, FlightRecord

    rec = ingest_log(broad_trial("broad_10_*.hdf5"))
    model, _, _ = load_model(default_model_path())
    cfg = dataclasses.replace(AnchorConfig().learned_off, gyro_scale=(1.0, 0.99, 1.005))
    d = rec.data.copy()
    d[GYR_COLS] = d[GYR_COLS].to_numpy() * np.array([1.0, 0.99, 1.005])
    want = _vqf_reference(FlightRecord(d, dict(rec.meta)))
    np.testing.assert_array_equal(estimate_anchored(model, rec, cfg)[Q].to_numpy(), want)
    assert np.abs(_vqf_reference(rec) - want).max() > 1e-4
    assert cfg.learned_off.gyro_scale == (1.0, 1.0, 1.0)


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.1])
def test_tilt_pull_turns_about_a_horizontal_axis_by_the_fraction(fraction):
    rng = np.random.default_rng(3)
    q = Rotation.random(random_state=4).as_quat()[[3, 0, 1, 2]]
    up_target = rng.normal(size=3)
    up_target /= np.linalg.norm(up_target)
    d = tilt_pull_quat(q, up_target, fraction)
    assert abs(d[3]) < 1e-12  # no component about the earth's vertical: heading untouched
    r_q = Rotation.from_quat(q[[1, 2, 3, 0]])
    before = r_q.apply(up_target)  # target up in the filter's earth frame
    after = (Rotation.from_quat(d[[1, 2, 3, 0]]) * r_q).apply(up_target)
    ang0 = math.acos(np.clip(before[2], -1, 1))
    ang1 = math.acos(np.clip(after[2], -1, 1))
    assert ang1 == pytest.approx((1 - fraction) * ang0, abs=1e-9)


def test_a_pull_survives_the_next_samples_because_the_accelerometer_state_turns_with_it():
    """Turning only VQF's inclination quaternion is undone at the next sample (its low-passed
    accelerometer still says level); AnchoredVQF.pull turns that state too."""
    n = 200
    gyr = np.zeros((n, 3))
    acc = np.tile([0.0, 0.0, -9.81], (n, 1))  # level at rest, body FRD
    f = AnchoredVQF(AnchorConfig(), 0.01)
    f.update(np.arange(n) * 0.01, gyr, acc)
    d = np.array([math.cos(0.1), math.sin(0.1), 0.0, 0.0])  # 11.5° about the earth x axis
    f.pull(d)
    q6, _, _, _ = f.update(np.arange(n, n + 1) * 0.01, gyr[:1], acc[:1])
    tilt = math.degrees(2 * math.acos(min(1.0, math.sqrt(q6[0, 0] ** 2 + q6[0, 3] ** 2))))
    assert tilt == pytest.approx(math.degrees(0.2), abs=0.2)  # one sample of the 3-s low-pass
    naive = vqf.VQF(0.01)
    naive.updateBatch(to_sensor(gyr), to_sensor(acc))
    st = naive.state
    st["accQuat"] = d
    naive.state = st
    q = q_nb_from_vqf(naive.updateBatch(to_sensor(gyr[:1]), to_sensor(acc[:1]))["quat6D"])
    assert math.degrees(2 * math.acos(min(1.0, math.sqrt(q[0, 0] ** 2 + q[0, 3] ** 2)))) < 0.01


def test_gates_use_the_network_only_with_evidence():
    """Level at rest: a network window claiming 20° of tilt moves nothing at hand-held speed, and
    pulls by the configured fraction (0.5 → 10°) at flight speed or after a saturated gyro
    sample (one sample of VQF's 3-s low-pass after the pull takes ~0.1° back)."""
    n = 100
    t = np.arange(n) * 0.01
    gyr, acc = np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1))
    tilted = np.array([math.cos(math.radians(10)), math.sin(math.radians(10)), 0.0, 0.0])

    def tilt_after(vel, clipped=None, gain=0.5, clip_min_s=0.1):
        # (rest_relevel_s off: these clip marks sit on a still gyro, which the re-levelling at rest would
        # take for a rest after a saturation; a gyro at its range is not still: the tests below)
        f = AnchoredVQF(AnchorConfig(pull_gain=gain, centripetal=False, clip_min_s=clip_min_s, rest_relevel_s=0.0), 0.01)
        f.update(t, gyr, acc, clipped=clipped)
        f.correct(WindowOutput(tilted, 0.01, np.zeros(3), np.asarray(vel, float), np.zeros(3)))
        q = f.update(t[-1:] + 0.01, gyr[:1], acc[:1])[0][0]
        return math.degrees(2 * math.acos(min(1.0, math.sqrt(q[0] ** 2 + q[3] ** 2))))

    assert tilt_after([3.0, 0, 0]) < 0.01
    assert tilt_after([60.0, 0, 0]) == pytest.approx(10.0, abs=0.15)
    assert tilt_after([25.0, 0, 0]) == pytest.approx(5.0, abs=0.15)  # half-way up the ramp
    clip = np.zeros(n, bool)
    clip[50:59] = True  # 0.09 s saturated: below clip_min_s (0.1 s), too little to open the gate
    assert AnchorConfig().clip_min_s == pytest.approx(0.1)
    assert tilt_after([0.0, 0, 0], clipped=clip) < 0.01
    clip[50:60] = True  # 0.1 s: the gate opens
    assert tilt_after([0.0, 0, 0], clipped=clip) == pytest.approx(10.0, abs=0.15)
    one = np.zeros(n, bool)
    one[50] = True  # checkpoints made before clip_min_s (0): one clipped sample opens it
    assert tilt_after([0.0, 0, 0], clipped=one, clip_min_s=0.0) == pytest.approx(10.0, abs=0.15)
    one[50], one[0] = False, True  # ... for clip_hold_s (4 s) after it; a 6-s-old one no longer
    f = AnchoredVQF(AnchorConfig(pull_gain=0.5, centripetal=False, clip_min_s=0.0), 0.01)
    f.update(t, gyr, acc, clipped=one)
    f.update(t + 5.0, gyr, acc)
    f.correct(WindowOutput(tilted, 0.01, np.zeros(3), np.zeros(3), np.zeros(3)))
    assert f.gate == 0.0


def test_in_a_gap_after_a_gate_sigma_holds_the_networks_disagreement_for_sigma_gap_hold_s():
    """Level at rest (no pull: pull_gain 0, so VQF stays level): a window at flight speed opens the gate, the
    next one at hand-held speed shuts it; the network's target is tilted 10° (its down against the level
    filter's, by scipy). In the gap σ² grows by (k·10°)² over the same filter with k = 0, until the gate has
    been shut for sigma_gap_hold_s; a filter whose gate never acted has no gap term."""
    from scipy.spatial.transform import Rotation

    n = 100
    t = np.arange(n) * 0.01
    gyr, acc = np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1))
    target = np.array([math.cos(math.radians(5)), math.sin(math.radians(5)), 0.0, 0.0])  # 10° of roll
    down_t = Rotation.from_quat(target[[1, 2, 3, 0]]).inv().apply([0.0, 0.0, 1.0])
    d_deg = math.degrees(math.acos(float(np.clip(down_t @ [0.0, 0.0, 1.0], -1, 1))))
    assert d_deg == pytest.approx(10.0, abs=1e-9)

    def sigmas(k, windows, hold_s=30.0):
        f = AnchoredVQF(AnchorConfig(pull_gain=0.0, centripetal=False, sigma_gap_gain=k, sigma_gap_hold_s=hold_s), 0.01)
        out = []
        t0 = 0.0
        for vel, wait_s in windows:
            sig = f.update(t + t0, gyr, acc)[2]
            t0 += 1.0 + wait_s
            if wait_s:
                f.update(np.arange(int(wait_s * 100)) * 0.01 + t0 - wait_s, gyr[:1].repeat(int(wait_s * 100), 0),
                         acc[:1].repeat(int(wait_s * 100), 0))  # fmt: skip
            f.correct(WindowOutput(target, 0.01, np.zeros(3), np.array([vel, 0.0, 0.0]), np.zeros(3)))
            out.append((f.gate, float(f.update(t[:1] + t0, gyr[:1], acc[:1])[2][0])))
            t0 += 0.01
        return out

    plan = [(60.0, 0.0), (3.0, 0.0), (3.0, 20.0), (3.0, 15.0)]  # gate on; shut 1 s later; 21 s; 37 s after it acted
    new, old = sigmas(1.5, plan), sigmas(0.0, plan)
    assert [g for g, _ in new] == [1.0, 0.0, 0.0, 0.0]
    assert new[0][1] == pytest.approx(old[0][1], rel=1e-12)  # while the gate acts: the network's σ, as before
    for i in (1, 2):  # in the gap: σ² + (k·D)²
        assert new[i][1] ** 2 - old[i][1] ** 2 == pytest.approx(math.radians(1.5 * d_deg) ** 2, rel=1e-6)
    assert new[3][1] == pytest.approx(old[3][1], rel=1e-12)  # 37 s after the gate acted: no gap term
    never = sigmas(1.5, [(3.0, 0.0), (3.0, 0.0)])
    assert [s for _, s in never] == pytest.approx([s for _, s in sigmas(0.0, [(3.0, 0.0), (3.0, 0.0)])], rel=1e-12)


def test_sigma_holds_the_networks_disagreement_while_the_uncalibrated_gyro_evidence_builds():
    """Rule 22: level at rest on a gyro with a 1 °/s bias on x (VQF reads it at rest: ≥ 0.2 °/s), no gate acting (hand-held
    speed; the older fusion's horizontal bias 2.5 °/s, beyond quiet_bias_deg_s but below the gate's 3 °/s), the network's
    target tilted 10°: σ² grows by (k·D)² against the same filter without the rule; not where the fusion's bias is
    1 °/s, nor where the gyro has no bias (VQF's estimate stays near 0), nor with sigma_gap_bias_evidence off."""
    n = 500
    t = np.arange(n) * 0.01
    acc = np.tile([0.0, 0.0, -9.81], (n, 1))
    target = np.array([math.cos(math.radians(5)), math.sin(math.radians(5)), 0.0, 0.0])  # 10° of roll

    def sigma(gyr_bias_deg_s, fusion_bias_deg_s, on=True, k=1.5):
        cfg = AnchorConfig(pull_gain=0.0, centripetal=False, sigma_gap_gain=k, sigma_gap_bias_evidence=on)
        f = AnchoredVQF(cfg, 0.01)
        gyr = np.tile([math.radians(gyr_bias_deg_s), 0.0, 0.0], (n, 1))
        q_last = f.update(t, gyr, acc)[0][-1]
        vqf_bias = math.degrees(float(np.max(np.abs(f.vqf_bias_s()))))
        f.correct(WindowOutput(target, 0.01, np.zeros(3), np.array([3.0, 0.0, 0.0]), np.zeros(3),
                               np.array([math.radians(fusion_bias_deg_s), 0.0, 0.0])))  # fmt: skip
        assert f.gate == 0.0 and not f.bias_latched
        # D by scipy: the angle between the target's down and the filter's, both in body axes
        downs = [Rotation.from_quat(np.asarray(q)[[1, 2, 3, 0]]).inv().apply([0.0, 0.0, 1.0]) for q in (target, q_last)]
        d = math.acos(float(np.clip(downs[0] @ downs[1], -1.0, 1.0)))
        return float(f.update(t[-1:] + 0.01, gyr[:1], acc[:1])[2][0]), vqf_bias, d

    (on, vb, d), (off, _, _) = sigma(1.0, 2.5), sigma(1.0, 2.5, on=False)
    assert 0.2 <= vb < 1.9  # VQF reads the bias: the evidence, below its clip (where the gate itself would latch)
    assert math.degrees(d) == pytest.approx(10.0, abs=1.0)
    assert on**2 - off**2 == pytest.approx((1.5 * d) ** 2, rel=1e-3)
    assert sigma(1.0, 1.0)[0] == pytest.approx(off, rel=1e-12)  # the fusion's bias within quiet_bias_deg_s
    no_bias, vb0, _ = sigma(0.0, 2.5)
    assert vb0 < 0.2 and no_bias == pytest.approx(sigma(0.0, 2.5, on=False)[0], rel=1e-12)
    assert AnchorConfig().sigma_gap_bias_evidence and not AnchorConfig().learned_off.sigma_gap_gain


def test_a_non_finite_sample_is_a_hole_not_the_end_of_the_estimate():
    rec = synthetic_record(seed=1, duration_s=12.0, rate_hz=100.0)
    model, _, _ = load_model(default_model_path())
    clean = estimate_anchored(model, rec, _shipped())[Q].to_numpy()
    rec.data.loc[600, "gyr_x_rad_s"] = np.nan
    rec.data.loc[700, "acc_z_m_s2"] = np.inf
    holed = estimate_anchored(model, rec, _shipped())[Q].to_numpy()
    assert np.all(np.isfinite(holed))
    assert np.abs(holed[600] - holed[599]).max() < 0.05  # bridged with the previous sample
    ang = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(holed * clean, 1)), 0, 1)))
    assert ang[590:].max() < 2.0  # one lost sample, not a lost flight


def test_the_live_estimator_builds_every_field_of_a_window():
    """``StreamingEstimator._anchored_step`` builds each window's ``WindowOutput`` field by field (a
    ``dataclasses.replace`` cost 13 µs a window live): a field added to it must be added there too."""
    from tepinn_flight.model.anchor import WindowOutput

    assert [f.name for f in dataclasses.fields(WindowOutput)] == [
        "q_nb_wxyz", "sigma_rad", "gyr_bias_rad_s", "vel_m_s", "acc_m_s2", "fusion_bias_rad_s", "gnss_aided", "gnss_fast"]


def test_live_equals_offline_with_the_gates_on():
    """The streaming estimator gives the offline estimate to 1e-6 from its first estimate on,
    with every gate forced on (pull, centripetal correction) so that all of it is exercised."""
    rec = synthetic_record(seed=2, duration_s=8.0, rate_hz=100.0)
    model, _, _ = load_model(default_model_path())
    cfg = dataclasses.replace(_shipped(), speed_lo_m_s=0.0, speed_hi_m_s=1e-3)
    off = estimate_anchored(model, rec, cfg)
    q_live = _live(model, cfg, rec)
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 60
    q_off = off[Q].to_numpy()
    np.testing.assert_allclose(q_live[have], q_off[have], atol=1e-6)
    # the gates did act: the plain filter differs
    plain = estimate_anchored(model, rec, cfg.learned_off)[Q].to_numpy()
    assert np.abs(plain[-100:] - q_off[-100:]).max() > 1e-3


def _spin_record(yaw_rate_rad_s=0.5, duration_s=30.0, rate_hz=100.0, disturbance_ut=None, heading0=0.7):
    """A level vehicle at rest spinning about its z axis in a 50 µT field with 60° dip: closed-form
    truth (heading = heading0 + rate·t), magnetometer = R_nbᵀ m_ned (+ a constant body-frame
    disturbance from t = 10 s where given)."""
    import pandas as pd

    from tepinn_flight.record import FlightRecord

    t = np.arange(0, duration_s, 1.0 / rate_hz)
    yaw = heading0 + yaw_rate_rad_s * t
    q = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], 1)  # body → NED, level
    m_ned = 50.0 * np.array([math.cos(math.radians(60)), 0.0, math.sin(math.radians(60))])
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    mag = rot.inv().apply(m_ned)
    if disturbance_ut is not None:
        mag[t >= 10.0] += disturbance_ut
    d = {"t_s": t, "segment": np.zeros(len(t), np.int64)}
    for i, ax in enumerate("xyz"):
        d[f"gyr_{ax}_rad_s"] = [0.0, 0.0, yaw_rate_rad_s][i] + 0 * t
        d[f"acc_{ax}_m_s2"] = [0.0, 0.0, -9.81][i] + 0 * t
        d[f"mag_{ax}_ut"] = mag[:, i]
    for i, c in enumerate("wxyz"):
        d[f"q_ref_{c}"] = q[:, i]
    d["clipped"] = np.zeros(len(t), bool)
    return FlightRecord(pd.DataFrame(d), {"source_kind": "synthetic"}), yaw


def _heading_err_deg(est, yaw):
    q = est[Q].to_numpy()
    h = np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2))
    return np.degrees(np.abs(np.angle(np.exp(1j * (h - yaw)))))


def test_nine_d_reads_the_heading_from_the_field_of_a_level_vehicle_spun_about_z():
    rec, yaw = _spin_record()
    model, _, _ = load_model(default_model_path())
    six = estimate_anchored(model, rec, _shipped())
    nine = estimate_anchored(model, rec, dataclasses.replace(_shipped(), mode="9d"))
    late = rec.t_s > 20.0
    assert _heading_err_deg(nine, yaw)[late].max() < 1.0  # absolute heading: magnetic north
    assert _heading_err_deg(six, yaw)[late].min() > 30.0  # 6-D starts at heading 0, not 0.7 rad


def test_nine_d_rejects_a_constant_disturbance_of_the_field():
    """A vehicle spinning at 29 °/s (so that VQF learns the undisturbed field's norm and dip) gets
    a constant 30 µT disturbance in body axes at t = 10 s (steel or a magnet beside the sensor: a
    hard-iron offset). The heading stays within 12° (VQF's disturbance rejection); the disturbed
    field taken at face value would be off by up to ~50° (a field that stays changed for 20 s is
    VQF's new normal, so the check ends there), and VQF with rejection switched off
    drifts much further than the anchored estimator."""
    rec, yaw = _spin_record(yaw_rate_rad_s=0.5, disturbance_ut=np.array([0.0, 30.0, 0.0]), duration_s=40.0)
    model, _, _ = load_model(default_model_path())
    nine = estimate_anchored(model, rec, dataclasses.replace(_shipped(), mode="9d"))
    after = (rec.t_s > 10.0) & (rec.t_s < 28.0)  # VQF takes a field that stays 20 s as the new normal
    err = _heading_err_deg(nine, yaw)[after]
    assert err.max() < 12.0
    m = rec.mag_ut[after]
    raw = np.degrees(np.abs(np.angle(np.exp(1j * (-np.arctan2(m[:, 1], m[:, 0]) - yaw[after])))))
    assert raw.max() > 40.0  # the disturbed field's own heading (level: heading = −atan2(m_y, m_x))
    no_rej = vqf.VQF(0.01, magDistRejectionEnabled=False).updateBatch(
        to_sensor(rec.gyr_rad_s), to_sensor(rec.acc_m_s2), to_sensor(rec.mag_ut))["quat9D"]
    h = _heading_err_deg(_frame_q(q_nb_from_vqf(no_rej)), yaw)[after]
    assert np.sqrt(np.mean(h**2)) > 1.5 * np.sqrt(np.mean(err**2))


def _frame_q(q):
    import pandas as pd

    return pd.DataFrame(q, columns=Q)


def test_nine_d_on_a_record_without_magnetometer_is_one_clear_error():
    from tepinn_flight.model.estimate import MissingMagnetometer

    rec = synthetic_record(seed=1, duration_s=5.0, rate_hz=100.0)
    rec.data[["mag_x_ut", "mag_y_ut", "mag_z_ut"]] = np.nan
    model, _, _ = load_model(default_model_path())
    with pytest.raises(MissingMagnetometer):
        estimate_anchored(model, rec, dataclasses.replace(_shipped(), mode="9d"))
    auto = estimate_anchored(model, rec, dataclasses.replace(_shipped(), mode="auto"))
    np.testing.assert_array_equal(auto[Q].to_numpy(), estimate_anchored(model, rec, _shipped())[Q].to_numpy())


def test_estimate_cli_bridges_a_nan_sample_says_so_in_one_line_and_estimates_the_rest(tmp_path, capsys):
    import pandas as pd

    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    rec = synthetic_record(seed=3, duration_s=12.0, rate_hz=100.0)
    rec.data.loc[len(rec) // 2, "gyr_y_rad_s"] = np.nan
    src = tmp_path / "r.parquet"
    write_record(rec, src)
    assert main(["estimate", str(src), "-o", str(tmp_path / "e.parquet"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "1 non-finite IMU sample(s) bridged" in err and len(err.strip().splitlines()) == 1
    q = pd.read_parquet(tmp_path / "e.parquet")["q_est_w"].to_numpy()
    assert np.all(np.isfinite(q))  # every sample estimated (was: 42 % after one NaN)


@pytest.mark.parametrize("mode", ["9d", "auto"])
def test_live_nine_d_equals_offline(mode):
    rec, yaw = _spin_record(duration_s=12.0)
    model, _, _ = load_model(default_model_path())
    cfg = dataclasses.replace(_shipped(), mode=mode)
    off = estimate_anchored(model, rec, cfg)[Q].to_numpy()
    live = StreamingEstimator(model, cfg)
    q_live = np.full((len(rec), 4), np.nan)
    for i in range(len(rec)):
        e = live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i], rec.mag_ut[i], False)
        if e.q_nb_wxyz is not None:
            q_live[i] = e.q_nb_wxyz
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 60
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)
    assert _heading_err_deg(_frame_q(q_live[have]), yaw[have])[-100:].max() < 1.0  # absolute heading live


def _with_clipped(rec, t0_s, t1_s):
    """``rec`` with its samples in [t0_s, t1_s) marked saturated."""
    from tepinn_flight.record import FlightRecord

    data = rec.data.copy()
    data["clipped"] = (data["t_s"] >= t0_s) & (data["t_s"] < t1_s)
    return FlightRecord(data, dict(rec.meta))


@pytest.mark.parametrize("stride", [1, 2])
def test_live_equals_offline_with_quiet_blocks_busy_blocks_and_a_saturated_stretch(stride):
    """Quiet blocks: live and offline run the same windows (the blocks' first ones, every window —
    or every ``busy_stride``-th — of a block a gate may open in, every window holding a saturated
    token) and give the same estimate."""
    from tepinn_flight.model.estimate import anchored_windows

    rec = _with_clipped(synthetic_record(seed=2, duration_s=24.0, rate_hz=100.0), 15.0, 15.3)
    model, _, _ = load_model(default_model_path())
    # the fusion's bias on this record crosses 2.5 °/s in some blocks and not in others (with a
    # shorter start-up for the stride, so that busy blocks follow it outside the saturated stretch)
    cfg = dataclasses.replace(_shipped(), quiet_blocks=True, quiet_bias_deg_s=2.5, busy_stride=stride,
                              quiet_after_blocks=10 if stride == 1 else 4)  # fmt: skip
    idx, _ = anchored_windows(model, rec, fusion=cfg.fusion_config, anchor=cfg)
    if stride > 1:  # fewer windows than with every window of the busy blocks, the start-up's all
        every, _ = anchored_windows(model, rec, fusion=cfg.fusion_config, anchor=dataclasses.replace(cfg, busy_stride=1))
        start = cfg.quiet_after_blocks * cfg.fusion_config.bias_feedback_windows
        np.testing.assert_array_equal(idx[:start], every[:start])
        assert len(idx) < len(every) - 10
    full, _ = anchored_windows(model, rec, fusion=cfg.fusion_config)
    q_live, ran = live_run(model, cfg, rec)
    np.testing.assert_array_equal(ran, idx)
    blocks = -(-len(full) // cfg.fusion_config.bias_feedback_windows)
    assert blocks + 20 < len(idx) < len(full) - 50  # quiet blocks and busy ones
    t_win = rec.t_s[idx]
    # every window holding a saturated token ran (those ending up to a window length after the stretch)
    after = rec.t_s[full][(rec.t_s[full] >= 15.0) & (rec.t_s[full] < 15.3 + model.config.window_s - 0.1)]
    assert np.isin(after, t_win).all()
    off = estimate_anchored(model, rec, cfg)[Q].to_numpy()
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 60
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)


def test_quiet_blocks_change_nothing_where_no_gate_opens_on_a_real_log():
    """On a real flight where no gate opens, the estimate with quiet blocks is the full one (VQF's,
    σ included) while the network runs on about one window in 25 after the segment's first blocks."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.estimate import anchored_windows

    from tests.conftest import real_log

    rec = ingest_log(real_log("erle_pxf_copter_15-12-2014_16.BIN"))
    model, _, _ = load_model(default_model_path())
    # the network's gates alone (erle flies with a GNSS fix: the GNSS aid and the offline smoothing, physics
    # steps, are not under test)
    full_cfg = dataclasses.replace(_shipped(), quiet_blocks=False, gnss_aid=False, smoother=False)
    quiet_cfg = dataclasses.replace(_shipped(), quiet_blocks=True, gnss_aid=False, smoother=False)
    idx_full, _ = anchored_windows(model, rec, fusion=full_cfg.fusion_config, anchor=full_cfg)
    idx_quiet, _ = anchored_windows(model, rec, fusion=quiet_cfg.fusion_config, anchor=quiet_cfg)
    start = quiet_cfg.quiet_after_blocks * quiet_cfg.fusion_config.bias_feedback_windows  # all of them run
    assert len(idx_quiet) - start <= (len(idx_full) - start) / 20
    full = estimate_anchored(model, rec, full_cfg)
    quiet = estimate_anchored(model, rec, quiet_cfg)
    cols = Q + ["sigma_rad"]
    np.testing.assert_allclose(quiet[cols].to_numpy(), full[cols].to_numpy(), rtol=0, atol=1e-12)
    plain = estimate_anchored(model, rec, _no_gates(full_cfg))
    np.testing.assert_allclose(quiet[Q].to_numpy(), plain[Q].to_numpy(), rtol=0, atol=1e-12)


def test_only_the_gyro_clipping_opens_the_saturation_gate_on_a_real_log():
    """An accelerometer at its range (a DataFlash VIBE clip counter, PX4's accelerometer_clipping)
    leaves the integrated rate right: on a real ArduCopter log with 2 s marked clipped by the
    accelerometer alone, the estimate stays VQF's; marked as the gyro's, the gate opens and pulls."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import FlightRecord

    from tests.conftest import real_log

    rec = ingest_log(real_log("erle_pxf_copter_15-12-2014_16.BIN"))
    model, _, _ = load_model(default_model_path())
    cfg = dataclasses.replace(_shipped(), gnss_aid=False, smoother=False)  # the gates alone (erle has a GNSS fix)
    stretch = (rec.t_s >= 60.0) & (rec.t_s < 62.0)

    def marked(gyro: bool):
        data = rec.data.copy()
        data["clipped"] = stretch
        data["gyr_clipped"] = stretch if gyro else np.zeros(len(rec), bool)
        return FlightRecord(data, dict(rec.meta))

    plain = estimate_anchored(model, rec, _no_gates(cfg))[Q].to_numpy()
    acc_only = estimate_anchored(model, marked(False), cfg)[Q].to_numpy()
    np.testing.assert_allclose(acc_only, plain, rtol=0, atol=1e-12)
    gyro = estimate_anchored(model, marked(True), cfg)[Q].to_numpy()
    ang = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(gyro * plain, 1)), 0, 1)))
    np.testing.assert_allclose(gyro[rec.t_s < 60.0], plain[rec.t_s < 60.0], rtol=0, atol=1e-12)  # causal
    assert ang[(rec.t_s >= 60.0) & (rec.t_s < 70.0)].max() > 0.05  # the gate pulled toward the network


@pytest.mark.parametrize("seed", range(5))
def test_the_gate_per_sample_is_what_writing_each_window_to_the_end_would_give(seed):
    """The per-sample gate of a pass (each window's from the sample after it on) is filled once at
    the end; the reference writes every window's gate up to the segment's end in turn (the former,
    quadratic, way), repeated starts and a window at the segment's last sample included."""
    from tepinn_flight.model.estimate import _piecewise

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    starts = np.sort(rng.integers(0, n + 1, size=int(rng.integers(1, 40))))
    values = rng.choice([0.0, 0.25, 1.0], size=len(starts))
    ref = np.zeros(n)
    for s, v in zip(starts, values):
        ref[s:] = v
    np.testing.assert_array_equal(_piecewise(starts, values, n), ref)


def _tumble_then_rest(rate_hz=100.0, rest_s=3.0, free_fall_rest=False, reading=6.9):
    """Level at rest 2 s, a 0.2-s tumble about y at 15 rad/s read clipped at ``reading`` rad/s (the gyro
    past its range: a ±400 °/s one by default, 1.6 rad of the 3.0 missed) in free fall, then a rest at
    the true attitude (the accelerometer reads −g in body axes; or nothing, a free fall, with
    ``free_fall_rest``) → (t, gyr, acc, clipped, true tilt at rest in degrees)."""
    dt = 1.0 / rate_hz
    n0, n1, n2 = int(2.0 * rate_hz), int(0.2 * rate_hz), int(rest_s * rate_hz)
    t = np.arange(n0 + n1 + n2) * dt
    gyr = np.zeros((len(t), 3))
    gyr[n0 : n0 + n1, 1] = reading  # the clipped reading
    clipped = np.zeros(len(t), bool)
    clipped[n0 : n0 + n1] = True
    acc = np.tile([0.0, 0.0, -9.81], (len(t), 1))
    acc[n0 : n0 + n1] = 0.0
    theta = 15.0 * 0.2  # the true pitch turned through
    g_body = Rotation.from_rotvec([0.0, theta, 0.0]).inv().apply([0.0, 0.0, 9.81])  # gravity in body axes
    acc[n0 + n1 :] = 0.0 if free_fall_rest else -g_body
    tilt_true = math.degrees(math.acos(max(-1.0, min(1.0, g_body[2] / 9.81))))
    return t, gyr, acc, clipped, tilt_true


def _tilt_deg(q):
    return math.degrees(2 * math.acos(min(1.0, math.sqrt(q[0] ** 2 + q[3] ** 2))))


@pytest.mark.parametrize("relevel_s", [0.5, 0.0])
def test_at_rest_after_a_saturation_the_tilt_is_the_accelerometers(relevel_s):
    """After a tumble past the gyro's range, once the rest has lasted rest_relevel_s the tilt is the
    accelerometer's (to 0.05°), the saturation gate shut and its σ term cleared, and it stays so (VQF's
    low-pass starts again rather than remembering the tumble); a network window then still holding the
    tumble (a level tilt, 172° from the truth, and 40 m/s: the flight-speed gate) pulls nothing while the rest
    lasts; the first moving sample ends it. Off (0), that window pulls by pull_gain and VQF's missed
    1.6 rad stays for seconds."""
    t, gyr, acc, clipped, tilt_true = _tumble_then_rest()
    cfg = AnchorConfig(centripetal=False, rest_relevel_s=relevel_s)
    f = AnchoredVQF(cfg, 0.01)
    wrong = WindowOutput(np.array([1.0, 0.0, 0.0, 0.0]), 0.01, np.zeros(3), np.array([40.0, 0, 0]), np.zeros(3))
    i_rest = 230
    q0 = f.update(t[:i_rest], gyr[:i_rest], acc[:i_rest], clipped=clipped[:i_rest])[0]
    assert abs(_tilt_deg(q0[-1]) - tilt_true) > 30  # VQF after the clipped tumble
    for k in range(i_rest, len(t), 10):  # windows every 0.1 s through the rest
        q = f.update(t[k : k + 10], gyr[k : k + 10], acc[k : k + 10], clipped=clipped[k : k + 10])[0]
        f.correct(wrong)
        if t[k] >= t[i_rest] + 0.6 and relevel_s:
            assert f.gate == 0.0 and f.e_clip == 0.0
            assert _tilt_deg(q[-1]) == pytest.approx(tilt_true, abs=0.05)
    if relevel_s:
        assert len(f.relevel_t) == 1 and f.at_rest
        assert _tilt_deg(q[-1]) == pytest.approx(tilt_true, abs=0.05)
        f.update(t[-1:] + 0.01, np.array([[0.0, 0.0, 0.5]]), acc[-1:])  # it turns: the rest is over
        assert not f.at_rest
        f.correct(wrong)
        assert f.gate == 1.0  # the flight-speed gate as anywhere
    else:
        assert not f.relevel_t and f.gate == 1.0
        assert abs(_tilt_deg(q[-1]) - tilt_true) > 20


@pytest.mark.parametrize("rule23", [True, False])
def test_a_noisy_gyro_at_rest_after_a_saturation_still_re_levels_and_stays_at_rest(rule23):
    """Rule 23: the same tumble and rest with white gyro noise of 2 °/s per sample and axis at 400 Hz (|n| ≈ 3.2 °/s:
    most samples above the 2 °/s rest rate). The still run keeps a sample up to 4 × that rate while its mean gyro
    stays still, and the re-levelling keeps that run: the tilt is the accelerometer's (to 0.1°) and "at rest" holds
    through the whole rest, so a window holding the tumble at flight speed pulls nothing. Before the rule
    (spike factor 1, a fresh run at the re-levelling) the rest never re-levels or does not stay at rest, and the
    tilt ends far from the truth."""
    t, gyr, acc, clipped, tilt_true = _tumble_then_rest(rate_hz=400.0, rest_s=4.0)
    gyr = gyr + np.where(clipped[:, None], 0.0, math.radians(2.0) * np.random.default_rng(5).standard_normal(gyr.shape))
    assert np.mean(np.linalg.norm(gyr[900:], axis=1) > math.radians(2.0)) > 0.7
    cfg = AnchorConfig(centripetal=False) if rule23 else AnchorConfig(centripetal=False, rest_spike_factor=1.0,
                                                                      rest_keeps_run=False)  # fmt: skip
    f = AnchoredVQF(cfg, 0.0025)
    wrong = WindowOutput(np.array([1.0, 0.0, 0.0, 0.0]), 0.01, np.zeros(3), np.array([40.0, 0, 0]), np.zeros(3))
    i_rest = 880  # the tumble ends at 2.2 s
    f.update(t[:i_rest], gyr[:i_rest], acc[:i_rest], clipped=clipped[:i_rest])
    rested = []
    for k in range(i_rest, len(t), 40):  # windows every 0.1 s through the rest
        q = f.update(t[k : k + 40], gyr[k : k + 40], acc[k : k + 40], clipped=clipped[k : k + 40])[0]
        f.correct(wrong)
        rested.append(f.at_rest)
    if rule23:
        assert len(f.relevel_t) == 1 and f.relevel_t[0] < t[i_rest] + 1.0
        assert all(rested[10:])  # at rest from the re-levelling to the end
        assert _tilt_deg(q[-1]) == pytest.approx(tilt_true, abs=0.1)
    else:
        assert not all(rested[10:])
        assert abs(_tilt_deg(q[-1]) - tilt_true) > 5


def test_a_free_fall_is_no_rest():
    """A still run whose accelerometer reads less than half of g (a free fall) shows no gravity: the
    saturation gate stays on and no tilt is set from it."""
    t, gyr, acc, clipped, _ = _tumble_then_rest(free_fall_rest=True, rest_s=1.5)
    f = AnchoredVQF(AnchorConfig(centripetal=False), 0.01)
    f.update(t, gyr, acc, clipped=clipped)
    f.correct(WindowOutput(np.array([1.0, 0.0, 0.0, 0.0]), 0.01, np.zeros(3), np.zeros(3), np.zeros(3)))
    assert f.still[0] * 0.01 >= 1.0 and not f.relevel_t and f.gate == 1.0


def _crash_record(reading=6.9):
    """A synthetic record (8 s) with :func:`_tumble_then_rest`'s tumble and a 4-s rest appended."""
    import pandas as pd

    from tepinn_flight.record import FlightRecord

    rec = synthetic_record(seed=2, duration_s=8.0, rate_hz=100.0)
    t, gyr, acc, clipped, _ = _tumble_then_rest(rest_s=4.0, reading=reading)
    t = t[200:] - t[200] + rec.t_s[-1] + 0.01  # the tumble and the rest after the record
    extra = {"t_s": t, "segment": np.zeros(len(t), np.int64), "clipped": clipped[200:], "gyr_clipped": clipped[200:]}
    for i, ax in enumerate("xyz"):
        extra[f"gyr_{ax}_rad_s"], extra[f"acc_{ax}_m_s2"] = gyr[200:, i], acc[200:, i]
    data = rec.data.copy()
    data["gyr_clipped"] = False
    tail = pd.DataFrame(extra)
    for c in data.columns:
        if c not in tail:
            tail[c] = data[c].iloc[-1] if c.startswith("q_ref") or c in ("valid",) else np.nan
    return FlightRecord(pd.concat([data, tail[list(data.columns)]], ignore_index=True), dict(rec.meta))


@pytest.mark.parametrize("reading", [6.9, 34.5])
def test_live_equals_offline_through_a_rest_after_a_saturation(reading):
    """The re-levelling at rest acts at the same window live and offline: a synthetic record with a
    tumble past the gyro's range (±400 °/s, the saturation pull on; ±2000 °/s, off and σ's saturation
    term decaying at VQF's pace) and a rest appended, streamed and estimated offline: q to 1e-6, σ to 1e-5."""
    rec = _crash_record(reading)
    model, _, _ = load_model(default_model_path())
    cfg = dataclasses.replace(_shipped(), smoother=False)  # the causal estimate (the 8 s before the tumble are smoothed offline)
    df = estimate_anchored(model, rec, cfg)
    off, s_off = df[Q].to_numpy(), df["sigma_rad"].to_numpy()
    n_off = int(df.attrs["rest_relevel"].split("accelerometer ")[1].split("×")[0]) if "rest_relevel" in df.attrs else 0
    live = StreamingEstimator(model, cfg)
    q_live, s_live = np.full((len(rec), 4), np.nan), np.full(len(rec), np.nan)
    for i in range(len(rec)):
        e = live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i], None, bool(rec.clipped[i]), bool(rec.gyr_clipped[i]))
        if e.q_nb_wxyz is not None:
            q_live[i], s_live[i] = e.q_nb_wxyz, e.sigma_rad
    assert n_off >= 1 and len(live.anchored.relevel_t) == n_off  # it acted, live as often as offline
    have = np.all(np.isfinite(q_live), 1)
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)
    # σ to 1e-5: while a gate acts it carries the network's float32 σ, and a window run alone (live) and in a batch
    # (offline) round differently where the CPU's matrix kernels depend on the batch (an AVX-512 Xeon: 1.3e-6)
    np.testing.assert_allclose(s_live[have], s_off[have], rtol=1e-5)
    assert s_off[have].max() > math.radians(10)  # the saturation term acted


def test_checkpoints_written_before_the_re_levelling_run_without_it():
    from tepinn_flight.model.checkpoint import anchor_config_from, read_checkpoint

    old = {"bias_gate_fusion_deg_s": 3.0, "accel_scale_selfcal": True}  # a checkpoint of session 18
    assert anchor_config_from({"anchor_config": old}).rest_relevel_s == 0.0
    assert anchor_config_from({"anchor_config": {**old, "rest_relevel_s": 0.5}}).rest_relevel_s == 0.5
    assert read_checkpoint(default_model_path())["anchor_config"]["rest_relevel_s"] == 0.5  # the shipped one stores it
    assert AnchorConfig().learned_off.rest_relevel_s == 0.0  # plain VQF has none
    # σ's gap term (session 26) likewise: off in older checkpoints and in plain VQF, stored in the shipped one
    assert anchor_config_from({"anchor_config": old}).sigma_gap_gain == 0.0
    assert read_checkpoint(default_model_path())["anchor_config"]["sigma_gap_gain"] == 1.0
    assert AnchorConfig().learned_off.sigma_gap_gain == 0.0


def test_estimate_says_where_it_re_levelled(tmp_path, capsys):
    """`estimate` reports the re-levelling in its one line per record and in the output's metadata."""
    import pyarrow.parquet as pq

    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    rec = _crash_record()
    write_record(rec, tmp_path / "r.parquet")
    assert main(["estimate", str(tmp_path / "r.parquet"), "-o", str(tmp_path / "e.parquet")]) == 0
    out = capsys.readouterr().out
    t_rest = rec.t_s[rec.data["gyr_clipped"].to_numpy(bool)][-1] + 0.5  # the last clipped sample, then 0.5 s
    assert "gyro saturation then rest: tilt set from the accelerometer 1× (t = " in out
    t_said = float(out.split("(t = ")[1].split(" s;")[0])
    assert t_rest <= t_said < t_rest + 0.2  # at the first window after half a second of rest
    meta = pq.read_schema(tmp_path / "e.parquet").metadata
    assert b"rest_relevel" in meta and meta[b"rest_relevel"].decode().endswith("; applied")
    gates = meta[b"network_gates"].decode()  # the saturation pull acted, no other gate
    assert "gyro saturation" in gates and "flight speed" not in gates and gates.endswith("; applied") and gates in out


@pytest.mark.parametrize("reading_deg_s", [395.0, 1990.0])
def test_the_saturation_pull_only_at_the_gyro_ranges_the_network_learned(reading_deg_s):
    """A clipped stretch read at 395 °/s (the ±400 °/s range of the training's tactical gyro) opens the
    saturation pull; one read at 1990 °/s (an autopilot's ±2000 °/s past its range, beyond
    clip_gate_max_deg_s) leaves it shut for clip_hold_s — VQF integrates, the accelerometer brings the tilt
    back — and σ's saturation term E then decays at VQF's accelerometer time constant, not
    sigma_clip_tau_s (both from the same E at the window). Checkpoints before the option (0) pull at any
    range."""
    cfg = AnchorConfig(centripetal=False, rest_relevel_s=0.0)
    r = math.radians(reading_deg_s)
    n = 300
    t = np.arange(n) * 0.01
    gyr, acc = np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1))
    clipped = np.zeros(n, bool)
    gyr[100:115, 1], clipped[100:115] = r, True  # 0.15 s clipped
    acc[100:115] = 0.0
    tilted = WindowOutput(np.array([math.cos(0.2), math.sin(0.2), 0.0, 0.0]), 0.01, np.zeros(3), np.zeros(3), np.zeros(3))
    f = AnchoredVQF(cfg, 0.01)
    f.update(t[:120], gyr[:120], acc[:120], clipped=clipped[:120])
    f.correct(tilted)
    e0 = f.e_clip
    assert e0 > 0.1
    f.update(t[120:220], gyr[120:220], acc[120:220])  # 1 s after the window
    tau = cfg.sigma_clip_tau_s if reading_deg_s < cfg.clip_gate_max_deg_s else cfg.tau_acc_s
    assert f.e_clip == pytest.approx(e0 * math.exp(-1.0 / tau), rel=1e-9)
    f.correct(tilted)
    assert f.gate == (1.0 if reading_deg_s < cfg.clip_gate_max_deg_s else 0.0)
    old = AnchoredVQF(dataclasses.replace(cfg, clip_gate_max_deg_s=0.0), 0.01)
    old.update(t[:120], gyr[:120], acc[:120], clipped=clipped[:120])
    old.correct(tilted)
    assert old.gate == 1.0


def test_a_hole_breaks_the_still_run_one_sample_at_a_time_as_in_a_block():
    """The still run sees each sample as it came, live (update_one) as offline (update on blocks): a
    non-finite sample in the rest starts it again in both, and both re-level at the same sample."""
    t, gyr, acc, clipped, _ = _tumble_then_rest(rest_s=2.0)
    acc[260] = np.nan  # 0.4 s into the rest
    block, one = AnchoredVQF(AnchorConfig(centripetal=False), 0.01), AnchoredVQF(AnchorConfig(centripetal=False), 0.01)
    window = WindowOutput(np.array([1.0, 0.0, 0.0, 0.0]), 0.01, np.zeros(3), np.zeros(3), np.zeros(3))
    for k in range(0, len(t), 10):
        block.update(t[k : k + 10], gyr[k : k + 10], acc[k : k + 10], clipped=clipped[k : k + 10])
        for i in range(k, min(k + 10, len(t))):
            one.update_one(t[i], gyr[i], acc[i], None, bool(clipped[i]))
        np.testing.assert_array_equal(one.still, block.still)
        block.correct(window)
        one.correct(window)
    assert block.relevel_t == one.relevel_t and len(block.relevel_t) == 1
    assert block.relevel_t[0] >= t[261] + 0.5 - 1e-9  # the hole started the run again


@pytest.mark.parametrize("seed", range(6))
def test_the_open_time_per_gate_is_what_a_sample_by_sample_count_gives(seed):
    """Each gate's open seconds and first opening (the `network_gates` line): the reference walks the
    samples, each taking the gates of the last window started at or before it (a later window at the
    same sample wins) and adding its time to the next sample (the last one's: the median step)."""
    from tepinn_flight.model.estimate import _add_open_time

    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 300))
    t = 3.0 + np.cumsum(rng.uniform(0.001, 0.05, n))
    starts = np.sort(rng.integers(0, n + 1, size=int(rng.integers(1, 50))))
    is_open = rng.random((len(starts), 3)) < 0.4
    open_s, first_t = np.zeros(3), np.full(3, np.inf)
    _add_open_time(t, starts, is_open, open_s, first_t)
    step = np.r_[np.diff(t), np.median(np.diff(t))]
    ref_s, ref_t = np.zeros(3), np.full(3, np.inf)
    for i in range(n):
        k = np.flatnonzero(starts <= i)
        if k.size:
            for g in range(3):
                if is_open[k[-1], g]:
                    ref_s[g] += step[i]
                    ref_t[g] = min(ref_t[g], t[i])
    np.testing.assert_allclose(open_s, ref_s, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(first_t, ref_t)


def test_the_estimate_says_which_network_gate_acted_and_where():
    """`attrs["network_gates"]`: on a record whose gyro clips for 0.3 s, the saturation gate alone, first
    open at the first window after 0.1 s of clipping (clip_min_s) and for at most the clipped stretch
    plus clip_hold_s; with every learned correction off, shut throughout (the estimate is VQF's)."""
    model, cfg, _ = load_model(default_model_path())
    cfg = dataclasses.replace(cfg, gnss_aid=False, rest_relevel_s=0.0)
    rec = _with_clipped(synthetic_record(seed=3, duration_s=30.0, rate_hz=100.0), 12.0, 12.3)
    line = estimate_anchored(model, rec, cfg).attrs["network_gates"]
    assert line.endswith("; applied") and "flight speed" not in line and "uncalibrated gyro" not in line
    secs = float(line.split("gyro saturation ")[1].split(" s from")[0])
    t0 = float(line.split("from t = ")[1].split(" s")[0])
    assert 12.1 <= t0 <= 12.1 + 0.05  # a window every token (25 Hz) after 0.1 s of clipped samples
    assert 0.0 < secs <= 0.2 + cfg.clip_hold_s + 0.05
    off = estimate_anchored(model, rec, cfg.learned_off).attrs["network_gates"]
    assert off == "network gates: shut throughout (the network corrected nothing); not applied"


def test_with_every_learned_correction_off_a_flight_speed_window_leaves_it_vqf():
    """The flight-speed gate also lengthens VQF's accelerometer time constant (tau_acc_flight_s): with
    every learned correction off, windows reading 40 m/s leave the estimate VQF's bit for bit, and no
    gate is reported as having acted."""
    rec = synthetic_record(seed=5, duration_s=20.0, rate_hz=100.0)
    t, gyr, acc = rec.t_s, rec.gyr_rad_s, rec.acc_m_s2
    fast = WindowOutput(np.array([1.0, 0.0, 0.0, 0.0]), 0.01, np.zeros(3), np.array([40.0, 0.0, 0.0]), np.zeros(3))
    f = AnchoredVQF(AnchorConfig().learned_off, float(np.median(np.diff(t[:52]))))
    q = []
    for a in range(0, len(t), 4):  # a window every 4 samples
        q.append(f.update(t[a : a + 4], gyr[a : a + 4], acc[a : a + 4])[0])
        f.correct(fast)
        assert f.gate_parts == (0.0, 0.0, 0.0) and f.gate == 1.0  # the gate reads the speed, nothing acts on it
    np.testing.assert_array_equal(np.concatenate(q), _vqf_reference(rec))
    on = AnchoredVQF(dataclasses.replace(AnchorConfig(), pull_gain=0.0, centripetal=False), f.ts)
    on.update(t[:4], gyr[:4], acc[:4])
    on.correct(fast)
    assert on.gate_parts[0] == 1.0 and on.tau_acc == AnchorConfig().tau_acc_flight_s  # the time constant acts


@pytest.mark.slow
def test_evaluate_keeps_per_record_where_the_network_gates_acted_and_sums_them_up_in_one_note(tmp_path):
    import json

    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    plain = synthetic_record(seed=3, duration_s=30.0, rate_hz=100.0)
    write_record(plain, tmp_path / "plain.parquet")
    write_record(_with_clipped(plain, 12.0, 12.3), tmp_path / "clipped.parquet")
    out = tmp_path / "rep"
    assert main(["evaluate", str(tmp_path / "plain.parquet"), str(tmp_path / "clipped.parquet"), "-o", str(out), "--no-peers", "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    by_name = {r["name"]: r for r in m["records"]}
    clipped = next(r for n, r in by_name.items() if "clipped" in n)["network_gates"]["tepinn"]
    shut = next(r for n, r in by_name.items() if "plain" in n)["network_gates"]["tepinn"]
    assert "gyro saturation" in clipped and clipped.endswith("; applied") and shut.endswith("; not applied")
    acted = [n for n in m["notes"] if "network gates acted" in n]
    assert len(acted) == 1 and "on 1 of 2 record(s)" in acted[0] and "clipped" in acted[0] and "plain" not in acted[0]
    assert acted[0] in (out / "report.md").read_text()


def test_the_gates_over_several_records_name_those_where_one_acted():
    from tepinn_flight.model.estimate import describe_gates, gates_acted

    shut = describe_gates({"flight speed": (0.0, np.inf)}, 0.0, 60.0)
    acted = describe_gates({"flight speed": (0.5, 105.5), "gyro saturation": (0.0, np.inf)}, 0.5, 250.0)
    assert acted == "network gates open on 0.2 % of the record (flight speed 0.5 s from t = 105.5 s); applied"
    assert gates_acted({"a": shut, "b": shut}) == "network gates shut on all 2 record(s) (the network corrected nothing)"
    assert gates_acted({"a": shut, "b": acted}) == ("network gates acted on 1 of 2 record(s), elsewhere the network corrected "
                                                    "nothing: b (flight speed 0.5 s from t = 105.5 s)")  # fmt: skip


def test_the_fusion_tilt_on_the_filters_heading_by_scipy():
    """``with_fusion_tilt``: each row gets the other's down direction in body axes by the shortest turn in body
    axes (about down × down', checked with scipy's rotations); a row whose fusion estimate is missing, or
    whose downs are opposite, stays as it was."""
    from tepinn_flight.model.anchor import with_fusion_tilt

    rng = np.random.default_rng(5)
    r_a, r_b = Rotation.random(50, random_state=rng), Rotation.random(50, random_state=rng)
    q_a, q_b = (np.roll(r.as_quat(), 1, axis=1) for r in (r_a, r_b))  # scipy's x, y, z, w → w, x, y, z
    q_b[3] = np.nan
    q_b[4] = np.roll(Rotation.from_rotvec([np.pi, 0.0, 0.0]).__mul__(r_a[4]).as_quat(), 1)  # turned upside down in earth axes
    out = with_fusion_tilt(q_a, q_b)
    r_out = Rotation.from_quat(np.roll(out, -1, axis=1))
    down_out = r_out.inv().apply([0.0, 0.0, 1.0])
    down_a, down_b = r_a.inv().apply([0.0, 0.0, 1.0]), r_b.inv().apply([0.0, 0.0, 1.0])
    keep = np.ones(50, bool)
    keep[[3, 4]] = False
    np.testing.assert_allclose(down_out[keep], down_b[keep], atol=1e-12)
    turn = (r_a.inv() * r_out).as_rotvec()  # in body axes
    axis = np.cross(down_a, down_b)
    np.testing.assert_allclose(np.linalg.norm(np.cross(turn[keep], axis[keep]), axis=1), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(turn[keep], axis=1),
                               np.arccos(np.clip(np.sum(down_a * down_b, 1), -1, 1))[keep], atol=1e-9)  # fmt: skip
    np.testing.assert_array_equal(out[[3, 4]], q_a[[3, 4]])
    from tepinn_flight.model.anchor_kernels import fusion_tilt_f  # the live path's per-sample form

    one = np.array([fusion_tilt_f(*a, *b) for a, b in zip(q_a, q_b)])
    np.testing.assert_allclose(one, out, rtol=0, atol=1e-12)


def test_while_the_saturation_gate_is_on_the_tilt_is_the_older_fusions():
    """Rule 17: while the saturation gate is on, the estimate's down direction is the older fusion's (its
    per-sample, causal estimate), on the filter's own heading; everywhere else the estimate is the filter's,
    bit for bit; live equals offline; checkpoints written before it (the key missing) keep the filter's tilt."""
    from tepinn_flight.model.checkpoint import estimator_settings, read_checkpoint
    from tepinn_flight.model.estimate import anchored_windows
    from tepinn_flight.quat import gravity_body

    rec = _with_clipped(synthetic_record(seed=2, duration_s=24.0, rate_hz=100.0), 15.0, 15.3)
    model, shipped, _ = load_model(default_model_path())
    assert shipped.clip_tilt_from_fusion
    cfg = dataclasses.replace(shipped, smoother=False, gnss_aid=False)
    windows = anchored_windows(model, rec, fusion=cfg.fusion_config, anchor=cfg)
    on = estimate_anchored(model, rec, cfg, windows=windows)[Q].to_numpy()
    off = estimate_anchored(model, rec, dataclasses.replace(cfg, clip_tilt_from_fusion=False), windows=windows)[Q].to_numpy()
    changed = np.flatnonzero(np.any(on != off, axis=1))
    t = rec.t_s
    assert len(changed) > 100 and np.all(np.diff(changed) == 1)  # one spell ...
    assert 15.0 < t[changed[0]] < 15.0 + 0.2 and t[changed[-1]] <= 15.3 + cfg.clip_hold_s + model.config.window_s  # ... the gate's
    q_fusion = windows[1]["q_fusion"]
    np.testing.assert_allclose(gravity_body(on[changed]), gravity_body(q_fusion[changed]), atol=1e-9)
    assert np.degrees(np.max(np.arccos(np.clip(np.sum(gravity_body(off[changed]) * gravity_body(q_fusion[changed]), 1),
                                               -1, 1)))) > 0.05  # the two tilts differ there  # fmt: skip
    q_live = _live(model, cfg, rec)
    np.testing.assert_allclose(q_live[changed], on[changed], atol=1e-6)
    ck = read_checkpoint(default_model_path())
    del ck["anchor_config"]["clip_tilt_from_fusion"]
    assert not estimator_settings(ck).clip_tilt_from_fusion


@pytest.mark.parametrize("rate_hz, opens", [(10.0, False), (19.0, False), (20.0, True), (25.0, True)])
def test_no_network_gate_below_the_imu_rates_the_network_learned(rate_hz, opens):
    """Rule 18: on an IMU slower than ``min_network_rate_hz`` (20 Hz, the tool's "too slow for windowed
    estimation") a window claiming flight speed and 20° of tilt moves nothing — the estimate is VQF's bit for bit —
    while at 20 Hz and faster the gate opens; checkpoints written before it (the key missing) gate at any rate."""
    from tepinn_flight.model.checkpoint import estimator_settings, read_checkpoint

    n = 60
    t = np.arange(n) / rate_hz
    gyr, acc = np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1))
    tilted = np.array([math.cos(math.radians(10)), math.sin(math.radians(10)), 0.0, 0.0])
    cfg = dataclasses.replace(AnchorConfig(), pull_gain=0.5, centripetal=False)
    assert cfg.min_network_rate_hz == 20.0 and _shipped().min_network_rate_hz == 20.0
    f, plain = AnchoredVQF(cfg, 1.0 / rate_hz), AnchoredVQF(cfg.learned_off, 1.0 / rate_hz)
    f.update(t, gyr, acc)
    plain.update(t, gyr, acc)
    f.correct(WindowOutput(tilted, 0.01, np.zeros(3), np.array([60.0, 0.0, 0.0]), np.zeros(3)))
    q, _, sig, _ = f.update(t[-1:] + 1.0 / rate_hz, gyr[:1], acc[:1])
    q0, _, sig0, _ = plain.update(t[-1:] + 1.0 / rate_hz, gyr[:1], acc[:1])
    assert (f.gate > 0) == opens
    if opens:
        assert _tilt_deg(q[0]) == pytest.approx(10.0, abs=0.3)
    else:
        np.testing.assert_array_equal(q, q0)
        np.testing.assert_array_equal(sig, sig0)
    ck = read_checkpoint(default_model_path())
    del ck["anchor_config"]["min_network_rate_hz"]
    assert estimator_settings(ck).min_network_rate_hz == 0.0


def test_live_equals_offline_on_an_imu_too_slow_for_the_network():
    """A 10-Hz record (a telemetry log) with a saturated stretch: live and offline give the same estimate, and the
    network's gates never act (the estimate says so)."""
    rec = _with_clipped(synthetic_record(seed=4, duration_s=40.0, rate_hz=10.0), 15.0, 16.0)
    model, shipped, _ = load_model(default_model_path())
    cfg = dataclasses.replace(shipped, smoother=False, gnss_aid=False, gyro_selfcal=False, accel_scale_selfcal=False)
    df = estimate_anchored(model, rec, cfg)
    assert "shut throughout" in df.attrs["network_gates"]
    q_live = _live(model, cfg, rec)
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 60
    np.testing.assert_allclose(q_live[have], df[Q].to_numpy()[have], atol=1e-6)

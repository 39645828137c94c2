"""The gyro's per-axis scale read from a record alone (:mod:`tepinn_flight.model.gyro_selfcal`):
the carried gravity against scipy's rotations, the fit against a known scale error on a record with
rests between turns, the evidence gate where there is nothing to read, and a real BROAD trial against
its optical truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.model.anchor import AnchorConfig
from tepinn_flight.model.gyro_selfcal import GyroSelfCalConfig, Phases, carried, self_calibrate
from tepinn_flight.quat import gravity_body, quat_canonical, quat_from_rotvec, quat_mul, quat_normalize
from tepinn_flight.record import FlightRecord, make_frame


def random_phases():
    rng = np.random.default_rng(3)
    gyr = rng.normal(size=(3000, 3)) * 2.0
    dt = np.full(3000, 0.0025) + rng.uniform(0, 0.001, 3000)
    up = rng.normal(size=(3, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    ph = Phases(np.array([50, 400, 1200]), np.array([350, 2900, 1900]), up, up[::-1].copy(), np.array([0.01, -0.02, 0.03]))
    return gyr, dt, ph


def test_the_carried_gravity_is_scipys_composition_of_the_scaled_turns():
    gyr, dt, ph = random_phases()
    s = np.array([1.02, 0.97, 1.005])
    c, _ = carried(gyr, dt, ph, s)
    for j in range(len(ph)):
        r = Rotation.identity()  # body i → body i0
        for i in range(ph.i0[j], ph.i1[j]):
            r = r * Rotation.from_rotvec(s * (gyr[i] - ph.bias) * dt[i])
        np.testing.assert_allclose(c[j], r.inv().apply(ph.up0[j]), atol=1e-10)


def test_the_one_pass_jacobian_is_the_finite_difference_of_the_carried_gravity():
    gyr, dt, ph = random_phases()
    s = np.array([1.01, 0.99, 1.003])
    _, dc = carried(gyr, dt, ph, s)
    h, fd = 1e-6, np.empty((len(ph), 3, 3))
    for k in range(3):
        up, dn = s.copy(), s.copy()
        up[k] += h
        dn[k] -= h
        fd[:, :, k] = (carried(gyr, dt, ph, up)[0] - carried(gyr, dt, ph, dn)[0]) / (2 * h)
    # first order in the step (5-9 mrad here): within 1 % of the largest entry
    assert np.abs(dc - fd).max() < 0.01 * np.abs(fd).max(), (dc, fd)
    assert np.abs(fd).max() > 0.1


def turns_with_rests(scale_true=(1.0, 1.0, 1.0), seed: int = 0, rate_hz: float = 100.0, n_turns: int = 8,
                     clipped_turn: int | None = None) -> tuple[FlightRecord, np.ndarray]:  # fmt: skip
    """Rests of 3 s between 2-s turns of 120–300° about random axes (hand-held trial-like), with the
    gyro reading ``true rate / scale_true`` (so ``scale_true`` is the calibration that fixes it), a
    small bias and noise. Returns the record and the true attitude."""
    rng = np.random.default_rng(seed)
    rates = []
    for k in range(n_turns):
        rates.append(np.zeros((int(3 * rate_hz), 3)))
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        m = int(2 * rate_hz)
        angle = np.radians(rng.uniform(120, 300))
        shape = np.sin(np.pi * (np.arange(m) + 0.5) / m)  # smooth start and stop
        rates.append(axis[None] * (angle * shape / shape.sum() * rate_hz)[:, None])
    rates.append(np.zeros((int(3 * rate_hz), 3)))
    w = np.concatenate(rates)
    n = len(w)
    t = np.arange(n) / rate_hz
    q = np.empty((n, 4))
    q[0] = quat_normalize(rng.normal(size=4))
    for i in range(1, n):
        q[i] = quat_normalize(quat_mul(q[i - 1], quat_from_rotvec(w[i - 1] / rate_hz)))
    acc = -gravity_body(q) * GRAVITY_M_S2 + rng.normal(size=(n, 3)) * 0.05
    bias = np.array([0.004, -0.003, 0.002])
    gyr = w / np.array(scale_true) + bias + rng.normal(size=(n, 3)) * 0.003
    clip = np.zeros(n, bool)
    if clipped_turn is not None:
        start = int((3 + 5 * clipped_turn) * rate_hz)
        clip[start + 50] = True
    df = make_frame(t, np.zeros(n, int), gyr, acc, None, quat_canonical(q), clip, gyr_clipped=clip)
    meta = {"format_version": 1, "source_file": "turns", "source_kind": "synthetic", "imu_rate_hz": rate_hz,
            "reference_source": "synthetic-truth", "vehicle_type": "synthetic"}  # fmt: skip
    return FlightRecord(df, meta), q


def calibrate(rec, cfg=None):
    return self_calibrate(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.segment, rec.gyr_clipped, cfg)


def test_a_known_scale_error_is_read_back_from_the_rests():
    true = (1.0, 1.012, 0.99)
    rec, _ = turns_with_rests(true)
    cal = calibrate(rec)
    assert cal.applied and cal.phases == 8
    np.testing.assert_allclose(cal.scale, true, atol=1.5e-3)
    assert cal.rms_loo_deg < 0.3 * cal.rms_deg


def test_a_calibrated_gyro_gives_no_evidence_and_keeps_scale_one():
    rec, _ = turns_with_rests((1.0, 1.0, 1.0), seed=1)
    cal = calibrate(rec)
    assert cal.phases == 8 and not cal.applied and cal.scale == (1.0, 1.0, 1.0)
    assert max(abs(v - 1.0) for v in cal.fitted) < 2e-3  # the fit itself finds nothing to correct


def test_a_noisy_gyro_still_takes_its_bias_from_the_stillest_rest_samples_not_from_slow_motion():
    """Rule 20 (session 30): white noise of 2 °/s per sample averages to |ω| ≈ 0.056 rad/s, above the
    fixed still threshold (0.05 rad/s); without the noise floor the bias came from every rest sample,
    slow motion (here 0.1 rad/s for half of each rest) included."""
    from tepinn_flight.model.gyro_selfcal import find_phases

    rec, _ = turns_with_rests((1.0, 1.0, 1.0), seed=3)
    rate_hz, rng = 100.0, np.random.default_rng(30)
    gyr = rec.gyr_rad_s + rng.normal(size=(len(rec), 3)) * np.radians(2.0)
    t = rec.t_s
    creep = (np.mod(t, 5.0) < 1.5) & (t < 5.0 * 8 + 1.5)  # the first 1.5 s of each 3-s rest
    gyr[creep] += 0.1 * np.array([0.6, 0.0, 0.8])
    true_bias = np.array([0.004, -0.003, 0.002])

    def bias(cfg):
        return find_phases(t, np.ascontiguousarray(gyr), rec.acc_m_s2, rec.segment, rec.gyr_clipped, cfg)[1].bias

    np.testing.assert_allclose(bias(GyroSelfCalConfig()), true_bias, atol=2e-3)
    assert np.abs(bias(GyroSelfCalConfig(still_floor_factor=0.0)) - true_bias).max() > 0.01  # the rule before
    # a quiet gyro keeps the fixed threshold: the floor is far below it
    quiet, _ = turns_with_rests((1.0, 1.0, 1.0), seed=3)
    args = (quiet.t_s, quiet.gyr_rad_s, quiet.acc_m_s2, quiet.segment, quiet.gyr_clipped)
    np.testing.assert_array_equal(find_phases(*args, GyroSelfCalConfig())[1].bias,
                                  find_phases(*args, GyroSelfCalConfig(still_floor_factor=0.0))[1].bias)


def test_phases_need_rests_at_both_ends_and_no_saturation():
    rec, _ = turns_with_rests((1.0, 1.01, 1.0), n_turns=2)
    cal = calibrate(rec)
    assert cal.phases == 2 and not cal.applied and cal.fitted is None  # fewer than min_phases
    assert "too few" in cal.describe()
    rec, _ = turns_with_rests((1.0, 1.01, 1.0), clipped_turn=3)
    assert calibrate(rec).phases == 7  # the turn holding a clipped gyro sample is not read
    # rests further apart than max_phase_s (the turns take 2 s) bound no phase
    assert calibrate(rec, GyroSelfCalConfig(max_phase_s=1.5)).phases == 0


def test_the_anchored_estimate_runs_on_the_self_calibrated_gyro_and_gets_closer_to_the_truth():
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored

    model, anchor, _ = load_model(default_model_path())
    assert anchor.gyro_selfcal  # the shipped estimator reads it
    rec, q_true = turns_with_rests((1.0, 1.03, 0.97), seed=2)
    cal = calibrate(rec)
    assert cal.applied
    est = estimate_anchored(model, rec, anchor)
    assert est.attrs["gyro_selfcal"] == cal.describe()
    same = estimate_anchored(model, rec, dataclasses.replace(anchor, gyro_selfcal=False, gyro_scale=cal.scale))
    np.testing.assert_allclose(est[EST_Q_COLS].to_numpy(), same[EST_Q_COLS].to_numpy(), atol=1e-12)

    def rmse_deg(e):  # after VQF's start-up from its own initial tilt
        m = rec.t_s >= 5.0
        err = inclination_error_rad(error_quat_earth(e[EST_Q_COLS].to_numpy()[m], q_true[m]))
        return np.degrees(np.sqrt(np.mean(err**2)))

    # the physics filter alone (on these synthetic turns the network is far out of its domain)
    plain = estimate_anchored(model, rec, anchor.learned_off)
    selfcal = estimate_anchored(model, rec, dataclasses.replace(anchor.learned_off, gyro_selfcal=True))
    assert rmse_deg(selfcal) < 0.5 * rmse_deg(plain), (rmse_deg(selfcal), rmse_deg(plain))  # 0.62° vs 1.58°
    # where the record shows its own scale, that replaces a vehicle's fine-tuned one; where it shows
    # none, the fine-tuned one stays
    tuned = dataclasses.replace(anchor, gyro_scale=(1.01, 1.0, 1.0))
    np.testing.assert_array_equal(estimate_anchored(model, rec, tuned)[EST_Q_COLS].to_numpy(), est[EST_Q_COLS].to_numpy())
    few, _ = turns_with_rests((1.0, 1.03, 0.97), seed=2, n_turns=2)
    assert not calibrate(few).applied
    np.testing.assert_array_equal(estimate_anchored(model, few, tuned)[EST_Q_COLS].to_numpy(),
                                  estimate_anchored(model, few, dataclasses.replace(tuned, gyro_selfcal=False))[EST_Q_COLS].to_numpy())  # fmt: skip
    # with every learned correction off it is plain VQF again: no self-calibration either
    assert not anchor.learned_off.gyro_selfcal


def test_a_checkpoint_written_before_the_self_calibration_runs_without_it():
    from tepinn_flight.model.checkpoint import anchor_config_from

    old = {"anchor_config": {"enabled": True, "pull_target": "fusion"}, "fusion_config": None}
    assert anchor_config_from(old).gyro_selfcal is False
    assert AnchorConfig().gyro_selfcal is True


@pytest.mark.slow
def test_on_a_real_trial_the_scale_read_without_truth_brings_vqf_closer_to_the_optical_truth():
    # BROAD trial 08 (fast rotation with breaks): its rests disagree with the gyro's turns by ~8°
    # at scale 1; the scale read from them takes VQF from 1.76° to 1.01° against the optical truth,
    # which the self-calibration never sees. A translation trial (12) shows no evidence: untouched.
    from tests.conftest import broad_trial
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.finetune import inclination_rmse_deg

    rec = load_record(broad_trial("broad_08_*.hdf5"))
    cal = calibrate(rec)
    assert cal.applied and cal.phases >= 5
    scaled = rec.data.copy()
    scaled[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] *= np.array(cal.scale)
    before = inclination_rmse_deg(rec, VqfEstimator().estimate(rec))
    after = inclination_rmse_deg(rec, VqfEstimator().estimate(FlightRecord(scaled, dict(rec.meta))))
    assert after < 0.75 * before, (before, after)
    assert not calibrate(load_record(broad_trial("broad_12_*.hdf5"))).applied


def test_estimate_says_what_the_self_calibration_found_and_keeps_it_in_the_output(tmp_path, capsys):
    import pyarrow.parquet as pq

    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    rec, _ = turns_with_rests((1.0, 1.03, 0.97), seed=2)
    write_record(rec, tmp_path / "turns.parquet")
    assert main(["estimate", str(tmp_path / "turns.parquet"), "-o", str(tmp_path / "est.parquet")]) == 0
    line = calibrate(rec).describe()
    assert line.endswith("; applied") and line in capsys.readouterr().out
    assert pq.read_schema(tmp_path / "est.parquet").metadata[b"gyro_selfcal"].decode() == line
    # --no-gyro-selfcal: the estimate the live bridge gives (no scale read), nothing said or stored
    assert main(["estimate", str(tmp_path / "turns.parquet"), "-o", str(tmp_path / "off.parquet"), "--no-gyro-selfcal"]) == 0
    assert "gyro self-calibration" not in capsys.readouterr().out
    assert b"gyro_selfcal" not in (pq.read_schema(tmp_path / "off.parquet").metadata or {})
    on, off = pq.read_table(tmp_path / "est.parquet").to_pandas(), pq.read_table(tmp_path / "off.parquet").to_pandas()
    assert np.abs(on["q_est_x"].to_numpy() - off["q_est_x"].to_numpy()).max() > 1e-3


@pytest.mark.slow
def test_evaluate_reports_where_the_self_calibration_applied(tmp_path, capsys):
    import json

    from tepinn_flight.cli.main import main
    from tepinn_flight.record import write_record

    rec, _ = turns_with_rests((1.0, 1.03, 0.97), seed=2)
    write_record(rec, tmp_path / "turns.parquet")
    few, _ = turns_with_rests((1.0, 1.03, 0.97), seed=2, n_turns=2)
    write_record(few, tmp_path / "few.parquet")
    out = tmp_path / "rep"
    assert main(["evaluate", str(tmp_path / "turns.parquet"), str(tmp_path / "few.parquet"), "-o", str(out), "--no-peers", "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    by_name = {r["name"]: r for r in m["records"]}
    turns = next(r for n, r in by_name.items() if "turns" in n)
    assert turns["gyro_selfcal"]["tepinn"] == calibrate(rec).describe()
    assert next(r for n, r in by_name.items() if "few" in n)["gyro_selfcal"]["tepinn"].endswith("not applied")
    assert "lstm" not in turns["gyro_selfcal"]  # the LSTM runs the older fusion: no self-calibration
    applied = [n for n in m["notes"] if "gyro self-calibration" in n]
    assert len(applied) == 1 and "turns" in applied[0] and applied[0].endswith("; applied")
    assert applied[0] in (out / "report.md").read_text()


def test_degenerate_records_give_no_phases_and_no_error():
    n = 500
    z = np.zeros((n, 3))
    assert self_calibrate(np.zeros(n), z, z).phases == 0  # one timestamp throughout
    assert self_calibrate(np.arange(2) * 0.01, z[:2], z[:2]).phases == 0  # two samples
    t = np.arange(n) * 0.01
    acc = np.tile([0.0, 0.0, -9.81], (n, 1))
    assert self_calibrate(t, np.full((n, 3), np.nan), acc).phases == 0  # no gyro: read as zeros, no turn
    still = self_calibrate(t, z, acc)  # at rest throughout: one rest, no phase
    assert still.phases == 0 and not still.applied and still.scale == (1.0, 1.0, 1.0)


def test_a_fit_beyond_the_plausible_calibration_error_is_not_applied():
    rec, _ = turns_with_rests((1.08, 1.0, 1.0), seed=3)  # 8 % off: not a calibration residual
    cal = calibrate(rec)
    assert cal.phases == 8 and cal.fitted[0] > 1.05 and cal.rms_loo_deg < 0.5 * cal.rms_deg
    assert not cal.applied and cal.scale == (1.0, 1.0, 1.0)
    assert calibrate(rec, GyroSelfCalConfig(max_scale_error=0.1)).applied  # the cap alone refused it

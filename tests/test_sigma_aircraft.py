"""Rules 28 and 29 (session 50): σ's aircraft terms. On a record whose log names a vehicle (multirotor, fixed wing or
another vehicle; not a hand-held IMU, not one not known), σ² takes σ_a² (``AnchorConfig.sigma_aircraft_deg``) — offline
after the smoothing, live sample by sample — and, where the estimate is causal (live, ``--no-smooth``), σ's
accelerometer term takes the gain c_a (``sigma_acc_gain_aircraft``); nothing else changes: the attitude and the bias
are the same bits. Older checkpoints run without them; a fine-tuned model sets both to 0 (its σ₀ and c are fitted on
the vehicle's own logs)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tepinn_flight.errors import ConfigError
from tepinn_flight.evaluation.sigma_calibration import ErrorSamples, motion_probe, score
from tepinn_flight.model.anchor import AnchorConfig, acc_gain, aircraft_var_rad2, with_aircraft_sigma
from tepinn_flight.model.checkpoint import ANCHOR_CONFIG_BEFORE, anchor_config_from, default_model_path, load_model
from tepinn_flight.model.estimate import estimate_anchored
from tepinn_flight.model.streaming import StreamingEstimator
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import EST_BIAS_COLS, EST_Q_COLS, FlightRecord

Q, B = EST_Q_COLS, EST_BIAS_COLS


@pytest.mark.parametrize("vehicle, takes", [
    ("copter", True), ("quadrotor", True), ("multirotor", True), ("plane", True), ("fixed-wing", True),
    ("sub", True), ("vtol-fixedrotor", True), ("helicopter", True),
    ("handheld-imu", False), (None, False), ("unknown", False), ("synthetic", False), ("mav_type_99", False),
])  # fmt: skip
def test_which_vehicles_take_the_term(vehicle, takes):
    cfg = AnchorConfig(sigma_aircraft_deg=0.35)
    assert aircraft_var_rad2(cfg, vehicle) == (math.radians(0.35) ** 2 if takes else 0.0)
    assert aircraft_var_rad2(AnchorConfig(sigma_aircraft_deg=0.0), vehicle) == 0.0


@pytest.mark.parametrize("vehicle, causal, c_a, want", [
    ("quadrotor", True, 0.2, 0.2), ("plane", True, 0.2, 0.2), ("sub", True, 0.2, 0.2),
    ("quadrotor", False, 0.2, 0.01), ("handheld-imu", True, 0.2, 0.01), (None, True, 0.2, 0.01),
    ("quadrotor", True, 0.0, 0.01),
])  # fmt: skip
def test_which_estimates_take_the_causal_gain(vehicle, causal, c_a, want):
    assert acc_gain(AnchorConfig(sigma_acc_gain=0.01, sigma_acc_gain_aircraft=c_a), vehicle, causal) == want


def test_the_setting_and_the_checkpoints():
    with pytest.raises(ConfigError, match="sigma_aircraft_deg"):
        AnchorConfig(sigma_aircraft_deg=-0.1)
    assert ANCHOR_CONFIG_BEFORE["sigma_aircraft_deg"] == 0.0
    raw = {k: v for k, v in dataclasses.asdict(AnchorConfig()).items() if k not in ("fusion_config", "sigma_aircraft_deg")}
    assert anchor_config_from({"anchor_config": raw}).sigma_aircraft_deg == 0.0  # written before rule 28: as it ran
    _, shipped, _ = load_model(default_model_path())
    assert shipped.sigma_aircraft_deg == AnchorConfig().sigma_aircraft_deg > 0  # the defaults are the shipped model


def test_with_aircraft_sigma_is_the_sum_of_variances():
    s = np.array([0.001, 0.01, 0.5, np.nan])
    v = math.radians(0.35) ** 2
    got = with_aircraft_sigma(s, v)
    np.testing.assert_allclose(got[:3], np.hypot(s[:3], math.radians(0.35)), rtol=1e-15)
    assert np.isnan(got[3])
    assert with_aircraft_sigma(s, 0.0) is s


def _named(rec: FlightRecord, vehicle: str) -> FlightRecord:
    return FlightRecord(rec.data, {**rec.meta, "vehicle_type": vehicle})


@pytest.fixture(scope="module")
def shipped():
    model, settings, _ = load_model(default_model_path())
    return model, settings


def test_offline_an_aircraft_log_takes_the_term_and_nothing_else_changes(shipped):
    """The same samples named a quadrotor and a hand-held IMU (both shut the flight-speed gate: the same estimate):
    the attitude and the bias identical, σ² larger by σ_a² exactly where the quadrotor's is."""
    model, settings = shipped
    rec = synthetic_record(seed=5, duration_s=12.0, rate_hz=100.0)
    quad = estimate_anchored(model, _named(rec, "quadrotor"), settings)
    hand = estimate_anchored(model, _named(rec, "handheld-imu"), settings)
    np.testing.assert_array_equal(quad[Q].to_numpy(), hand[Q].to_numpy())
    np.testing.assert_array_equal(quad[B].to_numpy(), hand[B].to_numpy())
    s_q, s_h = quad["sigma_rad"].to_numpy(), hand["sigma_rad"].to_numpy()
    ok = np.isfinite(s_h)
    assert ok.sum() > 0.9 * len(rec)
    np.testing.assert_allclose(s_q[ok] ** 2 - s_h[ok] ** 2, math.radians(settings.sigma_aircraft_deg) ** 2, rtol=1e-9)
    off = estimate_anchored(model, _named(rec, "quadrotor"), dataclasses.replace(settings, sigma_aircraft_deg=0.0))
    np.testing.assert_array_equal(off["sigma_rad"].to_numpy(), s_h)  # switched off: the hand-held σ


def test_live_takes_it_as_offline_and_from_the_next_sample_when_told_late(shipped):
    """The live estimator's σ is the causal offline one's (`--no-smooth`) for the vehicle it was told — both terms,
    rules 28 and 29 — and, told late, the hand-held one's before and the quadrotor's from the next sample on."""
    model, settings = shipped
    causal = dataclasses.replace(settings, smoother=False)
    rec = synthetic_record(seed=6, duration_s=8.0, rate_hz=100.0)
    quad, hand = _named(rec, "quadrotor"), _named(rec, "handheld-imu")
    off_q, off_h = estimate_anchored(model, quad, causal), estimate_anchored(model, hand, causal)
    q_off = off_q[Q].to_numpy()
    np.testing.assert_array_equal(q_off, off_h[Q].to_numpy())
    s_q, s_h = off_q["sigma_rad"].to_numpy(), off_h["sigma_rad"].to_numpy()
    told_at = 300
    for told_late in (False, True):
        live = StreamingEstimator(model, causal, vehicle="handheld" if told_late else "quadrotor")
        q, s = np.full((len(rec), 4), np.nan), np.full(len(rec), np.nan)
        for i in range(len(rec)):
            if told_late and i == told_at:
                live.set_vehicle("quadrotor")
            e = live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i])
            if e.q_nb_wxyz is not None:
                q[i], s[i] = e.q_nb_wxyz, e.sigma_rad
        have = np.all(np.isfinite(q), 1)
        assert have.sum() > 0.9 * len(rec)
        np.testing.assert_allclose(q[have], q_off[have], atol=1e-6)  # the estimate as offline, told or not
        after = have & (np.arange(len(rec)) >= (told_at if told_late else 0))
        np.testing.assert_allclose(s[after], s_q[after], rtol=1e-5)
        if told_late:  # before it was told: the hand-held σ
            before = have & (np.arange(len(rec)) < told_at)
            assert before.sum() > 200
            np.testing.assert_allclose(s[before], s_h[before], rtol=1e-5)


def test_the_causal_estimate_of_an_aircraft_takes_the_motion_gain(shipped):
    """Rule 29: without the smoothing (live, `--no-smooth`) a quadrotor's σ² is the hand-held one's + σ_a² + (c_a·e)²,
    e read through a probe (σ = e: floor, sampling, network and saturation terms off) — closed form; smoothed, only
    σ_a (the test above); a fine-tuned model, or an older checkpoint, has c_a = 0."""
    model, settings = shipped
    assert settings.sigma_acc_gain_aircraft == AnchorConfig().sigma_acc_gain_aircraft > 0
    assert ANCHOR_CONFIG_BEFORE["sigma_acc_gain_aircraft"] == 0.0
    causal = dataclasses.replace(settings, smoother=False)
    rec = synthetic_record(seed=8, duration_s=12.0, rate_hz=100.0)
    s_q = estimate_anchored(model, _named(rec, "quadrotor"), causal)["sigma_rad"].to_numpy()
    s_h = estimate_anchored(model, _named(rec, "handheld-imu"), causal)["sigma_rad"].to_numpy()
    e = estimate_anchored(model, _named(rec, "handheld-imu"), motion_probe(causal))["sigma_rad"].to_numpy()
    ok = np.isfinite(s_h) & np.isfinite(e)
    assert ok.sum() > 0.9 * len(rec) and np.degrees(np.median(e[ok])) > 1.0  # the synthetic motion moves e
    want = s_h[ok] ** 2 + math.radians(causal.sigma_aircraft_deg) ** 2 + (causal.sigma_acc_gain_aircraft * e[ok]) ** 2
    np.testing.assert_allclose(s_q[ok] ** 2, want, rtol=1e-9)


def test_scoring_counts_the_terms_on_the_files_that_take_them():
    """score() (the causal σ the fine-tuning scores) with σ_a and c_a: the quadrotor file's NEES is its error over
    σ₀² + (c_a·e)² + σ_a² (closed form), the hand-held file's over σ₀² + (c·e)²; the fit's own scores (both at 0) are
    those of σ₀ and c alone."""
    rng = np.random.default_rng(1)
    e2, e = rng.exponential(1e-5, 500), rng.uniform(0.0, 0.1, 500)
    files = [ErrorSamples("quad", e2, e, None, None, "quadrotor"), ErrorSamples("hand", e2, e, None, None, "handheld-imu")]
    v0, va = math.radians(0.3) ** 2, math.radians(0.35) ** 2
    var_q, var_h = v0 + (0.2 * e) ** 2 + va, v0 + (0.01 * e) ** 2
    n_with, cv_with = score(files, 0.3, 0.01, 0.0, 0.35, 0.2)
    assert n_with == pytest.approx((np.mean(e2 / var_q) + np.mean(e2 / var_h)) / 2, rel=1e-12)
    assert cv_with == pytest.approx((np.mean(e2 <= 9 * var_q) + np.mean(e2 <= 9 * var_h)) / 2)
    assert score(files, 0.3, 0.01) == pytest.approx((np.mean(e2 / var_h), np.mean(e2 <= 9 * var_h)))


def test_the_rule_finds_the_term_a_known_error_needs():
    """fit_added_sigma (the benchmark's part 6, which chose σ_a and c_a): on errors drawn with a per-axis σ of
    sqrt(σ² + 0.4°²) it picks 0.4° from a 0.05° grid; with errors that need no term, 0; the table's NEES at the true
    value is 2 (the closed form for a 2-D Gaussian error)."""
    from tepinn_flight.evaluation.sigma_calibration import fit_added_sigma

    rng = np.random.default_rng(7)
    s = np.full(20000, math.radians(0.3))
    files = []
    for k in range(3):
        e = rng.normal(size=(20000, 2)) * math.hypot(math.radians(0.3), math.radians(0.4))
        files.append((np.sum(e**2, axis=1), s, math.radians(1.0)))
    choice, table = fit_added_sigma(files)
    assert choice == pytest.approx(0.4)
    n_true = dict((sa, n) for sa, n, _ in table)[0.4]
    assert n_true == pytest.approx(2.0, abs=0.05)
    quiet = [(np.sum((rng.normal(size=(20000, 2)) * s[:, None]) ** 2, axis=1), s, math.radians(1.0))]
    assert fit_added_sigma(quiet)[0] == 0.0
    # a gain on a per-sample witness u (rule 29's c_a·e): errors drawn with σ² + (0.2·u)² → 0.2 from a 0.025 grid
    u = rng.uniform(0.0, 0.3, 20000)
    e = rng.normal(size=(20000, 2)) * np.sqrt(s**2 + (0.2 * u) ** 2)[:, None]
    assert fit_added_sigma([(np.sum(e**2, axis=1), s, u)], grid=np.arange(0, 0.601, 0.025))[0] == pytest.approx(0.2)

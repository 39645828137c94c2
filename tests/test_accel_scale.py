"""The accelerometer's scale read from a record (model/accel_scale.py) and divided out offline where it
is clearly not 1: closed forms on synthetic IMUs, and a real BROAD trial read as a board at 1.25 g."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.model.accel_scale import AccelScaleConfig, read_accel_scale
from tepinn_flight.model.checkpoint import anchor_config_from

from .conftest import broad_trial, estimate_says_and_stores


def _imu(seconds: float, rate_hz: float, scale: float, rate_rad_s: float = 0.0, seed: int = 0, gyr_noise: float = 0.01):
    """A level IMU (specific force −g·scale on z, white noise 0.5 m/s² per axis; the gyro's ``gyr_noise``
    rad/s per axis) turning about z at ``rate_rad_s``."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    gyr = rng.normal(0.0, gyr_noise, (n, 3)) + np.array([0.0, 0.0, rate_rad_s])
    acc = rng.normal(0.0, 0.5, (n, 3)) + np.array([0.0, 0.0, -GRAVITY_M_S2 * scale])
    return t, gyr, acc


@pytest.mark.parametrize("scale", [0.8, 1.25])
def test_a_board_off_by_a_fifth_is_read_and_divided_out(scale):
    t, gyr, acc = _imu(30.0, 200.0, scale)
    found = read_accel_scale(t, gyr, acc)
    assert found.applied and found.read == pytest.approx(scale, abs=0.005) and found.scale == found.read
    assert found.quiet_s > 25.0 and found.describe().endswith("; applied")


def test_a_board_within_the_tolerance_keeps_its_scale():
    t, gyr, acc = _imu(30.0, 200.0, 1.03)
    found = read_accel_scale(t, gyr, acc)
    assert found.read == pytest.approx(1.03, abs=0.005) and not found.applied and found.scale == 1.0
    # a tighter tolerance takes it: the rule is |s − 1| ≥ tolerance
    assert read_accel_scale(t, gyr, acc, AccelScaleConfig(tolerance=0.02)).applied


def test_turning_or_accelerating_samples_give_no_reading():
    # turning at 0.2 rad/s throughout (a banked turn reads more than g): never quiet
    t, gyr, acc = _imu(30.0, 200.0, 1.2, rate_rad_s=0.2)
    assert read_accel_scale(t, gyr, acc).read is None
    # not turning, but the norm swinging by ±3 m/s² at 0.5 Hz (a vehicle speeding up and slowing down)
    t, gyr, acc = _imu(30.0, 200.0, 1.0)
    acc[:, 2] += 3.0 * np.sin(2 * np.pi * 0.5 * t)
    assert read_accel_scale(t, gyr, acc).read is None


def test_a_noisy_gyro_at_rest_still_lets_the_board_be_read_offline_and_live():
    """Rule 21: white gyro noise of 2 °/s per sample averages to |ω| ≈ 1.6 × 0.035 = 0.056 rad/s, above the
    0.05 rad/s quiet rate; the threshold rises to 1.5 × the noise floor (the mean of |ω_i − ω_(i−1)|/√2)."""
    from tepinn_flight.model.accel_scale import AccelScaleTracker
    from tests.accel_scale_reference import noise_norms, quiet_threshold

    sd = np.radians(2.0)
    t, gyr, acc = _imu(30.0, 286.0, 1.25, gyr_noise=sd)
    floor = noise_norms(gyr, np.ones(len(t), bool))[1:].mean()  # closed form: the mean of a χ₃ × σ, 2·√(2/π)·σ
    assert floor == pytest.approx(2 * np.sqrt(2 / np.pi) * sd, rel=0.02)
    assert np.mean(np.linalg.norm(gyr, axis=1)) > AccelScaleConfig().quiet_rate_rad_s  # no sample quiet before rule 21
    assert quiet_threshold(floor, AccelScaleConfig()) == pytest.approx(1.5 * floor)
    found = read_accel_scale(t, gyr, acc)
    assert found.applied and found.read == pytest.approx(1.25, abs=0.005) and found.quiet_s > 25.0
    assert read_accel_scale(t, gyr, acc, AccelScaleConfig(noise_floor_factor=0.0)).read is None  # the rule off
    tr = AccelScaleTracker()
    for ti, g, a in zip(t, gyr, acc):
        tr.update(float(ti), g, a)
    assert tr.decided is not None and tr.decided.applied and tr.decided.read == pytest.approx(1.25, abs=0.005)
    tr = AccelScaleTracker(AccelScaleConfig(noise_floor_factor=0.0))
    for ti, g, a in zip(t, gyr, acc):
        tr.update(float(ti), g, a)
    assert tr.decided is None


def test_the_noise_floor_does_not_make_a_steady_turn_quiet():
    # a clean gyro turning steadily at 0.08 rad/s (a banked turn reads more than g): its consecutive
    # differences hold only the small noise, so the threshold stays 0.05 rad/s
    t, gyr, acc = _imu(30.0, 200.0, 1.2, rate_rad_s=0.08)
    assert read_accel_scale(t, gyr, acc).read is None
    # a gyro too noisy to tell (10 °/s per sample): the threshold stops at the cap, 0.1 rad/s, and nothing is read
    t, gyr, acc = _imu(30.0, 200.0, 1.2, gyr_noise=np.radians(10.0))
    assert read_accel_scale(t, gyr, acc).read is None
    from tepinn_flight.errors import ConfigError

    with pytest.raises(ConfigError, match="noise_floor_factor"):
        AccelScaleConfig(noise_floor_factor=-1.0)


def test_records_too_short_or_without_a_finite_sample_give_no_reading():
    for seconds in (0.004, 0.05, 1.0, 1.9):  # shorter than the averaging, than the steadiness window
        t, gyr, acc = _imu(seconds, 200.0, 0.8)
        found = read_accel_scale(t, gyr, acc)
        assert found.read is None and not found.applied and found.scale == 1.0
    t, gyr, acc = _imu(30.0, 200.0, 0.8)
    acc[:] = np.nan
    assert read_accel_scale(t, gyr, acc).read is None


def test_checkpoints_written_before_it_run_without_it():
    old = {"bias_gate_fusion_deg_s": 3.0}  # a checkpoint of session 16 (written after pull_target's removal)
    assert anchor_config_from({"anchor_config": old}).accel_scale_selfcal is False
    assert anchor_config_from({"anchor_config": {**old, "accel_scale_selfcal": True}}).accel_scale_selfcal is True


def _trial_05():
    """BROAD trial 05 from 20 s to 70 s: 15 s of its rest before the first rotation (quiet samples for the scale's
    reading, offline and live; the filters settled) and that rotation (35–68 s: the scored samples, where a misread
    scale opens the flight-speed gate), then the start of a break. (Tilt RMSE offline, logged or rescaled against
    without the reading: 0.29° and 1.06° here, 0.27° and 1.30° on the whole trial, 207 s, at 3× the cost; live here
    0.39° and 1.31°.)"""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import FlightRecord

    rec = ingest_log(broad_trial("broad_05_*.hdf5"))
    a, b = np.searchsorted(rec.t_s, rec.t_s[0] + np.array([20.0, 70.0]))
    return FlightRecord(rec.data.iloc[a:b].reset_index(drop=True), dict(rec.meta))


@pytest.mark.slow
def test_a_real_trial_read_as_a_board_at_1_25_g_is_estimated_as_the_trial_itself():
    """BROAD trial 05 (hand-held, optical truth) with its accelerometer × 1.25: the shipped estimator
    without the scale read, where the flight-speed gate may act (a log that names no vehicle: the gate as before
    rule 24), loses to its own estimate of the trial as logged by far (the gate opens); with it, the trial's scale
    is read as 1.25 and the estimate is the logged trial's. Named hand-held, the gate stays shut (rule 24) and the
    misread scale costs the tilt nothing: gravity's direction does not depend on it."""
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored
    from tepinn_flight.record import ACC_COLS

    rec = _trial_05()
    model, anchor, _ = load_model(default_model_path())
    assert anchor.accel_scale_selfcal  # shipped on
    big = copy.copy(rec)
    big.data = rec.data.copy()
    big.data[ACC_COLS] = rec.acc_m_s2 * 1.25

    def rmse(r, a):
        est = estimate_anchored(model, r, a)
        q = est[EST_Q_COLS].to_numpy()
        m = scoring_mask(r, 5.0) & np.all(np.isfinite(q), 1)
        return float(np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(q[m], r.q_ref_wxyz[m])) ** 2)))), est

    logged, est0 = rmse(rec, anchor)
    fixed, est1 = rmse(big, anchor)
    without, _ = rmse(big, dataclasses.replace(anchor, accel_scale_selfcal=False, speed_gate_shut_for=()))
    handheld, _ = rmse(big, dataclasses.replace(anchor, accel_scale_selfcal=False))
    assert "not applied" in est0.attrs["accel_scale_selfcal"] and est1.attrs["accel_scale_selfcal"].endswith("; applied")
    assert abs(fixed - logged) < 0.01
    assert without > 2.0 * logged
    assert abs(handheld - logged) < 0.01


def test_estimate_says_what_it_read_keeps_it_in_the_output_and_no_accel_scale_turns_it_off(tmp_path, capsys):
    from tepinn_flight.record import ACC_COLS, FlightRecord, write_record

    from .test_gyro_selfcal import turns_with_rests

    rec, _ = turns_with_rests((1.0, 1.0, 1.0), seed=3)  # turns between rests, the accelerometer as true
    data = rec.data.copy()
    data[ACC_COLS] = rec.acc_m_s2 * 0.8  # a board at 0.8 g
    write_record(FlightRecord(data, dict(rec.meta)), tmp_path / "low.parquet")
    line, _, _ = estimate_says_and_stores(tmp_path, capsys, tmp_path / "low.parquet", "accel_scale_selfcal",
                                          "--no-accel-scale", "accelerometer scale")  # fmt: skip
    assert line.startswith("accelerometer scale: 0.80") and line.endswith("; applied")
    # (what dividing it out does to the estimate: the real trial × 1.25 above; on this record no gate
    # opens at any scale, so the estimate is VQF's either way)


def test_the_live_reading_decides_once_from_the_first_quiet_seconds_and_matches_the_offline_one():
    from tepinn_flight.model.accel_scale import AccelScaleTracker

    t, gyr, acc = _imu(30.0, 200.0, 1.25)
    tr = AccelScaleTracker()
    out = np.array([tr.update(float(ti), g, a) for ti, g, a in zip(t, gyr, acc)])
    found = tr.decided
    assert found is not None and found.applied and found.read == pytest.approx(read_accel_scale(t, gyr, acc).read, abs=0.005)
    first = int(np.argmax(np.any(out != acc, axis=1)))  # the first sample divided: after 0.5 + 2 + 5 s
    assert 7.4 <= t[first] <= 7.7
    np.testing.assert_array_equal(out[:first], acc[:first])
    np.testing.assert_allclose(out[first:], acc[first:] / found.scale, rtol=1e-12)
    # a board within the tolerance passes unchanged, bit for bit
    t, gyr, acc = _imu(30.0, 200.0, 1.03)
    tr = AccelScaleTracker()
    out = np.array([tr.update(float(ti), g, a) for ti, g, a in zip(t, gyr, acc)])
    assert tr.decided is not None and not tr.decided.applied
    np.testing.assert_array_equal(out, acc)


def test_the_live_reading_restarts_its_windows_at_a_time_jump():
    from tepinn_flight.model.accel_scale import AccelScaleTracker

    t, gyr, acc = _imu(30.0, 200.0, 0.8)
    t = np.where(t < 4.0, t + 1000.0, t)  # the clock jumps back 1000 s after 4 s (an autopilot reboot)
    tr = AccelScaleTracker()
    for i, (ti, g, a) in enumerate(zip(t, gyr, acc)):
        tr.update(float(ti), g, a)
        if tr.decided is None:
            n_avg, n_norms = tr.window_lengths()
            assert n_avg <= 101 and n_norms <= 401  # the trailing windows stay their length
    # the 4 s before the jump were quiet but too short; after it, 2.5 s to fill the windows, then 5 s
    assert tr.decided is not None and tr.decided.applied and tr.decided.read == pytest.approx(0.8, abs=0.005)



def _awkward_stream(seed: int):
    """A live stream that exercises every branch of the reading: quiet and turning phases at 0.8 g,
    a 2 kHz stretch (the trailing windows outgrow their first buffers), a dropout over 1 s, the
    clock jumping back (a reboot) and samples at uneven steps."""
    rng = np.random.default_rng(seed)
    parts, t0 = [], 0.0
    for seconds, rate_hz, turn, noise in ((3.0, 200.0, 0.0, 0.01), (2.0, 200.0, 0.4, 0.01), (4.0, 2000.0, 0.0, 0.01),
                                          (1.0, 100.0, 0.0, 0.01), (6.0, 400.0, 0.0, 0.01), (3.0, 250.0, 0.0, 0.04),
                                          (8.0, 300.0, 0.0, 0.04)):  # fmt: skip  (the last two: a gyro noisy enough
        # to raise the quiet threshold, rule 21)
        t, gyr, acc = _imu(seconds, rate_hz, 0.8, turn, seed=int(rng.integers(1 << 30)), gyr_noise=noise)
        t = t + t0 + rng.uniform(0.0, 0.2 / rate_hz, len(t))
        parts.append((t, gyr, acc))
        t0 = t[-1] + (1.5 if len(parts) == 3 else 1.0 / rate_hz)  # a 1.5-s dropout after the 2 kHz stretch
    t, gyr, acc = (np.concatenate(x) for x in zip(*parts))
    t = np.where(np.arange(len(t)) > len(t) // 2, t - 500.0, t)  # the clock jumps back halfway
    return t, gyr, acc


@pytest.mark.parametrize("seed", [0, 1])
def test_the_compiled_live_reading_equals_the_python_one_bit_for_bit(seed):
    """The tracker's compiled step (``accel_scale_kernels``) against the former Python tracker, kept as
    ``tests/accel_scale_reference.py``: the same accelerometer out at every sample, the same windows,
    the same decision (read, quiet time) — through buffer growth, a dropout and a clock jump back."""
    from tepinn_flight.model.accel_scale import AccelScaleTracker
    from tests.accel_scale_reference import AccelScaleTrackerReference

    t, gyr, acc = _awkward_stream(seed)
    fast, ref = AccelScaleTracker(), AccelScaleTrackerReference()
    for i, (ti, g, a) in enumerate(zip(t, gyr, acc)):
        out_f, out_r = fast.update(float(ti), g, a), ref.update(float(ti), g, a)
        assert tuple(map(float, out_f)) == tuple(map(float, out_r)), i
        if ref.decided is None:
            assert fast.window_lengths() == (len(ref._avg), len(ref._norms)), i
    assert ref.decided is not None and ref.decided.applied  # the stream did reach a decision
    assert fast.decided == ref.decided
    # a vehicle that never holds still: no decision, the accelerometer passed as it is throughout
    t, gyr, acc = _imu(20.0, 400.0, 0.8, rate_rad_s=0.5, seed=seed)
    fast, ref = AccelScaleTracker(), AccelScaleTrackerReference()
    out = np.array([fast.update(float(ti), g, a) for ti, g, a in zip(t, gyr, acc)])
    [ref.update(float(ti), g, a) for ti, g, a in zip(t, gyr, acc)]
    assert fast.decided is None and ref.decided is None and fast.window_lengths() == (len(ref._avg), len(ref._norms))
    np.testing.assert_array_equal(out, acc)

@pytest.mark.slow
def test_the_live_estimator_on_a_real_trial_read_as_a_board_at_1_25_g():
    """BROAD trial 05 × 1.25 streamed sample by sample (what the bridge runs): with the causal reading,
    near the trial's own live estimate; without it, far off (the flight-speed gate opens)."""
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.streaming import StreamingEstimator

    rec = _trial_05()
    model, anchor, _ = load_model(default_model_path())

    def live(a, scale):
        se = StreamingEstimator(model, a)
        est = [se.push(t, g, acc * scale, None, c).q_nb_wxyz for t, g, acc, c in
               zip(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.clipped)]  # fmt: skip
        q = np.array([(np.nan,) * 4 if e is None else tuple(e) for e in est], np.float64)
        m = scoring_mask(rec, 5.0) & np.all(np.isfinite(q), 1)
        return float(np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(q[m], rec.q_ref_wxyz[m])) ** 2))))

    logged = live(anchor, 1.0)
    fixed = live(anchor, 1.25)
    without = live(dataclasses.replace(anchor, accel_scale_selfcal=False), 1.25)
    assert fixed < logged + 0.1 and without > 2.0 * logged, (logged, fixed, without)


@pytest.mark.parametrize("trial", [1, 6, 15])
def test_the_compiled_quiet_samples_equal_the_numpy_form_bit_for_bit(trial):
    """:func:`quiet_samples` (compiled in session 42: ``accel_scale_kernels.quiet_rows``) against the numpy form it
    replaced (``tests/accel_scale_reference.py``), mask and averaged accelerometer bit for bit: on a real BROAD trial
    as it is, with holes (a non-finite axis here and there) and a noisy gyro, given row- or column-ordered, and on a
    synthetic board at rest."""
    from tepinn_flight.model.accel_scale import quiet_samples

    from .accel_scale_reference import quiet_samples as reference

    from tepinn_flight.ingest import ingest_log

    rec = ingest_log(broad_trial(f"broad_{trial:02d}_*.hdf5"))
    rng = np.random.default_rng(trial)
    t, gyr, acc = rec.t_s, rec.gyr_rad_s.copy(), rec.acc_m_s2.copy()
    holes = np.flatnonzero(rng.random(len(t)) < 0.002)
    noisy = gyr + rng.normal(0.0, np.radians(2.0), gyr.shape)
    bad_gyr, bad_acc = gyr.copy(), acc.copy()
    bad_gyr[holes[::2], 1] = np.nan
    bad_acc[holes[1::2], 2] = np.inf
    cases = [(gyr, acc), (bad_gyr, bad_acc), (noisy, acc), (np.ascontiguousarray(gyr), np.ascontiguousarray(acc)),
             _imu(30.0, 200.0, 1.1)[1:]]  # fmt: skip
    for i, (g, a) in enumerate(cases):
        tt = t if i < 4 else _imu(30.0, 200.0, 1.1)[0]
        got, want = quiet_samples(tt, g, a), reference(tt, g, a)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]) and got[2] == want[2]
        assert 0.05 < want[0].mean() < (1.0 if i < 4 else 1.01)  # the trial's mask is exercised: quiet and not

"""A rise of the IMU's sample rate inside a segment starts a new one, offline and live at the same sample
(session 53, `record_gaps.rate_rise_cuts` / `RateRise`). The estimators take a segment's sample period from its
first 51 steps; the bridge's own request for a faster IMU, granted mid-flight, had left the live filter on a period
8× too long (tilt off by up to 157° on a simulated F450 flight, `/work/review53/live`)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from tepinn_flight.record import FlightRecord
from tepinn_flight.record_gaps import PERIOD_STEPS, RateRise, bridge_gaps, rate_rise_cuts


def _live_cuts(t: np.ndarray) -> list[int]:
    """The rows at which the live rule (RateRise, as StreamingEstimator.push drives it) starts a new segment."""
    cuts, dts, rise = [], [], None
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        if len(dts) < PERIOD_STEPS:
            dts.append(dt)
            if len(dts) == PERIOD_STEPS:
                rise = RateRise(float(np.median(dts)), dts)
        elif rise.step(dt):
            cuts.append(i)
            dts, rise = [], None
    return cuts


def _times(*parts) -> np.ndarray:
    """Times of runs of (count, rate_hz) in turn."""
    t, out = 0.0, []
    for n, hz in parts:
        out.append(t + np.arange(n) / hz)
        t = out[-1][-1] + 1.0 / hz
    return np.concatenate(out)


@pytest.mark.parametrize("parts, want", [
    (((100, 25.0), (200, 200.0)), [126]),  # at the 26th short step of the last 51 (row 100's is still 40 ms)
    (((100, 25.0), (100, 50.0), (200, 200.0)), [126, 226]),  # 2× then 4×: each rise, the new period read first
    (((100, 200.0), (200, 25.0)), []),  # a falling rate is gaps, not this
    (((100, 100.0), (100, 120.0)), []),  # 1.2×: under the 1.5× rise
])  # fmt: skip
def test_cuts_offline_and_live_at_the_same_sample(parts, want):
    t = _times(*parts)
    assert rate_rise_cuts(t, np.zeros(len(t), np.int32)).tolist() == want
    assert _live_cuts(t) == want


def test_jittered_and_lost_samples_at_one_rate_cut_nothing():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.0025, 0.0075, 20000))  # ±50 % jitter about 5 ms
    t = np.delete(t, rng.choice(len(t), 2000, replace=False))  # and 10 % of the samples lost
    assert len(rate_rise_cuts(t, np.zeros(len(t), np.int32))) == 0 and _live_cuts(t) == []


@functools.cache  # (made once for the two tests that read it; neither changes it)
def _slow_then_fast(seed: int = 4):
    """A synthetic flight at 25 Hz for 20 s, then 200 Hz for 10 s (the bridge's request granted)."""
    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=seed, duration_s=30.0, rate_hz=200.0, max_rate_rad_s=3.0)
    keep = (np.arange(len(rec)) % 8 == 0) | (rec.t_s >= 20.0)
    data = rec.data[keep].reset_index(drop=True)
    data["segment"] = np.zeros(len(data), np.int32)
    return FlightRecord(data, {**rec.meta, "imu_rate_hz": 25.0})


def test_a_rate_rise_cuts_the_bridged_record_once():
    rec = _slow_then_fast()
    br = bridge_gaps(rec)
    assert br.filled == 0 and br.record is not rec
    first_fast = int(np.searchsorted(rec.t_s, 20.0))
    assert np.flatnonzero(np.diff(br.record.segment)).tolist() == [first_fast + 25]  # the 26th short step (the step into first_fast is 40 ms), a row before the cut
    assert bridge_gaps(br.record).record is br.record  # cut once: nothing more to cut


def test_live_equals_offline_across_a_rate_rise_and_stays_on_the_attitude():
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import estimate_record
    from tepinn_flight.model.streaming import StreamingEstimator
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad

    from tests.live_run import live_run

    rec = _slow_then_fast()
    model, cfg, _ = load_model(default_model_path())
    cfg = dataclasses.replace(cfg, smoother=False, gyro_selfcal=False, gnss_aid=False)  # the causal estimate
    se = StreamingEstimator(model, cfg)
    q_live, _ = live_run(model, cfg, rec, live=se)
    off = estimate_record(model, rec, cfg)[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 120
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)
    # after the rise the tilt is as good as before it (max 5.2° against 8.0°; on a period 8× too long, as before
    # session 53: 20.1°)
    err = np.degrees(inclination_error_rad(error_quat_earth(off, rec.q_ref_wxyz)))
    late = rec.t_s >= 25.0
    early = (rec.t_s >= 10.0) & (rec.t_s < 20.0)
    assert np.nanmax(err[late]) < 1.5 * np.nanmax(err[early])
    assert se.rate_rises == 1  # (the estimator of the live run above: its estimates are the offline ones)


def test_a_lone_sample_between_two_gaps_is_its_own_segment_live_as_offline():
    """Right after a restart the live estimator tells gaps by the last segment's period, as ingest does by the
    record's (session 53: a lone sample between two gaps had been one segment with what followed, live only)."""
    from tepinn_flight.ingest.assemble import segments_from_time
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import estimate_record
    from tepinn_flight.model.synthetic import synthetic_record

    from tests.live_run import live_run

    rec = synthetic_record(seed=5, duration_s=15.0, rate_hz=200.0)  # (4.2 s after the second gap: the live
    # estimator's restart and 3.9 s of estimates after it, each compared with the offline one)
    t = rec.t_s
    keep = ~(((t > 10.0) & (t < 10.5)) | ((t > 10.5) & (t < 10.8)))  # a lone sample at 10.5 s between two gaps
    data = rec.data[keep].reset_index(drop=True)
    data["segment"] = segments_from_time(data["t_s"].to_numpy(), np.zeros(len(data), np.int64), 0.005)
    rec = FlightRecord(data, dict(rec.meta))
    assert int(rec.segment.max()) == 2  # three segments offline: before, the lone sample, after
    model, cfg, _ = load_model(default_model_path())
    cfg = dataclasses.replace(cfg, smoother=False, gyro_selfcal=False, gnss_aid=False)
    q_live, _ = live_run(model, cfg, rec)
    off = estimate_record(model, rec, cfg)[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    have = np.all(np.isfinite(q_live), 1)
    after = rec.t_s > 10.8
    assert have[after].sum() > after.sum() - 60
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)


def test_a_rate_fall_inside_a_segment_is_bridged_as_live():
    """A one-segment record whose rate falls 5× (a record made without ingest's gap rule): its long steps are gaps,
    bridged as the live estimator bridges them (session 53: they had been integrated as 2.5 periods each, the tilt
    off by up to 151° on a BROAD trial)."""
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import estimate_record
    from tepinn_flight.model.synthetic import synthetic_record

    from tests.live_run import live_run

    # 15 s at 200 Hz, then 10 s at 40 Hz: 400 long steps (each bridged row by row, here and in estimate_record: most
    # of the test's time)
    rec = synthetic_record(seed=6, duration_s=25.0, rate_hz=200.0, max_rate_rad_s=3.0)
    keep = (rec.t_s < 15.0) | (np.arange(len(rec)) % 5 == 0)
    data = rec.data[keep].reset_index(drop=True)
    data["segment"] = np.zeros(len(data), np.int32)
    rec = FlightRecord(data, {**rec.meta, "imu_rate_hz": 200.0})
    br = bridge_gaps(rec)
    assert br.gaps > 0.9 * (rec.t_s >= 15.0).sum() and br.filled == 4 * br.gaps
    assert np.diff(br.record.t_s).max() < 0.0051
    model, cfg, _ = load_model(default_model_path())
    cfg = dataclasses.replace(cfg, smoother=False, gyro_selfcal=False, gnss_aid=False)
    off = estimate_record(model, rec, cfg)[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    q_live, _ = live_run(model, cfg, rec)
    have = np.all(np.isfinite(q_live), 1)
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)
    err = np.degrees(inclination_error_rad(error_quat_earth(off, rec.q_ref_wxyz)))
    # (max 2.4° against 6.0°; integrated as 2.5 periods each: 60°)
    assert np.nanmax(err[rec.t_s >= 20.0]) < 1.5 * np.nanmax(err[(rec.t_s >= 5.0) & (rec.t_s < 15.0)])

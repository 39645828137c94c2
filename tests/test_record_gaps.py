"""Short logging dropouts are bridged (propagated through), longer gaps and reboots restart:
record_gaps.bridge_gaps against closed forms, the shipped estimator through a gap, live = offline,
and a real PX4 ULog with dropouts cut into it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from tepinn_flight.record import FlightRecord, make_frame
from tepinn_flight.record_gaps import GAP_PERIODS, MAX_BRIDGED_GAP_S, bridge_gaps
from tests.conftest import real_log

Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
RATE_HZ = 100.0


def _spin(duration_s=20.0, yaw_rate=0.5, drop=((10.0, 0.06),)):
    """A level vehicle spinning about z at ``yaw_rate`` (closed form: heading = rate·t), 100 Hz,
    with the samples of each (start, length) in ``drop`` removed and a segment break there, as
    ingest makes one."""
    t = np.arange(0, duration_s, 1.0 / RATE_HZ)
    keep = np.ones(len(t), bool)
    for a, d in drop:
        keep &= ~((t > a) & (t < a + d - 1e-9))
    t = t[keep]
    seg = np.concatenate([[0], np.cumsum(np.diff(t) > GAP_PERIODS / RATE_HZ)])
    n = len(t)
    yaw = yaw_rate * t
    q = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], 1)
    gyr = np.tile([0.0, 0.0, yaw_rate], (n, 1)) + 0.01 * np.sin(t)[:, None]  # a slowly varying rate
    acc = np.tile([0.0, 0.0, -9.81], (n, 1))
    meta = {"format_version": 1, "source_file": "spin.bin", "source_kind": "synthetic", "imu_rate_hz": RATE_HZ,
            "reference_source": "truth"}  # fmt: skip
    return FlightRecord(make_frame(t, seg, gyr, acc, None, q), meta)


def test_a_short_gap_is_filled_on_the_nominal_period_with_the_rates_interpolated():
    rec = _spin(drop=((10.0, 0.06),))
    assert rec.segment.max() == 1
    br = bridge_gaps(rec)
    out = br.record
    assert br.gaps == 1 and out.segment.max() == 0
    # the original rows are kept, unchanged, in order
    pd.testing.assert_frame_equal(br.original(out.data).drop(columns="segment"), rec.data.drop(columns="segment"))
    b = int(np.flatnonzero(np.diff(rec.segment))[0]) + 1
    t_a, t_b = rec.t_s[b - 1], rec.t_s[b]
    fill = out.data.iloc[br.rows[b - 1] + 1 : br.rows[b]]
    # the gap of (t_b - t_a) = 70 ms at 100 Hz: 6 samples 10 ms apart
    assert br.filled == len(fill) == int(round((t_b - t_a) * RATE_HZ)) - 1
    np.testing.assert_allclose(np.diff(np.r_[t_a, fill.t_s, t_b]), (t_b - t_a) / (len(fill) + 1), atol=1e-12)
    # closed form: gyro on the straight line between the two edge samples
    w = (fill.t_s.to_numpy() - t_a) / (t_b - t_a)
    g_a, g_b = rec.gyr_rad_s[b - 1], rec.gyr_rad_s[b]
    np.testing.assert_allclose(fill[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]].to_numpy(),
                               (1 - w)[:, None] * g_a + w[:, None] * g_b, atol=1e-12)  # fmt: skip
    assert fill[["q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z"]].isna().all().all()  # never scored
    assert not fill.clipped.any()


def test_long_gaps_and_reboot_like_breaks_are_not_bridged():
    rec = _spin(drop=((5.0, MAX_BRIDGED_GAP_S + 0.05), (12.0, 0.03)))
    assert rec.segment.max() == 2
    br = bridge_gaps(rec)
    assert br.gaps == 1 and br.record.segment.max() == 1  # only the 40 ms one
    # a break one period long (a reboot continues the record clock one period later) is kept
    data = rec.data.copy()
    data["segment"] = (data.t_s > 3.0).astype(np.int32)
    data = data[(data.t_s < 5.0)]
    br = bridge_gaps(FlightRecord(data.reset_index(drop=True), dict(rec.meta)))
    assert br.gaps == 0 and br.filled == 0 and br.record.segment.max() == 1


def _heading_deg(q):
    return np.degrees(np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)))


@pytest.mark.slow
def test_the_shipped_estimator_propagates_through_a_dropout_and_live_equals_offline():
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import estimate_record
    from tepinn_flight.model.streaming import StreamingEstimator

    if not default_model_path().exists():
        pytest.skip(f"shipped model not available ({default_model_path()})")
    model, est, _ = load_model(default_model_path())
    est = dataclasses.replace(est, smoother=False)  # the causal estimate, what live gives (14 s are smoothed offline)
    rec = _spin(duration_s=14.0, drop=((10.0, 0.06),))
    off = estimate_record(model, rec, est)
    assert len(off) == len(rec)
    np.testing.assert_array_equal(off.t_s.to_numpy(), rec.t_s)
    q = off[Q].to_numpy()
    assert np.all(np.isfinite(q))
    # 6-D heading is the integrated gyro: through the gap it keeps following the closed form
    # heading(t) = ∫ rate (one constant offset, taken before the gap); a restart would start over
    true = np.degrees(0.5 * rec.t_s - 0.01 * (np.cos(rec.t_s) - 1))
    err = (_heading_deg(q) - true + 180) % 360 - 180
    after = rec.t_s > 10.0
    before = (rec.t_s > 9.0) & (rec.t_s < 10.0)
    off0 = math.degrees(np.angle(np.mean(np.exp(1j * np.radians(err[before])))))
    jump = (err[after] - off0 + 180) % 360 - 180
    assert np.abs(jump[:300]).max() < 0.5, np.abs(jump[:300]).max()
    # live bridges the same gap with the same samples
    live = StreamingEstimator(model, est)
    q_live = np.full((len(rec), 4), np.nan)
    for i in range(len(rec)):
        e = live.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i], None, bool(rec.clipped[i]), bool(rec.gyr_clipped[i]))
        if e.q_nb_wxyz is not None:
            q_live[i] = e.q_nb_wxyz
    assert live.bridged_gaps == 1
    have = np.all(np.isfinite(q_live), 1)
    assert have[after].all()
    np.testing.assert_allclose(q_live[have], q[have], atol=1e-6)


@pytest.mark.slow
def test_a_real_px4_log_with_dropouts_is_estimated_further_and_no_worse():
    """pyulog_sample_px4_events.ulg (PX4, 250 Hz, one segment) with nine logging dropouts of
    12–65 ms cut into it, as in the issue: the evaluation bridges them (one warm-up, not ten), so
    more samples are scored, and TE-PINN and VQF stay as accurate against PX4's own attitude."""
    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.evaluation.harness import HarnessConfig, evaluate
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.checkpoint import default_model_path

    rec = ingest_log(real_log("pyulog_sample_px4_events.ulg"))
    assert rec.segment.max() == 0
    t = rec.t_s
    starts = np.linspace(t[0] + 2.0, t[-1] - 3.0, 9)
    lengths = np.array([0.012, 0.02, 0.03, 0.065, 0.04, 0.015, 0.05, 0.025, 0.06])
    keep = np.ones(len(t), bool)
    for a, d in zip(starts, lengths):
        keep &= ~((t > a) & (t < a + d))
    data = rec.data[keep].reset_index(drop=True)
    tt = data.t_s.to_numpy()
    data["segment"] = np.concatenate([[0], np.cumsum(np.diff(tt) > GAP_PERIODS / rec.meta["imu_rate_hz"])]).astype(np.int32)
    gapped = FlightRecord(data, dict(rec.meta))
    assert gapped.segment.max() == 9

    ests = [TepinnEstimator.from_checkpoint(default_model_path()), VqfEstimator()]
    cfg = HarnessConfig(warmup_s=2.0)
    res = evaluate([gapped], ests, cfg, progress=False, keep_series=False)
    r = res.records[0]
    assert r["bridged_gaps"] == 9
    # what a restart at every dropout gives: the segments evaluated apart (the old behaviour)
    from tepinn_flight.record_gaps import Bridged
    import tepinn_flight.evaluation.harness as H

    orig = H.bridge_gaps
    H.bridge_gaps = lambda rr: Bridged(rr, np.arange(len(rr)), 0, 0)
    try:
        old = evaluate([gapped], ests, cfg, progress=False, keep_series=False).records[0]
    finally:
        H.bridge_gaps = orig
    frac_new = r["n_scored_common"] / len(gapped)
    frac_old = old["n_scored_common"] / len(gapped)
    print(f"scored {frac_old:.1%} -> {frac_new:.1%}")
    assert frac_new > frac_old + 0.3
    for name in (e.name for e in ests):
        a, b = r["results"][name]["inclination_rmse_deg"], old["results"][name]["inclination_rmse_deg"]
        print(name, f"inclination RMSE restart {b:.3f} deg, bridged {a:.3f} deg")
        assert a <= b * 1.1 + 0.05


@pytest.mark.parametrize("f", [0.02, 0.2, 0.45])
def test_logged_timing_loses_the_share_asked_one_at_a_time(f):
    """`lost_fraction` f loses f of the samples (review60: f(1 − f) — 0.45 asked, 0.25 lost), never two in a row nor
    the first or last 5 — against a slow sequential reference on the same draws: each sample drawn to be lost is lost
    unless the one before was — and the first stamp is on time (its jitter had shifted the whole record's clock)."""
    from tepinn_flight.record_gaps import logged_timing

    n, period = 200_000, 0.0025
    t = np.arange(n) * period
    keep, stamps = logged_timing(np.random.default_rng(7), t, period, f, 0.2 * period)
    lost = ~keep
    draws = np.random.default_rng(7).random(n) < f / (1 - f)
    ref = np.zeros(n, bool)
    for i in range(n):
        ref[i] = draws[i] and not (i > 0 and ref[i - 1])
    ref[:5] = ref[n - 5 :] = False
    assert np.array_equal(lost, ref)
    assert not np.any(lost[1:] & lost[:-1]) and not lost[:5].any() and not lost[-5:].any()
    assert abs(lost.mean() - f) < 4 * np.sqrt(f * (1 - f) / n) + 1e-4, lost.mean()
    assert stamps[0] == t[0] and np.all(np.abs(stamps - t[keep]) <= 0.45 * period + 1e-12)

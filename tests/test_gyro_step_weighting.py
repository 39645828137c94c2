"""Rule 19: the anchored filter integrates each gyro sample over its own time step (a lost sample keeps its
rotation; jittered stamps are no gyro scale error), live and offline alike; regular stamps: bit for bit as
without it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from tests.conftest import broad_trial
from tests.test_anchor import _live
from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF
from tepinn_flight.model.anchor_kernels import step_weight
from tepinn_flight.model.checkpoint import default_model_path, estimator_settings, load_model, read_checkpoint
from tepinn_flight.model.estimate import estimate_anchored
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.record import FlightRecord

Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]


def test_the_weight_is_the_step_over_the_period_clamped():
    assert step_weight(0.02, 0.01, 2.5) == pytest.approx(2.0)
    assert step_weight(0.013, 0.01, 2.5) == pytest.approx(1.3)
    assert step_weight(0.05, 0.01, 2.5) == 2.5  # beyond GAP_PERIODS: a gap, never integrated as one sample
    assert step_weight(-0.001, 0.01, 2.5) == 0.0  # a step back: no rotation
    assert step_weight(0.01 * (1 + 1e-9), 0.01, 2.5) == 1.0  # the stamps' rounding: exactly one period
    assert step_weight(math.nan, 0.01, 2.5) == 1.0  # a segment's first sample


def _rolling(rate_hz=100.0, duration_s=30.0, roll_rate_rad_s=1.0, lose=0.0, jitter=0.0, seed=0):
    """A vehicle rolling at a constant rate about its x axis, its accelerometer reading gravity alone
    (closed-form truth by scipy); about ``lose`` of the samples lost at random, one at a time (steps of two periods),
    stamps jittered by N(0, (``jitter`` period)²) around the true sample times."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration_s, 1.0 / rate_hz)
    rot = Rotation.from_rotvec(np.outer(roll_rate_rad_s * t, [1.0, 0.0, 0.0]))  # body → NED
    acc = rot.inv().apply([0.0, 0.0, -9.81])
    keep = np.ones(len(t), bool)
    lost = rng.random(len(t)) < lose
    lost[:60] = False
    lost[1:] &= ~lost[:-1]  # single samples (two in a row make a gap: a new segment at ingest, bridged)
    keep[lost] = False
    stamps = t + np.clip(rng.normal(0.0, jitter / rate_hz, len(t)), -0.45 / rate_hz, 0.45 / rate_hz)
    q = rot.as_quat(scalar_first=True)
    d = {"t_s": stamps, "segment": np.zeros(len(t), np.int64), "clipped": np.zeros(len(t), bool)}
    for i, ax in enumerate("xyz"):
        d[f"gyr_{ax}_rad_s"] = np.full(len(t), [roll_rate_rad_s, 0.0, 0.0][i])
        d[f"acc_{ax}_m_s2"] = acc[:, i]
        d[f"mag_{ax}_ut"] = np.full(len(t), np.nan)
    for i, c in enumerate("wxyz"):
        d[f"q_ref_{c}"] = q[:, i]
    return FlightRecord(pd.DataFrame(d)[keep].reset_index(drop=True), {"source_kind": "synthetic"})


def _rmse_deg(rec, q, warmup_s=5.0):
    m = rec.t_s >= warmup_s
    return float(np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(q[m], rec.q_ref_wxyz[m])) ** 2))))


def _filter_only(on: bool) -> AnchorConfig:
    return dataclasses.replace(AnchorConfig().learned_off, gyro_step_weighting=on)


def _filter_errors(rec, ts: float) -> dict:
    """{weighting on?: the filter alone's inclination RMSE (deg) from 5 s} with VQF's period ``ts``."""
    errs = {}
    for on in (False, True):
        q, _, _, _ = AnchoredVQF(_filter_only(on), ts).update(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)
        errs[on] = _rmse_deg(rec, q)
    return errs


@pytest.mark.parametrize("lose", [0.05, 0.2])
def test_a_lost_sample_keeps_its_rotation(lose):
    # the filter alone (every learned part off): integrated over one fixed period, each lost sample's
    # rotation is lost (the tilt lags the roll by about lose × rate × VQF's time constant); over its own step,
    # a constant rate is integrated exactly
    rec = _rolling(lose=lose)
    assert np.max(np.diff(rec.t_s)) > 1.9 / 100.0
    errs = _filter_errors(rec, 1.0 / 100.0)
    assert errs[True] < 0.05
    assert errs[False] > 20 * errs[True] and errs[False] > 1.0


def test_jittered_stamps_are_no_gyro_scale_error():
    # samples regular, stamps jittered: the period the filter takes (the median of its first steps) is off by
    # percents; each sample over its own step, the turn over any stretch is the stamps' span times the rate
    rec = _rolling(jitter=0.2, seed=3)
    dts = np.diff(rec.t_s[:52])
    ts = float(np.median(dts))
    assert abs(ts * 100.0 - 1.0) > 0.01  # the premise: this median is more than 1 % off
    errs = _filter_errors(rec, ts)
    assert errs[True] < 0.2
    assert errs[False] > 5 * errs[True]


def test_the_offline_smoothing_integrates_over_each_step_too():
    model, shipped, _ = load_model(default_model_path())
    rec = _rolling(lose=0.1, seed=1)
    base = dataclasses.replace(shipped, gyro_selfcal=False, gnss_aid=False, accel_scale_selfcal=False)
    assert base.smoother and base.gyro_step_weighting
    on = estimate_anchored(model, rec, base)
    off = estimate_anchored(model, rec, dataclasses.replace(base, gyro_step_weighting=False))
    assert "applied" in on.attrs["smoother"]
    assert _rmse_deg(rec, on[Q].to_numpy()) < 0.05
    assert _rmse_deg(rec, off[Q].to_numpy()) > 1.0


def test_regular_stamps_are_bit_for_bit_as_without_it():
    from tepinn_flight.ingest import ingest_log

    model, shipped, _ = load_model(default_model_path())
    assert shipped.gyro_step_weighting
    for rec in (synthetic_record(seed=7, duration_s=20.0, rate_hz=400.0), ingest_log(broad_trial("broad_06_*.hdf5"))):
        a = estimate_anchored(model, rec, shipped)
        b = estimate_anchored(model, rec, dataclasses.replace(shipped, gyro_step_weighting=False))
        np.testing.assert_array_equal(a[Q].to_numpy(), b[Q].to_numpy())
        np.testing.assert_array_equal(a["sigma_rad"].to_numpy(), b["sigma_rad"].to_numpy())


def test_live_equals_offline_with_lost_samples_and_jittered_stamps():
    model, shipped, _ = load_model(default_model_path())
    rec = synthetic_record(seed=5, duration_s=20.0, rate_hz=100.0)
    rng = np.random.default_rng(5)
    d = rec.data.copy()
    d["t_s"] = d["t_s"] + np.clip(rng.normal(0.0, 0.002, len(d)), -0.002, 0.002)
    lost = rng.random(len(d)) < 0.03
    lost[:80] = False
    lost[1:] &= ~lost[:-1]  # one at a time: steps up to 2.4 periods, inside the segment
    keep = ~lost
    rec = FlightRecord(d[keep].reset_index(drop=True), dict(rec.meta))
    cfg = dataclasses.replace(shipped, smoother=False, gnss_aid=False, gyro_selfcal=False, accel_scale_selfcal=False,
                              speed_lo_m_s=0.0, speed_hi_m_s=1e-3)  # every gate on: all of it exercised
    off = estimate_anchored(model, rec, cfg)[Q].to_numpy()
    q_live = _live(model, cfg, rec)
    have = np.all(np.isfinite(q_live), 1)
    assert have.sum() > len(rec) - 60
    np.testing.assert_allclose(q_live[have], off[have], atol=1e-6)
    unweighted = estimate_anchored(model, rec, dataclasses.replace(cfg, gyro_step_weighting=False))[Q].to_numpy()
    assert np.abs(unweighted - off)[have].max() > 1e-3


def test_checkpoints_written_before_it_run_without_it():
    ck = read_checkpoint(default_model_path())
    assert ck["anchor_config"]["gyro_step_weighting"] is True
    del ck["anchor_config"]["gyro_step_weighting"]
    assert estimator_settings(ck).gyro_step_weighting is False
    assert AnchorConfig().learned_off.gyro_step_weighting is False  # plain VQF


def test_evaluate_says_where_samples_were_lost_and_how_the_estimators_differ_there():
    # 5 % of a rolling record's samples lost: the record's row counts them, a note says what sets TE-PINN and VQF
    # apart there, and the scores show it (VQF integrates over one period)
    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.evaluation.harness import evaluate
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.evaluation.report_html import RECORD_COLUMNS, record_rows

    rec = _rolling(lose=0.05, seed=2)
    rec.meta.update(imu_rate_hz=100.0, reference_source="synthetic-truth")
    steps = np.diff(rec.t_s) * 100.0
    want = int(np.sum((steps > 1.5) & (steps < 2.5)))
    assert want > 50
    res = evaluate([rec], [TepinnEstimator.from_checkpoint(default_model_path(), "tepinn"), VqfEstimator()], progress=False)
    r = res.records[0]
    assert r["lost_samples"] == want
    assert any(f"{want} sample(s) lost one at a time" in n for n in res.notes)
    assert f"({want} lost one at a time)" in record_rows(res)[0][RECORD_COLUMNS.index("samples")]
    incl = {k: v["inclination_rmse_deg"] for k, v in r["results"].items()}
    assert incl["tepinn"] < 0.05 and incl["vqf"] > 1.0
